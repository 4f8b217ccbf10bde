#include "server/jobs/update_worker.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <optional>
#include <set>

#include "absl/strings/str_cat.h"
#include "core/continual/continual_update.h"
#include "core/continual/deployment_gate.h"
#include "core/data/image.h"
#include "core/pose/place_map.h"
#include "core/pose/pose_arbitration.h"
#include "core/pose/pose_check.h"
#include "core/pose/registration.h"
#include "core/pose/sfm.h"
#include "core/data/stopwatch.h"
#include "server/common/crash_point.h"
#include "server/common/log_util.h"
#include "server/common/metrics.h"
#include "server/jobs/training_scheduler.h"
#include "server/common/thread_priority.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {

// COLMAP's starting camera for a later scan of a place: the place's latest
// camera scaled to the photos' size (a rescan is usually taken with the
// same phone; COLMAP still refines it). None for a first scan, or when the
// photos' aspect differs from the camera's by more than 1 %.
std::optional<Intrinsics> PlaceCameraFor(const Servable* prev, const std::vector<std::string>& photos) {
  if (prev == nullptr || prev->memory().num_cameras() == 0 || photos.empty()) return std::nullopt;
  absl::StatusOr<ImageSize> size = ReadImageSize(photos.front());
  if (!size.ok() || size->width <= 0 || size->height <= 0) return std::nullopt;
  const Intrinsics in = prev->memory().GetCamera(prev->memory().num_cameras() - 1).intrinsics;
  if (in.width <= 0 || in.height <= 0) return std::nullopt;
  const double aspect = double(size->width) / size->height, place_aspect = double(in.width) / in.height;
  if (std::abs(aspect / place_aspect - 1) > 0.01) return std::nullopt;
  return in.Scaled(size->width, size->height);
}

JobPhase ToJobPhase(UpdatePhase p) {
  switch (p) {
    case UpdatePhase::kPreparingReplay: return JobPhase::kPreparingReplay;
    case UpdatePhase::kTraining: return JobPhase::kTraining;
    case UpdatePhase::kFinalizing: return JobPhase::kTraining;
  }
  return JobPhase::kTraining;
}

// Why a job stopped by shutdown ended: its scan stays for the next start.
constexpr const char* kKeptForRestart = "server shut down; the scan is kept and retrained after restart";
constexpr const char* kPlaceDeleted = "the place was deleted; its scans went with it";

// The frame the scan's poses are in, as its upload declared it ("own" when
// it cannot be read: registration then decides).
std::string PoseFrameOf(const ScanStore& scans, const std::string& scan_id) {
  absl::StatusOr<ScanRecord> r = scans.Record(scan_id);
  return r.ok() && r->pose_frame == "place" ? "place" : "own";
}

// The previous version's PSNR on its own new scan, measured as this gate
// will measure the new one (0 = unknown).
double PlacePsnr(const VersionInfo& prev, bool held_out) {
  auto it = prev.metrics.find(held_out ? "new_psnr" : "new_train_psnr");
  return it == prev.metrics.end() ? 0.0 : it->second;
}

// The scan's training frames' names, in the order ContinualUpdate records
// their cameras.
std::vector<std::string> FrameNames(const Scene& scene) {
  std::vector<std::string> names;
  for (const View& v : scene.train) names.push_back(v.name);
  return names;
}

// Rough seconds per SfM stage on 2 cores at about 480x270, from COLMAP 3.8
// runs (64 frames: features 16 s, sequential matching 40 s, 2,016
// exhaustive pairs 141 s, mapping 13 s): the first ETA, rescaled by how
// long the finished stages really took.
std::vector<double> SfmStageEstimate(int frames, bool sequential) {
  const double pairs = sequential ? 10.0 * frames : 0.5 * frames * (frames - 1);
  return {0.25 * frames, (sequential ? 0.063 : 0.07) * pairs, 0.2 * frames};
}

// A scan the service posed: frames whose SfM pose the place's map disputes
// move to their PnP pose (pose_arbitration.h), as "registration_*" metrics.
// `suspect` (training views the pose check disputed) are kept where the map
// vouches for them and removed otherwise (pose_check_dropped).
// `r` forgets the frames removed.
void ArbitrateFrames(const std::string& job_id, const PlaceMap& map, double extent, const ArbitrationOptions& o,
                     const std::set<std::string>& suspect, RegistrationReport* r, Scene* scene,
                     std::map<std::string, double>* metrics) {
  std::set<std::string> drop;
  absl::StatusOr<ArbitrationReport> a = ArbitrateRegisteredScan(map, extent, o, suspect, r, scene, &drop);
  if (!a.ok()) spdlog::warn("job {}: frame arbitration skipped: {}", job_id, a.status().ToString());
  if (!suspect.empty()) (*metrics)["pose_check_dropped"] = double(DropViewsNamed(drop, &scene->train));
  if (!a.ok()) return;
  if (!suspect.empty()) (*metrics)["pose_check_confirmed"] = a->confirmed;
  (*metrics)["registration_disputed_frames"] = a->disputed;
  (*metrics)["registration_frames_moved_to_pnp"] = a->taken;
  if (a->disputed > 0 || !suspect.empty()) spdlog::info("job {}: {} ({:.1f} s)", job_id, a->Summary(), a->seconds);
}

