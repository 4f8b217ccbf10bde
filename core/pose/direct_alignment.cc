#include "core/pose/direct_alignment.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "Eigen/Geometry"

namespace clnerf {

GreyImage::GreyImage(const Image& im) : w(im.width), h(im.height), v(im.num_pixels()), gx(v.size()), gy(v.size()) {
  for (size_t i = 0; i < v.size(); ++i) v[i] = Luma(im.rgb.data() + 3 * i);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const int xl = std::max(x - 1, 0), xr = std::min(x + 1, w - 1);
      const int yu = std::max(y - 1, 0), yd = std::min(y + 1, h - 1);
      gx[size_t(y) * w + x] = (v[size_t(y) * w + xr] - v[size_t(y) * w + xl]) / float(std::max(xr - xl, 1));
      gy[size_t(y) * w + x] = (v[size_t(yd) * w + x] - v[size_t(yu) * w + x]) / float(std::max(yd - yu, 1));
    }
  }
}

absl::StatusOr<Keyframe> RenderKeyframe(const PlaceMap& map, const Camera& camera, float min_opacity,
                                        float min_gradient) {
  absl::StatusOr<MapView> view = map.Render(camera);
  if (!view.ok()) return view.status();
  const GreyImage g(view->rgb);
  Keyframe k;
  for (int y = 0; y < g.h; ++y) {
    for (int x = 0; x < g.w; ++x) {
      const size_t i = size_t(y) * g.w + x;
      const float d = view->depth[i];
      if (!(view->opacity[i] >= min_opacity) || !std::isfinite(d) || d <= 0) continue;
      if (std::hypot(g.gx[i], g.gy[i]) < min_gradient) continue;
      Eigen::Vector3f origin, dir;
      camera.Ray(x + 0.5f, y + 0.5f, &origin, &dir);
      k.points.push_back((origin + d * dir).cast<double>());
      k.grey.push_back(g.v[i]);
    }
  }
  return k;
}

W2C W2C::FromPose(const Pose& c2w) {
  W2C w;
  const Eigen::Matrix3d rc = c2w.leftCols<3>().cast<double>();
  w.r = rc.transpose();
  w.t = -w.r * c2w.col(3).cast<double>();
  return w;
}

Pose W2C::ToPose() const {
  Pose p;
  p.leftCols<3>() = r.transpose().cast<float>();
  p.col(3) = (-r.transpose() * t).cast<float>();
  return p;
}

W2C W2C::Moved(const Eigen::Matrix<double, 6, 1>& xi) const {
  const Eigen::Vector3d w = xi.head<3>();
  const double angle = w.norm();
  const Eigen::Matrix3d dr =
      angle > 0 ? Eigen::AngleAxisd(angle, w / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
  W2C m;
  m.r = dr * r;
  m.t = dr * t + xi.tail<3>();
  return m;
}

bool Project(const Intrinsics& in, const Eigen::Vector3d& xc, Eigen::Vector2d* px, Eigen::Matrix<double, 2, 3>* jac) {
  if (xc.z() <= 1e-9) return false;
  const double iz = 1.0 / xc.z();
  const Eigen::Vector2f n(float(xc.x() * iz), float(xc.y() * iz));
  Eigen::Matrix2d dd = Eigen::Matrix2d::Identity();
  Eigen::Vector2f d = n;
  if (in.has_distortion()) {
    d = Distort(in, n);
    const float e = 1e-4f;
    dd.col(0) = ((Distort(in, n + Eigen::Vector2f(e, 0)) - Distort(in, n - Eigen::Vector2f(e, 0))) / (2 * e))
                    .cast<double>();
    dd.col(1) = ((Distort(in, n + Eigen::Vector2f(0, e)) - Distort(in, n - Eigen::Vector2f(0, e))) / (2 * e))
                    .cast<double>();
  }
  *px = Eigen::Vector2d(in.fx * double(d.x()) + in.cx, in.fy * double(d.y()) + in.cy);
  Eigen::Matrix<double, 2, 3> dn;
  dn << iz, 0, -xc.x() * iz * iz, 0, iz, -xc.y() * iz * iz;
  *jac = Eigen::DiagonalMatrix<double, 2>(in.fx, in.fy) * dd * dn;
  return true;
}

double RobustSigma(const std::vector<double>& r) {
  std::vector<double> a;
  for (double x : r) {
    if (std::isfinite(x)) a.push_back(std::abs(x));
  }
  if (a.empty()) return 1e-3;
  std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
  return std::max(1.4826 * a[a.size() / 2], 1e-3);
}

double HuberCost(const std::vector<double>& r, double delta) {
  double sum = 0;
  int n = 0;
  for (double x : r) {
    if (!std::isfinite(x)) continue;
    const double a = std::abs(x);
    sum += a <= delta ? 0.5 * x * x : delta * (a - 0.5 * delta);
    ++n;
  }
  return n > 0 ? sum / n : std::numeric_limits<double>::infinity();
}

Camera AtSize(const Camera& c, int w, int h) {
  Camera out = c;
  out.intrinsics = c.intrinsics.Scaled(w, h);
  return out;
}

void PinLeading(int n, Eigen::MatrixXd* h, Eigen::VectorXd* g) {
  h->topRows(n).setZero();
  h->leftCols(n).setZero();
  h->topLeftCorner(n, n).setIdentity();
  g->head(n).setZero();
}

}  // namespace clnerf
