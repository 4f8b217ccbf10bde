// Renderer: inference-time rendering of a NgpModel. Rays are processed in
// blocks; each block marches all live rays a few samples at a time ("waves"),
// evaluates the density MLP on the whole wave, composites front to back, and
// runs the colour MLP only on samples whose weight matters. Rays stop at
// transmittance <= 1e-4 or when they leave the box. RenderView orders its
// rays in 32 x 16 pixel tiles, so a block's rays are image neighbours.
//
// All functions take the model by const reference and are safe to call from
// many threads at once on the same model (each call uses its own scratch).
// Parallelism: each call splits its rays over the OpenMP threads of the
// calling context (set with SetRenderThreads / omp_set_num_threads).
#ifndef CLNERF_CORE_RENDER_RENDERER_H_
#define CLNERF_CORE_RENDER_RENDERER_H_

#include <functional>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/field/ngp_model.h"

namespace clnerf {

struct RenderOptions {
  int time_step = -1;       // Embedding row to use; -1 = the latest step.
  int block_rays = 512;     // Rays per parallel task.
  int threads = 0;          // OpenMP threads; 0 = all available.
  // Samples whose weight is below min_weight skip the colour MLP (92% of a
  // fox_8 view's samples reach 2e-5, 71% reach 5e-4), as long as the ray's
  // skipped weight stays within max_skipped_weight (so a hazy ray of many
  // faint samples is still coloured). The skipped weight takes the mean
  // colour of the ray's coloured samples. Measured on fox_8's service model:
  // 5e-4 renders 57.3 dB PSNR against the colour-everything render (max
  // pixel error 2/255) in ~13% less time; 0 colours every sample.
  float min_weight = 5e-4f;
  float max_skipped_weight = 0.01f;
  // A ray stops once its transmittance falls to this; what is left of it
  // takes the colour of what it saw (pixel and expected depth divided by
  // the opacity) instead of the background's. Training stops at
  // kMinTransmittance (1e-4), which leaves the rest to the background as
  // before. 0.01 is instant-ngp's viewer default (render_min_transmittance):
  // in haze the last 1 % of the light takes as many samples as the first
  // 99 %. Test views (session 73, one Xeon, 1e-4 -> 0.01): fox_8 75.8 ->
  // 56.7 ms at 30.16 dB both, flower_4 591 -> 388 ms (29.79 -> 29.78),
  // beer_2 1452 -> 1247 ms (23.25 -> 23.24), lego_100 11.5 -> 10.9 ms
  // (31.89 -> 31.88); at 0.03 fox_8 51.6 ms but lego_100 -0.07 dB.
  float min_transmittance = 0.01f;
  // Proposal models: full-field samples per ray (0 = the model's, which it
  // was trained with). Fewer is faster and less accurate.
  int nerf_samples = 0;
  // Polled before each block of rays (from the rendering threads, so it must
  // be thread-safe); once it returns true the remaining blocks are skipped
  // and RenderView returns CANCELLED. Empty = never stop. Used for renders
  // whose caller went away or whose deadline passed, and for cancelled
  // updates.
  std::function<bool()> should_stop;
  // depth outputs: the expected distance (the weights' mean, default) or the
  // median one (where the transmittance first falls to 1/2; the ray's end
  // when it never does), which a few faint floaters or a hazy tail do not
  // pull (registration lifts features to 3-D with it).
  bool median_depth = false;
  // The MLPs in bfloat16 on AMX tiles where the CPU has them (Intel's
  // Sapphire Rapids and later; elsewhere float, as with false): weights and
  // layer inputs rounded to 8-bit mantissas, sums in float (bf16_mlp.h).
  // Session 76, one 2-core Xeon, test views, float -> bfloat16 (means of
  // 2-4 runs): fox_8 61 -> 49 ms, flower_4 470 -> 375, beer_2 1122 -> 822,
  // lego_100 11.3 -> 9.7; PSNR within 0.01 dB on all four.
  bool bf16_mlp = true;
  absl::Status Validate() const;
};

struct RenderedView {
  Image rgb;
  std::vector<float> opacity;  // Accumulated alpha per pixel.
  std::vector<float> depth;    // Expected distance (world units) per pixel.
  long long samples = 0;       // Network evaluations (density).
  long long steps = 0;         // Baked renderer only: march iterations, empty blocks included.
};

// Renders rays given in model space (origins/directions n x 3; directions
// unit length). rgb: n x 3, opacity/depth: n (may be null; depth in model
// units). Returns the number of density evaluations, or -1 when
// options.should_stop stopped it (the outputs are then incomplete).
long long RenderRays(const NgpModel& model, const float* origins, const float* dirs, int n, int time_step,
                     const RenderOptions& options, float* rgb, float* opacity, float* depth);

// Renders a full image for a world-space camera. INVALID_ARGUMENT for a bad
// camera or a time step the model does not have; CANCELLED when
// options.should_stop stopped it.
absl::StatusOr<RenderedView> RenderView(const NgpModel& model, const Camera& world_camera,
                                        const RenderOptions& options);

}  // namespace clnerf

#endif  // CLNERF_CORE_RENDER_RENDERER_H_
