#include "core/bake/baked_renderer.h"

#include <omp.h>

#include <algorithm>
#include <cmath>

namespace clnerf {
namespace {

// RGBA in [0, 1] at u of the brick that block (b[0], b[1], b[2]) names,
// seen along d (the view-dependent term is added to the premultiplied
// colour).
bool SampleBlock(const BakedAsset& a, const Eigen::Vector3f& u, const int b[3], const Eigen::Vector3f& d,
                 Eigen::Vector4f* rgba) {
  const int64_t brick = BlockBrick(a, b);
  if (brick < 0) return false;
  const float l[3] = {u[0] - float(kBakeBlock * b[0]), u[1] - float(kBakeBlock * b[1]), u[2] - float(kBakeBlock * b[2])};
  auto texel = [&](int x, int y, int z) { return 4 * BrickTexel(a, uint32_t(brick), x, y, z); };
  *rgba = TrilinearBrick(l, [&](int x, int y, int z, int c) { return float(a.atlas[texel(x, y, z) + size_t(c)]); }) /
          255.0f;
  if (a.view_dependent()) {
    const size_t plane = a.atlas.size();
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector4f h = TrilinearBrick(l, [&](int x, int y, int z, int c) {
        return c == 3 ? 0.0f : float(a.view[size_t(k) * plane + texel(x, y, z) + size_t(c)]) - 128.0f;
      });
      rgba->head<3>() += d[k] * h.head<3>() / 127.0f;
    }
  }
  return true;
}

}  // namespace

BakedRay RenderBakedRay(const BakedAsset& a, const Eigen::Vector3f& o, const Eigen::Vector3f& d) {
  BakedRay out;
  const float T = MarchBaked(
      a, o, d,
      [&](int, const Eigen::Vector3f& u, const int b[3], Eigen::Vector4f* rgba) { return SampleBlock(a, u, b, d, rgba); },
      [&](int, float w, float t, const Eigen::Vector4f& rgba) {
        ++out.samples;
        out.rgb += w * BakedColour(rgba);
        out.depth += w * t;
      });
  out.rgb += T * a.background;
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
  long long samples = 0;
  const int threads = options.threads > 0 ? options.threads : omp_get_max_threads();
#pragma omp parallel for schedule(dynamic) reduction(+ : samples) num_threads(threads)
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
    }
  }
  view.samples = samples;
  return view;
}

}  // namespace clnerf
