// Publisher: the single writer of published state. It owns the version store,
// the manifest (deployed version and id counters) and the model registry
// that renders read from, and it is the only code that changes them:
//
//   Recover        at start-up: finish a publish that crashed between the
//                  version and the manifest, load the deployed version
//   ReserveIds     scan and job ids for an upload (counters persisted first)
//   Publish        write versions/N -> manifest -> deploy -> prune
//   SetDeployed    rollback / pin
//
// Sticky background error (as LevelDB's bg_error_): when a write of the
// manifest or of a version fails (a full disk, a read-only mount, ...) or the
// deployed version cannot be loaded, the publisher records the error and
// refuses every later write with UNAVAILABLE naming it, instead of letting
// later jobs train and fail one by one or reuse a version number. Renders of
// stored versions keep working. Retry() re-checks the store and clears the
// error once the manifest can be written again and the deployed version
// loads; a successful SetDeployed also clears it.
//
// Thread-safety: every method is thread-safe; one mutex serialises writes
// (readers use the registry's snapshots and never wait for it).
#ifndef CLNERF_SERVER_PUBLISHER_H_
#define CLNERF_SERVER_PUBLISHER_H_

#include <chrono>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/continual/continual_update.h"
#include "server/cluster/coordinator.h"
#include "server/store/model_registry.h"
#include "server/store/version_store.h"

namespace clnerf {

class Metrics;
class Coordinator;

struct PublisherOptions {
  std::string store_dir;
  // The loaded models of every place (model_registry.h); null: a cache of
  // this publisher's own with no budget.
  std::shared_ptr<ServableCache> models;
  std::string place = "default";  // For the cache's keys and logs.
  // Replicas sharing the store (coordinator.h; null or local = a single
  // server): the deployed pointer is the coordinator's head of `place`,
  // version numbers and ids come from it, and a publish is a fenced commit.
  std::shared_ptr<Coordinator> coordinator;
  // Open loads the deployed version to check it (true), or only reads its
  // metadata and leaves the load to VerifyDeployed or its first use (false:
  // a server of many places starts serving without loading them all).
  bool verify_deployed_at_open = true;
  int keep_versions = 0;    // Versions kept on disk (0 = all; the deployed one is never pruned).
  double retry_seconds = 5;  // While the sticky error is set, writers re-check the store this often.
  Metrics* metrics = nullptr;  // Counts model loads (optional; must outlive the publisher).
};

struct ReservedIds {
  std::string scan_id, job_id;
};

class Publisher {
 public:
  // Opens the store and runs recovery. Only an unusable store directory is
  // an error; a store that cannot be written (or whose deployed version is
  // corrupt) opens with the sticky error set, serving what it can.
  static absl::StatusOr<std::unique_ptr<Publisher>> Open(const PublisherOptions& options);

  ModelRegistry& registry() { return registry_; }
  const ModelRegistry& registry() const { return registry_; }
  VersionStore& versions() { return *versions_; }

  // OK, or UNAVAILABLE naming the sticky error. While the error is set, a
  // call at least retry_seconds after the last check runs Retry() first, so
  // the store recovers by itself once space returns.
  absl::Status WritableStatus();
  // The sticky error's message ("" when healthy), for info and health.
  std::string error() const;

  absl::StatusOr<ReservedIds> ReserveIds();
  // Where a version came from: the scan and the job that trained it.
  struct Origin {
    std::string scan_id, scan_name, job_id;
    std::vector<std::string> frame_names;  // Its training frames, in camera order.
  };
  // Publishes θ_t and M_t trained from `parent` (0 = none) on `origin`'s scan.
  // Replicated: `fence` is the head read when the update started (SyncToHead);
  // the version is written staged, committed only if this replica still
  // holds the place's lease and the head has not moved (ABORTED otherwise,
  // and nothing is left behind), then promoted to versions/N.
  // `baked` (optional): the new version's asset for the browser, written
  // beside it before it is deployed (VersionStore::WriteBaked); a failure
  // to write it is logged and does not stop the publish.
  absl::StatusOr<VersionInfo> Publish(const ContinualState& state, int64_t parent, const Origin& origin,
                                      const std::map<std::string, double>& metrics, const PlaceHead* fence = nullptr,
                                      const BakedAsset* baked = nullptr);

