#include "server/places/places.h"

#include <unistd.h>

#include <filesystem>
#include <set>
#include <system_error>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "core/io/durable_file.h"
#include "server/common/log_util.h"
#include "server/places/place_name.h"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace fs = std::filesystem;

namespace {
constexpr char kDeletedPrefix[] = ".deleted-";
}  // namespace

namespace {

absl::StatusOr<SharedServices> MakeSharedServices(const ServerOptions& options) {
  SharedServices s;
  s.metrics = std::make_shared<Metrics>();
  if (options.etcd.empty()) {
    s.coordinator = MakeLocalCoordinator();
  } else {
    EtcdCoordinatorOptions eo;
    eo.endpoint = options.etcd;
    eo.prefix = options.etcd_prefix;
    eo.lease_ttl_seconds = options.lease_ttl_seconds;
    eo.metrics = s.metrics.get();
    absl::StatusOr<std::unique_ptr<Coordinator>> c = MakeEtcdCoordinator(eo);
    if (!c.ok()) return c.status();
    s.coordinator = std::shared_ptr<Coordinator>(*std::move(c));
    spdlog::info("replica {}: coordinating through etcd at {} (prefix {}, lease {} s)", s.coordinator->replica_id(),
                 options.etcd, options.etcd_prefix, options.lease_ttl_seconds);
  }
  s.trainings = std::make_shared<TrainingScheduler>(options.max_concurrent_trainings);
  s.render_slots = std::make_shared<RenderSlots>(options.render_concurrency);
  s.models = MakeServableCache(ResolvedModelMemoryBudget(options), s.metrics);
  s.assets = std::make_shared<AssetFiles>(options.asset_memory_budget, s.metrics);
  s.defer_model_load = true;  // Warm-up (below) loads them after the ports open.
  return s;
}

}  // namespace

Places::Places(const ServerOptions& options, SharedServices shared)
    : options_(options),
      shared_(std::move(shared)),
      places_dir_((fs::path(options.store_dir) / "places").string()) {}

Places::~Places() { Shutdown(); }

absl::StatusOr<std::unique_ptr<Places>> Places::Open(const ServerOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  absl::StatusOr<SharedServices> shared = MakeSharedServices(options);
  if (!shared.ok()) return shared.status();
  std::unique_ptr<Places> p(new Places(options, *std::move(shared)));
  std::error_code ec;
  fs::create_directories(p->places_dir_, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create '", p->places_dir_, "': ", ec.message()));
  // "default" lives at the store's root, where the single-place server kept
  // its files: such a store opens as the place "default" as it is.
  std::vector<std::string> names = {std::string(kDefaultPlace)};
  for (const fs::directory_entry& e : fs::directory_iterator(p->places_dir_, ec)) {
    const std::string name = e.path().filename().string();
    if (absl::StartsWith(name, kDeletedPrefix)) {  // A deletion a crash interrupted.
      fs::remove_all(e.path(), ec);
      if (ec) spdlog::warn("cannot remove '{}': {}", EscapeForLog(e.path().string()), ec.message());
      continue;
    }
    if (!e.is_directory()) continue;
    if (!ValidatePlaceName(name).ok() || name == kDefaultPlace) {
      spdlog::warn("ignoring '{}' in {}: not a place name", EscapeForLog(name), p->places_dir_);
      continue;
    }
    names.push_back(name);
  }
  if (ec) return absl::InternalError(absl::StrCat("cannot list '", p->places_dir_, "': ", ec.message()));
  for (const std::string& name : names) {
    absl::StatusOr<std::shared_ptr<ModelHost>> host = p->OpenHost(name);
    if (!host.ok()) return absl::Status(host.status().code(), absl::StrCat("place '", name, "': ", host.status().message()));
    p->hosts_[name] = *std::move(host);
  }
  spdlog::info("store {}: {} place(s)", options.store_dir, p->hosts_.size());
  p->warmup_ = std::thread([raw = p.get(), names] { raw->WarmUp(names); });
  if (p->shared_.coordinator->replicated()) p->follower_ = std::thread([raw = p.get()] { raw->FollowReplicas(); });
  return p;
}

std::string Places::DirOf(const std::string& name) const {
  if (name == kDefaultPlace) return options_.store_dir;
  return (fs::path(places_dir_) / name).string();
}

absl::StatusOr<std::shared_ptr<ModelHost>> Places::OpenHost(const std::string& name) const {
  ServerOptions o = options_;
  o.store_dir = DirOf(name);
  absl::StatusOr<std::unique_ptr<ModelHost>> host = ModelHost::Open(o, shared_, name);
  if (!host.ok()) return host.status();
  return std::shared_ptr<ModelHost>(*std::move(host));
}

absl::StatusOr<std::shared_ptr<ModelHost>> Places::Get(std::string_view name) const {
  const std::string n = PlaceOrDefault(name);
  if (absl::Status s = ValidatePlaceName(n); !s.ok()) return s;
  std::shared_ptr<ModelHost> gone;  // Deleted by another replica: shut down outside the lock.
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = hosts_.find(n);
    // The store is the record of which places exist: another replica sharing
    // it may have created or deleted this one since we looked.
    const bool on_disk = n == kDefaultPlace || fs::is_directory(DirOf(n));
    if (it != hosts_.end() && on_disk) return it->second;
    if (it == hosts_.end() && on_disk && !shut_down_) {
      absl::StatusOr<std::shared_ptr<ModelHost>> host = OpenHost(n);
      if (!host.ok()) return host.status();
      hosts_[n] = *host;
      spdlog::info("opened place '{}' (created by another replica)", n);
      return *host;
    }
    if (it != hosts_.end()) {
      gone = it->second;
      hosts_.erase(it);
    }
  }
  if (gone) {
    spdlog::info("place '{}' was deleted by another replica", n);
    gone->MarkDeleted();
    gone->Shutdown();
  }
  std::vector<std::string> known = Names();
  return UnknownPlace(n, known);
}