// A scan that could not be placed with the frames the pose check disputed
// (`why`) drops them, to be registered again without.
void DropSuspects(const std::string& job_id, const absl::Status& why, std::set<std::string>* suspect, Scene* scene,
                  std::map<std::string, double>* metrics) {
  spdlog::warn("job {}: not placed with the {} frames the pose check disputed ({}); again without them", job_id,
               suspect->size(), std::string(why.message()));
  (*metrics)["pose_check_dropped"] = double(DropViewsNamed(*suspect, &scene->train));
  suspect->clear();
}

}  // namespace

void MarkDoneBy(const VersionInfo& v, JobStatus* job) {
  job->phase = JobPhase::kDone;
  job->version = v.version;
  job->time_step = v.time_steps - 1;
  job->metrics = v.metrics;
  job->error.clear();
}

UpdateWorker::~UpdateWorker() {
  stopping_ = true;
  cancel_ = true;
  if (trainings_ != nullptr) trainings_->Wake();
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void UpdateWorker::Start() {
  thread_ = std::thread([this] {
    Loop();
    std::lock_guard<std::mutex> lock(mu_);
    exited_ = true;
    cv_.notify_all();
  });
}

bool UpdateWorker::Stop(std::chrono::duration<double> timeout) {
  stopping_ = true;
  cancel_ = true;
  jobs_->Shutdown();
  if (trainings_ != nullptr) trainings_->Wake();  // A wait for a training slot ends.
  cv_.notify_all();
  {
    std::unique_lock<std::mutex> lock(mu_);
    if (!cv_.wait_for(lock, timeout, [&] { return exited_ || !thread_.joinable(); })) return false;
  }
  if (thread_.joinable()) thread_.join();
  return true;
}

void UpdateWorker::Loop() {
  // Before the first parallel region, so the OpenMP team inherits it.
  if (options_.train_nice > 0) {
    if (absl::Status s = SetCurrentThreadNice(options_.train_nice); !s.ok()) {
      spdlog::warn("training keeps the renders' priority: {}", s.ToString());
    }
  }
  omp_set_num_threads(options_.train_threads);
  while (!stopping_) {
    if (trainings_ == nullptr && coordinator_ == nullptr) {  // Alone: train whatever is queued.
      std::optional<std::string> id = jobs_->WaitNext();
      if (!id) return;
      RunJob(*id);
      continue;
    }
    // The place's lease and a training slot shared with the other places
    // first; the job stays queued (and cancellable as such) until it has both.
    if (!jobs_->WaitQueued()) return;
    if (coordinator_ != nullptr && !HoldLease()) {  // Another replica trains this place now.
      if (!Pause()) return;
      continue;
    }
    if (trainings_ != nullptr && !trainings_->Acquire(place_, &stopping_)) return;
    std::optional<std::string> id = jobs_->TryNext();  // Cancelled meanwhile: none.
    if (id) RunJob(*id);
    if (trainings_ != nullptr) trainings_->Finish(place_);
    // Nothing more to train here: let any replica take the next upload.
    if (coordinator_ != nullptr && jobs_->queued() == 0) coordinator_->Release(place_);
  }
}

bool UpdateWorker::HoldLease() {
  absl::StatusOr<bool> held = coordinator_->TryAcquire(place_);
  if (!held.ok()) {
    spdlog::warn("place {}: cannot reach the coordinator: {}", place_, held.status().ToString());
    return false;
  }
  return *held;
}

bool UpdateWorker::Pause() {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait_for(lock, std::chrono::duration<double>(options_.replica_poll_seconds), [&] { return stopping_.load(); });
  return !stopping_;
}

bool UpdateWorker::WaitForWritableStore(const std::string& job_id) {
  while (true) {
    absl::Status s = publisher_->WritableStatus();
    if (s.ok()) return true;
    jobs_->Update(job_id, [&](JobStatus* j) { j->error = absl::StrCat("waiting for the store: ", s.message()); });
    std::unique_lock<std::mutex> lock(mu_);
    cv_.wait_for(lock, std::chrono::duration<double>(options_.store_retry_seconds), [&] { return stopping_.load(); });
    lock.unlock();
    if (stopping_) return false;
    if (publisher_->Retry().ok()) {
      jobs_->Update(job_id, [&](JobStatus* j) { j->error.clear(); });
      return true;
    }
  }
}

void UpdateWorker::Finish(const std::string& job_id, const std::string& scan_id, JobPhase phase,
                          const std::string& error, bool remove_scan, const char* outcome) {
  if (metrics_ != nullptr) {
    metrics_->UpdateDone(outcome != nullptr ? outcome : (phase == JobPhase::kFailed ? "failed" : "cancelled"),
                         SecondsSince(job_started_));
  }
  if (remove_scan) {
    if (absl::Status s = scans_->Remove(scan_id); !s.ok()) spdlog::warn("job {}: {}", job_id, s.ToString());
  } else {
    // Stopped cleanly (shutdown): this attempt does not count as a poison
    // attempt.
    scans_->ClearAttempts(scan_id);
  }
  jobs_->Update(job_id, [&](JobStatus* j) {
    j->phase = phase;
    j->error = error;
  });
  if (phase == JobPhase::kFailed) spdlog::error("job {} failed: {}", job_id, EscapeForLog(error));
  if (phase == JobPhase::kCancelled) spdlog::warn("job {} cancelled: {}", job_id, EscapeForLog(error));
}

const char* UpdateWorker::StoppedWhy() const { return place_deleted_ ? kPlaceDeleted : kKeptForRestart; }

void UpdateWorker::FinishStopped(const std::string& job_id, const std::string& scan_id) {
  Finish(job_id, scan_id, JobPhase::kCancelled, StoppedWhy(), false);
}

void UpdateWorker::FinishCancelled(const std::string& job_id, const std::string& scan_id) {
  if (stopping_) {
    FinishStopped(job_id, scan_id);
  } else {
    Finish(job_id, scan_id, JobPhase::kCancelled, "cancelled by request", true);
  }
}

std::function<void(int, int)> UpdateWorker::StepProgress(const std::string& job_id) {
  return [this, job_id, t0 = std::chrono::steady_clock::now()](int done, int total) {
    jobs_->Update(job_id, [&](JobStatus* j) {
      j->iteration = done;
      j->total_iterations = total;
      j->elapsed_seconds = SecondsSince(t0);
      j->eta_seconds = done > 0 ? j->elapsed_seconds * (total - done) / done : 0;
    });
  };
}

bool UpdateWorker::PoseScan(const std::string& job_id, const ScanRecord& scan, const Servable* prev,
                            std::map<std::string, double>* metrics) {
  absl::StatusOr<std::vector<std::string>> photos = scans_->ImageFiles(scan.scan_id);
  const std::vector<double> estimate =
      SfmStageEstimate(photos.ok() ? int(photos->size()) : 0, scan.sequential);
  const auto t0 = std::chrono::steady_clock::now();
  int stage = 0;
  auto report = [&](const std::string& name) {
    static const std::map<std::string, int> kIndex = {{"features", 0}, {"matching", 1}, {"mapping", 2}};
    stage = kIndex.count(name) ? kIndex.at(name) : stage;
    const double elapsed = SecondsSince(t0);
    double done = 0, left = 0;
    for (int i = 0; i < 3; ++i) (i < stage ? done : left) += estimate[i];
    const double scale = stage > 0 && done > 0 ? elapsed / done : 1.0;
    jobs_->Update(job_id, [&](JobStatus* j) {
      j->phase = JobPhase::kPosing;
      j->iteration = stage;
      j->total_iterations = 3;
      j->elapsed_seconds = elapsed;
      j->eta_seconds = left * scale;
    });
  };
  report("features");
  SfmOptions o = options_.posing;
  o.sequential = scan.sequential;
  o.threads = options_.train_threads;
  o.workspace = (std::filesystem::path(scans_->dir()).parent_path() / "posing" / scan.scan_id).string();
  o.initial_camera = PlaceCameraFor(prev, photos.ok() ? *photos : std::vector<std::string>{});
  std::error_code ec;
  std::filesystem::remove_all(o.workspace, ec);  // A crashed run's leftovers.
  absl::StatusOr<SfmResult> r = photos.ok() ? ColmapSfm(options_.colmap_binary).Run(*photos, o, report, &cancel_)
                                            : absl::StatusOr<SfmResult>(photos.status());
  if (r.ok()) {
    (*metrics)["posing_frames"] = double(photos->size());
    (*metrics)["posing_registered"] = r->registered;
    (*metrics)["posing_reprojection_px"] = r->mean_reprojection_px;
    (*metrics)["posing_seconds"] = SecondsSince(t0);
    // The one camera every posed frame shares, as the tool settled on it: a
    // self-calibration that drifted shows here first.
    const auto posed = std::find_if(r->cameras.begin(), r->cameras.end(),
                                    [](const std::optional<Camera>& c) { return c.has_value(); });
    const Intrinsics cam = posed != r->cameras.end() ? (*posed)->intrinsics : Intrinsics();
    const double focal = 0.5 * (cam.fx + cam.fy);
    (*metrics)["posing_focal_px"] = focal;
    (*metrics)["posing_k1"] = cam.k1;
    absl::Status s = scans_->SetPoses(scan.scan_id, r->cameras, r->points);
    if (s.ok()) {
      spdlog::info("job {}: posed {} of {} frames ({:.2f} px, focal {:.1f} px, k1 {:.3f}, {:.1f} s)", job_id,
                   r->registered, photos->size(), r->mean_reprojection_px, focal, cam.k1, SecondsSince(t0));
      return true;
    }
    r = s;
  }
  if (absl::IsCancelled(r.status())) {
    FinishCancelled(job_id, scan.scan_id);
    return false;
  }
  if (absl::IsFailedPrecondition(r.status())) {  // The photos themselves: nothing to keep.
    Finish(job_id, scan.scan_id, JobPhase::kFailed,
           absl::StrCat("FAILED_PRECONDITION: the scan could not be posed: ", r.status().message(),
                        "; nothing was trained or stored"),
           true, "refused");
    return false;
  }
  // The tool or the store (COLMAP missing, a disk error): keep the scan.
  const std::string why = absl::StrCat("posing failed: ", r.status().ToString());
  if (absl::Status s = scans_->Park(scan.scan_id, why); !s.ok()) spdlog::warn("job {}: {}", job_id, s.ToString());
  Finish(job_id, scan.scan_id, JobPhase::kFailed,
         absl::StrCat(why, "; the scan is kept in ", scans_->parked_dir(), "/", scan.scan_id), false);
  return false;
}

// Each frame of a scan the service posed aligned photometrically to the
// place's renders (photometric_refine.h), with progress in the REGISTERING
// phase. False when the job ended (cancelled); a render error only skips it.
bool UpdateWorker::AlignToPlace(const std::string& job_id, const std::string& scan_id, const PlaceMap& map,
                                double extent, Scene* scene, std::map<std::string, double>* metrics) {
  absl::StatusOr<ScanPhotometricReport> r = RefineScanPhotometric(
      map, scene, extent, options_.registration.photometric_options, StepProgress(job_id),
      &cancel_);
  if (absl::IsCancelled(r.status())) {
    FinishCancelled(job_id, scan_id);
    return false;
  }
  if (!r.ok()) {
    spdlog::warn("job {}: photometric alignment skipped: {}", job_id, r.status().ToString());
    return true;
  }
  (*metrics)["registration_photometric_frames"] = r->accepted;
  (*metrics)["registration_photometric_rotation_deg"] = r->median_rotation_deg;
  (*metrics)["registration_photometric_seconds"] = r->seconds;
  spdlog::info("job {}: aligned {} of {} frames to the place's renders (median move {:.3f} deg) in {:.1f} s", job_id,
               r->accepted, r->frames, r->median_rotation_deg, r->seconds);
  return true;
}

// A scan posed in its own frame, once placed: its whole similarity refined
// photometrically against the place's renders (photometric_similarity.h),
// with progress in the REGISTERING phase. False when the job ended
// (cancelled); a render error or a refused refinement keeps the placement.
bool UpdateWorker::AlignSimilarityToPlace(const std::string& job_id, const std::string& scan_id,
                                          const PlaceMap& map, double extent, const RegistrationReport& reg,
                                          Scene* scene, std::map<std::string, double>* metrics) {
  absl::StatusOr<SimilarityRefinement> r = RefineSimilarityPhotometric(
      map, *scene, extent, options_.registration.similarity_options, StepProgress(job_id), &cancel_);
  if (absl::IsCancelled(r.status())) {
    FinishCancelled(job_id, scan_id);
    return false;
  }
  if (!r.ok()) {
    spdlog::warn("job {}: photometric similarity refinement skipped: {}", job_id, r.status().ToString());
    return true;
  }
  (*metrics)["registration_similarity_refined"] = r->accepted ? 1 : 0;
  (*metrics)["registration_similarity_refine_deg"] = r->rotation_deg;
  (*metrics)["registration_similarity_refine_seconds"] = r->seconds;
  if (!r->accepted) {
    spdlog::info("job {}: similarity kept as registered ({}) after {:.1f} s", job_id, r->why, r->seconds);
    return true;
  }
  if (ApplyRefinedSimilarity(reg, r->correction, options_.registration, scene)) {
    (*metrics)["registration_identity"] = 1;
    (*metrics)["registration_refined_to_identity"] = 1;
    spdlog::info("job {}: the refined similarity is within a hair of the identity (turned {:.3f} deg): the scan was "
                 "in the place's frame, kept as uploaded", job_id, r->rotation_deg);
    return true;
  }
  spdlog::info("job {}: similarity refined against the place's renders: turned {:.3f} deg, scaled {:.4f}, cameras "
               "moved up to {:.2f}% of the place, robust cost {:.4g} -> {:.4g}, {} frames, {:.1f} s",
               job_id, r->rotation_deg, r->scale, 100 * r->max_centre, r->cost_before, r->cost_after, r->frames,
               r->seconds);
  return true;
}

bool UpdateWorker::RegisterIntoPlace(const std::string& job_id, const std::string& scan_id, const Servable& prev,
                                     std::set<std::string> suspect, Scene* scene,
                                     std::map<std::string, double>* metrics) {
  const std::string frame = PoseFrameOf(*scans_, scan_id);
  jobs_->Update(job_id, [&](JobStatus* j) {
    j->phase = JobPhase::kRegistering;
    j->iteration = 0;
    j->total_iterations = 0;
  });
  std::vector<Camera> place;
  for (uint32_t i = 0; i < prev.memory().num_cameras(); ++i) place.push_back(prev.memory().GetCamera(i));
  RenderOptions ro;
  ro.threads = options_.train_threads;
  ModelPlaceMap map(prev.model(), ro);
  const double extent = PlaceExtent(place, prev.model().normalization());
  RegistrationReport r = RegisterScan(*scene, map, place, extent, options_.registration, StepProgress(job_id),
      &cancel_);
  if (!r.status.ok() && !absl::IsCancelled(r.status) && !suspect.empty()) {  // Again without them.
    DropSuspects(job_id, r.status, &suspect, scene, metrics);
    r = RegisterScan(*scene, map, place, extent, options_.registration, StepProgress(job_id), &cancel_);
  }
  if (absl::IsCancelled(r.status)) {
    FinishCancelled(job_id, scan_id);
    return false;
  }
  r.AddMetrics(metrics);
  if (r.status.ok()) {
    ApplySimilarity(r.transform, scene);
    if (metrics->count("posing_frames") > 0) {
      // Posed here by SfM over this scan alone: its self-calibrated camera
      // and its poses refined against the place (registration.h).
      if (options_.registration.arbitrate) {
        ArbitrateFrames(job_id, map, extent, options_.registration.arbitration, suspect, &r, scene, metrics);
      }
      SharedCameraReport cam;
      Intrinsics in;
      if (absl::Status s = RefineAgainstPlace(r, scene, &cam, &in, options_.registration.camera); s.ok()) {
        (*metrics)["registration_refined_fx"] = in.fx;
        (*metrics)["registration_refined_k1"] = in.k1;
        (*metrics)["registration_refine_rms_px"] = cam.rms_px;
        (*metrics)["registration_camera_refined"] = cam.camera_taken ? 1 : 0;
      } else {
        spdlog::warn("job {}: camera refinement skipped: {}", job_id, s.ToString());
      }
      if (options_.registration.photometric && !AlignToPlace(job_id, scan_id, map, extent, scene, metrics)) {
        return false;
      }
    } else if (!r.identity && options_.registration.photometric_similarity &&
               !AlignSimilarityToPlace(job_id, scan_id, map, extent, r, scene, metrics)) {
      return false;
    }
    spdlog::info("job {}: registered into the place's frame: {}", job_id, r.Summary());
    return true;
  }
  if (frame == "place") {  // Declared in the place's frame: train as uploaded.
    (*metrics)["registration_unverified"] = 1;
    spdlog::warn("job {}: could not verify the scan's place frame ({}); training it as uploaded", job_id,
                 std::string(r.status.message()));
    return true;
  }
  const std::string why = absl::StrCat("FAILED_PRECONDITION: the scan could not be placed in the place's frame: ",
                                       r.status.message());
  jobs_->Update(job_id, [&](JobStatus* j) { j->metrics = *metrics; });
  if (absl::Status s = scans_->Park(scan_id, why); !s.ok()) spdlog::warn("job {}: {}", job_id, s.ToString());
  Finish(job_id, scan_id, JobPhase::kFailed,
         absl::StrCat(why, "; nothing was trained, the scan is kept in ", scans_->parked_dir(), "/", scan_id),
         false, "refused");
  return false;
}

std::optional<BakedAsset> UpdateWorker::BakeForViewers(const std::string& job_id, const ContinualState& next,
                                                       std::map<std::string, double>* metrics) {
  if (!options_.bake_on_publish) return std::nullopt;
  jobs_->Update(job_id, [&](JobStatus* j) {
    j->phase = JobPhase::kBaking;
    j->iteration = j->total_iterations = 0;
  });
  std::vector<Camera> cameras;  // Every scan's cameras: what the photos saw, in the place's frame.
  for (uint32_t i = 0; i < next.memory.num_cameras(); ++i) cameras.push_back(next.memory.GetCamera(i));
  BakeOptions o = options_.bake;
  o.threads = options_.train_threads;
  BakeReport rep;
  absl::StatusOr<BakedAsset> asset = BakeModel(*next.model, -1, cameras, o, &rep);
  if (!asset.ok()) {
    spdlog::warn("job {}: baking for the browser failed ({}); publishing without it (viewers get server frames)",
                 job_id, asset.status().ToString());
    (*metrics)["bake_failed"] = 1;
    return std::nullopt;
  }
  (*metrics)["bake_seconds"] = rep.total_seconds;
  (*metrics)["bake_kept_blocks"] = rep.kept_blocks;
  (*metrics)["bake_raw_bytes"] = double(asset->raw_bytes());
  spdlog::info("job {}: baked time step {} for the browser in {:.1f} s ({} blocks)", job_id, asset->time_step,
               rep.total_seconds, rep.kept_blocks);
  return *std::move(asset);
}

bool UpdateWorker::ReadyToRun(const std::string& job_id, const JobStatus& job) {
  const std::string& scan_id = job.scan_id;
  if (coordinator_ != nullptr) {
    // Another replica may have trained it while this one waited for the lease.
    if (std::optional<VersionInfo> v = publisher_->VersionOfScan(scan_id)) {
      (void)scans_->Remove(scan_id);
      jobs_->Update(job_id, [&](JobStatus* j) { MarkDoneBy(*v, j); });
      return false;
    }
  }
  if (job.cancel_requested) {
    Finish(job_id, scan_id, JobPhase::kCancelled, "cancelled", true);
    return false;
  }
  // A deployed version not loaded yet is checked first: if it cannot load,
  // the store turns read-only and the job waits like any write would.
  (void)publisher_->VerifyDeployed();
  if (!WaitForWritableStore(job_id)) {
    FinishStopped(job_id, scan_id);
    return false;
  }
  if (absl::StatusOr<int> a = scans_->RecordAttempt(scan_id); !a.ok()) {
    spdlog::warn("job {}: attempt not recorded: {}", job_id, a.status().ToString());
  } else if (*a > 1) {
    spdlog::warn("job {}: attempt {} of {} for scan {}", job_id, *a, options_.max_scan_attempts, scan_id);
  }
  return true;
}

bool UpdateWorker::LoadDeployed(const std::string& job_id, const std::string& scan_id,
                                std::shared_ptr<const Servable>* prev, PlaceHead* head) {
  if (coordinator_ != nullptr) {
    absl::StatusOr<PlaceHead> h = publisher_->SyncToHead();
    if (!h.ok()) {
      spdlog::warn("job {}: cannot read the place's head: {}; retrying", job_id, h.status().ToString());
      scans_->ClearAttempts(scan_id);
      jobs_->Requeue(job_id, absl::StrCat("waiting for the coordinator: ", h.status().message()));
      (void)Pause();
      return false;
    }
    *head = *h;
  }
  if (absl::StatusOr<std::shared_ptr<const Servable>> d = publisher_->registry().Get(head->version); d.ok()) {
    *prev = *std::move(d);
  } else if (!absl::IsFailedPrecondition(d.status())) {  // FAILED_PRECONDITION: nothing deployed yet.
    Finish(job_id, scan_id, JobPhase::kFailed,
           absl::StrCat("cannot load the deployed version ", publisher_->registry().deployed_version(), ": ",
                        d.status().message(), "; the scan is kept and retried after a restart"),
           false);
    return false;
  }
  return true;
}

void UpdateWorker::CheckScanPoses(const std::string& job_id, bool posed_here, Scene* scene,
                                  std::map<std::string, double>* metrics, std::set<std::string>* suspect) {
  const std::string& action = options_.pose_check_action;
  const bool drop = DropsDisputed(action, posed_here);
  if (action == "off" || scene->train.empty()) return;
  const std::vector<View> views = CaptureInOrder(*scene);
  absl::StatusOr<PoseCheckReport> r = CheckPoses(views, options_.pose_check, options_.train_threads);
  if (!r.ok()) {
    spdlog::warn("job {}: pose check skipped: {}", job_id, r.status().ToString());
    return;
  }
  (*metrics)["pose_check_pairs"] = double(r->pairs.size());
  (*metrics)["pose_check_disputed"] = double(r->disputed.size());
  (*metrics)["pose_check_seconds"] = r->seconds;
  if (r->disputed.empty()) {
    spdlog::info("job {}: pose check: {}", job_id, r->Summary(views));
    return;
  }
  spdlog::warn("job {}: pose check: {}{}", job_id, r->Summary(views), drop ? "; training without them" : "");
  if (!drop) return;
  const std::set<std::string> disputed = DisputedNames(*r, views);
  DropViewsNamed(disputed, &scene->test);
  if (suspect != nullptr) {  // The place's map decides after registration.
    for (const View& v : scene->train) {
      if (disputed.count(v.name)) suspect->insert(v.name);
    }
    return;
  }
  (*metrics)["pose_check_dropped"] = double(DropViewsNamed(disputed, &scene->train));
}

std::optional<Scene> UpdateWorker::PrepareScan(const std::string& job_id, const std::string& scan_id,
                                               const Servable* prev, std::map<std::string, double>* metrics) {
  const int t = prev ? prev->model().num_time_steps() : 0;
  bool posed_here = false;
  if (absl::StatusOr<ScanRecord> rec = scans_->Record(scan_id); rec.ok() && rec->pose_frame == "unposed") {
    if (!PoseScan(job_id, *rec, prev, metrics)) return std::nullopt;
    posed_here = true;
  }
  absl::StatusOr<Scene> scene =
      scans_->Load(scan_id, t, prev ? std::optional<Eigen::Vector3f>(prev->model().background()) : std::nullopt);
  if (!scene.ok()) {
    // A stored scan that cannot be read will never train: park it.
    const std::string why = absl::StrCat("cannot read the stored scan: ", scene.status().message());
    if (absl::Status s = scans_->Park(scan_id, why); !s.ok()) spdlog::warn("job {}: {}", job_id, s.ToString());
    Finish(job_id, scan_id, JobPhase::kFailed, absl::StrCat(why, " (parked in ", scans_->parked_dir(), ")"), false);
    return std::nullopt;
  }
  if (prev) scene->kind = prev->model().kind();
  // A later scan the service posed leaves its disputed frames to the
  // place's map (pose_arbitration.h); any other scan drops them here.
  std::set<std::string> suspect;
  const bool arbitrated = prev != nullptr && posed_here && options_.registration.arbitrate;
  CheckScanPoses(job_id, posed_here, &*scene, metrics, arbitrated ? &suspect : nullptr);
  if (prev && !RegisterIntoPlace(job_id, scan_id, *prev, std::move(suspect), &*scene, metrics)) return std::nullopt;
  return *std::move(scene);
}

std::optional<ContinualState> UpdateWorker::Train(const std::string& job_id, const std::string& scan_id,
                                                  const Servable* prev, const Scene& scene, UpdateReport* report) {
  const int t = prev ? prev->model().num_time_steps() : 0;
  UpdateOptions uo = options_.update;
  if (!prev && options_.first_scan_iterations > 0) uo.train.iterations = options_.first_scan_iterations;
  uo.train.threads = options_.train_threads;
  uo.train.seed = options_.update.train.seed + uint64_t(t);
  auto last_report = std::chrono::steady_clock::now() - std::chrono::seconds(1);
  JobPhase last_phase = JobPhase::kPreparingReplay;
  // θ_{t-1}'s optimiser state, when updates carry it (read from its version;
  // without one, e.g. a version from before, the update starts a fresh one).
  // (A copy of the state only then: it shares the model, copies M_t.)
  std::optional<ContinualState> prev_state;
  if (prev && uo.carry_optimizer) {
    prev_state = prev->state;
    absl::StatusOr<std::shared_ptr<const OptimizerState>> opt = publisher_->LoadOptimizer(prev->info.version);
    if (opt.ok()) {
      prev_state->optimizer = *std::move(opt);
    } else {
      spdlog::warn("job {}: starting a fresh optimiser: {}", job_id, opt.status().ToString());
    }
  }
  absl::StatusOr<ContinualState> next = ContinualUpdate(
      scene, prev_state ? &*prev_state : prev ? &prev->state : nullptr, uo,
      [&](const UpdateProgress& p) {
        const JobPhase phase = ToJobPhase(p.phase);
        const auto now = std::chrono::steady_clock::now();
        const bool last = p.phase == UpdatePhase::kTraining && p.iteration == p.total;
        if (phase == last_phase && !last && now - last_report < std::chrono::milliseconds(100)) return;
        last_report = now;
        last_phase = phase;
        jobs_->Update(job_id, [&](JobStatus* j) {
          j->phase = phase;
          j->iteration = p.iteration;
          j->total_iterations = p.total;
          j->elapsed_seconds = p.elapsed_seconds;
          j->eta_seconds = p.eta_seconds;
          j->loss = p.loss;
          j->psnr = p.psnr;
        });
      },
      &cancel_, report);
  if (next.ok()) return *std::move(next);
  if (absl::IsCancelled(next.status())) {
    FinishCancelled(job_id, scan_id);
  } else {
    Finish(job_id, scan_id, JobPhase::kFailed, std::string(next.status().message()), true);
  }
  return std::nullopt;
}

std::optional<VersionInfo> UpdateWorker::PublishUpdate(const std::string& job_id, const JobStatus& job,
                                                       const Servable* prev, const PlaceHead& head,
                                                       const ContinualState& next, const Scene& scene,
                                                       const std::map<std::string, double>& metrics,
                                                       const std::optional<BakedAsset>& baked) {
  const std::string& scan_id = job.scan_id;
  jobs_->Update(job_id, [&](JobStatus* j) { j->phase = JobPhase::kPublishing; });
  while (true) {
    absl::StatusOr<VersionInfo> published =
        publisher_->Publish(next, prev ? prev->info.version : 0, {scan_id, job.scan_name, job_id, FrameNames(scene)},
                            metrics, coordinator_ != nullptr ? &head : nullptr, baked ? &*baked : nullptr);
    if (published.ok()) return *std::move(published);
    if (coordinator_ != nullptr && absl::IsAborted(published.status())) {
      // Fenced: this replica lost the place's lease (paused, cut off) or the
      // head moved. Nothing was published; the scan stays for the lease's
      // holder, and this job waits for the outcome like any other replica.
      spdlog::warn("job {}: {}", job_id, std::string(published.status().message()));
      scans_->ClearAttempts(scan_id);
      jobs_->Requeue(job_id, std::string(published.status().message()));
      return std::nullopt;
    }
    if (coordinator_ != nullptr && publisher_->error().empty()) {
      // The coordinator could not be reached: the store is fine, try again.
      spdlog::warn("job {}: publishing: {}; retrying", job_id, std::string(published.status().message()));
      if (!Pause()) break;
      continue;
    }
    spdlog::error("job {}: publishing failed: {}; retrying when the store recovers", job_id,
                  std::string(published.status().message()));
    if (!WaitForWritableStore(job_id)) break;
    // Recovery may itself have deployed a version of this scan (a write whose
    // error was reported after it landed): then the job is done.
    const std::optional<DeployedSummary> now = publisher_->registry().deployed();
    if (now && now->info.scan_id == scan_id) return now->info;
  }
  FinishStopped(job_id, scan_id);
  return std::nullopt;
}

void UpdateWorker::RunJob(const std::string& job_id) {
  cancel_ = false;
  job_started_ = std::chrono::steady_clock::now();
  absl::StatusOr<JobStatus> job = jobs_->Get(job_id);
  if (!job.ok() || IsFinal(job->phase) || !ReadyToRun(job_id, *job)) return;
  const std::string scan_id = job->scan_id;

  // 1. Load the scan as the next time step of the deployed model, posed and
  // registered into its frame.
  std::shared_ptr<const Servable> prev;  // Held for the whole update: the cache never evicts it meanwhile.
  PlaceHead head;                        // Replicas: where this update starts; its publish is fenced by it.
  if (!LoadDeployed(job_id, scan_id, &prev, &head)) return;
  const int t = prev ? prev->model().num_time_steps() : 0;
  std::map<std::string, double> registration_metrics;  // Posing's and registration's.
  std::optional<Scene> scene = PrepareScan(job_id, scan_id, prev.get(), &registration_metrics);
  if (!scene) return;
  std::vector<View> test = std::move(scene->test);
  scene->test.clear();
  jobs_->Update(job_id, [&](JobStatus* j) {
    j->phase = JobPhase::kPreparingReplay;
    j->time_step = t;
    j->total_iterations = !prev && options_.first_scan_iterations > 0 ? options_.first_scan_iterations
                                                                      : options_.update.train.iterations;
  });
  spdlog::info("job {}: training scan {} as time step {} on version {}", job_id, scan_id, t,
               prev ? prev->info.version : 0);

  // 2. Train.
  UpdateReport report;
  const auto t0 = std::chrono::steady_clock::now();
  std::optional<ContinualState> next = Train(job_id, scan_id, prev.get(), *scene, &report);
  if (!next) return;

  // 3. Deployment gate, at the cameras the update kept: with camera
  // refinement (UpdateOptions::refine_cameras) the training photos' are the
  // corrected ones, the last of M_t in the scan's order. The held-out frames
  // keep their registered poses (they were not trained on).
  jobs_->Update(job_id, [&](JobStatus* j) { j->phase = JobPhase::kValidating; });
  if (report.refined_cameras == int(scene->train.size()) && next->memory.num_cameras() >= scene->train.size()) {
    const uint32_t first = uint32_t(next->memory.num_cameras() - scene->train.size());
    for (size_t i = 0; i < scene->train.size(); ++i) {
      scene->train[i].camera = next->memory.GetCamera(first + uint32_t(i));
    }
  }
  scene->test = std::move(test);
  GateReport gate = RunDeploymentGate(*next->model, *scene, prev ? &prev->model() : nullptr,
                                      prev ? &prev->memory() : nullptr, options_.gate, options_.train_threads,
                                      prev ? PlacePsnr(prev->info, !scene->test.empty()) : 0.0);
  gate.metrics.insert(registration_metrics.begin(), registration_metrics.end());
  gate.metrics["train_seconds"] = report.train_seconds;
  gate.metrics["replay_prepare_seconds"] = report.replay_prepare_seconds;
  if (report.depth_pixels > 0) gate.metrics["depth_pixels"] = double(report.depth_pixels);
  if (report.refined_cameras > 0) {  // UpdateOptions::refine_cameras.
    gate.metrics["camera_refined"] = double(report.refined_cameras);
    gate.metrics["camera_turn_median_deg"] = report.camera_turn_median_deg;
    gate.metrics["camera_turn_max_deg"] = report.camera_turn_max_deg;
    gate.metrics["camera_shift_median"] = report.camera_shift_median;
    gate.metrics["camera_shift_max"] = report.camera_shift_max;
    gate.metrics["camera_clamped"] = double(report.camera_clamped);
  }
  gate.metrics["update_seconds"] = SecondsSince(t0);
  if (!prev) gate.metrics["time_to_first_view_seconds"] = double(NowUnixMs() - job->created_unix_ms) / 1000.0;
  jobs_->Update(job_id, [&](JobStatus* j) { j->metrics = gate.metrics; });
  if (!gate.status.ok()) {
    return Finish(job_id, scan_id, JobPhase::kFailed, std::string(gate.status.message()), true, "refused");
  }
  if (stopping_) return FinishStopped(job_id, scan_id);

  // 4. Bake for the browser (the publish writes it beside the version).
  const std::optional<BakedAsset> baked = BakeForViewers(job_id, *next, &gate.metrics);
  gate.metrics["update_seconds"] = SecondsSince(t0);
  jobs_->Update(job_id, [&](JobStatus* j) { j->metrics = gate.metrics; });
  if (stopping_) return FinishStopped(job_id, scan_id);

  // 5. Publish; on a store error keep the trained state and retry once the
  // store recovers (or until shutdown: the scan is then retrained).
  const std::optional<VersionInfo> published =
      PublishUpdate(job_id, *job, prev.get(), head, *next, *scene, gate.metrics, baked);
  if (!published) return;
  if (absl::Status s = scans_->Remove(scan_id); !s.ok()) spdlog::warn("job {}: {}", job_id, s.ToString());
  CrashPoint("publish:scan-removed");
  jobs_->Update(job_id, [&](JobStatus* j) {
    j->phase = JobPhase::kDone;
    j->version = published->version;
    j->error.clear();
  });
  if (metrics_ != nullptr) metrics_->UpdateDone("published", SecondsSince(job_started_));
  spdlog::info("job {} done: version {} deployed ({} time steps, {:.1f} s)", job_id, published->version,
               published->time_steps, SecondsSince(t0));
}

}  // namespace clnerf
