#include "server/model_host.h"

#include <omp.h>

#include <algorithm>
#include <filesystem>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/continual_update.h"
#include "core/renderer.h"
#include "core/deployment_gate.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {

double SecondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

JobPhase ToJobPhase(UpdatePhase p) {
  switch (p) {
    case UpdatePhase::kPreparingReplay: return JobPhase::kPreparingReplay;
    case UpdatePhase::kTraining: return JobPhase::kTraining;
    case UpdatePhase::kFinalizing: return JobPhase::kTraining;
  }
  return JobPhase::kTraining;
}

}  // namespace

ModelHost::ModelHost(const ServerOptions& options)
    : options_(options),
      started_(std::chrono::steady_clock::now()),
      registry_([this](int64_t v) { return LoadServable(v); }, options.cached_versions),
      jobs_(options.max_queue),
      render_slots_(options.render_concurrency) {}

absl::StatusOr<std::unique_ptr<ModelHost>> ModelHost::Open(const ServerOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  std::error_code ec;
  std::filesystem::create_directories(options.store_dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create store '", options.store_dir, "': ", ec.message()));
  std::unique_ptr<ModelHost> host(new ModelHost(options));
  absl::StatusOr<std::unique_ptr<ScanStore>> scans = ScanStore::Open(options.store_dir);
  if (!scans.ok()) return scans.status();
  host->scans_ = *std::move(scans);
  absl::StatusOr<std::unique_ptr<VersionStore>> versions = VersionStore::Open(options.store_dir);
  if (!versions.ok()) return versions.status();
  host->versions_ = *std::move(versions);
  if (absl::Status s = host->Recover(); !s.ok()) return s;
  host->worker_ = std::thread([h = host.get()] { h->WorkerLoop(); });
  return host;
}

ModelHost::~ModelHost() { Shutdown(); }

absl::StatusOr<std::shared_ptr<const Servable>> ModelHost::LoadServable(int64_t version) const {
  absl::StatusOr<LoadedVersion> lv = versions_->Load(version);
  if (!lv.ok()) return lv.status();
  auto s = std::make_shared<Servable>();
  s->info = lv->info;
  s->model = std::make_shared<const NgpModel>(std::move(lv->model));
  s->memory = std::make_shared<const ReplayMemory>(std::move(lv->memory));
  return std::shared_ptr<const Servable>(std::move(s));
}

int ModelHost::PredictedTimeStep() const {
  const std::shared_ptr<const Servable> deployed = registry_.Deployed();
  return (deployed ? deployed->model->num_time_steps() : 0) + jobs_.running_or_queued();
}

absl::Status ModelHost::Recover() {
  absl::StatusOr<Manifest> m = versions_->ReadManifest();
  if (!m.ok()) return m.status();
  manifest_ = *m;
  absl::StatusOr<std::vector<VersionInfo>> all = versions_->List();
  if (!all.ok()) return all.status();
  // A version written after the manifest's last update passed its gate but
  // crashed before being recorded: finish publishing it.
  if (!all->empty() && all->back().version >= manifest_.next_version) {
    spdlog::warn("recovery: version {} was written but not recorded; deploying it", all->back().version);
    manifest_.deployed = all->back().version;
    manifest_.next_version = all->back().version + 1;
  }
  if (manifest_.deployed != 0) {
    absl::StatusOr<std::shared_ptr<const Servable>> s = LoadServable(manifest_.deployed);
    if (!s.ok()) {
      return absl::Status(s.status().code(), absl::StrCat("cannot load deployed version ", manifest_.deployed, ": ",
                                                          s.status().message()));
    }
    registry_.Deploy(*s);
  }
  absl::StatusOr<std::vector<ScanRecord>> pending = scans_->List();
  if (!pending.ok()) return pending.status();
  int requeued = 0;
  for (const ScanRecord& r : *pending) {
    const bool trained = std::any_of(all->begin(), all->end(), [&](const VersionInfo& v) { return v.scan_id == r.scan_id; });
    if (trained) {
      spdlog::info("recovery: scan {} is already in a version; removing it", r.scan_id);
      if (absl::Status s = scans_->Remove(r.scan_id); !s.ok()) return s;
      continue;
    }
    JobStatus j;
    j.job_id = r.job_id;
    j.scan_id = r.scan_id;
    j.scan_name = r.name;
    j.created_unix_ms = r.created_unix_ms;
    j.time_step = PredictedTimeStep();
    if (absl::Status s = jobs_.Enqueue(std::move(j), /*force=*/true); !s.ok()) return s;
    ++requeued;
  }
  if (requeued > 0) spdlog::info("recovery: re-queued {} acknowledged scan(s) that were not trained yet", requeued);
  spdlog::info("store {}: deployed version {}, {} version(s)", options_.store_dir, manifest_.deployed, all->size());
  return versions_->WriteManifest(manifest_);
}

absl::StatusOr<UploadAck> ModelHost::AcceptScan(const ScanUpload& upload) {
  if (stopping_) return absl::UnavailableError("server is shutting down");
  if (int(upload.frames.size()) > options_.max_frames) {
    return absl::InvalidArgumentError(absl::StrCat("scan has ", upload.frames.size(), " frames; the limit is ",
                                                   options_.max_frames));
  }
  if (upload.num_bytes() > options_.max_scan_bytes) {
    return absl::InvalidArgumentError(absl::StrCat("scan is ", upload.num_bytes(), " bytes; the limit is ",
                                                   options_.max_scan_bytes));
  }
  if (absl::Status s = ValidateScanUpload(upload); !s.ok()) return s;
  std::lock_guard<std::mutex> lock(manifest_mu_);
  if (jobs_.queued() >= options_.max_queue) {
    return absl::ResourceExhaustedError(absl::StrCat("update queue is full (", options_.max_queue,
                                                     " scans wait for training); retry later"));
  }
  Manifest next = manifest_;
  ScanRecord rec;
  rec.scan_id = absl::StrFormat("scan-%06d", next.next_scan++);
  rec.job_id = absl::StrFormat("job-%06d", next.next_job++);
  rec.name = upload.name.empty() ? rec.scan_id : upload.name;
  rec.scene_kind = upload.scene_kind;
  rec.mask_nonzero_is_exclude = upload.mask_nonzero_is_exclude;
  rec.created_unix_ms = NowUnixMs();
  for (const ScanFrame& f : upload.frames) (f.test ? rec.num_test_frames : rec.num_frames)++;
  rec.num_bytes = upload.num_bytes();
  // Counters first, so an id is never reused even if the save fails.
  if (absl::Status s = versions_->WriteManifest(next); !s.ok()) return s;
  manifest_.next_scan = next.next_scan;
  manifest_.next_job = next.next_job;
  if (absl::Status s = scans_->Save(rec, upload); !s.ok()) return s;
  JobStatus j;
  j.job_id = rec.job_id;
  j.scan_id = rec.scan_id;
  j.scan_name = rec.name;
  j.created_unix_ms = rec.created_unix_ms;
  j.time_step = PredictedTimeStep();
  const int time_step = j.time_step;
  if (absl::Status s = jobs_.Enqueue(std::move(j)); !s.ok()) {
    (void)scans_->Remove(rec.scan_id);
    return s;
  }
  spdlog::info("accepted scan {} '{}' ({} frames, {} test, {} bytes) as job {}, time step {}", rec.scan_id,
               rec.name, rec.num_frames, rec.num_test_frames, rec.num_bytes, rec.job_id, time_step);
  return UploadAck{rec.scan_id, rec.job_id, time_step, rec.num_bytes};
}

absl::StatusOr<RenderResult> ModelHost::Render(const Camera& world_camera, std::optional<int> time_step,
                                               int64_t version) {
  if (absl::Status s = ValidateCamera(world_camera); !s.ok()) return s;
  const int64_t pixels = int64_t(world_camera.intrinsics.width) * world_camera.intrinsics.height;
  if (pixels > options_.max_render_pixels) {
    return absl::InvalidArgumentError(absl::StrCat("render of ", pixels, " pixels exceeds the limit of ",
                                                   options_.max_render_pixels));
  }
  absl::StatusOr<std::shared_ptr<const Servable>> snap = registry_.Get(version);
  if (!snap.ok()) return snap.status();
  const NgpModel& model = *(*snap)->model;
  const int t = time_step.value_or(model.num_time_steps() - 1);
  if (t < 0 || t >= model.num_time_steps()) {
    return absl::InvalidArgumentError(absl::StrCat("time step ", t, " is out of range: version ",
                                                   (*snap)->info.version, " has time steps 0..",
                                                   model.num_time_steps() - 1));
  }
  const auto wait = std::chrono::duration<double>(options_.render_wait_seconds);
  if (!render_slots_.try_acquire_for(std::chrono::duration_cast<std::chrono::milliseconds>(wait))) {
    return absl::ResourceExhaustedError("all render slots stayed busy; retry later");
  }
  const auto t0 = std::chrono::steady_clock::now();
  RenderOptions ro;
  ro.threads = options_.render_threads;
  ro.time_step = t;
  absl::StatusOr<RenderedView> view = RenderView(model, world_camera, ro);
  render_slots_.release();
  if (!view.ok()) return view.status();
  return RenderResult{(*snap)->info.version, t, std::move(view->rgb), SecondsSince(t0)};
}

absl::StatusOr<JobStatus> ModelHost::CancelJob(const std::string& id) {
  absl::StatusOr<JobStatus> before = jobs_.Get(id);
  if (!before.ok()) return before.status();
  absl::StatusOr<bool> was_queued = jobs_.Cancel(id);
  if (!was_queued.ok()) return was_queued.status();
  if (*was_queued) {
    if (absl::Status s = scans_->Remove(before->scan_id); !s.ok()) spdlog::warn("cancel {}: {}", id, s.ToString());
    spdlog::info("job {} cancelled while queued; scan {} removed", id, before->scan_id);
  } else {
    cancel_running_ = true;
    spdlog::info("job {}: cancellation requested", id);
  }
  return jobs_.Get(id);
}

absl::StatusOr<VersionInfo> ModelHost::SetDeployedVersion(int64_t v) {
  if (v <= 0) return absl::InvalidArgumentError(absl::StrCat("version ", v, " is not a version number"));
  absl::StatusOr<std::shared_ptr<const Servable>> s = registry_.Get(v);
  if (!s.ok()) return s.status();
  std::lock_guard<std::mutex> lock(manifest_mu_);
  Manifest next = manifest_;
  next.deployed = v;
  if (absl::Status w = versions_->WriteManifest(next); !w.ok()) return w;
  manifest_ = next;
  registry_.Deploy(*s);
  spdlog::info("deployed version {} (rollback/pin)", v);
  return (*s)->info;
}

HostInfo ModelHost::Info() const {
  HostInfo info;
  auto d = registry_.Deployed();
  if (d) {
    info.deployed_version = d->info.version;
    info.time_steps = d->model->num_time_steps();
    info.model_bytes = int64_t(d->model->num_bytes());
    info.replay_cameras = int64_t(d->memory->num_cameras());
  }
  info.queued_jobs = jobs_.queued();
  info.running_job = jobs_.running();
  info.uptime_seconds = SecondsSince(started_);
  return info;
}

void ModelHost::Shutdown() {
  if (stopping_.exchange(true)) {
    if (worker_.joinable()) worker_.join();
    return;
  }
  cancel_running_ = true;
  jobs_.Shutdown();
  if (worker_.joinable()) worker_.join();
}

void ModelHost::PruneVersions() {
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

void ModelHost::WorkerLoop() {
  omp_set_num_threads(options_.train_threads);
  while (true) {
    std::optional<std::string> id = jobs_.WaitNext();
    if (!id) return;
    RunJob(*id);
  }
}

void ModelHost::FinishJob(const std::string& job_id, const std::string& scan_id, JobPhase phase,
                          const std::string& error, bool remove_scan) {
  if (remove_scan) {
    if (absl::Status s = scans_->Remove(scan_id); !s.ok()) spdlog::warn("job {}: {}", job_id, s.ToString());
  }
  jobs_.Update(job_id, [&](JobStatus* j) {
    j->phase = phase;
    j->error = error;
  });
  if (phase == JobPhase::kFailed) spdlog::error("job {} failed: {}", job_id, error);
  if (phase == JobPhase::kCancelled) spdlog::warn("job {} cancelled: {}", job_id, error);
}

void ModelHost::RunJob(const std::string& job_id) {
  cancel_running_ = false;
  absl::StatusOr<JobStatus> job = jobs_.Get(job_id);
  if (!job.ok()) return;
  const std::string scan_id = job->scan_id;
  if (job->cancel_requested) return FinishJob(job_id, scan_id, JobPhase::kCancelled, "cancelled", true);
  const std::shared_ptr<const Servable> prev = registry_.Deployed();
  const int t = prev ? prev->model->num_time_steps() : 0;

  // Later scans take the deployed model's background; the first, its kind's.
  absl::StatusOr<Scene> scene =
      scans_->Load(scan_id, t, prev ? std::optional<Eigen::Vector3f>(prev->model->background()) : std::nullopt);
  if (!scene.ok()) {
    return FinishJob(job_id, scan_id, JobPhase::kFailed, absl::StrCat("cannot read the stored scan: ", scene.status().message()), false);
  }
  if (prev) scene->kind = prev->model->kind();
  std::vector<View> test = std::move(scene->test);
  scene->test.clear();
  jobs_.Update(job_id, [&](JobStatus* j) {
    j->phase = JobPhase::kPreparingReplay;
    j->time_step = t;
    j->total_iterations = options_.update.train.iterations;
  });
  spdlog::info("job {}: training scan {} as time step {} on version {}", job_id, scan_id, t,
               prev ? prev->info.version : 0);

  UpdateOptions uo = options_.update;
  uo.train.threads = options_.train_threads;
  uo.train.seed = options_.update.train.seed + uint64_t(t);
  ContinualState prev_state;
  if (prev) {
    prev_state.model = prev->model;
    prev_state.memory = *prev->memory;
  }
  auto last_report = std::chrono::steady_clock::now() - std::chrono::seconds(1);
  JobPhase last_phase = JobPhase::kPreparingReplay;
  UpdateReport report;
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<ContinualState> next = ContinualUpdate(
      *scene, prev ? &prev_state : nullptr, uo,
      [&](const UpdateProgress& p) {
        const JobPhase phase = ToJobPhase(p.phase);
        const auto now = std::chrono::steady_clock::now();
        const bool last = p.phase == UpdatePhase::kTraining && p.iteration == p.total;
        if (phase == last_phase && !last && now - last_report < std::chrono::milliseconds(100)) return;
        last_report = now;
        last_phase = phase;
        jobs_.Update(job_id, [&](JobStatus* j) {
          j->phase = phase;
          j->iteration = p.iteration;
          j->total_iterations = p.total;
          j->elapsed_seconds = p.elapsed_seconds;
          j->eta_seconds = p.eta_seconds;
          j->loss = p.loss;
          j->psnr = p.psnr;
        });
      },
      &cancel_running_, &report);
  if (!next.ok()) {
    if (absl::IsCancelled(next.status())) {
      if (stopping_) {
        return FinishJob(job_id, scan_id, JobPhase::kCancelled,
                         "server shut down during training; the scan is kept and retrained after restart", false);
      }
      return FinishJob(job_id, scan_id, JobPhase::kCancelled, "cancelled by request", true);
    }
    return FinishJob(job_id, scan_id, JobPhase::kFailed, std::string(next.status().message()), true);
  }

  jobs_.Update(job_id, [&](JobStatus* j) { j->phase = JobPhase::kValidating; });
  scene->test = std::move(test);
  GateReport gate = RunDeploymentGate(*next->model, *scene, prev ? prev->model.get() : nullptr,
                                      prev ? prev->memory.get() : nullptr, options_.gate, options_.train_threads);
  gate.metrics["train_seconds"] = report.train_seconds;
  gate.metrics["replay_prepare_seconds"] = report.replay_prepare_seconds;
  gate.metrics["update_seconds"] = SecondsSince(t0);
  jobs_.Update(job_id, [&](JobStatus* j) { j->metrics = gate.metrics; });
  if (!gate.status.ok()) return FinishJob(job_id, scan_id, JobPhase::kFailed, std::string(gate.status.message()), true);
  if (stopping_) {
    return FinishJob(job_id, scan_id, JobPhase::kCancelled,
                     "server shut down before publishing; the scan is kept and retrained after restart", false);
  }

  jobs_.Update(job_id, [&](JobStatus* j) { j->phase = JobPhase::kPublishing; });
  std::lock_guard<std::mutex> lock(manifest_mu_);
  VersionInfo info;
  info.version = manifest_.next_version;
  info.parent = prev ? prev->info.version : 0;
  info.time_steps = next->model->num_time_steps();
  info.created_unix_ms = NowUnixMs();
  info.scan_id = scan_id;
  info.metrics = gate.metrics;
  absl::StatusOr<VersionInfo> written = versions_->Write(*next->model, next->memory, info);
  if (!written.ok()) {
    return FinishJob(job_id, scan_id, JobPhase::kFailed, absl::StrCat("cannot write the version: ", written.status().message()), false);
  }
  Manifest m = manifest_;
  m.deployed = info.version;
  m.next_version = info.version + 1;
  if (absl::Status s = versions_->WriteManifest(m); !s.ok()) {
    // The version is durable; recovery deploys it on the next start.
    return FinishJob(job_id, scan_id, JobPhase::kFailed, absl::StrCat("cannot update the manifest: ", s.message()), false);
  }
  manifest_ = m;
  auto servable = std::make_shared<Servable>();
  servable->info = *written;
  servable->model = next->model;
  servable->memory = std::make_shared<const ReplayMemory>(std::move(next->memory));
  registry_.Deploy(std::move(servable));
  if (absl::Status s = scans_->Remove(scan_id); !s.ok()) spdlog::warn("job {}: {}", job_id, s.ToString());
  PruneVersions();
  jobs_.Update(job_id, [&](JobStatus* j) {
    j->phase = JobPhase::kDone;
    j->version = info.version;
  });
  spdlog::info("job {} done: version {} deployed ({} time steps, {:.1f} s)", job_id, info.version, info.time_steps,
               SecondsSince(t0));
}

}  // namespace clnerf
