// Places: every place of one store. A place (a room, a shop, a floor) has its
// own scans, job history, versions, manifest and deployed model, in its own
// directory, served by its own ModelHost with today's guarantees (durable
// before ack, crash recovery, poison-scan parking, sticky store errors). The
// gRPC service and the HTTP API look a place up here by name and call its
// host; the empty name means the place "default", which always exists, so
// clients from before places keep working.
//
// Store layout:
//   STORE/manifest.json, versions/, scans/, jobs.json
//                           the place "default", where the single-place
//                           server kept its files: a store it wrote opens as
//                           the place "default" with no migration step
//   STORE/places/NAME/...   every other place (place_name.h rules; a
//                           directory named "default" there is ignored)
// Deleting a place renames its directory to STORE/places/.deleted-NAME-N
// (atomic; such names cannot be place names), syncs, then removes it; a
// leftover from a crash is removed at the next start.
//
// Shared by all places: the training slots (max_concurrent_trainings, taken
// in turn: training_scheduler.h), the render slots (render_concurrency) and
// the metrics (one registry, no per-place labels).
//
// Start-up: Open reads each place's manifest and version metadata only, so a
// store of many places answers at once (readiness does not wait for models);
// a background warm-up then loads and checks each deployed model in turn,
// keeping them while the memory budget has room. A model that cannot load
// makes its place read-only, as the single-place server did at start.
//
// Thread-safety: every method is thread-safe. Hosts are handed out as
// shared_ptr, so a request in flight keeps its place's host alive while the
// place is deleted.
#ifndef CLNERF_SERVER_PLACES_H_
#define CLNERF_SERVER_PLACES_H_

#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "server/common/metrics.h"
#include "server/places/model_host.h"
#include "server/server_options.h"

namespace clnerf {

class Places {
 public:
  static absl::StatusOr<std::unique_ptr<Places>> Open(const ServerOptions& options);
  ~Places();
  Places(const Places&) = delete;
  Places& operator=(const Places&) = delete;

  // The host of place `name` ("" = default). INVALID_ARGUMENT for a name that
  // cannot be a place, NOT_FOUND (naming the known places) for an unknown one.
  absl::StatusOr<std::shared_ptr<ModelHost>> Get(std::string_view name) const;
  std::shared_ptr<ModelHost> Default() const;
  // Creates an empty place. ALREADY_EXISTS if it exists.
  absl::StatusOr<std::shared_ptr<ModelHost>> Create(std::string_view name);
  // Stops the place's update (its queued scans are dropped with it) and
  // removes its directory durably. FAILED_PRECONDITION for "default".
  absl::Status Delete(std::string_view name);
  // Every place, sorted by name.
  std::vector<std::string> Names() const;

  Metrics& metrics() const { return *shared_.metrics; }
  // The loaded models of every place, under --model-memory-budget.
  const ServableCache& models() const { return *shared_.models; }
  const ServerOptions& options() const { return options_; }
  bool shutting_down() const;
  // Shuts every place's host down; false if any worker did not stop in time.
  bool Shutdown();

 private:
  Places(const ServerOptions& options, SharedServices shared);
  void FollowReplicas();
  std::string DirOf(const std::string& name) const;
  // ALREADY_EXISTS when a place (here or in the store) has `name` in
  // another case ("Default" beside "default"): it would confuse the viewer's
  // picker and collide on case-insensitive volumes. Needs mu_.
  absl::Status RefuseCaseTwin(const std::string& name) const;
  absl::StatusOr<std::shared_ptr<ModelHost>> OpenHost(const std::string& name) const;
  void WarmUp(const std::vector<std::string>& names);

  const ServerOptions options_;
  const SharedServices shared_;
  std::string places_dir_;
  mutable std::mutex mu_;        // Guards hosts_ and serialises create/delete.
  // The places opened so far. The store's directories are the record of
  // which exist (replicas sharing the store create and delete them): Get and
  // Names open and drop hosts to match, hence mutable.
  mutable std::map<std::string, std::shared_ptr<ModelHost>> hosts_;
  bool shut_down_ = false;
  int deletions_ = 0;
  std::thread warmup_;    // Loads the deployed models after Open (WarmUp).
  std::thread follower_;  // Replicas only: FollowReplicas.
  std::condition_variable stop_cv_;  // Wakes the follower at Shutdown.
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_PLACES_H_
