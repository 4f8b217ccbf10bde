// RaySampler: where training rays come from. A sampler fills a RayBatch with
// model-space rays, their supervision colour, time step and loss weight.
// ImageRaySampler draws rays uniformly over views (pick a view uniformly,
// then a pixel uniformly among its unmasked pixels), the ngp_pl
// "all_images" strategy that CLNeRF's uniform sampling builds on; the
// continual update adds samplers for generative replay.
//
// Sample() may be called from one thread at a time; it parallelises
// internally and is deterministic for a given rng state.
#ifndef CLNERF_CORE_TRAIN_RAY_SAMPLER_H_
#define CLNERF_CORE_TRAIN_RAY_SAMPLER_H_

#include <cstdint>
#include <random>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/field/ngp_model.h"
#include "core/data/scene.h"
#include "core/train/view_error_sampler.h"

namespace clnerf {

struct RayBatch {
  std::vector<float> origin;   // n x 3, model space.
  std::vector<float> dir;      // n x 3, unit, model space.
  std::vector<float> target;   // n x 3, supervision colour.
  std::vector<int> time_step;  // n.
  std::vector<float> weight;   // n, loss weight (1 for plain training).
  std::vector<uint8_t> robust; // n, 1 = Charbonnier loss sqrt(e^2 + 1e-6) instead of MSE.
  // n, the ray distance (model units) to a known surface point on this ray
  // (a capture's point, or θ_{t-1}'s surface behind a replay label), or 0
  // when none (sparse-depth supervision; TrainOptions::depth_weight).
  std::vector<float> depth;
  // n, the index of the photo this ray's target comes from (for its
  // per-view colour transform, view_colour.h), in [0, RaySampler::
  // NumPhotoViews()); -1 = none (replay labels, or a sampler without them).
  std::vector<int> view;
  int size() const { return int(time_step.size()); }
  void Resize(int n);
};

class RaySampler {
 public:
  virtual ~RaySampler() = default;
  virtual void Sample(int n, std::mt19937_64* rng, RayBatch* out) = 0;
  // Training progress in [0, 1], set by the trainer before each Sample()
  // (MEIL-NeRF weights its replay rays by it).
  virtual void SetProgress(float progress) {}
  // After each applied step: the batch just trained and each ray's squared
  // colour error (mean over RGB) under the model before the update, for
  // samplers that draw where the model is wrong (view_error_sampler.h).
  virtual void ObserveErrors(const RayBatch& batch, const std::vector<float>& sq_err) {}
  // Model-space cameras of every view the sampler draws from (for the
  // occupancy grid's visibility mask).
  virtual std::vector<Camera> Cameras() const = 0;
  // Replaces view `view`'s model-space camera (the index Cameras() and
  // RayBatch::view use), for CameraRefiner's pose corrections: later batches
  // draw that view's rays from it. Sparse-depth targets keep the distances
  // computed at the original camera (a correction of a fraction of a degree
  // moves them by less than their Gaussian's width).
  virtual void SetCamera(int view, const Camera& model_camera) {}
  // How many photos RayBatch::view indexes (0 = the sampler sets none).
  virtual int NumPhotoViews() const { return 0; }
};

// Uniform over views, then over each view's unmasked pixels. When views
// carry sparse depth (View::depth), a fraction `depth_fraction` of each batch
// is drawn from those pixels instead (uniform over such views, then over
// their depth pixels) and carries RayBatch::depth; these rays are ordinary
// colour rays too. Holds pointers into `views`, which must outlive the
// sampler.
class ImageRaySampler : public RaySampler {
 public:
  // Fails with INVALID_ARGUMENT when a view has no image or no usable pixel,
  // or depth_fraction is outside [0, 1]. 0 = no depth rays.
  static absl::StatusOr<std::unique_ptr<ImageRaySampler>> Create(const std::vector<const View*>& views,
                                                                  const NgpModel& model, float depth_fraction = 0.0f);
  // Depth pixels over all views.
  long long num_depth_pixels() const { return num_depth_pixels_; }
  void Sample(int n, std::mt19937_64* rng, RayBatch* out) override;
  // Draw views (or tiles of views) partly in proportion to their current
  // error (view_error_sampler.h) instead of uniformly; off until called with
  // error_share > 0. Sparse-depth rays are drawn as before.
  void SetViewErrorSampling(const ViewErrorOptions& options);
  void ObserveErrors(const RayBatch& batch, const std::vector<float>& sq_err) override;
  std::vector<Camera> Cameras() const override { return cameras_; }
  void SetCamera(int view, const Camera& model_camera) override { cameras_.at(size_t(view)) = model_camera; }
  // Every view is a photo; RayBatch::view is its index in `views`.
  int NumPhotoViews() const override { return int(views_.size()); }

 private:
  ImageRaySampler() = default;
  std::vector<const View*> views_;
  std::vector<Camera> cameras_;                 // Model space.
  std::vector<std::vector<uint32_t>> valid_;    // Unmasked pixel ids (empty = all).
  // Sparse depth: views that have some, and per view its pixels and their
  // model-space ray distances.
  float depth_fraction_ = 0.0f;
  std::vector<int> depth_views_;
  std::vector<std::vector<uint32_t>> depth_pixel_;
  std::vector<std::vector<float>> depth_t_;
  long long num_depth_pixels_ = 0;
  std::unique_ptr<ViewErrorSampler> error_;  // Null = uniform over views.
  std::vector<int> last_cell_;               // Each ray's cell in the last batch (-1: none).
};

// Renders the rays `rays` (indices into `batch`) with `model`, each with its
// own time step's embeddings (one RenderRays call per step; rays of steps the
// model does not have are left alone), writing ray i's colour to
// (*rgb)[3 i .. 3 i + 2]; *rgb is resized to 3 x batch.size(). Returns the
// density evaluations. Used for replay labels and pruning's calibration.
long long RenderBatchRays(const NgpModel& model, const RayBatch& batch, const std::vector<int>& rays,
                          std::vector<float>* rgb);

// Generates the model-space ray of a pixel of a model-space camera.
void PixelRay(const Camera& model_camera, uint32_t pixel, float* origin, float* dir);

// Sparse-depth targets of one view: for each depth pixel inside the image,
// its id (appended to *pixels) and the model-space distance along its pixel
// ray to the foot of the known point (appended to *t; the point projects
// into the pixel, not onto its centre). Points behind the camera are skipped.
void SparseDepthTargets(const Camera& model_camera, const Normalization& norm, const std::vector<DepthPoint>& depth,
                        std::vector<uint32_t>* pixels, std::vector<float>* t);

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_RAY_SAMPLER_H_
