#include "core/data/camera.h"

#include <cmath>

#include "absl/strings/str_format.h"
#include "Eigen/Dense"

namespace clnerf {

Pose ConvertPose(const Pose& c2w, PoseConvention from) {
  if (from == PoseConvention::kOpenCV) return c2w;
  Pose out = c2w;
  out.col(1) = -c2w.col(1);  // OpenGL y up   -> OpenCV y down
  out.col(2) = -c2w.col(2);  // OpenGL looks -z -> OpenCV looks +z
  return out;
}

Pose ExportPose(const Pose& c2w_opencv, PoseConvention to) {
  return ConvertPose(c2w_opencv, to);  // The flip is its own inverse.
}

Eigen::Vector2f Distort(const Intrinsics& in, const Eigen::Vector2f& u) {
  const float x = u.x(), y = u.y();
  const float r2 = x * x + y * y;
  const float radial = 1.0f + in.k1 * r2 + in.k2 * r2 * r2;
  const float dx = 2.0f * in.p1 * x * y + in.p2 * (r2 + 2.0f * x * x);
  const float dy = in.p1 * (r2 + 2.0f * y * y) + 2.0f * in.p2 * x * y;
  return {x * radial + dx, y * radial + dy};
}

Eigen::Vector2f Undistort(const Intrinsics& in, const Eigen::Vector2f& d) {
  // Newton iterations on f(u) = Distort(u) - d, as in instant-ngp/COLMAP.
  Eigen::Vector2f u = d;
  for (int it = 0; it < 10; ++it) {
    const float x = u.x(), y = u.y();
    const float r2 = x * x + y * y;
    const float radial = 1.0f + in.k1 * r2 + in.k2 * r2 * r2;
    const float drad_dr2 = in.k1 + 2.0f * in.k2 * r2;
    const Eigen::Vector2f f = Distort(in, u) - d;
    // Jacobian of Distort.
    const float j00 = radial + 2.0f * x * x * drad_dr2 + 2.0f * in.p1 * y + 6.0f * in.p2 * x;
    const float j01 = 2.0f * x * y * drad_dr2 + 2.0f * in.p1 * x + 2.0f * in.p2 * y;
    const float j10 = 2.0f * x * y * drad_dr2 + 2.0f * in.p1 * x + 2.0f * in.p2 * y;
    const float j11 = radial + 2.0f * y * y * drad_dr2 + 6.0f * in.p1 * y + 2.0f * in.p2 * x;
    const float det = j00 * j11 - j01 * j10;
    if (std::abs(det) < 1e-12f) break;
    const Eigen::Vector2f step((j11 * f.x() - j01 * f.y()) / det, (-j10 * f.x() + j00 * f.y()) / det);
    u -= step;
    if (step.squaredNorm() < 1e-16f) break;
  }
  return u;
}

Eigen::Vector3f Camera::CameraDirection(float px, float py) const {
  const Intrinsics& in = intrinsics;
  Eigen::Vector2f n((px - in.cx) / in.fx, (py - in.cy) / in.fy);
  if (in.has_distortion()) n = Undistort(in, n);
  return {n.x(), n.y(), 1.0f};
}

void Camera::Ray(float px, float py, Eigen::Vector3f* origin, Eigen::Vector3f* dir) const {
  const Eigen::Vector3f d = c2w.leftCols<3>() * CameraDirection(px, py);
  *dir = d.normalized();
  *origin = c2w.col(3);
}

Intrinsics Intrinsics::Scaled(int new_width, int new_height) const {
  Intrinsics out = *this;
  const float sx = float(new_width) / float(width), sy = float(new_height) / float(height);
  out.width = new_width;
  out.height = new_height;
  out.fx *= sx;
  out.cx *= sx;
  out.fy *= sy;
  out.cy *= sy;
  return out;
}

absl::Status ValidateCamera(const Camera& camera, float tolerance) {
  const Intrinsics& in = camera.intrinsics;
  if (in.width <= 0 || in.height <= 0 || in.width > 16384 || in.height > 16384) {
    return absl::InvalidArgumentError(
        absl::StrFormat("invalid image size %dx%d", in.width, in.height));
  }
  for (float v : {in.fx, in.fy, in.cx, in.cy, in.k1, in.k2, in.p1, in.p2}) {
    if (!std::isfinite(v)) return absl::InvalidArgumentError("intrinsics contain NaN/Inf");
  }
  if (in.fx <= 0 || in.fy <= 0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("focal length must be positive (fx=%g, fy=%g)", in.fx, in.fy));
  }
  if (!camera.c2w.allFinite()) return absl::InvalidArgumentError("pose contains NaN/Inf");
  const float far = camera.c2w.col(3).cwiseAbs().maxCoeff();
  if (far > kMaxCameraCoordinate) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "camera position %g is beyond +-%g: float32 poses cannot resolve a scene there; recentre the poses",
        far, kMaxCameraCoordinate));
  }
  const Eigen::Matrix3f r = camera.c2w.leftCols<3>();
  const float orth_err = (r.transpose() * r - Eigen::Matrix3f::Identity()).cwiseAbs().maxCoeff();
  if (orth_err > tolerance) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "pose rotation is not orthonormal (max |R^T R - I| = %g); poses must be rigid", orth_err));
  }
  if (r.determinant() < 0) {
    return absl::InvalidArgumentError("pose rotation has determinant -1 (a reflection)");
  }
  if (camera.time_step < 0) return absl::InvalidArgumentError("negative time step");
  return absl::OkStatus();
}

}  // namespace clnerf
