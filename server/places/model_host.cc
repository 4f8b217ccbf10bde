#include "server/places/model_host.h"

#include <algorithm>
#include <filesystem>
#include <map>
#include <set>

#include "absl/strings/str_cat.h"
#include "core/bake/baker.h"
#include "core/io/durable_file.h"
#include "core/pose/place_map.h"
#include "core/render/renderer.h"
#include "core/data/stopwatch.h"
#include "server/common/log_util.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {

// The finished record of the job that published `v` (`known`: what this
// host knew of it, or null).
JobStatus DoneJobOf(const VersionInfo& v, const JobStatus* known) {
  JobStatus j;
  j.job_id = v.job_id;
  j.scan_id = v.scan_id;
  j.scan_name = v.scan_name;
  MarkDoneBy(v, &j);
  j.created_unix_ms = known != nullptr ? known->created_unix_ms : v.created_unix_ms;
  j.finished_unix_ms = v.created_unix_ms;
  return j;
}

}  // namespace

ModelHost::ModelHost(const ServerOptions& options, SharedServices shared)
    : options_(options),
      started_(std::chrono::steady_clock::now()),
      metrics_(std::move(shared.metrics)),
      // Replicas share the store: each rebuilds job records from it (scans,
      // versions) instead of racing on one history file.
      jobs_(options.max_queue, shared.coordinator != nullptr && shared.coordinator->replicated()
                                   ? std::string()
                                   : (std::filesystem::path(options.store_dir) / "jobs.json").string()),
      trainings_(std::move(shared.trainings)),
      render_slots_(std::move(shared.render_slots)),
      coordinator_(shared.coordinator),
      assets_(shared.assets ? shared.assets : std::make_shared<AssetFiles>(options.asset_memory_budget, metrics_)),
      cores_(std::max(1, int(std::thread::hardware_concurrency()))) {}

absl::StatusOr<std::unique_ptr<ModelHost>> ModelHost::Open(const ServerOptions& options, SharedServices shared,
                                                           const std::string& place) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (!shared.metrics) shared.metrics = std::make_shared<Metrics>();
  if (!shared.render_slots) shared.render_slots = std::make_shared<RenderSlots>(options.render_concurrency);
  std::unique_ptr<ModelHost> host(new ModelHost(options, shared));
  host->place_ = place;
  PublisherOptions po;
  po.store_dir = options.store_dir;
  po.models = shared.models ? shared.models
                            : MakeServableCache(ResolvedModelMemoryBudget(options), host->metrics_);
  po.place = place;
  po.verify_deployed_at_open = !shared.defer_model_load;
  po.coordinator = shared.coordinator;
  po.keep_versions = options.keep_versions;
  po.retry_seconds = options.store_retry_seconds;
  po.metrics = host->metrics_.get();
  absl::StatusOr<std::unique_ptr<Publisher>> publisher = Publisher::Open(po);
  if (!publisher.ok()) return publisher.status();
  host->publisher_ = *std::move(publisher);
  const bool replicated = shared.coordinator != nullptr && shared.coordinator->replicated();
  absl::StatusOr<std::unique_ptr<ScanStore>> scans = ScanStore::Open(options.store_dir, !replicated);
  if (!scans.ok()) return scans.status();
  host->scans_ = *std::move(scans);
  host->jobs_.LoadHistory();
  if (absl::Status s = host->RecoverScans(); !s.ok()) return s;
  host->worker_ = std::make_unique<UpdateWorker>(options, host->scans_.get(), host->publisher_.get(), &host->jobs_,
                                                 host->metrics_.get(), host->trainings_.get(), place,
                                                 host->coordinator_.get());
  host->worker_->Start();
  return host;
}

ModelHost::~ModelHost() { Shutdown(); }

int ModelHost::PredictedTimeStep() const {
  const std::optional<DeployedSummary> deployed = publisher_->registry().deployed();
  return (deployed ? deployed->info.time_steps : 0) + jobs_.running_or_queued();
}

