// ModelHost: the service's core, without any gRPC. It composes the parts and
// offers what the RPCs need:
//
//   Publisher      versions, manifest, deployed model, sticky store error
//   ScanStore      the durable inbox of uploaded scans
//   JobTracker     job states, the FIFO queue, the persisted job history
//   UpdateWorker   load -> train -> gate -> publish, one job at a time
//   render slots   at most render_concurrency big renders at once (small
//                  ones skip the queue); adaptive threads per render
//
//   AcceptScan   validate -> write durably -> queue a job -> acknowledge
//   Render       snapshot (shared_ptr<const Servable>) -> bounded render slot
//   versions, rollback, jobs, cancel, info, scene summaries
//
// The gRPC service (grpc_service.h) and the HTTP API (http_api.h) are thin
// front ends over this class; neither calls the other.
//
// Start-up recovery: the publisher finishes a publish that crashed between
// the version and the manifest; a job whose version was published but whose
// DONE record a crash lost is restored from the version's metadata (so every
// acknowledged job id stays known); scans already trained into a version are
// removed; a scan whose training was interrupted max_scan_attempts times
// (crash, kill or hang) is parked with a FAILED job; every other stored scan
// is re-queued in upload order with its original job id. So a crash at any
// point loses no acknowledged scan, and a poison scan cannot wedge the
// server for good. A store that cannot be written starts read-only (renders
// work, writes answer UNAVAILABLE with the reason) and recovers by itself.
//
// Time steps: a scan becomes time step (deployed model's steps) when its job
// starts; the acknowledgement predicts it assuming every earlier job
// succeeds. A rollback makes the next job train on top of the rolled-back
// version; a job already running keeps the parent it started from.
//
// Thread-safety: all public methods are thread-safe. Shutdown() (also run by
// the destructor) cancels a running update (its scan stays stored and is
// retrained after restart) and stops the worker.
#ifndef CLNERF_SERVER_MODEL_HOST_H_
#define CLNERF_SERVER_MODEL_HOST_H_

#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <semaphore>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/pose/photo_localization.h"
#include "server/cluster/coordinator.h"
#include "server/jobs/job_tracker.h"
#include "server/places/asset_files.h"
#include "server/common/metrics.h"
#include "server/jobs/training_scheduler.h"
#include "server/store/model_registry.h"
#include "server/store/publisher.h"
#include "server/store/scan_store.h"
#include "server/store/scene_summary.h"
#include "server/server_options.h"
#include "server/jobs/update_worker.h"
#include "server/store/version_store.h"

namespace clnerf {

struct UploadAck {
  std::string scan_id, job_id;
  int time_step = 0;
  int64_t bytes = 0;
};

struct RenderResult {
  int64_t version = 0;
  int time_step = 0;
  Image image;
  double seconds = 0;
};

// The cameras a version was trained on (replay memory order: by time
// step, then training order), in the place's frame.
struct CameraList {
  int64_t version = 0;
  int time_steps = 0;
  std::vector<Camera> cameras;  // camera.time_step says whose.
  // Per camera, its frame's name ("" where the version's lineage did not
  // record names, e.g. stores from before they were).
  std::vector<std::string> names;
  std::vector<int> index;  // Per camera, its index within its time step.
};

// One file of a version's baked asset (issue 41; core/bake/baked_asset.h):
// what GET /api/asset serves. Versions are immutable, and so is each time
// step's asset once written: the same (version, time step, file) always has
// the same bytes and the same etag.
struct AssetFile {
  int64_t version = 0;
  int time_step = 0;
  std::string name;   // manifest.json, index.bin.gz, atlas.bin.gz or view.bin.gz.
  std::shared_ptr<const AssetBlob> blob;  // The bytes (index/atlas/view: gzip streams, sent as they are).
  std::string etag;   // Quoted, for ETag / If-None-Match.
  bool baked_now = false;  // This request baked the time step.
};

// Where photos were taken in the place's frame (core/pose/photo_localization.h).
struct LocalizeResult {
  int64_t version = 0;
  PhotoLocalizationReport report;
  double seconds = 0;
};

// The render slots of a server: at most render_concurrency big renders at
// once, across every place.
struct RenderSlots {
  explicit RenderSlots(int n) : slots(n) {}
  std::counting_semaphore<1024> slots;
  std::atomic<int> active{0};  // Big renders running now (small ones excluded).
};

// What the places of one server share (places.h). Null members: the host
// makes its own (a lone host, as in tests).
struct SharedServices {
  std::shared_ptr<Metrics> metrics;
  std::shared_ptr<TrainingScheduler> trainings;  // Null: this host trains whenever a job is queued.
  std::shared_ptr<RenderSlots> render_slots;
  // The loaded models of every place under --model-memory-budget (null: the
  // host makes its own with that budget).
  std::shared_ptr<ServableCache> models;
  // Open reads only the deployed version's metadata; VerifyDeployed() loads
  // and checks it later (Places does, in the background, so a server of
  // many places answers at once). false: Open loads it.
  bool defer_model_load = false;
  // Replicas sharing the store (coordinator.h); null: a single server.
  std::shared_ptr<Coordinator> coordinator;
  // Baked-asset files in memory under --asset-memory-budget (null: the host
  // makes its own with that budget).
  std::shared_ptr<AssetFiles> assets;
};

struct HostInfo {
  int64_t deployed_version = 0;
  int time_steps = 0;
  int queued_jobs = 0;
  std::string running_job;
  std::string store_error;  // The publisher's sticky error ("" = healthy).
  int64_t model_bytes = 0;     // The deployed model's parameter bytes.
  int64_t memory_bytes = 0;    // What it holds in memory when loaded (0 = not known until it loads).
  int64_t replay_cameras = 0;
  bool loaded = false;         // The deployed model is in memory now.
  double uptime_seconds = 0;
};

class ModelHost {
 public:
  // `shared`: what it shares with the other places of the server; `place`:
  // its name (for the training scheduler and logs).
  static absl::StatusOr<std::unique_ptr<ModelHost>> Open(const ServerOptions& options, SharedServices shared = {},
                                                         const std::string& place = "default");
  ~ModelHost();
  ModelHost(const ModelHost&) = delete;
  ModelHost& operator=(const ModelHost&) = delete;

