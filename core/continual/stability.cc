#include "core/continual/stability.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <optional>
#include <random>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/continual/continual_update.h"
#include "core/data/stopwatch.h"
#include "core/render/evaluate.h"
#include "core/train/fit.h"
#include "core/data/procedural_scene.h"
#include "core/continual/scan_sequence.h"

namespace clnerf {

namespace {

constexpr std::pair<Stressor, const char*> kStressors[] = {
    {Stressor::kNone, "none"},
    {Stressor::kItersX5, "iters_x5"},
    {Stressor::kLrX3, "lr_x3"},
    {Stressor::kLrX10, "lr_x10"},
    {Stressor::kChain20, "chain_20"},
    {Stressor::kBlankScan, "blank_scan"},
    {Stressor::kSingleView, "single_view"},
    {Stressor::kFarCameras, "far_cameras"},
    {Stressor::kNanGradient, "nan_gradient"},
    {Stressor::kStaleMemory, "stale_memory"},
};

absl::StatusOr<ScanSequence> Sequence(const StabilityOptions& o, int scans, float camera_radius) {
  ProceduralSceneOptions po;
  po.name = "stability";
  po.width = po.height = o.image_size;
  po.num_train_views = o.train_views;
  po.num_test_views = o.test_views;
  po.num_time_steps = scans;
  po.seed = o.seed;
  po.camera_radius = camera_radius;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  if (!scene.ok()) return scene.status();
  return FromTimeSteps(*scene);
}

// The sequence with the stressor's change applied to its last scan.
absl::StatusOr<ScanSequence> StressedSequence(const StabilityOptions& o, Stressor stressor) {
  const int scans = stressor == Stressor::kChain20 ? o.chain_scans : o.scans;
  absl::StatusOr<ScanSequence> seq = Sequence(o, scans, 4.0f);
  if (!seq.ok()) return seq.status();
  Scan& last = seq->scans.back();
  switch (stressor) {
    case Stressor::kBlankScan: {
      // Near-constant grey: 0.5 +- 0.01 of deterministic noise.
      std::mt19937 rng(uint32_t(o.seed) ^ 0xb1a4u);
      std::uniform_real_distribution<float> u(-0.01f, 0.01f);
      for (auto* views : {&last.train, &last.test}) {
        for (View& v : *views) {
          for (float& x : v.image.rgb) x = 0.5f + u(rng);
        }
      }
      break;
    }
    case Stressor::kSingleView:
      last.train.resize(1);
      break;
    case Stressor::kFarCameras: {
      // The same world seen from 5x farther out (radius 20 instead of 4):
      // the cameras are far outside the box the first scan set.
      absl::StatusOr<ScanSequence> far = Sequence(o, scans, 20.0f);
      if (!far.ok()) return far.status();
      last = far->scans.back();
      break;
    }
    default:
      break;
  }
  return seq;
}

void SetTimeStep(Scene* s, int t) {
  for (auto* views : {&s->train, &s->test}) {
    for (View& v : *views) v.camera.time_step = t;
  }
}

bool SameBits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0);
}

// θ_{t-1} and M_{t-1} as bits, to check that an update left them alone.
struct Snapshot {
  ModelParams params;
  std::vector<float> density;
  std::string memory;
  static Snapshot Of(const ContinualState& s) {
    return {s.model->params(), s.model->occupancy().density(), s.memory.Serialize()};
  }
  bool Matches(const ContinualState& s) const {
    const ModelParams& p = s.model->params();
    return SameBits(p.grid, params.grid) && SameBits(p.mlp, params.mlp) && SameBits(p.emb, params.emb) &&
           SameBits(s.model->occupancy().density(), density) && s.memory.Serialize() == memory;
  }
};

void SetBatch(const StabilityOptions& o, TrainOptions* t) {
  t->target_samples = o.batch_samples;
  t->batch_rays = std::clamp(o.batch_samples / 32, 256, t->batch_rays);
}

void Stress(Stressor stressor, TrainOptions* t) {
  switch (stressor) {
    case Stressor::kItersX5: t->iterations *= 5; break;
    case Stressor::kLrX3: t->learning_rate *= 3; break;
    case Stressor::kLrX10: t->learning_rate *= 10; break;
    case Stressor::kNanGradient: t->inject_nan_gradient_at_step = std::max(1, t->iterations / 2); break;
    default: break;
  }
}