JobStatus ModelHost::QueuedJobFor(const ScanRecord& r) const {
  JobStatus j;
  j.job_id = r.job_id;
  j.scan_id = r.scan_id;
  j.scan_name = r.name;
  j.created_unix_ms = r.created_unix_ms;
  j.time_step = PredictedTimeStep();
  return j;
}

absl::Status ModelHost::RecoverScans() {
  absl::StatusOr<std::vector<ScanRecord>> pending = scans_->List();
  if (!pending.ok()) return pending.status();
  absl::StatusOr<std::vector<VersionInfo>> all = publisher_->versions().List();
  if (!all.ok()) return all.status();
  // A crash between a publish and the job's DONE record (the history is
  // written when a job finishes) would lose an acknowledged job: every
  // version names the job that trained it, so restore that record as DONE.
  for (const VersionInfo& v : *all) {
    followed_version_ = std::max(followed_version_, v.version);
    if (v.job_id.empty() || !v.unavailable.empty()) continue;
    absl::StatusOr<JobStatus> known = jobs_.Get(v.job_id);
    if (known.ok() && known->phase == JobPhase::kDone && known->version == v.version) continue;
    jobs_.AddFinished(DoneJobOf(v, known.ok() ? &*known : nullptr));
    spdlog::warn("recovery: job {} published version {} before a crash; recorded as done", v.job_id, v.version);
  }
  int requeued = 0;
  for (const ScanRecord& r : *pending) {
    const bool trained = std::any_of(all->begin(), all->end(), [&](const VersionInfo& v) { return v.scan_id == r.scan_id; });
    if (trained) {
      spdlog::info("recovery: scan {} is already in a version; removing it", r.scan_id);
      if (absl::Status s = scans_->Remove(r.scan_id); !s.ok()) spdlog::warn("recovery: {}", s.ToString());
      continue;
    }
    JobStatus j = QueuedJobFor(r);
    const int attempts = scans_->Attempts(r.scan_id);
    if (attempts >= options_.max_scan_attempts) {
      // Its training ended in a crash, a kill or a hang this many times:
      // park it instead of wedging every start.
      const std::string why = absl::StrCat("parked after ", attempts,
                                           " training attempts that never finished (crash, kill or hang); the scan "
                                           "is kept in ", scans_->parked_dir(), "/", r.scan_id);
      if (absl::Status s = scans_->Park(r.scan_id, why); !s.ok()) spdlog::warn("recovery: {}", s.ToString());
      j.phase = JobPhase::kFailed;
      j.error = why;
      jobs_.AddFinished(std::move(j));
      spdlog::error("recovery: scan {} ({}): {}", r.scan_id, EscapeForLog(r.name), why);
      continue;
    }
    if (absl::Status s = jobs_.Enqueue(std::move(j), /*force=*/true); !s.ok()) return s;
    ++requeued;
  }
  if (requeued > 0) spdlog::info("recovery: re-queued {} acknowledged scan(s) that were not trained yet", requeued);
  return absl::OkStatus();
}

