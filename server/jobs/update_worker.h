// UpdateWorker: the single background thread that turns queued scans into
// published versions, one job at a time, in upload order:
//
//   wait until the store accepts writes -> record an attempt -> load the scan
//   -> ContinualUpdate(S_t, θ_{t-1}, M_{t-1}) -> deployment gate -> publish
//
// Each step is a short method; a failed step ends the job with its reason.
// Poison scans: an attempt is recorded durably before training and cleared
// when the job ends cleanly, so a scan whose training crashed, was killed or
// hung is seen at the next start (ModelHost parks it after
// ServerOptions::max_scan_attempts). A publish that fails on the store keeps
// the trained model and retries after the publisher recovers, so time steps
// stay in upload order and nothing is trained twice.
//
// Cancellation (CancelRunning, Stop) is checked in every long loop of the
// update: replay preparation (per block of rays), every training step, and
// while waiting for the store.
//
// Thread-safety: Start/Stop from one thread; CancelRunning from any.
#ifndef CLNERF_SERVER_UPDATE_WORKER_H_
#define CLNERF_SERVER_UPDATE_WORKER_H_

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>

#include "core/continual/continual_update.h"
#include "server/cluster/coordinator.h"
#include "server/jobs/job_tracker.h"
#include "server/store/model_registry.h"
#include "server/store/publisher.h"
#include "server/store/scan_store.h"
#include "server/server_options.h"

namespace clnerf {

class Metrics;
class TrainingScheduler;

// Ends `job` as DONE by version `v` (the one that holds its scan): its
// phase, version, time step and the version's metrics.
void MarkDoneBy(const VersionInfo& v, JobStatus* job);

class UpdateWorker {
 public:
  // `metrics` (optional) counts updates by outcome; it must outlive the worker.
  // `trainings` (optional) is the slot scheduler shared by every place's
  // worker: a queued job waits for a slot there (as `place`) before it
  // starts, and its phase stays QUEUED meanwhile.
  // `coordinator` (optional): with replicas (coordinator.h), a job starts
  // only while this replica holds the place's training lease, trains from
  // the head it read then, and publishes fenced by it; a fenced job goes
  // back to the queue (the lease's new holder trains its scan).
  UpdateWorker(const ServerOptions& options, ScanStore* scans, Publisher* publisher, JobTracker* jobs,
               Metrics* metrics = nullptr, TrainingScheduler* trainings = nullptr, std::string place = "default",
               Coordinator* coordinator = nullptr)
      : options_(options),
        scans_(scans),
        publisher_(publisher),
        jobs_(jobs),
        metrics_(metrics),
        trainings_(trainings),
        place_(std::move(place)),
        coordinator_(coordinator != nullptr && coordinator->replicated() ? coordinator : nullptr) {}
  ~UpdateWorker();
  UpdateWorker(const UpdateWorker&) = delete;
  UpdateWorker& operator=(const UpdateWorker&) = delete;

  void Start();
  // Asks the running update to stop (it ends CANCELLED; its scan is removed).
  void CancelRunning() { cancel_ = true; }
  // Stops the worker: the running update is cancelled (its scan stays stored
  // and is retrained after a restart) and the thread is joined. Returns false
  // if it did not stop within `timeout` (the thread is then left running; the
  // caller should exit the process).
  bool Stop(std::chrono::duration<double> timeout);
  // Before Stop() when the place is being deleted: jobs stopped then say so
  // instead of promising a retrain after restart.
  void PlaceDeleted() { place_deleted_ = true; }
  bool stopping() const { return stopping_.load(); }

