#include "server/store/publisher.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <random>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/io/durable_file.h"
#include "server/common/crash_point.h"
#include "server/common/metrics.h"
#include "server/common/unix_time.h"
#include "spdlog/spdlog.h"

namespace clnerf {

Publisher::Publisher(const PublisherOptions& options)
    : options_(options),
      registry_([this](int64_t v) { return LoadServable(v); }, options.models, options.place),
      replicated_(options.coordinator != nullptr && options.coordinator->replicated()),
      replica_tag_(absl::StrFormat("%d-%08x", getpid(), uint32_t(std::random_device{}()))) {}

absl::StatusOr<std::unique_ptr<Publisher>> Publisher::Open(const PublisherOptions& options) {
  std::error_code ec;
  std::filesystem::create_directories(options.store_dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create store '", options.store_dir, "': ", ec.message()));
  std::unique_ptr<Publisher> p(new Publisher(options));
  // Replicas may be writing into a shared store right now: leave temporaries
  // alone there (a crash leaves at most a few small ones).
  if (!p->replicated_) {
    if (const int n = RemoveAtomicWriteTemps((std::filesystem::path(options.store_dir) / "manifest.json").string())) {
      spdlog::info("removed {} manifest temporary file(s) left by an interrupted write", n);
    }
  }
  absl::StatusOr<std::unique_ptr<VersionStore>> versions = VersionStore::Open(options.store_dir, !p->replicated_);
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

namespace {

// A version just published from `state` (shares its model and memory).
std::shared_ptr<const Servable> MakeServable(const VersionInfo& info, const ContinualState& state) {
  auto servable = std::make_shared<Servable>();
  servable->info = info;
  servable->state.model = state.model;
  servable->state.memory = state.memory;
  return servable;
}

}  // namespace

absl::StatusOr<std::shared_ptr<const OptimizerState>> Publisher::LoadOptimizer(int64_t version) const {
  return versions_->LoadOptimizer(version);
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
  if (replicated_) {
    // The head in the coordinator is the deployed pointer; the first replica
    // to open a place starts it from the store's own record.
    absl::StatusOr<PlaceHead> head = options_.coordinator->ReadHead(options_.place);
    if (head.ok() && head->generation == 0) head = options_.coordinator->InitHead(options_.place, m.deployed);
    if (!head.ok()) return head.status();
    if (absl::Status s = FinishCommittedLocked(*head); !s.ok()) return s;
    m.deployed = head->version;
    m.next_version = std::max(m.next_version, head->version + 1);
    head_generation_ = std::max(head_generation_, head->generation);
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
  if (replicated_) {  // Unique across the replicas; the manifest's counters are only a floor.
    absl::StatusOr<int64_t> n =
        options_.coordinator->NextId(options_.place, std::max(manifest_.next_scan, manifest_.next_job));
    if (!n.ok()) return absl::UnavailableError(absl::StrCat("cannot reserve an id: ", n.status().message()));
    return ReservedIds{absl::StrFormat("scan-%06d", *n), absl::StrFormat("job-%06d", *n)};
  }
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

void Publisher::WriteBakedLocked(const BakedAsset* baked, int64_t version, const std::string& staged_tag) {
  if (baked == nullptr) return;
  if (absl::Status s = versions_->WriteBaked(version, baked->time_step, *baked, staged_tag); !s.ok()) {
    spdlog::warn("version {}: its baked asset was not stored ({}); it is baked again when a viewer asks",
                 version, s.ToString());
  }
}

absl::StatusOr<VersionInfo> Publisher::Publish(const ContinualState& state, int64_t parent, const Origin& origin,
                                               const std::map<std::string, double>& metrics, const PlaceHead* fence,
                                               const BakedAsset* baked) {
  std::lock_guard<std::mutex> lock(mu_);
  if (absl::Status s = RefusalLocked(); !s.ok()) return s;
  VersionInfo info;
  info.version = manifest_.next_version;
  if (replicated_) {
    if (fence == nullptr) return absl::InternalError("a replicated publish needs the head its update started from");
    info.version = std::max(info.version, fence->version + 1);
    if (absl::StatusOr<std::vector<VersionInfo>> all = versions_->List(); all.ok() && !all->empty()) {
      info.version = std::max(info.version, all->back().version + 1);  // Another replica's, or a rolled-back one.
    }
  }
  info.parent = parent;
  info.time_steps = state.model->num_time_steps();
  info.created_unix_ms = NowUnixMs();
  info.scan_id = origin.scan_id;
  info.scan_name = origin.scan_name;
  info.job_id = origin.job_id;
  info.frame_names = origin.frame_names;
  info.metrics = metrics;
  if (replicated_) return PublishReplicatedLocked(state, info, *fence, baked);
  absl::StatusOr<VersionInfo> written = versions_->Write(*state.model, state.memory, info);
  if (!written.ok()) {
    // Nothing was left behind; the caller may publish the same state again
    // once Retry() succeeds.
    SetErrorLocked(written.status());
    return written.status();
  }
  CrashPoint("publish:version-written");
  WriteBakedLocked(baked, info.version, "");
  // The version is durable from here on: it is deployed now, and recovery
  // deploys it on the next start even if the manifest cannot be updated.
  manifest_.next_version = info.version + 1;
  registry_.Deploy(MakeServable(*written, state));
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
  StoreOptimizerLocked(state, info.version);
  PruneLocked();
  return *written;
}

absl::StatusOr<VersionInfo> Publisher::PublishReplicatedLocked(const ContinualState& state, const VersionInfo& info,
                                                               const PlaceHead& fence, const BakedAsset* baked) {
  versions_->RemoveStaged(info.version, replica_tag_);  // A leftover of this process's earlier attempt.
  absl::StatusOr<VersionInfo> written = versions_->WriteStaged(*state.model, state.memory, info, replica_tag_);
  if (!written.ok()) {
    SetErrorLocked(written.status());
    return written.status();
  }
  WriteBakedLocked(baked, info.version, replica_tag_);
  CrashPoint("publish:staged");
  // The fenced commit: only while this replica holds the place's lease and
  // the head is where this update started. Refused: nothing stays behind.
  absl::StatusOr<PlaceHead> head = options_.coordinator->CommitHead(options_.place, fence, info.version, replica_tag_);
  if (!head.ok()) {
    versions_->RemoveStaged(info.version, replica_tag_);
    return head.status();
  }
  CrashPoint("publish:committed");
  head_generation_ = std::max(head_generation_, head->generation);
  manifest_.next_version = info.version + 1;
  absl::Status promoted = versions_->PromoteStaged(info.version, replica_tag_);
  if (!promoted.ok() && !absl::IsAlreadyExists(promoted)) promoted = FinishCommittedLocked(*head);
  if (absl::Status s = promoted; !s.ok()) {
    SetErrorLocked(absl::Status(s.code(), absl::StrCat("version ", info.version, " is committed but could not be moved "
                                                       "into place: ", s.message())));
    return s;
  }
  registry_.Deploy(MakeServable(*written, state));
  Manifest m = manifest_;
  m.deployed = info.version;
  // The head is the record; the manifest is a local copy (best effort).
  if (absl::Status s = versions_->WriteManifest(m); s.ok()) {
    manifest_ = m;
  } else {
    spdlog::warn("version {} is published; the manifest copy was not updated: {}", info.version, s.ToString());
  }
  StoreOptimizerLocked(state, info.version);
  PruneLocked();
  return *written;
}

void Publisher::StoreOptimizerLocked(const ContinualState& state, int64_t version) {
  if (state.optimizer == nullptr) return;
  if (absl::Status s = versions_->WriteOptimizer(version, *state.optimizer); !s.ok()) {
    spdlog::warn("version {} is published; its optimiser state was not stored (the next update starts a fresh "
                 "one): {}", version, s.ToString());
  }
}

absl::Status Publisher::FinishCommittedLocked(const PlaceHead& head) {
  if (head.version == 0) return absl::OkStatus();
  absl::StatusOr<VersionInfo> there = versions_->Info(head.version);
  if (there.ok() || !absl::IsNotFound(there.status())) return absl::OkStatus();  // On disk (a bad one is isolated).
  absl::Status s = head.tag.empty() ? absl::NotFoundError("no staged copy is named")
                                    : versions_->PromoteStaged(head.version, head.tag);
  if (s.ok()) {
    spdlog::warn("version {} was committed but not moved into place (a crash); promoted it", head.version);
    return absl::OkStatus();
  }
  if (absl::IsAlreadyExists(s) || versions_->Info(head.version).ok()) return absl::OkStatus();  // Another replica did.
  return absl::DataLossError(absl::StrCat("the deployed version ", head.version, " of place ", options_.place,
                                          " is not in the store: ", s.message()));
}

absl::StatusOr<PlaceHead> Publisher::SyncToHead() {
  if (!replicated_) return PlaceHead{registry_.deployed_version(), 0, ""};
  absl::StatusOr<PlaceHead> head = options_.coordinator->ReadHead(options_.place);
  if (!head.ok()) return head.status();
  if (absl::Status s = FollowHead(*head); !s.ok()) return s;
  return head;
}

absl::Status Publisher::FollowHead(const PlaceHead& head) {
  if (!replicated_) return absl::OkStatus();
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (head.generation < head_generation_) return absl::OkStatus();  // Older than what we know.
    head_generation_ = head.generation;
    if (head.version == 0 || head.version == registry_.deployed_version()) return absl::OkStatus();
    if (absl::Status s = FinishCommittedLocked(head); !s.ok()) return s;
  }
  absl::StatusOr<VersionInfo> info = versions_->Info(head.version);
  if (!info.ok()) return info.status();
  // Loaded here: load the new one beside it, then swap (no gap for renders).
  // Not loaded: record it; it loads on first use.
  std::shared_ptr<const Servable> loaded;
  if (registry_.loaded(0)) {
    absl::StatusOr<std::shared_ptr<const Servable>> s = LoadServable(head.version);
    if (!s.ok()) return s.status();
    loaded = *s;
  }
  std::lock_guard<std::mutex> lock(mu_);
  if (head.generation < head_generation_) return absl::OkStatus();
  if (loaded) {
    registry_.Deploy(loaded);
  } else {
    registry_.DeployUnloaded(*info);
  }
  manifest_.next_version = std::max(manifest_.next_version, head.version + 1);
  spdlog::info("place {}: now serving version {} (deployed by another replica)", options_.place, head.version);
  return absl::OkStatus();
}

std::optional<VersionInfo> Publisher::VersionOfScan(const std::string& scan_id) {
  absl::StatusOr<std::vector<VersionInfo>> all = versions_->List();
  if (!all.ok()) return std::nullopt;
  for (const VersionInfo& v : *all) {
    if (v.scan_id == scan_id && v.unavailable.empty()) return v;
  }
  return std::nullopt;
}

absl::StatusOr<VersionInfo> Publisher::SetDeployed(int64_t v) {
  if (v <= 0) return absl::InvalidArgumentError(absl::StrCat("version ", v, " is not a version number"));
  absl::StatusOr<std::shared_ptr<const Servable>> s = registry_.Get(v);
  if (!s.ok()) return s.status();
  if (replicated_) {
    // A rollback is a commit like a publish: under the place's lease.
    Coordinator& c = *options_.coordinator;
    const bool held = c.Holds(options_.place);
    if (!held) {
      absl::StatusOr<bool> took = c.TryAcquire(options_.place);
      if (!took.ok()) return took.status();
      if (!*took) {
        return absl::FailedPreconditionError(absl::StrCat("place ", options_.place, " is being updated by another "
                                                          "replica; deploy again when its update has finished"));
      }
    }
    absl::StatusOr<PlaceHead> head = c.ReadHead(options_.place);
    absl::StatusOr<PlaceHead> committed = head.ok() ? c.CommitHead(options_.place, *head, v, "") : head.status();
    if (!held) c.Release(options_.place);
    if (!committed.ok()) return committed.status();
    std::lock_guard<std::mutex> lock(mu_);
    head_generation_ = std::max(head_generation_, committed->generation);
  }
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
