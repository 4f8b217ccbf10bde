#include "core/continual/continual_update.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "absl/strings/str_format.h"
#include "core/continual/continual_sampler.h"
#include "core/data/stopwatch.h"
#include "core/render/metrics.h"
#include "core/render/renderer.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {
constexpr std::pair<ContinualMethod, const char*> kMethods[] = {
    {ContinualMethod::kNT, "nt"},         {ContinualMethod::kEWC, "ewc"},
    {ContinualMethod::kER, "er"},         {ContinualMethod::kMEIL, "meil"},
    {ContinualMethod::kCLNeRF, "clnerf"}, {ContinualMethod::kCLNeRFNoER, "clnerf-noer"},
};
// The new scan's cameras as M_t keeps them: as uploaded, or with the
// refiner's corrections (model space back to world), which go into `rep`.
std::vector<Camera> NewScanCameras(const Scene& scan, const NgpModel& model, const CameraRefiner* refiner,
                                   UpdateReport* rep) {
  std::vector<Camera> out;
  for (const View& v : scan.train) out.push_back(v.camera);
  if (refiner == nullptr) return out;
  const Normalization& norm = model.normalization();
  for (size_t i = 0; i < out.size(); ++i) {
    const Camera& m = refiner->camera(int(i));
    out[i].c2w.leftCols<3>() = norm.rotation.transpose() * m.c2w.leftCols<3>();
    out[i].c2w.col(3) = norm.ToWorld(m.c2w.col(3));
  }
  const CameraRefiner::Stats st = refiner->CorrectionStats();
  rep->refined_cameras = int(out.size());
  rep->camera_turn_median_deg = st.turn_median_deg;
  rep->camera_turn_max_deg = st.turn_max_deg;
  rep->camera_shift_median = st.shift_median / norm.scale;  // World units.
  rep->camera_shift_max = st.shift_max / norm.scale;
  rep->camera_clamped = refiner->clamped();
  rep->camera_refine_summary = refiner->Summary();
  return out;
}

}  // namespace

absl::StatusOr<ContinualMethod> ParseContinualMethod(const std::string& name) {
  for (const auto& [m, n] : kMethods) {
    if (name == n) return m;
  }
  return absl::InvalidArgumentError(
      absl::StrFormat("unknown method '%s' (nt, ewc, er, meil, clnerf, clnerf-noer)", name));
}

const char* ContinualMethodName(ContinualMethod m) {
  for (const auto& [mm, n] : kMethods) {
    if (mm == m) return n;
  }
  return "?";
}

absl::StatusOr<InitMode> ParseInitMode(const std::string& name) {
  if (name == "warm") return InitMode::kWarm;
  if (name == "reinit") return InitMode::kReinit;
  return absl::InvalidArgumentError(absl::StrFormat("unknown init mode '%s' (warm, reinit)", name));
}

const char* InitModeName(InitMode m) { return m == InitMode::kWarm ? "warm" : "reinit"; }

absl::StatusOr<ReplayMode> ParseReplayMode(const std::string& name) {
  if (name == "offline") return ReplayMode::kOffline;
  if (name == "online") return ReplayMode::kOnline;
  return absl::InvalidArgumentError(absl::StrFormat("unknown replay mode '%s' (offline, online)", name));
}

const char* ReplayModeName(ReplayMode m) { return m == ReplayMode::kOffline ? "offline" : "online"; }

const char* UpdatePhaseName(UpdatePhase p) {
  switch (p) {
    case UpdatePhase::kPreparingReplay: return "preparing replay";
    case UpdatePhase::kTraining: return "training";
    case UpdatePhase::kFinalizing: return "finalizing";
  }
  return "?";
}