void ModelHost::FollowReplicas(const std::optional<PlaceHead>& head) {
  if (coordinator_ == nullptr || !coordinator_->replicated() || stopping_) return;
  if (head) {
    if (absl::Status s = publisher_->FollowHead(*head); !s.ok()) {
      spdlog::warn("following version {}: {}", head->version, s.ToString());
    }
  }
  // Under the upload lock from before the listing: a scan acknowledged here
  // after the listing would otherwise look removed and be marked cancelled.
  // Scans before versions: one trained elsewhere meanwhile is then in one of
  // the two lists.
  std::lock_guard<std::mutex> lock(upload_mu_);
  absl::StatusOr<std::vector<ScanRecord>> pending = scans_->List();
  absl::StatusOr<std::vector<VersionInfo>> versions = publisher_->versions().List();
  if (!pending.ok() || !versions.ok()) {
    spdlog::warn("following other replicas: cannot list the store: {}; next poll retries",
                 (pending.ok() ? versions.status() : pending.status()).ToString());
    return;
  }
  std::map<std::string, const VersionInfo*> by_scan;
  for (const VersionInfo& v : *versions) {
    if (v.unavailable.empty()) by_scan[v.scan_id] = &v;
  }
  std::set<std::string> stored;
  // Scans uploaded through other replicas: known here as queued jobs (this
  // replica trains them if it gets the place's lease first).
  for (const ScanRecord& r : *pending) {
    stored.insert(r.scan_id);
    if (jobs_.Get(r.job_id).ok() || by_scan.count(r.scan_id)) continue;
    if (jobs_.Enqueue(QueuedJobFor(r), /*force=*/true).ok()) {
      spdlog::info("job {}: scan {} uploaded through another replica", r.job_id, r.scan_id);
    }
  }
  // Versions published elsewhere by jobs this replica never saw queued (the
  // scan was uploaded and trained between two of its polls): known here as
  // done, so GetJob answers the same on every replica.
  for (const VersionInfo& v : *versions) {
    if (v.version <= followed_version_) continue;
    followed_version_ = v.version;
    if (v.job_id.empty() || !v.unavailable.empty() || jobs_.Get(v.job_id).ok()) continue;
    jobs_.AddFinished(DoneJobOf(v, nullptr));
    spdlog::info("job {}: published version {} through another replica", v.job_id, v.version);
  }
  // Jobs whose scan left the store elsewhere: trained into a version there,
  // or cancelled or parked there.
  const std::string running = jobs_.running();
  for (const JobStatus& j : jobs_.List()) {
    if (IsFinal(j.phase) || j.job_id == running) continue;
    auto v = by_scan.find(j.scan_id);
    // In a version: done, even while the trainer has not removed the scan yet.
    if (v == by_scan.end() && stored.count(j.scan_id)) continue;
    jobs_.Update(j.job_id, [&](JobStatus* s) {
      if (v != by_scan.end()) {
        MarkDoneBy(*v->second, s);
      } else {
        s->phase = JobPhase::kCancelled;
        s->error = "its scan was removed through another replica (cancelled or parked there)";
      }
    });
  }
}

absl::Status ModelHost::WritableStatus() const {
  if (stopping_) return StoppedStatus();
  return publisher_->WritableStatus();
}

absl::StatusOr<UploadAck> ModelHost::AcceptScan(const ScanUpload& upload) {
  absl::StatusOr<UploadAck> ack = AcceptScanImpl(upload);
  metrics_->UploadDone(ack.status().code(), ack.ok() ? ack->bytes : 0);
  return ack;
}

absl::StatusOr<UploadAck> ModelHost::AcceptScanImpl(const ScanUpload& upload) {
  if (absl::Status s = WritableStatus(); !s.ok()) return s;
  // Uploads handed over in one piece (in-process callers) get the limits that
  // ScanAssembler applies to streamed ones.
  if (absl::Status s = CheckUploadLimits(upload, options_.upload_limits()); !s.ok()) return s;
  if (absl::Status s = ValidateScanUpload(upload); !s.ok()) return s;
  std::lock_guard<std::mutex> lock(upload_mu_);
  if (jobs_.queued() >= options_.max_queue) {
    return absl::ResourceExhaustedError(absl::StrCat("update queue is full (", options_.max_queue,
                                                     " scans wait for training); retry later"));
  }
  absl::StatusOr<ReservedIds> ids = publisher_->ReserveIds();
  if (!ids.ok()) return ids.status();
  ScanRecord rec;
  rec.scan_id = ids->scan_id;
  rec.job_id = ids->job_id;
  rec.name = upload.name.empty() ? rec.scan_id : upload.name;
  rec.scene_kind = upload.scene_kind;
  rec.mask_nonzero_is_exclude = upload.mask_nonzero_is_exclude;
  rec.pose_frame = upload.pose_frame;
  rec.sequential = upload.sequential;
  rec.created_unix_ms = NowUnixMs();
  for (const ScanFrame& f : upload.frames) (f.test ? rec.num_test_frames : rec.num_frames)++;
  rec.num_bytes = upload.num_bytes();
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
               EscapeForLog(rec.name), rec.num_frames, rec.num_test_frames, rec.num_bytes, rec.job_id, time_step);
  return UploadAck{rec.scan_id, rec.job_id, time_step, rec.num_bytes};
}

