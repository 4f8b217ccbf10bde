// CameraRefiner: per-photo pose corrections learnt together with the field
// (a camera optimiser, as nerfacto's and BARF's). A scan posed by structure
// from motion and registered into its place's frame is left a fraction of a
// degree off per frame (on a 360 x 640 phone video, 0.25 degrees median is
// ~2.4 px at its focal length), which no later training step can undo: the
// field fits each photo where its camera says, and the place blurs. With a
// refiner, every training ray of a refined photo also carries the gradient of
// the loss with respect to its origin and direction (Trainer: through the
// hash grid's positions, the contraction, and the colour's spherical-harmonic
// view dependence), and each photo's correction is one Adam step per batch:
//
//   R = Exp(omega) R0   (a turn about the camera's own centre)
//   c = c0 + v
//
// where (R0, c0) is the photo's pose when refinement began, omega in radians
// and v in model units. For a ray o = c, d = R d_cam the loss's gradient is
// dL/domega = d x dL/dd and dL/dv = dL/do, summed over the photo's rays.
// Only photos named at construction move; the others (replay labels, past
// images, test views) hold the frame, so a refined scan cannot drift as a
// whole. Corrections are bounded (max_rotation_deg, max_translation): a photo
// that wants more is clamped, and the clamp is reported, not hidden.
//
// Thread-safety: not thread-safe; the trainer owns one and calls it between
// batches.
#ifndef CLNERF_CORE_TRAIN_CAMERA_REFINER_H_
#define CLNERF_CORE_TRAIN_CAMERA_REFINER_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "core/data/camera.h"
#include "Eigen/Core"

namespace clnerf {

struct CameraRefineOptions {
  // Adam's learning rate for the corrections (radians for the turn, model
  // units for the shift), scaled by the trainer's schedule (lr / initial lr),
  // so the corrections settle as the field does. nerfacto's camera optimiser
  // uses 6e-4. (With the inverse-sqrt schedules and a carried optimiser the
  // trainer's rate starts lower each update, and so does this one.)
  float learning_rate = 5e-4f;
  // Bounds on a photo's total correction: a turn of at most this many
  // degrees and a shift of at most this many model units (the model's box is
  // [-1, 1]^3 around the cameras for real captures).
  float max_rotation_deg = 2.0f;
  float max_translation = 0.05f;
  // Training steps before the corrections start (the field first fits the
  // batch's colours at the given poses).
  int start_iteration = 0;
  absl::Status Validate() const;
};

class CameraRefiner {
 public:
  // `cameras`: model-space cameras of the sampler's views (RayBatch::view
  // indexes them); `refine[v]` != 0 for those that may move.
  CameraRefiner(std::vector<Camera> cameras, std::vector<uint8_t> refine, const CameraRefineOptions& options);

  bool Refines(int view) const { return view >= 0 && view < int(refine_.size()) && refine_[view] != 0; }
  int num_refined() const;
  const CameraRefineOptions& options() const { return options_; }

  // Clears the gradients of the next batch.
  void ZeroGradients();
  // Adds one ray's gradient (model space: dL/do, dL/dd of its unit direction
  // d) to its photo's.
  void AddRayGradient(int view, const Eigen::Vector3f& dir, const Eigen::Vector3f& d_origin,
                      const Eigen::Vector3f& d_dir);
  // The accumulated gradient of a view: (dL/domega, dL/dv).
  Eigen::Matrix<double, 6, 1> Gradient(int view) const { return grad_[size_t(view)]; }
  // One Adam step on every refined photo with a gradient this batch, at
  // learning_rate * lr_scale; `step` is the 1-based refinement step (bias
  // correction). Returns false (nothing moved) when a gradient is not finite.
  bool Step(int step, float lr_scale);

  // The view's model-space camera now.
  const Camera& camera(int view) const { return current_[size_t(view)]; }
  // The view's correction so far: its turn in degrees and shift in model units.
  double rotation_deg(int view) const;
  double translation(int view) const;
  // Photos whose correction reached a bound at least once.
  int clamped() const;
  // Over the refined photos: median and largest turn (degrees) and shift
  // (model units); zeros when none is refined.
  struct Stats {
    double turn_median_deg = 0, turn_max_deg = 0, shift_median = 0, shift_max = 0;
  };
  Stats CorrectionStats() const;
  // "N photos: median turn X deg (max Y), median shift Z (max W), K clamped".
  std::string Summary() const;

 private:
  void Apply(int view);

  CameraRefineOptions options_;
  std::vector<Camera> base_, current_;
  std::vector<uint8_t> refine_, clamped_;
  std::vector<Eigen::Matrix<double, 6, 1>> param_, grad_, m_, v_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_CAMERA_REFINER_H_