// Mean test PSNR over all test images of the listed scans, each scored with
// the time step it was deployed as.
absl::StatusOr<std::pair<double, int>> Score(const NgpModel& model, const ScanSequence& seq,
                                              const std::vector<std::pair<int, int>>& deployed, int threads) {
  std::vector<View> views;
  for (const auto& [scan, step] : deployed) {
    for (View v : seq.scans[scan].test) {
      v.camera.time_step = step;
      views.push_back(std::move(v));
    }
  }
  if (views.empty()) return std::make_pair(0.0, 0);
  EvalOptions eo;
  eo.render.threads = threads;
  absl::StatusOr<EvalResult> r = EvaluateViews(model, views, eo);
  if (!r.ok()) return r.status();
  return std::make_pair(r->psnr, int(deployed.size()));  // Mean over the views.

}

absl::StatusOr<StabilityCell> RunUpperBound(StabilityCell cell, const ScanSequence& seq, const StabilityOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  FitOptions fo;
  fo.train.iterations = o.iterations * seq.size();
  fo.train.seed = o.seed;
  fo.train.threads = o.threads;
  SetBatch(o, &fo.train);
  Stress(cell.stressor, &fo.train);
  fo.model = o.model;
  fo.capacity = o.capacity;
  const Scene all = seq.Union(seq.size() - 1);
  cell.updates = 1;
  absl::StatusOr<FitResult> fit = FitScene(all, fo, nullptr);
  if (!fit.ok()) {
    if (!absl::IsInternal(fit.status())) return fit.status();
    cell.failed = 1;
    cell.reason = std::string(fit.status().message());
    cell.seconds = SecondsSince(t0);
    return cell;
  }
  cell.skipped_batches = fit->skipped_batches;
  const GateReport gate = RunDeploymentGate(*fit->model, all, nullptr, nullptr, o.gate, o.threads);
  std::vector<std::pair<int, int>> deployed;
  for (int t = 0; t < seq.size(); ++t) deployed.push_back({t, t});
  absl::StatusOr<std::pair<double, int>> sc = Score(*fit->model, seq, deployed, o.threads);
  if (!sc.ok()) return sc.status();
  if (!gate.status.ok()) {
    cell.refused = 1;
    cell.reason = std::string(gate.status.message());
    cell.refused_psnr = sc->first;
    cell.seconds = SecondsSince(t0);
    return cell;
  }
  cell.stressed_deployed = cell.has_model = true;
  cell.deployed_always_finite = fit->model->AllFinite();
  cell.psnr = sc->first;
  cell.scored_scans = sc->second;
  cell.seconds = SecondsSince(t0);
  return cell;
}

}  // namespace

const std::vector<Stressor>& AllStressors() {
  static const std::vector<Stressor> all = [] {
    std::vector<Stressor> v;
    for (const auto& [s, n] : kStressors) v.push_back(s);
    return v;
  }();
  return all;
}

const char* StressorName(Stressor s) {
  for (const auto& [ss, n] : kStressors) {
    if (ss == s) return n;
  }
  return "?";
}

absl::StatusOr<Stressor> ParseStressor(const std::string& name) {
  for (const auto& [s, n] : kStressors) {
    if (name == n) return s;
  }
  return absl::InvalidArgumentError(absl::StrFormat("unknown stressor '%s'", name));
}