  absl::StatusOr<UploadAck> AcceptScan(const ScanUpload& upload);
  // Counters of renders, uploads, updates and model loads (GET /metrics).
  Metrics& metrics() const { return *metrics_; }
  // OK, or why uploads are refused now (shutting down, store read-only).
  absl::Status WritableStatus() const;

  // `time_step` unset = the version's latest; `version` 0 = deployed.
  // `should_stop` (optional, thread-safe) is polled while waiting for a slot
  // and while rendering: the caller went away or its deadline passed. A
  // render it stopped is CANCELLED, or what `why_stopped` (optional) says
  // (e.g. DEADLINE_EXCEEDED), which is also the code the metrics count.
  absl::StatusOr<RenderResult> Render(const Camera& world_camera, std::optional<int> time_step, int64_t version,
                                      const std::function<bool()>& should_stop = {},
                                      const std::function<absl::Status()>& why_stopped = {});
  // The largest render one request may ask for.
  int64_t max_pixels_per_render() const;

  absl::StatusOr<JobStatus> GetJob(const std::string& id) const { return jobs_.Get(id); }
  std::vector<JobStatus> ListJobs() const { return jobs_.List(); }
  std::vector<JobStatus> ListJobs(size_t offset, size_t limit, size_t* total) const {
    return jobs_.List(offset, limit, total);
  }
  absl::StatusOr<JobStatus> WaitJob(const std::string& id, uint64_t after_revision,
                                    std::chrono::steady_clock::time_point deadline) const {
    return jobs_.WaitForChange(id, after_revision, deadline);
  }
  // Cancels a queued job (its scan is removed) or stops the running one.
  // With replicas, FAILED_PRECONDITION while another replica holds the
  // place's training lease (it may be running the job; a cancel here could
  // not stop it), UNAVAILABLE when the coordinator cannot be reached.
  absl::StatusOr<JobStatus> CancelJob(const std::string& id);

