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

namespace clnerf {

struct RayBatch {
  std::vector<float> origin;   // n x 3, model space.
  std::vector<float> dir;      // n x 3, unit, model space.
  std::vector<float> target;   // n x 3, supervision colour.
  std::vector<int> time_step;  // n.
  std::vector<float> weight;   // n, loss weight (1 for plain training).
  std::vector<uint8_t> robust; // n, 1 = Charbonnier loss sqrt(e^2 + 1e-6) instead of MSE.
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
  // Model-space cameras of every view the sampler draws from (for the
  // occupancy grid's visibility mask).
  virtual std::vector<Camera> Cameras() const = 0;
};

// Uniform over views, then over each view's unmasked pixels. Holds pointers
// into `views`, which must outlive the sampler.
class ImageRaySampler : public RaySampler {
 public:
  // Fails with INVALID_ARGUMENT when a view has no image or no usable pixel.
  static absl::StatusOr<std::unique_ptr<ImageRaySampler>> Create(const std::vector<const View*>& views,
                                                                  const NgpModel& model);
  void Sample(int n, std::mt19937_64* rng, RayBatch* out) override;
  std::vector<Camera> Cameras() const override { return cameras_; }

 private:
  ImageRaySampler() = default;
  std::vector<const View*> views_;
  std::vector<Camera> cameras_;                 // Model space.
  std::vector<std::vector<uint32_t>> valid_;    // Unmasked pixel ids (empty = all).
};

// Generates the model-space ray of a pixel of a model-space camera.
void PixelRay(const Camera& model_camera, uint32_t pixel, float* origin, float* dir);

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_RAY_SAMPLER_H_