absl::Status StabilityOptions::Validate() const {
  if (scans < 2) return absl::InvalidArgumentError("stability: scans must be >= 2 (the stressed update needs a past)");
  if (chain_scans < 2) return absl::InvalidArgumentError("stability: chain_scans must be >= 2");
  if (image_size < 8 || image_size > 512) return absl::InvalidArgumentError("stability: image_size must be in [8, 512]");
  if (train_views < 1 || test_views < 1) return absl::InvalidArgumentError("stability: need train and test views");
  if (iterations < 1) return absl::InvalidArgumentError("stability: iterations must be >= 1");
  if (buffer < 0) return absl::InvalidArgumentError("stability: buffer must be >= 0");
  if (batch_samples < 256) return absl::InvalidArgumentError("stability: batch_samples must be >= 256");
  if (threads < 0) return absl::InvalidArgumentError("stability: threads must be >= 0");
  for (const absl::Status& s : {gate.Validate(), model.Validate(), capacity.Validate()}) {
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

std::string StabilityCell::Summary() const {
  if (!applicable) return "n/a";
  std::string s;
  if (stressed_deployed) {
    s = absl::StrFormat("%.2f", psnr);
  } else if (failed > 0 && reason.find("diverged") != std::string::npos) {
    s = "diverged -> refused";
  } else if (failed > 0) {
    s = "failed -> refused";
  } else {
    s = absl::StrFormat("refused by gate (%.2f)", refused_psnr);
  }
  const int others = failed + refused - (stressed_deployed ? 0 : 1);
  if (others > 0) s += absl::StrFormat(" (%d refused)", others);
  if (!deployed_always_finite) s += " NON-FINITE DEPLOYED";
  if (!previous_always_intact) s += " PREVIOUS MODIFIED";
  return s;
}

absl::StatusOr<StabilityCell> RunStabilityCell(const std::string& method, Stressor stressor,
                                               const StabilityOptions& o) {
  if (absl::Status s = o.Validate(); !s.ok()) return s;
  StabilityCell cell;
  cell.method = method;
  cell.stressor = stressor;
  const bool ub = method == "ub";
  ContinualMethod cm = ContinualMethod::kCLNeRF;
  if (!ub) {
    absl::StatusOr<ContinualMethod> m = ParseContinualMethod(method);
    if (!m.ok()) return absl::InvalidArgumentError(absl::StrCat(m.status().message(), " or ub"));
    cm = *m;
  }
  if (ub && stressor == Stressor::kStaleMemory) {
    cell.applicable = false;
    return cell;
  }
  absl::StatusOr<ScanSequence> seq = StressedSequence(o, stressor);
  if (!seq.ok()) return seq.status();
  if (ub) return RunUpperBound(std::move(cell), *seq, o);

  const auto t0 = std::chrono::steady_clock::now();
  UpdateOptions base;
  base.method = cm;
  base.init = InitMode::kWarm;
  base.replay = ReplayMode::kOffline;
  base.buffer_size = cm == ContinualMethod::kCLNeRFNoER ? 0 : o.buffer;
  base.train.iterations = o.iterations;
  base.train.seed = o.seed;
  base.train.threads = o.threads;
  SetBatch(o, &base.train);
  base.model = o.model;
  base.capacity = o.capacity;
  if (absl::Status s = base.Validate(); !s.ok()) return s;

  std::optional<ContinualState> deployed, before;  // θ_{t-1}, and the version before it.
  std::vector<std::pair<int, int>> held;           // (scan, time step) the deployed model holds.
  const int T = seq->size();
  for (int t = 0; t < T; ++t) {
    const bool stressed = t == T - 1;
    UpdateOptions uo = base;
    if (stressed) Stress(stressor, &uo.train);
    Scene scan = seq->ScanScene(t);
    const int step = deployed ? deployed->model->num_time_steps() : 0;
    SetTimeStep(&scan, step);
    // The state the update starts from (stale_memory: θ_{t-1} with M_{t-2}).
    std::optional<ContinualState> from = deployed;
    if (stressed && stressor == Stressor::kStaleMemory && from && before) from->memory = before->memory;
    std::optional<Snapshot> snap;
    if (from) snap = Snapshot::Of(*from);
    ++cell.updates;
    UpdateReport rep;
    absl::StatusOr<ContinualState> next = ContinualUpdate(scan, from ? &*from : nullptr, uo, nullptr, nullptr, &rep);
    if (snap && !snap->Matches(*from)) cell.previous_always_intact = false;
    std::string why;
    if (!next.ok()) {
      ++cell.failed;
      why = std::string(next.status().message());
    } else {
      cell.skipped_batches += rep.skipped_batches;
      const GateReport gate = RunDeploymentGate(*next->model, scan, deployed ? deployed->model.get() : nullptr,
                                                deployed ? &deployed->memory : nullptr, o.gate, o.threads);
      if (!gate.status.ok()) {
        ++cell.refused;
        why = std::string(gate.status.message());
        if (stressed) {
          std::vector<std::pair<int, int>> would = held;
          would.push_back({t, step});
          absl::StatusOr<std::pair<double, int>> sc = Score(*next->model, *seq, would, o.threads);
          if (!sc.ok()) return sc.status();
          cell.refused_psnr = sc->first;
        }
      } else {
        if (!next->model->AllFinite()) cell.deployed_always_finite = false;
        before = std::move(deployed);
        deployed = std::move(*next);
        held.push_back({t, step});
        if (stressed) cell.stressed_deployed = true;
      }
    }
    if (!why.empty() && (stressed || cell.reason.empty())) {
      cell.reason = absl::StrFormat("update %d: %s", t + 1, why);
    }
  }
  if (deployed) {
    cell.has_model = true;
    absl::StatusOr<std::pair<double, int>> sc = Score(*deployed->model, *seq, held, o.threads);
    if (!sc.ok()) return sc.status();
    cell.psnr = sc->first;
    cell.scored_scans = sc->second;
  }
  cell.seconds = SecondsSince(t0);
  return cell;
}

}  // namespace clnerf
