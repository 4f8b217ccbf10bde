// Evaluation: renders a set of views with a model and scores them against
// their images (PSNR and SSIM per image, then averaged, as in NeRF papers).
// Each view is rendered with its own time step's embeddings. Thread-safe with
// respect to the (const) model.
#ifndef CLNERF_CORE_RENDER_EVALUATE_H_
#define CLNERF_CORE_RENDER_EVALUATE_H_

#include <functional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/field/ngp_model.h"
#include "core/render/renderer.h"
#include "core/data/scene.h"

namespace clnerf {

struct EvalOptions {
  RenderOptions render;
  // When set, writes each render as <save_dir>/<index>_<name without
  // extension>.png and the photo it is scored against beside it (.photo.png).
  std::string save_dir;
  int max_views = 0;     // 0 = all views; otherwise an evenly spaced subset.
  absl::Status Validate() const;
};

struct ViewScore {
  std::string name;
  int time_step = 0;
  double psnr = 0, ssim = 0;
  double render_seconds = 0;
  double psnr_cc = 0;  // Colour-corrected PSNR (metrics.h).
  double speckle = 0, blur = 0;  // Fine detail the photo lacks / the render lacks (speckle.h).
};

struct EvalResult {
  // Means over views. psnr_cc: colour-corrected PSNR (a per-view affine
  // colour fit, metrics.h). Protocol: every view is rendered with its scan's
  // time-step embedding (test views have no per-image embedding of their
  // own), the same for every method.
  double psnr = 0, ssim = 0, psnr_cc = 0;
  double speckle = 0, blur = 0;  // speckle.h.
  double mean_render_seconds = 0;
  std::vector<ViewScore> views;
};

// PSNR over `test` of predicting the mean training colour everywhere: the
// floor a trained model must clear.
double ConstantColourPsnr(const std::vector<View>& train, const std::vector<View>& test);

absl::StatusOr<EvalResult> EvaluateViews(const NgpModel& model, const std::vector<View>& views,
                                         const EvalOptions& options);

// The same scoring for any renderer (e.g. a baked asset's reference
// renderer, core/bake/baked_renderer.h); options.render is not used.
using ViewRenderer = std::function<absl::StatusOr<RenderedView>(const View& view)>;
absl::StatusOr<EvalResult> EvaluateWith(const ViewRenderer& render, const std::vector<View>& views,
                                        const EvalOptions& options);

}  // namespace clnerf

#endif  // CLNERF_CORE_RENDER_EVALUATE_H_
