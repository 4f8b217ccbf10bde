#include "core/train/fit.h"

#include <algorithm>

#include "core/render/evaluate.h"
#include "core/train/ray_sampler.h"
#include "core/train/view_colour.h"
#include "spdlog/spdlog.h"

namespace clnerf {

absl::Status FitOptions::Validate() const {
  for (const absl::Status& s :
       {train.Validate(), model.Validate(), capacity.Validate(), overrides.Validate(), prune_options.Validate(),
        view_error.Validate()}) {
    if (!s.ok()) return s;
  }
  if (curve_every < 0 || curve_views < 1) return absl::InvalidArgumentError("fit: bad curve options");
  if (!(depth_fraction >= 0.0f && depth_fraction <= 1.0f)) {
    return absl::InvalidArgumentError("fit: depth_fraction must be in [0, 1]");
  }
  return absl::OkStatus();
}

absl::StatusOr<FitResult> FitScene(const Scene& scene, const FitOptions& options, const FitProgress& progress,
                                   const std::atomic<bool>* cancel) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (scene.train.empty()) return absl::InvalidArgumentError("the scene has no training views");
  if (absl::Status s = ValidateScene(scene); !s.ok()) return s;
  const Normalization norm = ComputeNormalization(scene);
  FitResult result;
  ModelOptions mo = options.model;
  if (options.derive_capacity) mo = DeriveModelOptions(scene, norm, options.capacity, mo, &result.capacity);
  mo = options.overrides.ApplyTo(mo);  // NgpModel::Create validates the result.
  if (!options.derive_capacity || !options.overrides.empty()) {
    // Sizes given by the caller: report them as used (the footprint, if
    // derived, is kept).
    result.capacity.finest_resolution = mo.grid.finest_resolution;
    result.capacity.log2_table_size = mo.grid.log2_table_size;
    result.capacity.occupancy_resolution = mo.occupancy.resolution;
    result.capacity.steps_per_diagonal = mo.march.steps_per_diagonal;
  }
  absl::StatusOr<NgpModel> model =
      NgpModel::Create(mo, norm, scene.kind, scene.background, std::max(1, scene.num_time_steps()), options.train.seed);
  if (!model.ok()) return model.status();
  result.model = std::make_unique<NgpModel>(std::move(*model));
  spdlog::info("model: {} parameters, {} bytes; {}", result.model->num_params(), result.model->num_bytes(),
               result.capacity.ToString());

  std::vector<const View*> views;
  for (const View& v : scene.train) views.push_back(&v);
  absl::StatusOr<std::unique_ptr<ImageRaySampler>> sampler =
      ImageRaySampler::Create(views, *result.model, options.depth_fraction);
  if (!sampler.ok()) return sampler.status();
  if ((*sampler)->num_depth_pixels() > 0 && options.depth_fraction > 0) {
    spdlog::info("sparse depth: {} pixels with a known depth; {:.0f}% of each batch, weight {:g}",
                 (*sampler)->num_depth_pixels(), 100.0 * options.depth_fraction, options.train.depth_weight);
  }
  (*sampler)->SetViewErrorSampling(options.view_error);
  Trainer trainer(result.model.get(), sampler->get(), options.train);

  const std::vector<View>& held_out = scene.test.empty() ? scene.val : scene.test;
  EvalOptions eval;
  eval.max_views = options.curve_views;
  absl::Status status = trainer.Run(
      [&](const StepStats& s) {
        if (progress) progress(s, trainer);
        const bool last = s.step == options.train.iterations;
        if (options.curve_every > 0 && !held_out.empty() && (s.step % options.curve_every == 0 || last)) {
          absl::StatusOr<EvalResult> r = EvaluateViews(*result.model, held_out, eval);
          if (r.ok()) result.curve.push_back({s.step, trainer.total_seconds(), r->psnr, r->ssim});
        }
      },
      cancel);
  if (!status.ok()) return status;
  result.iterations = trainer.step();
  result.train_seconds = trainer.total_seconds();
  result.samples = trainer.total_samples();
  result.skipped_batches = trainer.skipped_batches();
  result.view_colours = trainer.view_colours();
  if (!result.view_colours.empty()) {  // How far the photos' exposures spread.
    float lo = 1e9f, hi = -1e9f;
    for (size_t v = 0; v < result.view_colours.size(); v += kViewColourParams) {
      const float* p = &result.view_colours[v];
      const float gain = (p[0] + p[4] + p[8]) / 3.0f;
      lo = std::min(lo, gain);
      hi = std::max(hi, gain);
    }
    spdlog::info("per-photo colour transforms: {} photos, mean gain {:.3f} .. {:.3f}",
                 result.view_colours.size() / kViewColourParams, lo, hi);
  }
  result.samples_per_second = result.train_seconds > 0 ? result.samples / result.train_seconds : 0;
  result.composited_samples_per_second =
      result.train_seconds > 0 ? trainer.total_composited() / result.train_seconds : 0;
  result.rays_per_second = result.train_seconds > 0 ? trainer.total_rays() / result.train_seconds : 0;
  if (options.prune && !result.model->uses_proposals()) {
    absl::StatusOr<PruneReport> pr = PruneOccupancy(result.model.get(), views, options.prune_options);
    if (!pr.ok()) return pr.status();
    result.prune = *pr;
    spdlog::info("occupancy pruned: {} -> {} cells (density threshold {:.3g}), {:.1f} -> {:.1f} samples per ray, "
                 "training-pixel PSNR {:.2f} -> {:.2f} dB",
                 pr->cells_before, pr->cells_after, pr->threshold, pr->samples_before, pr->samples_after,
                 pr->psnr_before, pr->psnr_after);
  }
  return result;
}

}  // namespace clnerf