  absl::StatusOr<std::vector<VersionInfo>> ListVersions() const { return publisher_->versions().List(); }
  absl::StatusOr<VersionInfo> GetVersion(int64_t v) const { return publisher_->versions().Info(v); }
  // What a viewer needs to look around version `v` (0 = deployed): time
  // steps, the scans' cameras, up, a focus point. Errors as Render's.
  absl::StatusOr<SceneSummary> Scene(int64_t v) const;
  // Every trained camera of version `v` (0 = deployed). Errors as Render's.
  absl::StatusOr<CameraList> Cameras(int64_t v) const;
  // Localises `photos` against renders of version `v` (0 = deployed), in a
  // render slot (RESOURCE_EXHAUSTED when none frees up in time).
  absl::StatusOr<LocalizeResult> Localize(int64_t v, const std::vector<PhotoQuery>& photos,
                                          const std::function<bool()>& should_stop = {}) const;
  // File `file` of version `version`'s (0 = deployed) asset of `time_step`
  // (unset = the version's latest): stored when the version was published,
  // or baked now (a few seconds; bakes of one place run one at a time) and
  // kept beside the version. INVALID_ARGUMENT for another file name or a
  // time step out of range, NOT_FOUND for an unknown version, errors as
  // Render's otherwise; a failed bake is INTERNAL with its reason (the
  // viewer then shows server frames).
  absl::StatusOr<AssetFile> Asset(int64_t version, std::optional<int> time_step, const std::string& file);
  // Rollback / pin. NOT_FOUND for an unknown version.
  absl::StatusOr<VersionInfo> SetDeployedVersion(int64_t v);
  int64_t deployed_version() const { return publisher_->registry().deployed_version(); }

  HostInfo Info() const;
  // Replicas: follows `head` (the place's deployed version in the
  // coordinator, if it has one) and the store: scans uploaded through other
  // replicas become queued jobs here, and jobs whose scans another replica
  // trained (or removed) end as it did. Called every replica_poll_seconds by
  // Places. No-op for a single server.
  void FollowReplicas(const std::optional<PlaceHead>& head);
  // Loads the deployed version if it is not in memory; one that cannot load
  // makes the store read-only, as at start-up (publisher.h).
  absl::Status VerifyDeployed() { return publisher_->VerifyDeployed(); }
  const ServerOptions& options() const { return options_; }
  bool shutting_down() const { return stopping_.load(); }
  // What a request to a host that is shutting down gets: UNAVAILABLE while
  // the server stops (clients retry), NOT_FOUND once its place was deleted.
  absl::Status StoppedStatus() const;
  // Called by Places::Delete before Shutdown().
  void MarkDeleted();
  // Stops the worker (waiting up to shutdown_grace_seconds). Returns false if
  // it did not stop in time; the process should then exit (see main.cc).
  bool Shutdown();

  Publisher& publisher_for_testing() { return *publisher_; }

 private:
  ModelHost(const ServerOptions& options, SharedServices shared);
  // CancelJob once it may: dequeues (removing the scan) or stops the run.
  absl::StatusOr<JobStatus> CancelJobLocally(const std::string& id, const JobStatus& before);
  absl::Status RecoverScans();
  absl::StatusOr<UploadAck> AcceptScanImpl(const ScanUpload& upload);
  absl::StatusOr<RenderResult> RenderImpl(const Camera& world_camera, std::optional<int> time_step, int64_t version,
                                          const std::function<bool()>& should_stop);
  // Version `version` (0 = deployed) from the registry; UNAVAILABLE naming the
  // store error when nothing is deployed because the store failed.
  absl::StatusOr<std::shared_ptr<const Servable>> Snapshot(int64_t version) const;
  // The time step a scan queued now becomes if every job ahead succeeds.
  int PredictedTimeStep() const;
  // The queued job of a stored scan (its original ids, predicted time step).
  JobStatus QueuedJobFor(const ScanRecord& r) const;

  const ServerOptions options_;
  const std::chrono::steady_clock::time_point started_;
  const std::shared_ptr<Metrics> metrics_;  // Before the parts that report to it: destroyed after them.
  std::unique_ptr<Publisher> publisher_;
  std::unique_ptr<ScanStore> scans_;
  JobTracker jobs_;
  std::unique_ptr<UpdateWorker> worker_;
  std::mutex upload_mu_;  // Serialises uploads (id reservation, save, enqueue).
  std::mutex bake_mu_;    // Serialises bakes on request.
  int64_t followed_version_ = 0;  // Newest version FollowReplicas has seen; guarded by upload_mu_.
  const std::shared_ptr<TrainingScheduler> trainings_;
  const std::shared_ptr<RenderSlots> render_slots_;
  const std::shared_ptr<Coordinator> coordinator_;  // Null: a single server.
  const std::shared_ptr<AssetFiles> assets_;
  const int cores_;                     // For adaptive render threads.
  std::atomic<bool> stopping_{false};
  std::atomic<bool> deleted_{false};
  std::string place_;  // Its name; set once by Open.
  std::once_flag shutdown_once_;
  bool shutdown_clean_ = true;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_MODEL_HOST_H_