int64_t ModelHost::max_pixels_per_render() const {
  return std::min<int64_t>(options_.max_render_pixels,
                           options_.render_pixel_budget / std::max(1, options_.render_concurrency));
}

absl::StatusOr<RenderResult> ModelHost::Render(const Camera& world_camera, std::optional<int> time_step,
                                               int64_t version, const std::function<bool()>& should_stop,
                                               const std::function<absl::Status()>& why_stopped) {
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<RenderResult> r = RenderImpl(world_camera, time_step, version, should_stop);
  if (absl::IsCancelled(r.status()) && why_stopped) {
    if (absl::Status why = why_stopped(); !why.ok()) r = why;
  }
  metrics_->RenderDone(r.status().code(), SecondsSince(t0));
  return r;
}

absl::StatusOr<RenderResult> ModelHost::RenderImpl(const Camera& world_camera, std::optional<int> time_step,
                                                   int64_t version, const std::function<bool()>& should_stop) {
  if (absl::Status s = ValidateCamera(world_camera); !s.ok()) return s;
  const int64_t pixels = int64_t(world_camera.intrinsics.width) * world_camera.intrinsics.height;
  if (pixels > max_pixels_per_render()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "render of ", pixels, " pixels exceeds the per-request limit of ", max_pixels_per_render(),
        " (render_pixel_budget ", options_.render_pixel_budget, " / render_concurrency ",
        options_.render_concurrency, "); render in tiles or at a smaller size"));
  }
  if (time_step.has_value() && *time_step < 0) {
    return absl::InvalidArgumentError(absl::StrCat("time step ", *time_step,
                                                   " is negative; leave it unset for the latest time step"));
  }
  absl::StatusOr<std::shared_ptr<const Servable>> snap = Snapshot(version);
  if (!snap.ok()) return snap.status();
  const NgpModel& model = (*snap)->model();
  const int t = time_step.value_or(model.num_time_steps() - 1);
  if (t >= model.num_time_steps()) {
    return absl::InvalidArgumentError(absl::StrCat("time step ", t, " is out of range: version ",
                                                   (*snap)->info.version, " has time steps 0..",
                                                   model.num_time_steps() - 1));
  }
  // Big renders wait for a slot (in short slices, so a caller that gave up
  // stops waiting); small ones never queue behind them.
  const bool small = pixels <= options_.small_render_pixels;
  if (!small) {
    const auto give_up = std::chrono::steady_clock::now() +
                         std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                             std::chrono::duration<double>(options_.render_wait_seconds));
    while (!render_slots_->slots.try_acquire_for(std::chrono::milliseconds(50))) {
      if (should_stop && should_stop()) return absl::CancelledError("render abandoned while waiting for a slot");
      if (std::chrono::steady_clock::now() >= give_up) {
        return absl::ResourceExhaustedError("all render slots stayed busy; retry later");
      }
    }
  }
  // Adaptive threads: the cores shared among the big renders running now. A
  // small render lasts milliseconds, so it does not count: otherwise a
  // viewer's last preview, still finishing when its full frame starts, would
  // halve that frame's threads for its whole duration.
  const int big_running = small ? render_slots_->active.load() + 1 : render_slots_->active.fetch_add(1) + 1;
  const auto t0 = std::chrono::steady_clock::now();
  RenderOptions ro;
  ro.threads = options_.render_threads > 0 ? options_.render_threads : std::max(1, cores_ / big_running);
  ro.time_step = t;
  ro.should_stop = should_stop;
  absl::StatusOr<RenderedView> view = RenderView(model, world_camera, ro);
  if (!small) {
    render_slots_->active.fetch_sub(1);
    render_slots_->slots.release();
  }
  if (!view.ok()) return view.status();
  return RenderResult{(*snap)->info.version, t, std::move(view->rgb), SecondsSince(t0)};
}