  // Replicas: whether this store is shared through a coordinator.
  bool replicated() const { return replicated_; }
  // Replicas: reads the place's head and follows it (below); returns it.
  absl::StatusOr<PlaceHead> SyncToHead();
  // Replicas: makes `head` the deployed version if it is not already: it is
  // loaded beside the old one and swapped in if the old one was in memory,
  // else only recorded (it loads on first use). A committed version whose
  // promotion a crash interrupted is promoted first.
  absl::Status FollowHead(const PlaceHead& head);
  // Replicas: the version that holds scan `scan_id`, if any.
  std::optional<VersionInfo> VersionOfScan(const std::string& scan_id);
  // The optimiser state stored with `version` (null: none; VersionStore).
  absl::StatusOr<std::shared_ptr<const OptimizerState>> LoadOptimizer(int64_t version) const;
  // NOT_FOUND for an unknown version, DATA_LOSS for a corrupt one.
  absl::StatusOr<VersionInfo> SetDeployed(int64_t version);
  // Loads the deployed version if it is not in memory; if it cannot be
  // loaded, sets the sticky error (as Open does with verify_deployed_at_open)
  // and nothing is deployed until another version is. Keeps it loaded only if
  // the memory budget has room. Returns the error, if any.
  absl::Status VerifyDeployed();
  // Re-checks the store after a sticky error (see above). OK = healthy now.
  absl::Status Retry();

  // For tests: sets the sticky error as a failed write would.
  void SetErrorForTesting(const absl::Status& s);

 private:
  explicit Publisher(const PublisherOptions& options);
  absl::StatusOr<std::shared_ptr<const Servable>> LoadServable(int64_t version) const;
  // Recovery steps; caller holds mu_.
  absl::Status RecoverLocked();
  static absl::Status UnloadableDeployed(int64_t version, const absl::Status& why);
  // Promotes the staged directory `head` was committed from, if version
  // head.version is not on disk yet. Caller holds mu_.
  absl::Status FinishCommittedLocked(const PlaceHead& head);
  // After a publish: `state`'s optimiser (if it carries one) becomes the
  // place's, tagged with `version` (a failure only costs the next resume).
  void StoreOptimizerLocked(const ContinualState& state, int64_t version);
  void WriteBakedLocked(const BakedAsset* baked, int64_t version, const std::string& staged_tag);
  absl::StatusOr<VersionInfo> PublishReplicatedLocked(const ContinualState& state, const VersionInfo& info,
                                                      const PlaceHead& fence, const BakedAsset* baked);
  absl::Status RetryLocked();
  void MaybeRetryLocked();  // RetryLocked() if retry_seconds passed.
  void SetErrorLocked(const absl::Status& s);
  // OK, or UNAVAILABLE naming the sticky error; caller holds mu_.
  absl::Status RefusalLocked() const;
  void PruneLocked();

  const PublisherOptions options_;
  std::unique_ptr<VersionStore> versions_;
  ModelRegistry registry_;
  mutable std::mutex mu_;
  Manifest manifest_;        // As last written (or read).
  bool opening_ = false;     // In Open: the deployed version may be left unloaded.
  const bool replicated_;
  std::string replica_tag_;  // Part of staged directory names: unique per process.
  int64_t head_generation_ = 0;  // Newest head seen (replicated); guarded by mu_.
  absl::Status bg_error_;    // Sticky; guarded by mu_.
  std::chrono::steady_clock::time_point last_check_;  // Of the store, while bg_error_ is set.
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_PUBLISHER_H_
