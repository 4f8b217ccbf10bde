#include "core/data/sparse_depth.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"

namespace clnerf {

absl::Status SparseDepthOptions::Validate() const {
  if (max_points_per_view < 1) return absl::InvalidArgumentError("sparse depth: max_points_per_view must be >= 1");
  if (!(splat_radius >= 0.0f && splat_radius <= 0.25f)) {
    return absl::InvalidArgumentError("sparse depth: splat_radius must be in [0, 0.25]");
  }
  if (!(occlusion_tolerance >= 0.0f && occlusion_tolerance <= 1.0f)) {
    return absl::InvalidArgumentError("sparse depth: occlusion_tolerance must be in [0, 1]");
  }
  if (!(min_depth_fraction >= 0.0f && min_depth_fraction < 1.0f)) {
    return absl::InvalidArgumentError("sparse depth: min_depth_fraction must be in [0, 1)");
  }
  return absl::OkStatus();
}

bool ProjectPoint(const Camera& camera, const Eigen::Vector3f& world, Eigen::Vector2f* pixel, float* depth) {
  const Eigen::Matrix3f R = camera.c2w.leftCols<3>();
  const Eigen::Vector3f xc = R.transpose() * (world - camera.position());
  if (!(xc.z() > 0.0f)) return false;
  Eigen::Vector2f n(xc.x() / xc.z(), xc.y() / xc.z());
  const Intrinsics& in = camera.intrinsics;
  // Far outside the image the distortion polynomial folds back; such points
  // are not seen.
  if (std::abs(n.x()) > 4.0f || std::abs(n.y()) > 4.0f) return false;
  if (in.has_distortion()) n = Distort(in, n);
  const Eigen::Vector2f p(in.fx * n.x() + in.cx, in.fy * n.y() + in.cy);
  if (!(p.x() >= 0.0f && p.y() >= 0.0f && p.x() < float(in.width) && p.y() < float(in.height))) return false;
  *pixel = p;
  *depth = xc.z();
  return true;
}

namespace {

void AttachOne(const std::vector<Eigen::Vector3f>& points, const SparseDepthOptions& o, View* view) {
  view->depth.clear();
  if (view->image.empty()) return;
  const Camera& cam = view->camera;
  const int w = cam.intrinsics.width, h = cam.intrinsics.height;
  struct Hit {
    int x, y;
    float z;
    int point;
  };
  std::vector<Hit> hits;
  for (int k = 0; k < int(points.size()); ++k) {
    if (!points[k].allFinite()) continue;
    Eigen::Vector2f p;
    float z = 0;
    if (!ProjectPoint(cam, points[k], &p, &z)) continue;
    hits.push_back({std::min(int(p.x()), w - 1), std::min(int(p.y()), h - 1), z, k});
  }
  if (hits.empty()) return;
  std::vector<float> zs;
  zs.reserve(hits.size());
  for (const Hit& q : hits) zs.push_back(q.z);
  std::nth_element(zs.begin(), zs.begin() + zs.size() / 2, zs.end());
  const float min_z = o.min_depth_fraction * zs[zs.size() / 2];
  // Splat every point into a nearest-depth buffer.
  const int r = std::max(1, int(std::lround(o.splat_radius * float(std::max(w, h)))));
  std::vector<float> zbuf(size_t(w) * h, std::numeric_limits<float>::infinity());
  for (const Hit& q : hits) {
    if (q.z < min_z) continue;
    for (int dy = -r; dy <= r; ++dy) {
      const int y = q.y + dy;
      if (y < 0 || y >= h) continue;
      for (int dx = -r; dx <= r; ++dx) {
        const int x = q.x + dx;
        if (x < 0 || x >= w || dx * dx + dy * dy > r * r) continue;
        float& b = zbuf[size_t(y) * w + x];
        b = std::min(b, q.z);
      }
    }
  }
  // Visible points, the nearest one per pixel.
  std::vector<int> best(size_t(w) * h, -1);
  for (int i = 0; i < int(hits.size()); ++i) {
    const Hit& q = hits[i];
    if (q.z < min_z) continue;
    const size_t pix = size_t(q.y) * w + q.x;
    if (q.z > (1.0f + o.occlusion_tolerance) * zbuf[pix]) continue;
    if (!view->mask.empty() && !view->mask.keep[pix]) continue;
    if (best[pix] < 0 || q.z < hits[best[pix]].z) best[pix] = i;
  }
  std::vector<DepthPoint> kept;
  for (size_t pix = 0; pix < best.size(); ++pix) {
    if (best[pix] >= 0) kept.push_back({uint32_t(pix), points[hits[best[pix]].point]});
  }
  if (int(kept.size()) > o.max_points_per_view) {  // Even thinning, in pixel order.
    std::vector<DepthPoint> thin;
    thin.reserve(o.max_points_per_view);
    for (int i = 0; i < o.max_points_per_view; ++i) thin.push_back(kept[size_t(i) * kept.size() / o.max_points_per_view]);
    kept.swap(thin);
  }
  view->depth = std::move(kept);
}

}  // namespace

long long AttachSparseDepth(const std::vector<Eigen::Vector3f>& points, const SparseDepthOptions& options,
                            std::vector<View>* views) {
  long long total = 0;
#pragma omp parallel for schedule(dynamic) reduction(+ : total)
  for (int v = 0; v < int(views->size()); ++v) {
    AttachOne(points, options, &(*views)[v]);
    total += (long long)(*views)[v].depth.size();
  }
  return total;
}

}  // namespace clnerf
