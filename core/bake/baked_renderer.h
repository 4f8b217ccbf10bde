// Baked renderer: the C++ reference renderer of a BakedAsset. It marches the
// same samples, with the same interpolation and compositing, as the viewer's
// WebGL2 shader (server/frontends/web/baked.js), so an asset is scored exactly as the
// browser shows it (`clnerf eval --model DIR`), and the browser test compares
// the page's frame against it.
//
// The march, for a unit model-space ray o + t d (BakedRayInterval gives
// [t0, t1]: the grid's box, or for unbounded scenes the distance at which the
// contracted point reaches the grid's last half cell, clipped to the near
// plane), step = step_cells * cell:
//   t = t0 + step / 2; T = 1; C = 0
//   object (bounded) asset: the ray crosses the box of occupied blocks over
//     [ta, tb] or the pixel is the background; t advances by
//     max(0, floor((ta - t0) / step - 1/2)) steps, t1 = min(t1, tb + step)
//   while t < t1 and T > kBakedMinTransmittance:
//     x = o + t d; r = |x|_inf
//     dt = step * r^2 beyond the inner cube of an unbounded scene, else step
//     u = (contract(x) [or x] + B) * R / (2B)            (cell coordinates)
//     block empty, at chessboard distance D from the nearest occupied one:
//       t advances past the cube of blocks within D - 1 of it: inside the
//       model box (unbounded: the inner cube, the cube clipped to it) by
//       whole multiples of k steps (k below), so samples stay on the
//       lattice t0 + (j + 1/2) step;
//       in the shell to te + step * r(te)^2 / 2 (at least by dt), te where
//       the contracted point leaves the cube (ShellEmptyRun; a lower bound
//       off the ray from the centre)
//     else: rgba = trilinear(brick, u - 8 * block)
//       (format 2: rgba.rgb += the view term, sum_k d_k H_k, premultiplied)
//       a = 0 in the model box or inner cube: t advances by m steps, m =
//         BakedCodeSteps of the red channel (an empty-space code,
//         skip_codes.h; k if none), a multiple of k below, clipped to the
//         first multiple of k at or past the inner cube's exit; the
//         samples it passes have no density either
//       run = dt * k, k = 8 while T < 0.05, 4 while T < 0.2, 2 while T < 0.5, else 1
//         (BakedTailSteps: longer steps where little light is left)
//       alpha = 1 - exp(-(-log(1 - min(a^2, kBakedMaxAlpha))) * run / cell)
//       C += T alpha clamp(rgb / a) (the atlas's colour is premultiplied by a);
//       the median sample is the first after which T * (1 - alpha) < 1/2
//       T *= 1 - alpha; t += run
//   format 3: C += (1 - T) * (view term at the median sample) / its a
//   C = clamp(C + T * background)
//
// Thread-safe: the asset is read only; each call uses its own scratch.
// RenderBakedView splits rows over OpenMP threads.
#ifndef CLNERF_CORE_BAKE_BAKED_RENDERER_H_
#define CLNERF_CORE_BAKE_BAKED_RENDERER_H_

#include "absl/status/statusor.h"
#include "core/bake/baked_asset.h"
#include "core/bake/baked_march.h"
#include "core/data/camera.h"
#include "core/render/renderer.h"
#include "Eigen/Core"

namespace clnerf {

struct BakedRenderOptions {
  int threads = 0;  // OpenMP threads; 0 = all available.
};

struct BakedRay {
  Eigen::Vector3f rgb = Eigen::Vector3f::Zero();
  float opacity = 0.0f;
  float depth = 0.0f;   // Expected distance (model units).
  int samples = 0;      // Samples composited (those with density: samples with none add nothing).
  int steps = 0;        // March iterations, empty blocks included: the shader's loop count.
};
BakedRay RenderBakedRay(const BakedAsset& asset, const Eigen::Vector3f& o, const Eigen::Vector3f& d);

// A full image for a world-space camera (its distortion honoured, as the
// model's renderer does). RenderedView::samples counts samples composited and
// RenderedView::steps the march's iterations.
absl::StatusOr<RenderedView> RenderBakedView(const BakedAsset& asset, const Camera& world_camera,
                                             const BakedRenderOptions& options = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_BAKED_RENDERER_H_
