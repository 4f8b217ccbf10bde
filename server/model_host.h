// ModelHost: the service's core, without any gRPC. It owns the store (scans,
// versions, manifest), the model registry, the job tracker and the single
// update worker thread, and offers what the RPCs need:
//
//   AcceptScan   validate -> write durably -> queue a job -> acknowledge
//   worker       load scan -> ContinualUpdate(S_t, θ_{t-1}, M_{t-1}) ->
//                deployment gate -> write version -> manifest -> swap
//   Render       snapshot (shared_ptr<const Servable>) -> bounded render slot
//   versions, rollback, jobs, cancel, info
//
// Startup recovery: a version written but not yet in the manifest is
// deployed (its gate had passed); scans already trained into a version are
// removed; every other stored scan is re-queued in upload order with its
// original job id. So a crash at any point loses no acknowledged scan.
//
// Time steps: a scan becomes time step (deployed model's steps) when its job
// starts; the acknowledgement predicts it assuming every earlier job
// succeeds. A rollback makes the next job train on top of the rolled-back
// version; a job already running keeps the parent it started from.
//
// Thread-safety: all public methods are thread-safe. Shutdown() (also run by
// the destructor) cancels a running update (its scan stays stored and is
// retrained after restart) and joins the worker.
#ifndef CLNERF_SERVER_MODEL_HOST_H_
#define CLNERF_SERVER_MODEL_HOST_H_

#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <optional>
#include <semaphore>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "core/camera.h"
#include "core/image.h"
#include "server/job_tracker.h"
#include "server/model_registry.h"
#include "server/scan_store.h"
#include "server/server_options.h"
#include "server/version_store.h"

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

struct HostInfo {
  int64_t deployed_version = 0;
  int time_steps = 0;
  int queued_jobs = 0;
  std::string running_job;
  int64_t model_bytes = 0;
  int64_t replay_cameras = 0;
  double uptime_seconds = 0;
};

class ModelHost {
 public:
  static absl::StatusOr<std::unique_ptr<ModelHost>> Open(const ServerOptions& options);
  ~ModelHost();
  ModelHost(const ModelHost&) = delete;
  ModelHost& operator=(const ModelHost&) = delete;

  absl::StatusOr<UploadAck> AcceptScan(const ScanUpload& upload);

  // `time_step` unset = the version's latest; `version` 0 = deployed.
  absl::StatusOr<RenderResult> Render(const Camera& world_camera, std::optional<int> time_step,
                                      int64_t version);

  absl::StatusOr<JobStatus> GetJob(const std::string& id) const { return jobs_.Get(id); }
  std::vector<JobStatus> ListJobs() const { return jobs_.List(); }
  absl::StatusOr<JobStatus> WaitJob(const std::string& id, uint64_t after_revision,
                                    std::chrono::steady_clock::time_point deadline) const {
    return jobs_.WaitForChange(id, after_revision, deadline);
  }
  absl::StatusOr<JobStatus> CancelJob(const std::string& id);

  absl::StatusOr<std::vector<VersionInfo>> ListVersions() const { return versions_->List(); }
  absl::StatusOr<VersionInfo> GetVersion(int64_t v) const { return versions_->Info(v); }
  // Rollback / pin. NOT_FOUND for an unknown version.
  absl::StatusOr<VersionInfo> SetDeployedVersion(int64_t v);
  int64_t deployed_version() const { return registry_.deployed_version(); }

  HostInfo Info() const;
  const ServerOptions& options() const { return options_; }
  bool shutting_down() const { return stopping_.load(); }
  void Shutdown();

 private:
  explicit ModelHost(const ServerOptions& options);
  absl::Status Recover();
  // The time step a scan queued now becomes if every job ahead succeeds.
  int PredictedTimeStep() const;
  void WorkerLoop();
  void RunJob(const std::string& job_id);
  void FinishJob(const std::string& job_id, const std::string& scan_id, JobPhase phase, const std::string& error,
                 bool remove_scan);
  absl::StatusOr<std::shared_ptr<const Servable>> LoadServable(int64_t version) const;
  void PruneVersions();  // Applies keep_versions; caller holds manifest_mu_.

  const ServerOptions options_;
  const std::chrono::steady_clock::time_point started_;
  std::unique_ptr<ScanStore> scans_;
  std::unique_ptr<VersionStore> versions_;
  ModelRegistry registry_;
  JobTracker jobs_;

  std::mutex manifest_mu_;  // Guards manifest_ and its file; serialises uploads.
  Manifest manifest_;

  std::counting_semaphore<1024> render_slots_;
  std::atomic<bool> stopping_{false};
  std::atomic<bool> cancel_running_{false};
  std::thread worker_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_MODEL_HOST_H_
