// Camera: pinhole intrinsics with optional OpenCV radial-tangential distortion
// (k1, k2, p1, p2), a camera-to-world pose, and the time step the view belongs
// to. Rays are generated through pixel centres (+0.5).
//
// Convention: poses are stored internally in the OpenCV convention (x right,
// y down, camera looks along +z). Loaders convert from OpenGL/Blender
// (x right, y up, looks along -z) explicitly with ConvertPose(). Camera is a
// small value type; all methods are const and thread-safe.
#ifndef CLNERF_CORE_DATA_CAMERA_H_
#define CLNERF_CORE_DATA_CAMERA_H_

#include "absl/status/status.h"
#include "Eigen/Core"

namespace clnerf {

enum class PoseConvention { kOpenCV, kOpenGL };

struct Intrinsics {
  int width = 0;
  int height = 0;
  float fx = 0, fy = 0, cx = 0, cy = 0;
  float k1 = 0, k2 = 0, p1 = 0, p2 = 0;  // OpenCV radial-tangential.
  bool has_distortion() const { return k1 != 0 || k2 != 0 || p1 != 0 || p2 != 0; }
  // The same camera at a new image size: fx and cx scale with the width
  // ratio, fy and cy with the height ratio (so a non-square resize stays
  // correct); distortion is unchanged.
  Intrinsics Scaled(int new_width, int new_height) const;
};

// 3x4 camera-to-world matrix [R | t] in OpenCV convention.
using Pose = Eigen::Matrix<float, 3, 4>;

// Converts a camera-to-world matrix from `from` into the OpenCV convention.
Pose ConvertPose(const Pose& c2w, PoseConvention from);
// The inverse of ConvertPose: expresses an OpenCV pose in `to`.
Pose ExportPose(const Pose& c2w_opencv, PoseConvention to);

struct Camera {
  Intrinsics intrinsics;
  Pose c2w = Pose::Identity();
  int time_step = 0;

  // Unit-length world-space direction and origin of the ray through the
  // centre of pixel (px, py) (continuous pixel coordinates of the corner,
  // i.e. the centre of pixel (i, j) is (i + 0.5, j + 0.5)).
  void Ray(float px, float py, Eigen::Vector3f* origin, Eigen::Vector3f* dir) const;
  // Camera-space direction (z = 1) for pixel coordinate (px, py), undistorted.
  Eigen::Vector3f CameraDirection(float px, float py) const;
  Eigen::Vector3f position() const { return c2w.col(3); }
};

// Largest |coordinate| of a camera position. Beyond it float32 spacing
// exceeds 1 unit, so no scene can be resolved (GPS/ECEF-sized coordinates
// must be recentred first), and ray marching cannot advance.
inline constexpr float kMaxCameraCoordinate = 1e7f;

// Checks that intrinsics are positive/finite, that the rotation is a proper
// rigid rotation (orthonormal, det +1) within `tolerance` and that the
// position is within kMaxCameraCoordinate. Returns INVALID_ARGUMENT naming
// the problem otherwise.
absl::Status ValidateCamera(const Camera& camera, float tolerance = 1e-3f);

// Applies OpenCV radial-tangential distortion to normalised coordinates.
Eigen::Vector2f Distort(const Intrinsics& in, const Eigen::Vector2f& undistorted);
// Inverts Distort() by Newton iteration.
Eigen::Vector2f Undistort(const Intrinsics& in, const Eigen::Vector2f& distorted);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_CAMERA_H_