absl::Status UpdateOptions::Validate() const {
  if (buffer_size < 0) return absl::InvalidArgumentError("buffer size must be >= 0");
  if (!(ewc_lambda >= 0) || ewc_batches < 1) return absl::InvalidArgumentError("bad EWC options");
  if (!(warm_lr_scale > 0 && warm_lr_scale <= 1)) return absl::InvalidArgumentError("warm_lr_scale must be in (0, 1]");
  if (!(new_scan_share >= 0 && new_scan_share < 1)) return absl::InvalidArgumentError("new_scan_share must be in [0, 1)");
  if (!(depth_fraction >= 0 && depth_fraction <= 1)) return absl::InvalidArgumentError("depth_fraction must be in [0, 1]");
  if (!(meil_new_fraction > 0 && meil_new_fraction < 1)) {
    return absl::InvalidArgumentError("meil_new_fraction must be in (0, 1)");
  }
  for (const absl::Status& s : {train.Validate(), model.Validate(), capacity.Validate(), replay_labels.Validate(),
                                 replay_weights.Validate(), replay_confidence.Validate(), view_error.Validate(),
                                 refine_cameras ? camera_refine.Validate() : absl::OkStatus()}) {
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::StatusOr<ContinualState> ContinualUpdate(const Scene& scan, const ContinualState* prev,
                                               const UpdateOptions& options, const UpdateProgressFn& progress,
                                               const std::atomic<bool>* cancel, UpdateReport* report) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (scan.train.empty()) return absl::InvalidArgumentError("the new scan has no training views");
  if (absl::Status s = ValidateScene(scan); !s.ok()) return s;
  if (prev != nullptr && (prev->model == nullptr || !prev->model->AllFinite())) {
    return absl::FailedPreconditionError("the previous model is missing or has non-finite parameters");
  }
  const int t = prev != nullptr ? prev->model->num_time_steps() : 0;
  for (const View& v : scan.train) {
    if (v.camera.time_step != t) {
      return absl::InvalidArgumentError(
          absl::StrFormat("view '%s' has time step %d but the new scan is step %d", v.name, v.camera.time_step, t));
    }
  }
  if (prev != nullptr) {
    // M_{t-1} must be the memory of θ_{t-1}'s version: its cameras cover time
    // steps 0..t-1. A memory from an older (or newer) version would silently
    // drop (or invent) scans from the replay.
    const int max_step = prev->memory.MaxTimeStep();
    if (max_step != t - 1) {
      return absl::FailedPreconditionError(absl::StrFormat(
          "the replay memory does not belong to the previous model: its cameras reach time step %d, the model has "
          "%d time steps (a memory from another version?)",
          max_step, t));
    }
  }
  const auto start = std::chrono::steady_clock::now();
  UpdateReport rep;
  rep.time_step = t;
  const ContinualMethod method = options.method;
  const uint64_t seed = options.train.seed * 1000003ull + uint64_t(t);

  // θ_t's initialisation.
  std::unique_ptr<NgpModel> model;
  if (prev == nullptr) {
    const Normalization norm = ComputeNormalization(scan);
    ModelOptions mo = options.model;
    if (options.derive_capacity) mo = DeriveModelOptions(scan, norm, options.capacity, mo);
    absl::StatusOr<NgpModel> m = NgpModel::Create(mo, norm, scan.kind, scan.background, 1, seed);
    if (!m.ok()) return m.status();
    model = std::make_unique<NgpModel>(std::move(*m));
  } else if (options.init == InitMode::kWarm) {
    model = std::make_unique<NgpModel>(*prev->model);  // Copy: θ_{t-1} stays untouched.
    if (options.copy_embedding) {
      model->AddTimeStepCopyingLast();
    } else {
      model->AddTimeStep(seed);
    }
  } else {
    const NgpModel& p = *prev->model;
    absl::StatusOr<NgpModel> m = NgpModel::Create(p.options(), p.normalization(), p.kind(), p.background(), t + 1, seed);
    if (!m.ok()) return m.status();
    model = std::make_unique<NgpModel>(std::move(*m));
  }

  // Views for this step: new scan + (ER) buffer + (GR) every other past view.
  const bool use_buffer = method == ContinualMethod::kER || method == ContinualMethod::kCLNeRF;
  const bool use_gr = method == ContinualMethod::kCLNeRF || method == ContinualMethod::kCLNeRFNoER ||
                      method == ContinualMethod::kMEIL;
  std::vector<SamplerView> views;
  for (const View& v : scan.train) {
    views.push_back({v.camera, &v.image, v.mask.empty() ? nullptr : &v.mask, false, false, &v.depth});
  }
  rep.new_views = int(scan.train.size());
  std::vector<ReplayLabelView> cache;  // Offline replay labels.
  if (prev != nullptr) {
    const ReplayMemory& mem = prev->memory;
    if (use_buffer) {
      for (const BufferedImage& b : mem.buffer()) {
        views.push_back({mem.GetCamera(b.camera), &b.image, b.mask.empty() ? nullptr : &b.mask, false, true});
        ++rep.buffer_views;
      }
    }
    if (use_gr) {
      std::vector<uint32_t> gr;
      for (uint32_t i = 0; i < mem.num_cameras(); ++i) {
        if (!(use_buffer && mem.InBuffer(i))) gr.push_back(i);
      }
      rep.replay_views = int(gr.size());
      const auto t0 = std::chrono::steady_clock::now();
      if (options.replay == ReplayMode::kOffline) {
        std::vector<Camera> cams;
        for (uint32_t i : gr) cams.push_back(mem.GetCamera(i));
        // The replay draws this update can make: steps x the adaptive batch
        // (estimated from θ_{t-1}'s samples per ray; the first batch's size
        // when the batch is fixed) x the replay views' share of the batch.
        const double spr = ProbeSamplesPerRay(*prev->model, cams, options.replay_labels.probe_rays, seed ^ 0x9e37);
        const TrainOptions& tr = options.train;
        double batch = tr.batch_rays;
        if (tr.target_samples > 0 && spr > 0) {
          batch = std::clamp(double(tr.target_samples) / spr, 256.0, double(tr.max_batch_rays));
        }
        const double total_views = double(views.size() + gr.size());
        double share = double(gr.size()) / total_views;
        if (method == ContinualMethod::kMEIL) {
          share = 1.0 - options.meil_new_fraction;
        } else if (options.new_scan_share > 0) {
          share = (1.0 - options.new_scan_share) * double(gr.size()) / double(gr.size() + rep.buffer_views);
        }
        const long long per_view =
            LabelsPerView(double(tr.iterations) * batch * share, int(gr.size()), options.replay_labels);
        ReplayLabelReport lr;
        absl::StatusOr<std::vector<ReplayLabelView>> labels = RenderReplayLabels(
            *prev->model, cams, per_view, seed ^ 0x1abe1, cancel,
            [&](int done, int total) {
              if (!progress) return;
              UpdateProgress p;
              p.phase = UpdatePhase::kPreparingReplay;
              p.iteration = done;
              p.total = total;
              p.elapsed_seconds = SecondsSince(start);
              progress(p);
            },
            &lr);
        if (!labels.ok()) return labels.status();
        cache = std::move(*labels);
        ReplayWeightReport wr;
        if (absl::Status s = WeightReplayLabels(*prev->model, cams, scan.train, options.replay_weights, cancel, &cache,
                                                &wr);
            !s.ok()) {
          return s;
        }
        rep.replay_seen_labels = wr.seen;
        ReplayConfidenceReport cr;
        if (absl::Status s = ApplyReplayConfidence(prev->previous_model.get(), cams, options.replay_confidence, cancel,
                                                   &cache, &cr);
            !s.ok()) {
          return s;
        }
        rep.replay_confidence_mean = cr.mean_factor;
        rep.replay_compared_labels = cr.compared;
        rep.replay_confidence_seconds = cr.seconds;
        for (ReplayLabelView& v : cache) {
          rep.replay_depth_labels += SetDistillationDepths(options.replay_labels.depth_min_opacity, &v);
        }
        rep.replay_weight_seconds = wr.seconds;
        rep.replay_cache_bytes = lr.bytes;
        rep.replay_labels = lr.labels;
        rep.replay_view_pixels = lr.view_pixels;
        rep.replay_probe_samples_per_ray = spr;
        for (size_t k = 0; k < gr.size(); ++k) {
          if (cache[k].rgb.empty()) continue;  // Every label was seen by the new scan (seen_weight 0).
          SamplerView sv{cams[k], &cache[k].rgb, nullptr, true, true};
          if (!cache[k].pixels.empty()) sv.label_pixels = &cache[k].pixels;
          if (!cache[k].weight.empty()) sv.label_weight = &cache[k].weight;
          if (!cache[k].target_depth.empty()) sv.label_depth = &cache[k].target_depth;
          views.push_back(sv);
        }
      } else {
        for (uint32_t i : gr) views.push_back({mem.GetCamera(i), nullptr, nullptr, true, true});
      }
      rep.replay_prepare_seconds = SecondsSince(t0);
    }
  }
  const float meil = method == ContinualMethod::kMEIL ? options.meil_new_fraction : 0.0f;
  ContinualRaySampler sampler(std::move(views), *model, prev != nullptr ? prev->model.get() : nullptr, meil,
                              method == ContinualMethod::kMEIL ? 0.0f : options.new_scan_share,
                              options.depth_fraction);

  if (method != ContinualMethod::kMEIL && options.new_scan_share <= 0) sampler.SetViewErrorSampling(options.view_error);
  rep.depth_pixels = options.depth_fraction > 0 ? sampler.num_depth_pixels() : 0;
  TrainOptions to = options.train;
  to.seed = seed;
  if (prev != nullptr && options.init == InitMode::kWarm) to.learning_rate *= options.warm_lr_scale;
  if (method == ContinualMethod::kEWC && prev != nullptr && prev->ewc != nullptr) to.ewc = prev->ewc.get();
  if (options.carry_optimizer && options.init == InitMode::kWarm && prev != nullptr && prev->optimizer != nullptr) {
    if (absl::Status s = prev->optimizer->CompatibleWith(model->params()); s.ok()) {
      to.resume = prev->optimizer.get();
    } else {
      spdlog::warn("update step {}: starting a fresh optimiser: {}", t, std::string(s.message()));
    }
  }
  Trainer trainer(model.get(), &sampler, to);
  // Pose corrections of the new scan's photos (views 0..n-1 of the sampler),
  // only where past views hold the frame.
  // Not for re-init: a field that starts random gives the cameras noise.
  const bool refine = options.refine_cameras && prev != nullptr && options.init == InitMode::kWarm &&
                      rep.replay_views + rep.buffer_views > 0;
  if (refine) {
    std::vector<uint8_t> which(sampler.Cameras().size(), 0);
    std::fill_n(which.begin(), scan.train.size(), uint8_t(1));
    if (absl::Status s = trainer.RefineCameras(options.camera_refine, std::move(which)); !s.ok()) return s;
  }
  absl::Status st = trainer.Run(
      [&](const StepStats& s) {
        if (!progress) return;
        UpdateProgress p;
        p.phase = UpdatePhase::kTraining;
        p.iteration = s.step;
        p.total = to.iterations;
        p.elapsed_seconds = SecondsSince(start);
        p.eta_seconds = trainer.total_seconds() / std::max(1, s.step) * (to.iterations - s.step);
        p.loss = s.loss;
        p.psnr = s.psnr;
        progress(p);
      },
      cancel);
  if (!st.ok()) return st;
  cache.clear();
  cache.shrink_to_fit();
  rep.train_seconds = trainer.total_seconds();
  rep.samples = trainer.total_samples();
  rep.skipped_batches = trainer.skipped_batches();
  if (progress) {
    UpdateProgress p;
    p.phase = UpdatePhase::kFinalizing;
    p.iteration = p.total = to.iterations;
    p.elapsed_seconds = SecondsSince(start);
    progress(p);
  }

  // M_t: every new camera, then the buffer policy.
  ContinualState next;
  if (options.carry_optimizer) next.optimizer = std::make_shared<const OptimizerState>(trainer.ExportOptimizerState());
  if (options.replay_confidence.agreement_tolerance > 0.0f && prev != nullptr) next.previous_model = prev->model;
  // Only methods that replay real images keep any (clnerf-noer, nt, ewc and
  // meil store cameras only).
  const int k_buffer = use_buffer ? options.buffer_size : 0;
  next.memory = prev != nullptr ? prev->memory : ReplayMemory(k_buffer);
  std::mt19937_64 rng(seed ^ 0x5eed);
  std::vector<uint32_t> new_ids;
  const std::vector<Camera> new_cameras = NewScanCameras(scan, *model, trainer.camera_refiner(), &rep);
  for (const Camera& c : new_cameras) new_ids.push_back(next.memory.AddCamera(c));
  if (options.prioritized_buffer && k_buffer > 0) {
    // Keep the K images (old buffer ∪ new scan) with the lowest PSNR under θ_t.
    std::vector<std::pair<double, BufferedImage>> cand;
    for (const BufferedImage& b : next.memory.buffer()) cand.push_back({0.0, b});
    for (size_t i = 0; i < scan.train.size(); ++i) cand.push_back({0.0, {new_ids[i], scan.train[i].image, scan.train[i].mask}});
    for (auto& [score, b] : cand) {
      const Camera cam = next.memory.GetCamera(b.camera);
      RenderOptions ro;
      ro.time_step = cam.time_step;
      absl::StatusOr<RenderedView> r = RenderView(*model, cam, ro);
      if (!r.ok()) return r.status();
      score = Psnr(r->rgb, b.image);
    }
    std::sort(cand.begin(), cand.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<BufferedImage> keep;
    for (size_t i = 0; i < cand.size() && int(i) < k_buffer; ++i) keep.push_back(std::move(cand[i].second));
    next.memory.SetBuffer(std::move(keep));
  } else {
    for (size_t i = 0; i < scan.train.size(); ++i) {
      next.memory.OfferReservoir(new_ids[i], scan.train[i].image, scan.train[i].mask, &rng);
    }
  }

  // EWC: diagonal Fisher of θ_t on this step's data, for the next step.
  if (method == ContinualMethod::kEWC) {
    std::vector<const View*> vs;
    for (const View& v : scan.train) vs.push_back(&v);
    absl::StatusOr<std::unique_ptr<ImageRaySampler>> s = ImageRaySampler::Create(vs, *model);
    if (!s.ok()) return s.status();
    TrainOptions fo = options.train;
    fo.seed = seed + 17;
    Trainer fisher_trainer(model.get(), s->get(), fo);
    auto pen = std::make_shared<EwcPenalty>();
    pen->lambda = options.ewc_lambda;
    pen->anchor = model->params();
    pen->fisher.grid.assign(model->params().grid.size(), 0.0f);
    pen->fisher.mlp.assign(model->params().mlp.size(), 0.0f);
    pen->fisher.emb.assign(model->params().emb.size(), 0.0f);
    std::mt19937_64 frng(fo.seed);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int b = 0; b < options.ewc_batches; ++b) {
      RayBatch batch;
      (*s)->Sample(options.train.batch_rays, &frng, &batch);
      std::vector<float> jitter(batch.size());
      for (float& j : jitter) j = u(frng);
      Trainer::Gradients g;
      fisher_trainer.ComputeLossAndGradients(batch, jitter, &g);
      const float inv = 1.0f / options.ewc_batches;
      for (size_t i = 0; i < g.grid.size(); ++i) pen->fisher.grid[i] += g.grid[i] * g.grid[i] * inv;
      for (size_t i = 0; i < g.mlp.size(); ++i) pen->fisher.mlp[i] += g.mlp[i] * g.mlp[i] * inv;
      for (size_t i = 0; i < g.emb.size(); ++i) pen->fisher.emb[i] += g.emb[i] * g.emb[i] * inv;
    }
    next.ewc = pen;
  }
  if (!model->AllFinite()) return absl::InternalError("update produced non-finite parameters");
  if (rep.refined_cameras > 0) spdlog::info("update step {}: cameras refined: {}", t, rep.camera_refine_summary);
  next.model = std::move(model);
  if (report != nullptr) *report = rep;
  spdlog::debug("update step {}: {} new, {} buffer, {} replay views; replay prep {:.1f}s ({} bytes); train {:.1f}s",
                t, rep.new_views, rep.buffer_views, rep.replay_views, rep.replay_prepare_seconds,
                rep.replay_cache_bytes, rep.train_seconds);
  return next;
}

}  // namespace clnerf