 private:
  void Loop();
  void RunJob(const std::string& job_id);
  // RunJob's steps, each false / nullopt when the job ended (finished,
  // cancelled, stopped or requeued) and RunJob returns.
  // Whether the job runs at all: not done by another replica, not
  // cancelled, the store writable; records the attempt.
  bool ReadyToRun(const std::string& job_id, const JobStatus& job);
  // The deployed version the update starts from (null for a place's first
  // scan) and, with replicas, the head its publish is fenced by.
  bool LoadDeployed(const std::string& job_id, const std::string& scan_id, std::shared_ptr<const Servable>* prev,
                    PlaceHead* head);
  // The stored scan as the next time step, posed (unposed uploads) and
  // registered into the place's frame; posing and registration metrics
  // into `metrics`.
  std::optional<Scene> PrepareScan(const std::string& job_id, const std::string& scan_id, const Servable* prev,
                                   std::map<std::string, double>* metrics);
  // θ_t trained on `scene` from `prev` (ContinualUpdate), progress in the job.
  std::optional<ContinualState> Train(const std::string& job_id, const std::string& scan_id, const Servable* prev,
                                      const Scene& scene, UpdateReport* report);
  // Publishes θ_t, retrying store errors until the store recovers (fenced
  // publishes of replicas requeue the job instead).
  std::optional<VersionInfo> PublishUpdate(const std::string& job_id, const JobStatus& job, const Servable* prev,
                                           const PlaceHead& head, const ContinualState& next, const Scene& scene,
                                           const std::map<std::string, double>& metrics,
                                           const std::optional<BakedAsset>& baked);
  // Replicas: takes (or keeps) the place's lease; false if another holds it.
  bool HoldLease();
  // Sleeps replica_poll_seconds or until Stop(); false on Stop.
  bool Pause();
  // Blocks until the publisher accepts writes (retrying it every
  // store_retry_seconds) or Stop(); false on Stop.
  bool WaitForWritableStore(const std::string& job_id);
  // `outcome` for the metrics: "refused" for a gate refusal; otherwise
  // derived from the phase.
  void Finish(const std::string& job_id, const std::string& scan_id, JobPhase phase, const std::string& error,
              bool remove_scan, const char* outcome = nullptr);
  // Registers `scene` (the scan, with its test views) into the frame of
  // `prev` and moves it there (core/pose/registration.h), with the job in
  // phase REGISTERING. A scan that cannot be placed is parked and its job
  // ends FAILED ("place" scans train as uploaded instead). Returns false
  // when the job has ended; adds the registration's metrics to `metrics`.
  // Poses an unposed scan with structure from motion (ColmapSfm) in phase
  // POSING and stores the poses with it (ScanStore::SetPoses): the scan then
  // reads as posed in its own frame. A scan that cannot be posed ends its
  // job FAILED and is removed (nothing else changes). Returns false when
  // the job has ended; adds posing_* metrics to `metrics`.
  // `prev`: the place's deployed version, if any (its camera seeds COLMAP's).
  // Bakes the new version's latest time step for the browser in phase
  // BAKING (ServerOptions::bake_on_publish); nothing when baking is off or
  // fails (logged, bake_failed in `metrics`: the publish goes on). Adds
  // bake_* metrics to `metrics`.
  std::optional<BakedAsset> BakeForViewers(const std::string& job_id, const ContinualState& next,
                                           std::map<std::string, double>* metrics);
  bool PoseScan(const std::string& job_id, const ScanRecord& scan, const Servable* prev,
                std::map<std::string, double>* metrics);
  // `suspect`: training views the pose check disputed and left to the
  // place's map (CheckScanPoses): kept where it vouches for a pose
  // (pose_arbitration.h), removed otherwise.
  bool RegisterIntoPlace(const std::string& job_id, const std::string& scan_id, const Servable& prev,
                         std::set<std::string> suspect, Scene* scene, std::map<std::string, double>* metrics);
  // The scan's poses against its photos (ServerOptions::pose_check_action):
  // disputed frames logged, pose_check_* metrics added, and with "drop" (or
  // "auto" for a scan the service posed: `posed_here`) the disputed views
  // removed from `scene` (train and held out). With `suspect` (a later scan
  // the service posed, arbitration on) the disputed training views are put
  // there instead of removed, for RegisterIntoPlace.
  void CheckScanPoses(const std::string& job_id, bool posed_here, Scene* scene,
                      std::map<std::string, double>* metrics, std::set<std::string>* suspect);
  // After RegisterIntoPlace placed a scan the service posed: each frame
  // aligned photometrically to `map` (RefineScanPhotometric). False when the
  // job ended (cancelled).
  // `extent`: the place's size (PlaceExtent).
  bool AlignToPlace(const std::string& job_id, const std::string& scan_id, const PlaceMap& map, double extent,
                    Scene* scene, std::map<std::string, double>* metrics);
  // After RegisterIntoPlace placed a scan it did not pose by `reg` (not as
  // the identity): its whole similarity refined photometrically against
  // `map` (RefineSimilarityPhotometric) and applied when accepted, or the
  // scan put back as uploaded when the two land within a hair of the
  // identity (ApplyRefinedSimilarity). False when the job ended (cancelled).
  bool AlignSimilarityToPlace(const std::string& job_id, const std::string& scan_id, const PlaceMap& map,
                              double extent, const RegistrationReport& reg, Scene* scene,
                              std::map<std::string, double>* metrics);
  // Ends a job whose step saw its cancel flag: kept for a restart (or gone
  // with its place) when the server stops, "cancelled by request" otherwise.
  void FinishCancelled(const std::string& job_id, const std::string& scan_id);
  // The job stopped with the worker (shutdown or its place's deletion): the
  // scan is kept, the reason read now (StoppedWhy).
  void FinishStopped(const std::string& job_id, const std::string& scan_id);
  // A progress callback for a step counted in (done, total) units: fills
  // the job's iteration, total, elapsed and ETA from the step's start (now).
  std::function<void(int, int)> StepProgress(const std::string& job_id);

  const ServerOptions options_;
  ScanStore* const scans_;
  Publisher* const publisher_;
  JobTracker* const jobs_;
  Metrics* const metrics_;
  TrainingScheduler* const trainings_;
  const std::string place_;
  Coordinator* const coordinator_;  // Non-null only with replicas.
  std::chrono::steady_clock::time_point job_started_;  // Of the job RunJob runs (worker thread only).
  std::atomic<bool> cancel_{false};
  std::atomic<bool> stopping_{false};
  std::atomic<bool> place_deleted_{false};
  // Why a job stopped by Stop() ends: kept for a restart, or its place deleted.
  const char* StoppedWhy() const;
  std::mutex mu_;
  std::condition_variable cv_;  // Wakes store retries on Stop; signals exit.
  bool exited_ = false;         // Guarded by mu_.
  std::thread thread_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_UPDATE_WORKER_H_
