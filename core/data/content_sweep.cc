#include "core/data/content_sweep.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "absl/strings/str_cat.h"
#include "Eigen/Dense"

namespace clnerf {

absl::Status ContentSweepOptions::Validate() const {
  if (max_side < 8 || max_side > 1024) return absl::InvalidArgumentError("max_side must be in [8, 1024]");
  if (max_references < 1 || neighbours < 1) {
    return absl::InvalidArgumentError("max_references and neighbours must be >= 1");
  }
  if (!(max_axis_angle_deg > 0 && max_axis_angle_deg <= 90)) {
    return absl::InvalidArgumentError("max_axis_angle_deg must be in (0, 90]");
  }
  if (num_depths < 3 || num_depths > 4096) return absl::InvalidArgumentError("num_depths must be in [3, 4096]");
  if (!(near_over_extent > 0) || !(far_over_extent > near_over_extent) || !std::isfinite(far_over_extent)) {
    return absl::InvalidArgumentError("need 0 < near_over_extent < far_over_extent < inf");
  }
  if (patch_radius < 1 || patch_radius > 8) return absl::InvalidArgumentError("patch_radius must be in [1, 8]");
  if (!(min_texture >= 0) || !(min_score > -1 && min_score <= 1) || !(min_margin >= 0)) {
    return absl::InvalidArgumentError("min_texture and min_margin must be >= 0, min_score in (-1, 1]");
  }
  return absl::OkStatus();
}

namespace {

// A shrunk grey view: pixels, and the camera scaled to them.
struct Grey {
  int w = 0, h = 0;
  std::vector<float> v;
  Camera camera;
  float at(int x, int y) const { return v[size_t(y) * w + x]; }
};

// Box-filtered grey copy of `view` with its longer side at most `max_side`.
Grey Shrink(const View& view, int max_side) {
  const Image& im = view.image;
  const float s = std::max(1.0f, float(std::max(im.width, im.height)) / float(max_side));
  Grey g;
  g.w = std::max(1, int(std::lround(im.width / s)));
  g.h = std::max(1, int(std::lround(im.height / s)));
  g.v.assign(size_t(g.w) * g.h, 0.0f);
  for (int y = 0; y < g.h; ++y) {
    const int y0 = y * im.height / g.h, y1 = std::max(y0 + 1, (y + 1) * im.height / g.h);
    for (int x = 0; x < g.w; ++x) {
      const int x0 = x * im.width / g.w, x1 = std::max(x0 + 1, (x + 1) * im.width / g.w);
      double sum = 0;
      for (int yy = y0; yy < y1; ++yy) {
        for (int xx = x0; xx < x1; ++xx) {
          const float* p = im.pixel(xx, yy);
          sum += p[0] + p[1] + p[2];
        }
      }
      g.v[size_t(y) * g.w + x] = float(sum / (3.0 * (x1 - x0) * (y1 - y0)));
    }
  }
  g.camera = view.camera;
  g.camera.intrinsics = view.camera.intrinsics.Scaled(g.w, g.h);
  return g;
}

// Summed-area table of `v` (w x h) into `out` ((w+1) x (h+1)).
void Integral(const std::vector<float>& v, int w, int h, std::vector<double>* out) {
  out->assign(size_t(w + 1) * (h + 1), 0.0);
  for (int y = 0; y < h; ++y) {
    double row = 0;
    for (int x = 0; x < w; ++x) {
      row += v[size_t(y) * w + x];
      (*out)[size_t(y + 1) * (w + 1) + x + 1] = (*out)[size_t(y) * (w + 1) + x + 1] + row;
    }
  }
}

// Sum of the (2r+1)^2 window around (x, y); the window must lie inside.
double Box(const std::vector<double>& s, int w, int x, int y, int r) {
  const int x0 = x - r, y0 = y - r, x1 = x + r + 1, y1 = y + r + 1;
  const size_t W = size_t(w) + 1;
  return s[y1 * W + x1] - s[y0 * W + x1] - s[y1 * W + x0] + s[y0 * W + x0];
}

// Picks up to `k` neighbours of `r` at quantiles of their baseline among the
// views that look the same way.
std::vector<int> PickNeighbours(const std::vector<Grey>& g, int r, const ContentSweepOptions& o, float extent) {
  const Eigen::Vector3f axis = g[r].camera.c2w.col(2).normalized();
  const float cos_max = std::cos(o.max_axis_angle_deg * float(M_PI) / 180.0f);
  std::vector<std::pair<float, int>> cand;
  for (int j = 0; j < int(g.size()); ++j) {
    if (j == r) continue;
    const float b = (g[j].camera.position() - g[r].camera.position()).norm();
    if (!(b > 1e-3f * extent)) continue;
    if (g[j].camera.c2w.col(2).normalized().dot(axis) < cos_max) continue;
    cand.push_back({b, j});
  }
  std::sort(cand.begin(), cand.end());
  std::vector<int> out;
  const int n = int(cand.size()), k = std::min(o.neighbours, n);
  for (int i = 1; i <= k; ++i) {
    const int idx = int(std::lround(double(i) * (n - 1) / k));
    const int j = cand[std::clamp(idx, 0, n - 1)].second;
    if (std::find(out.begin(), out.end(), j) == out.end()) out.push_back(j);
  }
  return out;
}

}  // namespace

std::vector<Eigen::Vector3f> EstimateContentPoints(const std::vector<View>& views,
                                                   const ContentSweepOptions& o) {
  std::vector<Eigen::Vector3f> points;
  if (!o.Validate().ok()) return points;
  std::vector<Grey> g;
  for (const View& v : views) {
    if (v.image.empty() || v.image.width != v.camera.intrinsics.width ||
        v.image.height != v.camera.intrinsics.height) {
      continue;
    }
    g.push_back(Shrink(v, o.max_side));
  }
  if (g.size() < 2) return points;
  float extent = 0;
  for (size_t i = 0; i < g.size(); ++i) {
    for (size_t j = i + 1; j < g.size(); ++j) {
      extent = std::max(extent, (g[i].camera.position() - g[j].camera.position()).norm());
    }
  }
  if (!(extent > 0) || !std::isfinite(extent)) return points;

  const int nd = o.num_depths, pr = o.patch_radius;
  const double area = double(2 * pr + 1) * (2 * pr + 1);
  // Planes uniform in inverse depth, near to far.
  std::vector<float> depth(nd);
  const double inv_near = 1.0 / (o.near_over_extent * extent), inv_far = 1.0 / (o.far_over_extent * extent);
  for (int k = 0; k < nd; ++k) depth[k] = float(1.0 / (inv_near + (inv_far - inv_near) * k / (nd - 1)));

  const int num_refs = std::min<int>(o.max_references, int(g.size()));
  for (int ri = 0; ri < num_refs; ++ri) {
    const int r = int((size_t(ri) * g.size()) / num_refs);
    const Grey& ref = g[r];
    const std::vector<int> nb = PickNeighbours(g, r, o, extent);
    if (nb.empty()) continue;
    const int w = ref.w, h = ref.h;
    const size_t np = size_t(w) * h;
    std::vector<Eigen::Vector3f> dir(np);  // Camera-space, z = 1.
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) dir[size_t(y) * w + x] = ref.camera.CameraDirection(x + 0.5f, y + 0.5f);
    }
    std::vector<double> s_i, s_ii;
    std::vector<float> sq(np);
    for (size_t i = 0; i < np; ++i) sq[i] = ref.v[i] * ref.v[i];
    Integral(ref.v, w, h, &s_i);
    Integral(sq, w, h, &s_ii);

