// Similarity: a 7-degree-of-freedom transform x' = scale * R x + t between
// two frames of one place (a scan's own SfM or AR frame and the place's
// frame), with the fits that registration needs:
//   * FitSimilarity: least squares over point pairs (Umeyama 1991, through
//     Eigen::umeyama), exact for noise-free data;
//   * FitSimilarityRobust: RANSAC over frames whose pose is known in both
//     frames (a scan's own pose and where the place's model localised it),
//     each hypothesis from two frames, refined by FitSimilarity on the
//     inliers' centres and camera axes, so changed parts of a place (frames
//     localised wrongly) do not drag the fit, and a straight-line walk (all
//     centres collinear) still fixes the rotation.
// Plain value types and pure functions: thread-safe.
#ifndef CLNERF_CORE_POSE_SIMILARITY_H_
#define CLNERF_CORE_POSE_SIMILARITY_H_

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "Eigen/Core"

namespace clnerf {

struct Similarity {
  double scale = 1.0;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Eigen::Vector3d Apply(const Eigen::Vector3d& x) const { return scale * (rotation * x) + translation; }
  Eigen::Vector3f Apply(const Eigen::Vector3f& x) const { return Apply(Eigen::Vector3d(x.cast<double>())).cast<float>(); }
  // A camera-to-world pose in the source frame expressed in the target frame:
  // [R Rc | s R tc + t] (the camera's own axes stay orthonormal).
  Pose ApplyToPose(const Pose& c2w) const;
  Similarity Inverse() const;
  // this ∘ other: first `other`, then this.
  Similarity Compose(const Similarity& other) const;
  double RotationDegrees() const;  // Angle of `rotation`.
};

// The angle between two rotations, in degrees.
double RotationAngleDegrees(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b);

// Least-squares similarity mapping `from[i]` onto `to[i]` (at least 3 pairs,
// not all collinear). INVALID_ARGUMENT for mismatched or too few pairs,
// FAILED_PRECONDITION for a degenerate set.
absl::StatusOr<Similarity> FitSimilarity(const std::vector<Eigen::Vector3d>& from,
                                         const std::vector<Eigen::Vector3d>& to);

// One frame known in both frames: its pose in the source frame and in the
// target frame.
struct PosePair {
  Pose from;
  Pose to;
};

struct RobustSimilarityOptions {
  // RANSAC hypotheses (each from two frames); all pairs are tried when there
  // are fewer.
  int iterations = 1000;
  // A frame is an inlier when the transform puts its centre within
  // centre_tolerance * target_extent of where it was localised, and turns
  // its axes within rotation_tolerance_deg of the localised ones.
  double centre_tolerance = 0.05;
  double rotation_tolerance_deg = 5.0;
  uint64_t seed = 1;
  absl::Status Validate() const;
};

struct RobustSimilarity {
  Similarity transform;
  std::vector<int> inliers;  // Indices into the pairs, ascending.
  // Over the inliers, after refinement: centre error in target units and
  // rotation error in degrees.
  double median_centre_error = 0, median_rotation_error_deg = 0;
  // The inliers' per-axis noise, estimated from those medians: centres in
  // target units, rotations in radians (0 with fewer than 3 inliers). The
  // final refinement weighs each frame's centre and rotation by these.
  double centre_sigma = 0, rotation_sigma = 0;
};

// `target_extent`: the size of the place in target units (sets the centre
// tolerance). Needs at least 2 pairs whose source centres differ.
// FAILED_PRECONDITION when no hypothesis gathers 2 inliers.
absl::StatusOr<RobustSimilarity> FitSimilarityRobust(const std::vector<PosePair>& pairs, double target_extent,
                                                     const RobustSimilarityOptions& options);

// How much worse the identity explains the fit's inlier frames than the fit
// does: the difference of their weighted squared residuals (centres and
// rotations over the fit's own noise, centre_sigma and rotation_sigma). A
// scan that is already in the target frame gives about a chi-square with 7
// degrees of freedom (under 18.5 in 99 % of cases); +inf without a noise
// estimate (fewer than 3 inliers).
double IdentityLikelihoodRatio(const RobustSimilarity& fit, const std::vector<PosePair>& pairs);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_SIMILARITY_H_
