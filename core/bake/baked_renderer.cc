#include "core/bake/baked_renderer.h"

#include <omp.h>

#include <algorithm>
#include <cmath>

namespace clnerf {
namespace {

// The view-dependent term at local coordinates l of `brick`, premultiplied
// by the density code like the colour (H d in [0, 1] colour units times
// the blended code): sum_k d_k (texel_k - 128) / 127.
Eigen::Vector3f ViewTerm(const BakedAsset& a, int64_t brick, const float l[3], const Eigen::Vector3f& d) {
  const size_t plane = a.atlas.size();
  Eigen::Vector3f out = Eigen::Vector3f::Zero();
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector4f h = TrilinearBrick(l, [&](int x, int y, int z, int c) {
      return c == 3 ? 0.0f : float(a.view[size_t(k) * plane + 4 * BrickTexel(a, uint32_t(brick), x, y, z) + size_t(c)]) - 128.0f;
    });
    out += d[k] * h.head<3>() / 127.0f;
  }
  return out;
}

// RGBA in [0, 1] at u of the brick that block (b[0], b[1], b[2]) names,
// seen along d (format 2: the view-dependent term is added to the
// premultiplied colour). Records the brick and local coordinates.
bool SampleBlock(const BakedAsset& a, const Eigen::Vector3f& u, const int b[3], const Eigen::Vector3f& d,
                 Eigen::Vector4f* rgba, int64_t* brick_out, float l[3]) {
  const int64_t brick = BlockBrick(a, b);
  if (brick < 0) return false;
  LocalInBlock(u, b, l);
  *brick_out = brick;
  *rgba = TrilinearBrick(l, [&](int x, int y, int z, int c) {
            return float(a.atlas[4 * BrickTexel(a, uint32_t(brick), x, y, z) + size_t(c)]);
          }) / 255.0f;
  if (a.view_dependent() && a.view_term == BakedViewTerm::kPerSample) rgba->head<3>() += ViewTerm(a, brick, l, d);
  return true;
}

}  // namespace

BakedRay RenderBakedRay(const BakedAsset& a, const Eigen::Vector3f& o, const Eigen::Vector3f& d) {
  BakedRay out;
  int64_t brick = -1, median_brick = -1;
  float l[3] = {0, 0, 0}, median_l[3] = {0, 0, 0}, median_code = 0.0f;
  BakedMedian median;
  const float T = MarchBaked(
      a, o, d,
      [&](int, const Eigen::Vector3f& u, const int b[3], Eigen::Vector4f* rgba) {
        ++out.steps;
        return SampleBlock(a, u, b, d, rgba, &brick, l);
      },
      [&](int, float w, float t, const Eigen::Vector4f& rgba, float) {
        ++out.samples;
        out.rgb += w * BakedColour(rgba);
        out.depth += w * t;
        if (median.Step(w)) {  // The median sample (format 3).
          median_brick = brick;
          std::copy(l, l + 3, median_l);
          median_code = rgba[3];
        }
      },
      /*skip_codes=*/true);
  if (a.view_dependent() && a.view_term == BakedViewTerm::kAtMedian && median_brick >= 0) {
    out.rgb += (1.0f - T) * ViewTerm(a, median_brick, median_l, d) / std::max(median_code, 1.0f / 255.0f);
  }
  out.rgb = (out.rgb + T * a.background).cwiseMax(0.0f).cwiseMin(1.0f);
  out.opacity = 1.0f - T;
  return out;
}

absl::StatusOr<RenderedView> RenderBakedView(const BakedAsset& asset, const Camera& world_camera,
                                             const BakedRenderOptions& options) {
  if (absl::Status s = ValidateCamera(world_camera); !s.ok()) return s;
  const Camera cam = BakedModelCamera(asset, world_camera);
  const int W = cam.intrinsics.width, H = cam.intrinsics.height;
  RenderedView view;
  view.rgb = Image(W, H);
  view.opacity.assign(size_t(W) * H, 0.0f);
  view.depth.assign(size_t(W) * H, 0.0f);
  long long samples = 0, steps = 0;
  const int threads = options.threads > 0 ? options.threads : omp_get_max_threads();
#pragma omp parallel for schedule(dynamic) reduction(+ : samples, steps) num_threads(threads)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      Eigen::Vector3f o, d;
      cam.Ray(float(x) + 0.5f, float(y) + 0.5f, &o, &d);
      const BakedRay r = RenderBakedRay(asset, o, d);
      const size_t p = size_t(y) * W + x;
      for (int c = 0; c < 3; ++c) view.rgb.pixel(x, y)[c] = r.rgb[c];
      view.opacity[p] = r.opacity;
      view.depth[p] = r.depth / asset.normalization.scale;
      samples += r.samples;
      steps += r.steps;
    }
  }
  view.samples = samples;
  view.steps = steps;
  return view;
}

}  // namespace clnerf