absl::StatusOr<std::shared_ptr<const Servable>> ModelHost::Snapshot(int64_t version) const {
  absl::StatusOr<std::shared_ptr<const Servable>> snap = publisher_->registry().Get(version);
  if (!snap.ok() && version == 0 && absl::IsFailedPrecondition(snap.status()) && !publisher_->error().empty()) {
    return absl::UnavailableError(absl::StrCat("no version is deployed: ", publisher_->error()));
  }
  return snap;
}

absl::StatusOr<AssetFile> ModelHost::Asset(int64_t version, std::optional<int> time_step, const std::string& file) {
  if (!IsBakedAssetFileName(file)) {
    return absl::InvalidArgumentError(absl::StrCat("asset file '", EscapeForLog(file, 64),
                                                   "' is not manifest.json, index.bin.gz, atlas.bin.gz or view.bin.gz"));
  }
  if (time_step.has_value() && *time_step < 0) {
    return absl::InvalidArgumentError(absl::StrCat("time step ", *time_step, " is negative"));
  }
  const int64_t v = version != 0 ? version : deployed_version();
  if (v == 0) return Snapshot(0).status();  // Nothing deployed: the same error as a render's.
  absl::StatusOr<VersionInfo> info = publisher_->versions().Info(v);
  if (!info.ok()) return info.status();
  const int t = time_step.value_or(info->time_steps - 1);
  if (t >= info->time_steps) {
    return absl::InvalidArgumentError(
        absl::StrCat("time step ", t, " is out of range: version ", v, " has time steps 0..", info->time_steps - 1));
  }
  AssetFile out;
  out.version = v;
  out.time_step = t;
  out.name = file;
  const std::string dir = publisher_->versions().BakedDir(v, t);
  if (!IsBakedAssetDir(dir)) {
    std::lock_guard<std::mutex> lock(bake_mu_);
    if (!IsBakedAssetDir(dir)) {  // Not baked by the request before this one.
      absl::StatusOr<std::shared_ptr<const Servable>> snap = Snapshot(v);
      if (!snap.ok()) return snap.status();
      std::vector<Camera> cameras;
      for (uint32_t i = 0; i < (*snap)->memory().num_cameras(); ++i) cameras.push_back((*snap)->memory().GetCamera(i));
      BakeOptions o = options_.bake;
      o.threads = cores_;
      BakeReport rep;
      absl::StatusOr<BakedAsset> asset = BakeModel((*snap)->model(), t, cameras, o, &rep);
      if (!asset.ok()) {
        return absl::InternalError(absl::StrCat("baking version ", v, " time step ", t, " failed: ",
                                                asset.status().message()));
      }
      absl::Status s = publisher_->versions().WriteBaked(v, t, *asset);
      if (!s.ok() && !absl::IsAlreadyExists(s)) return s;
      metrics_->AssetBaked(rep.total_seconds);
      out.baked_now = true;
      spdlog::info("place {}: baked version {} time step {} for the browser in {:.1f} s", place_, v, t,
                   rep.total_seconds);
    }
  }
  // NOT_FOUND: a diffuse asset's view.bin.gz.
  absl::StatusOr<std::shared_ptr<const AssetBlob>> blob = assets_->Get(dir + "/" + file);
  if (!blob.ok()) return blob.status();
  out.etag = absl::StrCat("\"v", v, "-t", t, "-", file, "-", (*blob)->digest, "\"");
  out.blob = *std::move(blob);
  return out;
}

