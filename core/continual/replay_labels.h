// Replay labels: θ_{t-1}'s renders of past views, rendered once at the start
// of an update (offline generative replay) and then sampled by the
// ContinualRaySampler like photos.
//
// An update draws far fewer replay rays than its past views have pixels:
// beer_2's fifth scan replays 40 views of 360×640 (9.2 M pixels) while 300
// steps of about 450 rays draw about 0.1 M of them, so rendering every pixel
// spent 225 of a 255 s update on labels nobody read. Here each past view gets
// a random subset of its pixels sized from the draws the update can make
// (`labels_per_draw` labels per expected draw, so about 1 − e^(−1/4) ≈ 88 % of
// the draws still land on distinct pixels at the default 4); a view whose
// share reaches its pixel count is rendered whole. Labels are the same
// renders as before (the same rays through the same model), only fewer.
//
// Pure functions of their inputs; the model is read concurrently by the
// rendering threads and never modified. Thread-safe.
#ifndef CLNERF_CORE_CONTINUAL_REPLAY_LABELS_H_
#define CLNERF_CORE_CONTINUAL_REPLAY_LABELS_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/field/ngp_model.h"
#include "core/render/renderer.h"

namespace clnerf {

struct ReplayLabelOptions {
  // Labels rendered per expected replay draw. 0 = every pixel of every past
  // view (the whole-view cache, as the paper's code pre-renders).
  float labels_per_draw = 4.0f;
  // Rays of θ_{t-1} rendered to measure its samples per ray, from which the
  // trainer's adaptive batch (and so the draws) is estimated.
  int probe_rays = 1024;
  // Depth distillation (issue 23, item 3): a label whose θ_{t-1} render is
  // opaque, opacity >= depth_min_opacity, also teaches θ_{t-1}'s surface
  // distance (depth / opacity) through the sparse-depth loss
  // (TrainOptions::depth_weight, depth_sigma), scaled by the label's
  // weight: one colour per pixel constrains a whole ray of samples only
  // weakly. 0 = off; else in (0, 1].
  float depth_min_opacity = 0.0f;
  absl::Status Validate() const;
};

// The labels of one past view: either a whole image (`pixels` empty) or
// `pixels.size()` labels, label k being pixel pixels[k] (ascending), stored
// as an image of pixels.size() × 1.
struct ReplayLabelView {
  Image rgb;
  std::vector<uint32_t> pixels;
  // θ_{t-1}'s expected depth (model units, along the pixel's unit ray) and
  // accumulated opacity per label, in label order.
  std::vector<float> depth, opacity;
  // Loss weight per label (replay_weights.h); empty = 1 for every label.
  std::vector<float> weight;
  // Depth-distillation target per label (model units along the ray; 0 =
  // none); empty = none at all. Filled by SetDistillationDepths.
  std::vector<float> target_depth;
};

struct ReplayLabelReport {
  long long labels = 0;         // Pixels rendered.
  long long view_pixels = 0;    // Pixels the past views have in all.
  double probe_samples_per_ray = 0;  // Filled by the caller (ProbeSamplesPerRay).
  size_t bytes = 0;             // Labels plus pixel indices.
};

// θ_{t-1}'s mean density evaluations per ray over `probe_rays` random pixels
// of `cameras` (world space), each at its own time step. 0 when there is
// nothing to probe.
double ProbeSamplesPerRay(const NgpModel& model, const std::vector<Camera>& cameras, int probe_rays, uint64_t seed);

// Labels per past view for `expected_draws` replay draws spread uniformly
// over `num_views` views: ceil(labels_per_draw × draws / views), at least 1;
// 0 labels_per_draw (or a non-positive estimate) means every pixel, which
// callers see as a count >= the view's pixels.
long long LabelsPerView(double expected_draws, int num_views, const ReplayLabelOptions& options);

// Renders `labels_per_view` random pixels (without replacement; the whole
// view when that is at least its pixel count) of each camera with `model` at
// the camera's time step. progress(done, total) after each view; CANCELLED
// when *cancel turns true.
absl::StatusOr<std::vector<ReplayLabelView>> RenderReplayLabels(
    const NgpModel& model, const std::vector<Camera>& cameras, long long labels_per_view, uint64_t seed,
    const std::atomic<bool>* cancel, const std::function<void(int, int)>& progress, ReplayLabelReport* report);

// Renders `pixels` of the world-space camera `world` with `model` at the
// camera's time step: colour to rgb (3 per pixel) and, when not null,
// accumulated opacity and expected depth (model units); adds the density
// evaluations to *samples when not null. False when ro.should_stop stopped it.
bool RenderLabelPixels(const NgpModel& model, const Camera& world, const std::vector<uint32_t>& pixels,
                       const RenderOptions& ro, float* rgb, long long* samples, float* opacity = nullptr,
                       float* depth = nullptr);

// Fills view->target_depth: depth / opacity for each label that is opaque
// (opacity >= min_opacity, depth > 0), 0 for the others; clears it when
// min_opacity is 0 (off) or the labels carry no depth. Returns the labels
// that got a target.
long long SetDistillationDepths(float min_opacity, ReplayLabelView* view);

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_REPLAY_LABELS_H_
