// Fit: trains a fresh model on one scene from start to finish: normalisation,
// capacity derivation, sampler, trainer, and (optionally) a PSNR-vs-time curve
// on held-out views. This is what `clnerf train` runs; the continual update
// builds on the same pieces. Not thread-safe per call; independent calls may
// run concurrently (they share nothing), though each uses all OpenMP threads.
#ifndef CLNERF_CORE_TRAIN_FIT_H_
#define CLNERF_CORE_TRAIN_FIT_H_

#include <atomic>
#include <functional>
#include <memory>
#include <vector>

#include "absl/status/statusor.h"
#include "core/field/capacity.h"
#include "core/field/ngp_model.h"
#include "core/data/scene.h"
#include "core/train/occupancy_prune.h"
#include "core/train/ray_sampler.h"
#include "core/train/trainer.h"
#include "core/train/view_error_sampler.h"

namespace clnerf {

struct FitOptions {
  TrainOptions train;
  ModelOptions model;             // Network options etc.; see derive_capacity.
  bool derive_capacity = true;    // Overwrite grid/occupancy/march sizes from the scene.
  CapacityOptions capacity;
  // Applied after derivation (or to `model` as given without it).
  CapacityOverrides overrides;
  int curve_every = 0;            // Evaluate held-out views every N steps (0 = never).
  int curve_views = 8;            // Held-out views used for each curve point.
  // Share of each batch drawn from sparse-depth pixels when the views have
  // any (ImageRaySampler); 0 = no sparse-depth supervision. Views without
  // depth targets are unaffected. Measured in docs/sparse_depth.md.
  float depth_fraction = 0.125f;
  // After training, prune occupancy cells that no training pixel needs
  // (occupancy_prune.h; fewer samples per rendered ray). Off by default:
  // beer_2 rendered 1.9x faster (292 -> 131 samples per ray) for 0.10 dB of
  // test PSNR (docs/render_cost.md).
  bool prune = false;
  // Draw views (or tiles) partly in proportion to their current error
  // (view_error_sampler.h); error_share 0 = uniform over views, the default.
  ViewErrorOptions view_error;
  PruneOptions prune_options;
  absl::Status Validate() const;
};

struct CurvePoint {
  int iteration = 0;
  double train_seconds = 0;  // Training wall time only (evaluation excluded).
  double psnr = 0, ssim = 0;
};

struct FitResult {
  std::unique_ptr<NgpModel> model;
  CapacityReport capacity;
  int iterations = 0;
  double train_seconds = 0;
  long long samples = 0;      // Network-evaluated samples over the run.
  double samples_per_second = 0;             // Marched samples (density MLP) per second.
  double composited_samples_per_second = 0;  // Samples through colour MLP + full backward.
  double rays_per_second = 0;
  int skipped_batches = 0;    // NaN/Inf batches the trainer skipped.
  // Per-view colour transforms learned for the training views, in the order
  // of Scene::train (12 each, view_colour.h); empty unless
  // TrainOptions::view_colour.
  std::vector<float> view_colours;
  PruneReport prune;  // Empty unless FitOptions::prune.
  std::vector<CurvePoint> curve;
};

using FitProgress = std::function<void(const StepStats& step, const Trainer& trainer)>;

absl::StatusOr<FitResult> FitScene(const Scene& scene, const FitOptions& options, const FitProgress& progress,
                                   const std::atomic<bool>* cancel = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_FIT_H_