std::shared_ptr<ModelHost> Places::Default() const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = hosts_.find(std::string(kDefaultPlace));
  return it == hosts_.end() ? nullptr : it->second;
}

absl::Status Places::RefuseCaseTwin(const std::string& name) const {
  const std::string lower = absl::AsciiStrToLower(name);
  std::vector<std::string> names;
  for (const auto& [other, host] : hosts_) names.push_back(other);
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(places_dir_, ec)) names.push_back(e.path().filename().string());
  for (const std::string& other : names) {
    if (other != name && absl::AsciiStrToLower(other) == lower) {
      return absl::AlreadyExistsError(absl::StrCat("place '", name, "' differs from the place '", other,
                                                   "' only by case; names are compared ignoring case"));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<std::shared_ptr<ModelHost>> Places::Create(std::string_view name) {
  const std::string n(name);
  if (absl::Status s = ValidatePlaceName(n); !s.ok()) return s;
  std::lock_guard<std::mutex> lock(mu_);
  if (shut_down_) return absl::UnavailableError("server is shutting down");
  if (hosts_.count(n) > 0) return absl::AlreadyExistsError(absl::StrCat("place '", n, "' already exists"));
  if (absl::Status s = RefuseCaseTwin(n); !s.ok()) return s;
  const std::string dir = DirOf(n);
  std::error_code ec;
  if (!fs::create_directory(dir, ec) && !ec && !fs::is_empty(dir, ec)) {
    return absl::AlreadyExistsError(absl::StrCat("a directory for place '", n, "' already exists in the store"));
  }
  if (ec) return absl::InternalError(absl::StrCat("cannot create place '", n, "': ", ec.message()));
  if (absl::Status s = SyncDirectory(places_dir_); !s.ok()) return s;
  absl::StatusOr<std::shared_ptr<ModelHost>> host = OpenHost(n);
  if (!host.ok()) return host.status();
  hosts_[n] = *host;
  spdlog::info("created place '{}'", n);
  return *host;
}

absl::Status Places::Delete(std::string_view name) {
  const std::string n(name);
  if (absl::Status s = ValidatePlaceName(n); !s.ok()) return s;
  if (n == kDefaultPlace) {
    return absl::FailedPreconditionError("the place 'default' cannot be deleted (requests without a place use it)");
  }
  if (absl::StatusOr<std::shared_ptr<ModelHost>> h = Get(n); !h.ok()) return h.status();  // Also one made elsewhere.
  std::shared_ptr<ModelHost> host;
  std::string trash;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = hosts_.find(n);
    if (it == hosts_.end()) {
      std::vector<std::string> known;
      for (const auto& [k, v] : hosts_) known.push_back(k);
      return UnknownPlace(n, known);
    }
    host = it->second;
    hosts_.erase(it);
    trash = (fs::path(places_dir_) / absl::StrCat(kDeletedPrefix, n, "-", getpid(), "-", ++deletions_)).string();
  }
  // Stop its update first (a request in flight keeps the host object, but
  // no new scan is trained), then take the directory away atomically.
  host->MarkDeleted();
  host->Shutdown();
  std::error_code ec;
  fs::rename(DirOf(n), trash, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot remove place '", n, "': ", ec.message()));
  if (absl::Status s = SyncDirectory(places_dir_); !s.ok()) return s;
  fs::remove_all(trash, ec);
  if (ec) spdlog::warn("place '{}' deleted; removing its files: {}", n, ec.message());
  if (absl::Status s = shared_.coordinator->Forget(n); !s.ok()) spdlog::warn("place '{}': {}", n, s.ToString());
  spdlog::info("deleted place '{}'", n);
  return absl::OkStatus();
}

std::vector<std::string> Places::Names() const {
  // Places created or deleted by other replicas sharing the store.
  std::set<std::string> on_disk = {std::string(kDefaultPlace)};
  std::error_code ec;
  for (const fs::directory_entry& e : fs::directory_iterator(places_dir_, ec)) {
    const std::string name = e.path().filename().string();
    if (e.is_directory(ec) && name != kDefaultPlace && ValidatePlaceName(name).ok()) on_disk.insert(name);
  }
  std::set<std::string> open;
  {
    std::lock_guard<std::mutex> lock(mu_);
    for (const auto& [k, v] : hosts_) open.insert(k);
  }
  if (!ec && on_disk != open) {
    for (const std::string& n : on_disk) {
      if (!open.count(n)) (void)Get(n);
    }
    for (const std::string& n : open) {
      if (!on_disk.count(n)) (void)Get(n);
    }
  }
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<std::string> names;
  for (const auto& [k, v] : hosts_) names.push_back(k);
  return names;
}

bool Places::shutting_down() const {
  std::lock_guard<std::mutex> lock(mu_);
  return shut_down_;
}

// Loads and checks each place's deployed model in turn, while the server
// already answers: a model that cannot load makes its place read-only (as a
// check at open would), and models stay loaded while the budget has room.
void Places::WarmUp(const std::vector<std::string>& names) {
  const auto t0 = std::chrono::steady_clock::now();
  int checked = 0;
  for (const std::string& name : names) {
    std::shared_ptr<ModelHost> host;
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (shut_down_) return;
      auto it = hosts_.find(name);
      if (it == hosts_.end()) continue;  // Deleted meanwhile.
      host = it->second;
    }
    if (absl::Status s = host->VerifyDeployed(); !s.ok()) {
      spdlog::error("place '{}': {}", name, std::string(s.message()));
    }
    ++checked;
  }
  spdlog::info("warm-up: checked {} place(s) in {:.2f} s; {} model(s), {} bytes in memory", checked,
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
               shared_.models->stats().entries, shared_.models->stats().bytes);
}

// Replicas: every replica_poll_seconds, one read of every place's head from
// the coordinator, then each place follows it and the store (new places,
// scans uploaded elsewhere, versions deployed elsewhere).
void Places::FollowReplicas() {
  while (true) {
    {
      std::unique_lock<std::mutex> lock(mu_);
      stop_cv_.wait_for(lock, std::chrono::duration<double>(options_.replica_poll_seconds), [&] { return shut_down_; });
      if (shut_down_) return;
    }
    absl::StatusOr<std::map<std::string, PlaceHead>> heads = shared_.coordinator->ReadHeads();
    if (!heads.ok()) {
      spdlog::warn("replica: cannot read the places' heads: {}", heads.status().ToString());
      continue;
    }
    for (const std::string& name : Names()) {
      absl::StatusOr<std::shared_ptr<ModelHost>> host = Get(name);
      if (!host.ok()) continue;
      auto it = heads->find(name);
      (*host)->FollowReplicas(it == heads->end() ? std::nullopt : std::optional<PlaceHead>(it->second));
    }
  }
}

bool Places::Shutdown() {
  std::map<std::string, std::shared_ptr<ModelHost>> hosts;
  {
    std::lock_guard<std::mutex> lock(mu_);
    shut_down_ = true;
    hosts = hosts_;
  }
  stop_cv_.notify_all();
  if (follower_.joinable() && follower_.get_id() != std::this_thread::get_id()) follower_.join();
  if (warmup_.joinable() && warmup_.get_id() != std::this_thread::get_id()) warmup_.join();
  bool clean = true;
  for (auto& [name, host] : hosts) clean = host->Shutdown() && clean;
  return clean;
}

}  // namespace clnerf
