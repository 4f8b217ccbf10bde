#include "server/publisher.h"

#include <algorithm>
#include <chrono>
#include <filesystem>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/io/durable_file.h"
#include "server/crash_point.h"
#include "server/job_tracker.h"
#include "server/metrics.h"
#include "spdlog/spdlog.h"

namespace clnerf {

Publisher::Publisher(const PublisherOptions& options)
    : options_(options),
      registry_([this](int64_t v) { return LoadServable(v); }, options.models, options.place) {}

absl::StatusOr<std::unique_ptr<Publisher>> Publisher::Open(const PublisherOptions& options) {
  std::error_code ec;
  std::filesystem::create_directories(options.store_dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create store '", options.store_dir, "': ", ec.message()));
  if (const int n = RemoveAtomicWriteTemps((std::filesystem::path(options.store_dir) / "manifest.json").string())) {
    spdlog::info("removed {} manifest temporary file(s) left by an interrupted write", n);
  }
  std::unique_ptr<Publisher> p(new Publisher(options));
  absl::StatusOr<std::unique_ptr<VersionStore>> versions = VersionStore::Open(options.store_dir);
  if (!versions.ok()) return versions.status();
  p->versions_ = *std::move(versions);
  // A manifest that cannot be parsed is not a write error: refusing to start
  // is safer than guessing the id counters.
  absl::StatusOr<Manifest> m = p->versions_->ReadManifest();
  if (!m.ok()) return m.status();
  p->manifest_ = *m;
  std::lock_guard<std::mutex> lock(p->mu_);
  p->opening_ = !options.verify_deployed_at_open;
  if (absl::Status s = p->RecoverLocked(); !s.ok()) p->SetErrorLocked(s);
  p->opening_ = false;
  return p;
}

absl::StatusOr<std::shared_ptr<const Servable>> Publisher::LoadServable(int64_t version) const {
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<LoadedVersion> lv = versions_->Load(version);
  if (options_.metrics != nullptr) {
    if (lv.ok()) {
      options_.metrics->ModelLoaded(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    } else {
      options_.metrics->ModelLoadFailed();
    }
  }
  if (!lv.ok()) return lv.status();
  auto s = std::make_shared<Servable>();
  s->info = lv->info;
  s->state.model = std::make_shared<const NgpModel>(std::move(lv->model));
  s->state.memory = std::move(lv->memory);
  return std::shared_ptr<const Servable>(std::move(s));
}

absl::Status Publisher::UnloadableDeployed(int64_t version, const absl::Status& why) {
  return absl::Status(why.code(), absl::StrCat("deployed version ", version, " cannot be loaded (", why.message(),
                                               "); deploy another version (clnerf rollback VERSION) to resume updates"));
}

absl::Status Publisher::VerifyDeployed() {
  const int64_t v = registry_.deployed_version();
  if (v == 0 || registry_.loaded(v)) return absl::OkStatus();
  absl::StatusOr<std::shared_ptr<const Servable>> s = LoadServable(v);
  std::lock_guard<std::mutex> lock(mu_);
  if (registry_.deployed_version() != v) return absl::OkStatus();  // Replaced meanwhile.
  if (!s.ok()) {
    registry_.ClearDeployed(v);
    const absl::Status error = UnloadableDeployed(v, s.status());
    SetErrorLocked(error);
    return error;
  }
  registry_.Offer(*s);
  return absl::OkStatus();
}

absl::Status Publisher::RecoverLocked() {
  absl::StatusOr<Manifest> disk = versions_->ReadManifest();
  if (!disk.ok()) return disk.status();
  // Counters only grow; the disk is never behind what was acknowledged.
  Manifest m = *disk;
  m.next_scan = std::max(m.next_scan, manifest_.next_scan);
  m.next_job = std::max(m.next_job, manifest_.next_job);
  m.next_version = std::max(m.next_version, manifest_.next_version);
  absl::StatusOr<std::vector<VersionInfo>> all = versions_->List();
  if (!all.ok()) return all.status();
  for (const VersionInfo& v : *all) {
    if (!v.unavailable.empty()) spdlog::warn("version {} is unavailable: {}", v.version, v.unavailable);
    // Its number is taken even so: never hand it out again.
    m.next_version = std::max(m.next_version, v.version + 1);
  }
  // Only versions whose metadata reads can be finished or deployed.
  all->erase(std::remove_if(all->begin(), all->end(), [](const VersionInfo& v) { return !v.unavailable.empty(); }),
             all->end());
  // A version written after the manifest's last update passed its gate but
  // was not recorded (a crash, or a failed manifest write): finish it.
  if (!all->empty() && all->back().version >= disk->next_version) {
    if (all->back().version != m.deployed) {
      spdlog::warn("recovery: version {} was written but not recorded; deploying it", all->back().version);
    }
    m.deployed = all->back().version;
    m.next_version = std::max(m.next_version, all->back().version + 1);
  }
  // Record what is known before anything can fail, so no version number is
  // handed out twice.
  manifest_.next_version = m.next_version;
  if (m.deployed != 0 && registry_.deployed_version() != m.deployed) {
    if (opening_) {  // Metadata only; VerifyDeployed (or the first use) loads it.
      absl::StatusOr<VersionInfo> info = versions_->Info(m.deployed);
      if (!info.ok()) return UnloadableDeployed(m.deployed, info.status());
      registry_.DeployUnloaded(*info);
    } else {
      absl::StatusOr<std::shared_ptr<const Servable>> s = LoadServable(m.deployed);
      if (!s.ok()) return UnloadableDeployed(m.deployed, s.status());
      registry_.Deploy(*s, /*keep_loaded=*/false);  // Verified; stays loaded only if the budget has room.
    }
  }
  if (absl::Status s = versions_->WriteManifest(m); !s.ok()) {
    return absl::Status(s.code(), absl::StrCat("cannot write the manifest: ", s.message()));
  }
  manifest_ = m;
  spdlog::info("store {}: deployed version {}, {} version(s)", options_.store_dir, m.deployed, all->size());
  return absl::OkStatus();
}

void Publisher::SetErrorLocked(const absl::Status& s) {
  last_check_ = std::chrono::steady_clock::now();
  if (bg_error_.ok()) spdlog::error("store is read-only until it recovers: {}", std::string(s.message()));
  bg_error_ = s;
}

void Publisher::SetErrorForTesting(const absl::Status& s) {
  std::lock_guard<std::mutex> lock(mu_);
  SetErrorLocked(s);
}

void Publisher::MaybeRetryLocked() {
  if (bg_error_.ok()) return;
  if (std::chrono::steady_clock::now() - last_check_ < std::chrono::duration<double>(options_.retry_seconds)) return;
  (void)RetryLocked();
}

absl::Status Publisher::WritableStatus() {
  std::lock_guard<std::mutex> lock(mu_);
  MaybeRetryLocked();
  return RefusalLocked();
}

absl::Status Publisher::RefusalLocked() const {
  if (bg_error_.ok()) return absl::OkStatus();
  return absl::UnavailableError(absl::StrCat("the store refuses writes after an error: ", bg_error_.message(),
                                             " (renders of stored versions still work; writes resume once the "
                                             "store recovers)"));
}

std::string Publisher::error() const {
  std::lock_guard<std::mutex> lock(mu_);
  return std::string(bg_error_.message());
}

absl::Status Publisher::Retry() {
  std::lock_guard<std::mutex> lock(mu_);
  return RetryLocked();
}

absl::Status Publisher::RetryLocked() {
  if (bg_error_.ok()) return absl::OkStatus();
  last_check_ = std::chrono::steady_clock::now();
  absl::Status s = RecoverLocked();
  if (!s.ok()) {
    bg_error_ = s;
    return s;
  }
  spdlog::info("store recovered; writes resume");
  bg_error_ = absl::OkStatus();
  return absl::OkStatus();
}

absl::StatusOr<ReservedIds> Publisher::ReserveIds() {
  std::lock_guard<std::mutex> lock(mu_);
  MaybeRetryLocked();
  if (absl::Status s = RefusalLocked(); !s.ok()) return s;
  Manifest next = manifest_;
  ReservedIds ids{absl::StrFormat("scan-%06d", next.next_scan++), absl::StrFormat("job-%06d", next.next_job++)};
  // Counters first, so an id is never reused even if saving the scan fails.
  if (absl::Status s = versions_->WriteManifest(next); !s.ok()) {
    SetErrorLocked(absl::Status(s.code(), absl::StrCat("cannot write the manifest: ", s.message())));
    return s;
  }
  manifest_ = next;
  return ids;
}

absl::StatusOr<VersionInfo> Publisher::Publish(const ContinualState& state, int64_t parent, const Origin& origin,
                                               const std::map<std::string, double>& metrics) {
  std::lock_guard<std::mutex> lock(mu_);
  if (absl::Status s = RefusalLocked(); !s.ok()) return s;
  VersionInfo info;
  info.version = manifest_.next_version;
  info.parent = parent;
  info.time_steps = state.model->num_time_steps();
  info.created_unix_ms = NowUnixMs();
  info.scan_id = origin.scan_id;
  info.scan_name = origin.scan_name;
  info.job_id = origin.job_id;
  info.metrics = metrics;
  absl::StatusOr<VersionInfo> written = versions_->Write(*state.model, state.memory, info);
  if (!written.ok()) {
    // Nothing was left behind; the caller may publish the same state again
    // once Retry() succeeds.
    SetErrorLocked(written.status());
    return written.status();
  }
  CrashPoint("publish:version-written");
  // The version is durable from here on: it is deployed now, and recovery
  // deploys it on the next start even if the manifest cannot be updated.
  manifest_.next_version = info.version + 1;
  auto servable = std::make_shared<Servable>();
  servable->info = *written;
  servable->state.model = state.model;
  servable->state.memory = state.memory;
  registry_.Deploy(std::move(servable));
  Manifest m = manifest_;
  m.deployed = info.version;
  if (absl::Status s = versions_->WriteManifest(m); !s.ok()) {
    SetErrorLocked(absl::Status(s.code(), absl::StrCat("version ", info.version,
                                                       " is published but the manifest could not be updated: ",
                                                       s.message())));
    return *written;
  }
  CrashPoint("publish:manifest-written");
  manifest_ = m;
  PruneLocked();
  return *written;
}

absl::StatusOr<VersionInfo> Publisher::SetDeployed(int64_t v) {
  if (v <= 0) return absl::InvalidArgumentError(absl::StrCat("version ", v, " is not a version number"));
  absl::StatusOr<std::shared_ptr<const Servable>> s = registry_.Get(v);
  if (!s.ok()) return s.status();
  std::lock_guard<std::mutex> lock(mu_);
  Manifest next = manifest_;
  next.deployed = v;
  if (absl::Status w = versions_->WriteManifest(next); !w.ok()) {
    SetErrorLocked(absl::Status(w.code(), absl::StrCat("cannot write the manifest: ", w.message())));
    return w;
  }
  manifest_ = next;
  registry_.Deploy(*s);
  if (!bg_error_.ok()) {
    spdlog::info("store recovered (version {} deployed, manifest written); writes resume", v);
    bg_error_ = absl::OkStatus();
  }
  return (*s)->info;
}

void Publisher::PruneLocked() {
  if (options_.keep_versions <= 0) return;
  absl::StatusOr<std::vector<VersionInfo>> all = versions_->List();
  if (!all.ok()) return;
  int excess = int(all->size()) - options_.keep_versions;
  for (const VersionInfo& v : *all) {
    if (excess <= 0) break;
    if (v.version == manifest_.deployed) continue;
    if (absl::Status s = versions_->Remove(v.version); !s.ok()) {
      spdlog::warn("pruning version {}: {}", v.version, s.ToString());
      continue;
    }
    registry_.Evict(v.version);
    spdlog::info("pruned version {} (keep_versions = {})", v.version, options_.keep_versions);
    --excess;
  }
}

}  // namespace clnerf