absl::StatusOr<SceneSummary> ModelHost::Scene(int64_t version) const {
  absl::StatusOr<std::shared_ptr<const Servable>> snap = Snapshot(version);
  if (!snap.ok()) return snap.status();
  return Summarize(**snap);
}

absl::StatusOr<CameraList> ModelHost::Cameras(int64_t version) const {
  absl::StatusOr<std::shared_ptr<const Servable>> snap = Snapshot(version);
  if (!snap.ok()) return snap.status();
  CameraList out;
  out.version = (*snap)->info.version;
  out.time_steps = (*snap)->model().num_time_steps();
  const auto& memory = (*snap)->memory();
  for (uint32_t i = 0; i < memory.num_cameras(); ++i) out.cameras.push_back(memory.GetCamera(i));
  std::stable_sort(out.cameras.begin(), out.cameras.end(),
                   [](const Camera& a, const Camera& b) { return a.time_step < b.time_step; });
  // Names: each version of the lineage recorded its own scan's (its last
  // time step), in camera order.
  std::vector<std::vector<std::string>> names(size_t(out.time_steps));
  VersionInfo info = (*snap)->info;
  for (int guard = 0; guard <= out.time_steps && info.time_steps > 0; ++guard) {
    names[size_t(info.time_steps - 1)] = info.frame_names;
    if (info.parent == 0) break;
    absl::StatusOr<VersionInfo> parent = publisher_->versions().Info(info.parent);
    if (!parent.ok()) break;
    info = *std::move(parent);
  }
  std::vector<size_t> seen(size_t(out.time_steps), 0);
  for (const Camera& c : out.cameras) {
    const size_t t = size_t(std::clamp(c.time_step, 0, std::max(0, out.time_steps - 1)));
    const size_t i = seen[t]++;
    out.index.push_back(int(i));
    out.names.push_back(t < names.size() && i < names[t].size() ? names[t][i] : std::string());
  }
  return out;
}

absl::StatusOr<LocalizeResult> ModelHost::Localize(int64_t version, const std::vector<PhotoQuery>& photos,
                                                   const std::function<bool()>& should_stop) const {
  absl::StatusOr<std::shared_ptr<const Servable>> snap = Snapshot(version);
  if (!snap.ok()) return snap.status();
  const auto t0 = std::chrono::steady_clock::now();
  const auto give_up = t0 + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                std::chrono::duration<double>(options_.render_wait_seconds));
  while (!render_slots_->slots.try_acquire_for(std::chrono::milliseconds(50))) {
    if (should_stop && should_stop()) return absl::CancelledError("localisation abandoned while waiting for a slot");
    if (std::chrono::steady_clock::now() >= give_up) {
      return absl::ResourceExhaustedError("all render slots stayed busy; retry later");
    }
  }
  render_slots_->active.fetch_add(1);
  std::vector<Camera> place;
  for (uint32_t i = 0; i < (*snap)->memory().num_cameras(); ++i) place.push_back((*snap)->memory().GetCamera(i));
  RenderOptions ro;
  ro.threads = options_.render_threads > 0 ? options_.render_threads : cores_;
  ModelPlaceMap map((*snap)->model(), ro);
  absl::StatusOr<PhotoLocalizationReport> r = LocalizePhotos(photos, map, place, options_.registration);
  render_slots_->active.fetch_sub(1);
  render_slots_->slots.release();
  if (!r.ok()) return r.status();
  return LocalizeResult{(*snap)->info.version, *std::move(r), SecondsSince(t0)};
}

