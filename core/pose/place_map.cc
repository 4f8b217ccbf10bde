#include "core/pose/place_map.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace clnerf {

absl::StatusOr<MapView> ModelPlaceMap::Render(const Camera& camera) const {
  absl::StatusOr<RenderedView> r = RenderView(model_, camera, options_);
  if (!r.ok()) return r.status();
  MapView v;
  v.camera = camera;
  v.rgb = std::move(r->rgb);
  v.depth = std::move(r->depth);
  v.opacity = std::move(r->opacity);
  return v;
}

std::vector<int> SpreadCameras(const std::vector<Camera>& cameras, int max_views) {
  const int n = int(cameras.size());
  std::vector<int> picked;
  if (n == 0 || max_views <= 0) return picked;
  if (n <= max_views) {
    for (int i = 0; i < n; ++i) picked.push_back(i);
    return picked;
  }
  // Distance between cameras: centres scaled by the spread of all centres,
  // plus the angle between their optical axes (radians).
  Eigen::Vector3f lo = cameras[0].position(), hi = lo;
  for (const Camera& c : cameras) {
    lo = lo.cwiseMin(c.position());
    hi = hi.cwiseMax(c.position());
  }
  const float spread = std::max((hi - lo).norm(), 1e-6f);
  auto dist = [&](int a, int b) {
    const float dc = (cameras[a].position() - cameras[b].position()).norm() / spread;
    const float cosang = std::clamp(cameras[a].c2w.col(2).dot(cameras[b].c2w.col(2)), -1.0f, 1.0f);
    return dc + std::acos(cosang);
  };
  std::vector<float> nearest(n, std::numeric_limits<float>::infinity());
  int next = 0;
  while (int(picked.size()) < max_views) {
    picked.push_back(next);
    int far = -1;
    for (int i = 0; i < n; ++i) {
      nearest[i] = std::min(nearest[i], dist(i, next));
      if (far < 0 || nearest[i] > nearest[far]) far = i;
    }
    if (far < 0 || nearest[far] <= 0) break;
    next = far;
  }
  std::sort(picked.begin(), picked.end());
  return picked;
}

Camera CameraWithSideIn(const Camera& camera, int min_side, int max_side) {
  const Intrinsics& in = camera.intrinsics;
  const int side = std::max(in.width, in.height);
  if (side <= 0 || (side >= min_side && side <= max_side)) return camera;
  const double f = double(side < min_side ? min_side : max_side) / side;
  Camera out = camera;
  out.intrinsics = in.Scaled(std::max(1, int(std::lround(in.width * f))), std::max(1, int(std::lround(in.height * f))));
  return out;
}

double PlaceExtent(const std::vector<Camera>& cameras, const Normalization& norm) {
  double box = 0;
  if (!cameras.empty()) {
    Eigen::Vector3f lo = cameras[0].position(), hi = lo;
    for (const Camera& c : cameras) {
      lo = lo.cwiseMin(c.position());
      hi = hi.cwiseMax(c.position());
    }
    box = (hi - lo).norm();
  }
  const double inner = norm.scale > 0 ? 2.0 / norm.scale : 0.0;
  return std::max(box, inner);
}

}  // namespace clnerf