    std::vector<float> score(size_t(nd) * np, 0.0f);
    std::vector<uint8_t> count(size_t(nd) * np, 0);
    std::vector<float> warped(np), valid(np), ww(np), iw(np);
    std::vector<double> s_w, s_ww, s_iw, s_v;
    for (int n : nb) {
      const Grey& nbr = g[n];
      const Eigen::Matrix3f rn_t = nbr.camera.c2w.leftCols<3>().transpose();
      const Eigen::Matrix3f a = rn_t * ref.camera.c2w.leftCols<3>();
      const Eigen::Vector3f t = rn_t * (ref.camera.position() - nbr.camera.position());
      const Intrinsics& in = nbr.camera.intrinsics;
      for (int k = 0; k < nd; ++k) {
        for (size_t i = 0; i < np; ++i) {
          const Eigen::Vector3f xc = t + depth[k] * (a * dir[i]);
          warped[i] = 0;
          valid[i] = 0;
          if (!(xc.z() > 1e-6f * extent)) continue;
          Eigen::Vector2f u(xc.x() / xc.z(), xc.y() / xc.z());
          if (in.has_distortion()) {
            if (u.squaredNorm() > 4.0f) continue;  // Far outside any real lens's field.
            u = Distort(in, u);
          }
          const float px = in.fx * u.x() + in.cx - 0.5f, py = in.fy * u.y() + in.cy - 0.5f;
          if (!(px >= 0 && py >= 0 && px <= nbr.w - 1 && py <= nbr.h - 1)) continue;
          const int x0 = std::min(int(px), nbr.w - 2 >= 0 ? nbr.w - 2 : 0);
          const int y0 = std::min(int(py), nbr.h - 2 >= 0 ? nbr.h - 2 : 0);
          const int x1 = std::min(x0 + 1, nbr.w - 1), y1 = std::min(y0 + 1, nbr.h - 1);
          const float ax = px - x0, ay = py - y0;
          warped[i] = (1 - ay) * ((1 - ax) * nbr.at(x0, y0) + ax * nbr.at(x1, y0)) +
                      ay * ((1 - ax) * nbr.at(x0, y1) + ax * nbr.at(x1, y1));
          valid[i] = 1;
        }
        for (size_t i = 0; i < np; ++i) {
          ww[i] = warped[i] * warped[i];
          iw[i] = warped[i] * ref.v[i];
        }
        Integral(warped, w, h, &s_w);
        Integral(ww, w, h, &s_ww);
        Integral(iw, w, h, &s_iw);
        Integral(valid, w, h, &s_v);
        for (int y = pr; y < h - pr; ++y) {
          for (int x = pr; x < w - pr; ++x) {
            if (Box(s_v, w, x, y, pr) < area - 0.5) continue;  // Whole patch seen.
            const double si = Box(s_i, w, x, y, pr), sw = Box(s_w, w, x, y, pr);
            const double vi = Box(s_ii, w, x, y, pr) - si * si / area;
            const double vw = Box(s_ww, w, x, y, pr) - sw * sw / area;
            const double cov = Box(s_iw, w, x, y, pr) - si * sw / area;
            const double denom = std::sqrt(std::max(vi, 0.0) * std::max(vw, 0.0));
            const size_t at = size_t(k) * np + size_t(y) * w + x;
            score[at] += denom > 1e-12 ? float(cov / denom) : 0.0f;
            count[at] += 1;
          }
        }
      }
    }
    const double min_var = double(o.min_texture) * o.min_texture * area;
    for (int y = pr; y < h - pr; ++y) {
      for (int x = pr; x < w - pr; ++x) {
        const size_t i = size_t(y) * w + x;
        const double si = Box(s_i, w, x, y, pr);
        if (Box(s_ii, w, x, y, pr) - si * si / area < min_var) continue;  // No texture.
        int best = -1, seen = 0;
        float best_s = -2, sum = 0;
        for (int k = 0; k < nd; ++k) {
          const size_t at = size_t(k) * np + i;
          if (count[at] == 0) continue;
          const float s = score[at] / count[at];
          ++seen;
          sum += s;
          if (s > best_s) {
            best_s = s;
            best = k;
          }
        }
        if (best <= 0 || best >= nd - 1 || 8 * seen < nd) continue;
        if (best_s < o.min_score || best_s - sum / seen < o.min_margin) continue;
        const Eigen::Vector3f world =
            ref.camera.position() + depth[best] * (ref.camera.c2w.leftCols<3>() * dir[i]);
        if (world.allFinite()) points.push_back(world);
      }
    }
  }
  return points;
}

}  // namespace clnerf