absl::StatusOr<JobStatus> ModelHost::CancelJob(const std::string& id) {
  absl::StatusOr<JobStatus> before = jobs_.Get(id);
  if (!before.ok()) return before.status();
  // Replicas: a job queued here may be training on the replica that holds
  // the place's lease; removing its scan would not stop it, and it would
  // ship after this replica said "cancelled". So a queued job is cancelled
  // only while this replica holds the lease (no other can train or publish
  // the place meanwhile: their commits are fenced); else refused.
  bool took_lease = false;
  if (coordinator_ != nullptr && coordinator_->replicated() && !IsFinal(before->phase) &&
      jobs_.running() != id) {
    const bool held = coordinator_->Holds(place_);
    absl::StatusOr<bool> lease = coordinator_->TryAcquire(place_);
    if (!lease.ok()) return lease.status();
    if (!*lease) {
      return absl::FailedPreconditionError(absl::StrCat(
          "job ", id, " cannot be cancelled through this replica: another replica is training place '", place_,
          "' and may be running it; cancel it through that replica, or once it is idle"));
    }
    took_lease = !held;
  }
  absl::StatusOr<JobStatus> out = CancelJobLocally(id, *before);
  // As the worker does when it runs out of work: let any replica train next.
  if (took_lease && jobs_.queued() == 0 && jobs_.running().empty()) coordinator_->Release(place_);
  return out;
}

absl::StatusOr<JobStatus> ModelHost::CancelJobLocally(const std::string& id, const JobStatus& before_cancel) {
  const JobStatus* before = &before_cancel;
  absl::StatusOr<bool> was_queued = jobs_.Cancel(id);
  if (!was_queued.ok()) return was_queued.status();
  if (*was_queued) {
    if (absl::Status s = scans_->Remove(before->scan_id); !s.ok()) spdlog::warn("cancel {}: {}", id, s.ToString());
    spdlog::info("job {} cancelled while queued; scan {} removed", id, before->scan_id);
  } else {
    worker_->CancelRunning();
    spdlog::info("job {}: cancellation requested", id);
  }
  return jobs_.Get(id);
}

absl::StatusOr<VersionInfo> ModelHost::SetDeployedVersion(int64_t v) {
  absl::StatusOr<VersionInfo> info = publisher_->SetDeployed(v);
  if (info.ok()) spdlog::info("deployed version {} (rollback/pin)", v);
  return info;
}

HostInfo ModelHost::Info() const {
  HostInfo info;
  if (const std::optional<DeployedSummary> d = publisher_->registry().deployed()) {
    info.deployed_version = d->info.version;
    info.time_steps = d->info.time_steps;
    info.model_bytes = d->model_bytes;
    info.memory_bytes = d->memory_bytes;
    info.replay_cameras = d->replay_cameras;
    if (const std::shared_ptr<const Servable> s = publisher_->registry().Peek(); s != nullptr) {
      info.loaded = true;
      info.memory_bytes = ServableBytes(*s);
      info.replay_cameras = int64_t(s->memory().num_cameras());
    }
  }
  info.queued_jobs = jobs_.queued();
  info.running_job = jobs_.running();
  info.store_error = publisher_->error();
  info.uptime_seconds = SecondsSince(started_);
  return info;
}

absl::Status ModelHost::StoppedStatus() const {
  if (deleted_) return absl::NotFoundError(absl::StrCat("place '", place_, "' was deleted"));
  return absl::UnavailableError("server is shutting down");
}

void ModelHost::MarkDeleted() {
  deleted_ = true;
  if (worker_) worker_->PlaceDeleted();
}

bool ModelHost::Shutdown() {
  std::call_once(shutdown_once_, [this] {
    stopping_ = true;
    jobs_.Shutdown();
    if (worker_ && !worker_->Stop(std::chrono::duration<double>(options_.shutdown_grace_seconds))) {
      spdlog::error("the update worker did not stop within {} s", options_.shutdown_grace_seconds);
      shutdown_clean_ = false;
    }
  });
  return shutdown_clean_;
}

}  // namespace clnerf
