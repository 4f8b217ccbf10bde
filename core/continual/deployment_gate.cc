#include "core/continual/deployment_gate.h"

#include <cmath>

#include "absl/strings/str_format.h"
#include "core/render/evaluate.h"
#include "core/render/metrics.h"
#include "core/render/renderer.h"

namespace clnerf {

absl::Status GateOptions::Validate() const {
  if (!(min_new_psnr >= 0 && min_new_psnr < 100)) return absl::InvalidArgumentError("gate.min_new_psnr must be in [0, 100)");
  if (!(max_replay_drop_db >= 0)) return absl::InvalidArgumentError("gate.max_replay_drop_db must be >= 0");
  if (!(min_replay_consistency_psnr >= 0 && min_replay_consistency_psnr < 100)) {
    return absl::InvalidArgumentError("gate.min_replay_consistency_psnr must be in [0, 100)");
  }
  if (validation_views < 1) return absl::InvalidArgumentError("gate.validation_views must be >= 1");
  if (!(max_new_psnr_drop_db >= 0)) return absl::InvalidArgumentError("gate.max_new_psnr_drop_db must be >= 0");
  if (std::isnan(replay_memorised_margin_db)) return absl::InvalidArgumentError("gate.replay_memorised_margin_db is NaN");
  return absl::OkStatus();
}

namespace {

std::vector<size_t> Spaced(size_t n, int k) {
  std::vector<size_t> idx;
  if (n == 0) return idx;
  const size_t m = std::min(n, size_t(k));
  for (size_t i = 0; i < m; ++i) idx.push_back(i * n / m);
  return idx;
}

absl::StatusOr<double> MeanPsnr(const NgpModel& model, const std::vector<View>& views, int threads) {
  EvalOptions eo;
  eo.render.threads = threads;
  absl::StatusOr<EvalResult> r = EvaluateViews(model, views, eo);
  if (!r.ok()) return r.status();
  return r->psnr;
}

}  // namespace

absl::Status CheckReplayDrop(double before, double after, double place_psnr, const GateOptions& o) {
  const bool capped = place_psnr > 0 && o.replay_memorised_margin_db >= 0 &&
                      before > place_psnr + o.replay_memorised_margin_db;
  const double baseline = capped ? place_psnr + o.replay_memorised_margin_db : before;
  if (baseline - after <= o.max_replay_drop_db) return absl::OkStatus();
  if (!capped) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "deployment gate: PSNR on earlier scans' buffered images fell from %.2f to %.2f dB (more than %.2f dB)",
        before, after, o.max_replay_drop_db));
  }
  return absl::FailedPreconditionError(absl::StrFormat(
      "deployment gate: PSNR on earlier scans' buffered images fell from %.2f to %.2f dB, more than %.2f dB below "
      "%.2f (the place's %.2f dB on held-out views plus %.2f)",
      before, after, o.max_replay_drop_db, baseline, place_psnr, o.replay_memorised_margin_db));
}

GateReport RunDeploymentGate(const NgpModel& next, const Scene& scan, const NgpModel* prev,
                             const ReplayMemory* prev_memory, const GateOptions& o, int threads,
                             double place_psnr) {
  GateReport rep;
  auto fail = [&](std::string why) {
    rep.status = absl::FailedPreconditionError(std::move(why));
    return rep;
  };
  if (!next.AllFinite()) return fail("deployment gate: the trained model has NaN/Inf parameters (training diverged)");

  // 2. The new scan.
  std::vector<View> views;
  const bool held_out = !scan.test.empty();
  const std::vector<View>& src = held_out ? scan.test : scan.train;
  for (size_t i : Spaced(src.size(), o.validation_views)) views.push_back(src[i]);
  absl::StatusOr<double> new_psnr = MeanPsnr(next, views, threads);
  if (!new_psnr.ok()) {
    rep.status = new_psnr.status();
    return rep;
  }
  const char* key = held_out ? "new_psnr" : "new_train_psnr";
  rep.metrics[key] = *new_psnr;
  if (*new_psnr < o.min_new_psnr) {
    return fail(absl::StrFormat("deployment gate: PSNR %.2f dB on the new scan's %s views is below the floor %.2f dB",
                                *new_psnr, held_out ? "held-out" : "training", o.min_new_psnr));
  }
  if (place_psnr > 0 && o.max_new_psnr_drop_db > 0 && *new_psnr < place_psnr - o.max_new_psnr_drop_db) {
    return fail(absl::StrFormat(
        "deployment gate: PSNR %.2f dB on the new scan's %s views is %.2f dB below the place's %.2f dB (at most %.2f "
        "allowed); was the scan placed in the place's frame?",
        *new_psnr, held_out ? "held-out" : "training", place_psnr - *new_psnr, place_psnr, o.max_new_psnr_drop_db));
  }
  if (prev == nullptr || prev_memory == nullptr) return rep;

  // 3. Buffered real images of earlier scans.
  std::vector<View> buffered;
  for (const BufferedImage& b : prev_memory->buffer()) {
    View v;
    v.name = absl::StrFormat("buffer_%u", b.camera);
    v.camera = prev_memory->GetCamera(b.camera);
    v.image = b.image;
    buffered.push_back(std::move(v));
  }
  if (!buffered.empty()) {
    std::vector<View> sub;
    for (size_t i : Spaced(buffered.size(), o.validation_views)) sub.push_back(buffered[i]);
    absl::StatusOr<double> before = MeanPsnr(*prev, sub, threads);
    absl::StatusOr<double> after = MeanPsnr(next, sub, threads);
    if (!before.ok() || !after.ok()) {
      rep.status = before.ok() ? after.status() : before.status();
      return rep;
    }
    rep.metrics["replay_buffer_psnr_prev"] = *before;
    rep.metrics["replay_buffer_psnr"] = *after;
    if (absl::Status s = CheckReplayDrop(*before, *after, place_psnr, o); !s.ok()) {
      rep.status = s;
      return rep;
    }
  }

  // 4. Past cameras without images: agreement with θ_{t-1}.
  std::vector<uint32_t> cams;
  for (uint32_t i = 0; i < prev_memory->num_cameras(); ++i) {
    if (!prev_memory->InBuffer(i)) cams.push_back(i);
  }
  if (!cams.empty()) {
    std::vector<View> labelled;
    RenderOptions ro;
    ro.threads = threads;
    for (size_t k : Spaced(cams.size(), o.validation_views)) {
      View v;
      v.camera = prev_memory->GetCamera(cams[k]);
      v.name = absl::StrFormat("camera_%u", cams[k]);
      ro.time_step = v.camera.time_step;
      absl::StatusOr<RenderedView> label = RenderView(*prev, v.camera, ro);
      if (!label.ok()) {
        rep.status = label.status();
        return rep;
      }
      v.image = std::move(label->rgb);
      labelled.push_back(std::move(v));
    }
    absl::StatusOr<double> agree = MeanPsnr(next, labelled, threads);
    if (!agree.ok()) {
      rep.status = agree.status();
      return rep;
    }
    rep.metrics["replay_consistency_psnr"] = *agree;
    if (*agree < o.min_replay_consistency_psnr) {
      return fail(absl::StrFormat(
          "deployment gate: renders of past views drifted from the previous model (%.2f dB < %.2f dB)", *agree,
          o.min_replay_consistency_psnr));
    }
  }
  return rep;
}

}  // namespace clnerf
