#include "core/bake/colour_fit.h"

#include <cmath>
#include <random>

#include "core/bake/baked_renderer.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {


// A 32^3 grid over [-1, 1]^3 with `blocks` random occupied blocks around
// the centre, random density codes and premultiplied colours, and (with
// `view`) a random view-dependent term.
BakedAsset RandomAsset(int blocks, bool view, uint32_t seed) {
  std::mt19937 rng(seed);
  BakedAsset a;
  a.half_size = 1.0f;
  a.resolution = 32;
  a.background = Eigen::Vector3f(0.9f, 0.8f, 0.7f);
  a.bricks = {blocks, 1, 1};
  const int nb = a.blocks_per_axis();
  a.index.assign(size_t(nb) * nb * nb, 0);
  for (int k = 0; k < blocks; ++k) {
    const int b[3] = {1 + k % 2, 1 + (k / 2) % 2, 1 + k / 4};
    a.index[size_t(b[0]) + size_t(nb) * (size_t(b[1]) + size_t(nb) * size_t(b[2]))] = uint32_t(k + 1);
  }
  const std::array<int, 3> t = a.atlas_texels();
  a.atlas.resize(4 * size_t(t[0]) * t[1] * t[2]);
  std::uniform_int_distribution<int> byte(0, 255);
  for (size_t i = 0; i < a.atlas.size(); i += 4) {
    const int code = byte(rng) / 3;  // Translucent, so rays cross several blocks.
    // Premultiplied colours in [0.3, 0.7]: with |H d| <= 1/4 they never clip.
    for (int c = 0; c < 3; ++c) a.atlas[i + size_t(c)] = uint8_t(code * (77 + byte(rng) * 102 / 255) / 255);
    a.atlas[i + 3] = uint8_t(code);
  }
  if (view) {
    a.view.resize(3 * a.atlas.size());
    const size_t plane = a.atlas.size();
    for (size_t i = 0; i < plane; i += 4) {
      const float s = float(a.atlas[i + 3]) / 255.0f;
      for (int k = 0; k < 3; ++k) {
        for (int c = 0; c < 3; ++c) {
          const float h = float(byte(rng) - 128) / 1024.0f;  // |H| <= 1/8 per axis: |H d| < 1/4.
          a.view[size_t(k) * plane + i + size_t(c)] = uint8_t(128 + std::lround(127.0f * s * h));
        }
      }
    }
  }
  EXPECT_TRUE(a.Validate().ok()) << a.Validate();
  return a;
}

// Colour c0 and view term H of lattice point j, as the atlas stores them
// (divided back by the density code).
void PointColour(const BakedAsset& a, uint32_t j, Eigen::Vector3f* c0, Eigen::Matrix3f* H) {
  const size_t texel = 4 * LatticeTexel(a, j);
  const float s = float(a.atlas[texel + 3]) / 255.0f;
  for (int c = 0; c < 3; ++c) (*c0)[c] = float(a.atlas[texel + size_t(c)]) / 255.0f / s;
  H->setZero();
  if (!a.view_dependent()) return;
  for (int k = 0; k < 3; ++k) {
    for (int c = 0; c < 3; ++c) {
      (*H)(c, k) = (float(a.view[size_t(k) * a.atlas.size() + texel + size_t(c)]) - 128.0f) / 127.0f / s;
    }
  }
}

// The pixel the weights predict for the asset's own colours.
Eigen::Vector3f Predicted(const BakedAsset& a, const std::vector<std::pair<uint32_t, float>>& w,
                          const std::vector<std::pair<uint32_t, float>>& vw, float T, const Eigen::Vector3f& d) {
  Eigen::Vector3f px = T * a.background;
  Eigen::Vector3f c0;
  Eigen::Matrix3f H;
  for (const auto& [j, v] : w) {
    PointColour(a, j, &c0, &H);
    px += v * c0;
  }
  for (const auto& [j, v] : vw) {
    PointColour(a, j, &c0, &H);
    px += v * (H * d);
  }
  return px;
}

// The fit's rows are the reference renderer's pixels exactly (the renderer
// is linear in the lattice colours): the weights applied to the asset's
// own colours give the rendered pixel, without the view term and with it
// applied at the median sample (format 3) or at every sample (format 2),
// stepping one cell or half a cell.
TEST(ColourFitTest, RayWeightsReproduceTheReferenceRenderer) {
  for (int mode = 0; mode < 4; ++mode) {
    const bool view = mode > 0;
    BakedAsset a = RandomAsset(8, view, 3);
    a.view_term = mode == 2 ? BakedViewTerm::kPerSample : BakedViewTerm::kAtMedian;
    a.step_cells = mode == 3 ? 0.5f : 1.0f;
    std::mt19937 rng(9);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    int rays = 0;
    for (int i = 0; i < 200; ++i) {
      const Eigen::Vector3f target(0.5f + 0.4f * u(rng), 0.5f + 0.4f * u(rng), 0.5f + 0.4f * u(rng));
      const Eigen::Vector3f o = Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized() * 3.0f;
      const Eigen::Vector3f d = (target - o).normalized();
      std::vector<std::pair<uint32_t, float>> w, vw;
      const float T = BakedRayWeights(a, o, d, &w, &vw);
      const BakedRay r = RenderBakedRay(a, o, d);
      EXPECT_NEAR(T, 1.0f - r.opacity, 1e-5f);
      if (w.empty()) continue;
      ++rays;
      for (size_t k = 1; k < w.size(); ++k) EXPECT_LT(w[k - 1].first, w[k].first);  // Sorted, merged.
      if (mode == 1) {
        EXPECT_LE(vw.size(), 8u);  // One sample's corners.
      }
      if (mode == 2) {
        EXPECT_EQ(vw, w);
      }
      const Eigen::Vector3f p = Predicted(a, w, vw, T, d);
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(p[c], r.rgb[c], 2e-3f) << "ray " << i << " mode " << mode;
    }
    EXPECT_GT(rays, 60);
  }
}

// The weights are the pixel's derivatives: central finite differences of
// the reference renderer over one lattice point's stored colour match them.
TEST(ColourFitTest, RayWeightsAreThePixelsDerivativesByCentralDifferences) {
  BakedAsset a = RandomAsset(8, false, 5);
  const Eigen::Vector3f o(-3.0f, 0.1f, 0.2f), d = (Eigen::Vector3f(0.55f, 0.6f, 0.4f) - o).normalized();
  std::vector<std::pair<uint32_t, float>> w;
  BakedRayWeights(a, o, d, &w);
  ASSERT_GT(w.size(), 8u);
  int checked = 0;
  for (size_t k = 0; k < w.size(); k += w.size() / 6) {
    const uint32_t j = w[k].first;
    uint8_t* px = a.atlas.data() + 4 * LatticeTexel(a, j);
    const int code = px[3];
    if (code < 20 || px[0] < 10 || px[0] > 245) continue;  // Room for +-h without clipping the byte.
    const int step = 8;  // Bytes of premultiplied colour: h = step / code in colour units.
    const uint8_t saved = px[0];
    px[0] = uint8_t(saved + step);
    const float plus = RenderBakedRay(a, o, d).rgb[0];
    px[0] = uint8_t(saved - step);
    const float minus = RenderBakedRay(a, o, d).rgb[0];
    px[0] = saved;
    const float h = float(step) / float(code);
    EXPECT_NEAR((plus - minus) / (2.0f * h), w[k].second, 1e-3f + 0.01f * w[k].second) << "point " << j;
    ++checked;
  }
  EXPECT_GE(checked, 3);
}

// Format 3: the view weights are the pixel's derivatives over the median
// sample's view-term bytes, by central finite differences of the renderer.
TEST(ColourFitTest, MedianViewWeightsAreThePixelsDerivativesByCentralDifferences) {
  BakedAsset a = RandomAsset(8, true, 7);
  a.view_term = BakedViewTerm::kAtMedian;
  // The first of some rays through the blocks that reaches a median.
  std::mt19937 rng(13);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  Eigen::Vector3f o, d;
  std::vector<std::pair<uint32_t, float>> w, vw;
  for (int tries = 0; tries < 200 && vw.size() < 4; ++tries) {
    o = Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized() * 3.0f;
    d = (Eigen::Vector3f(0.5f + 0.3f * u(rng), 0.5f + 0.3f * u(rng), 0.5f + 0.3f * u(rng)) - o).normalized();
    BakedRayWeights(a, o, d, &w, &vw);
  }
  ASSERT_GE(vw.size(), 4u);
  int checked = 0;
  for (const auto& [j, v] : vw) {
    const size_t texel = 4 * LatticeTexel(a, j);
    const int code = a.atlas[texel + 3];
    uint8_t* hx = a.view.data() + texel;  // H's x column, red: the pixel moves by d_x times it.
    if (code < 20 || *hx < 20 || *hx > 235) continue;
    const int step = 8;  // Bytes: h = step / 127 / (code / 255) in H units.
    const uint8_t saved = *hx;
    *hx = uint8_t(saved + step);
    const float plus = RenderBakedRay(a, o, d).rgb[0];
    *hx = uint8_t(saved - step);
    const float minus = RenderBakedRay(a, o, d).rgb[0];
    *hx = saved;
    const float h = float(step) / 127.0f / (float(code) / 255.0f);
    EXPECT_NEAR((plus - minus) / (2.0f * h), v * d.x(), 1e-3f + 0.01f * std::abs(v * d.x())) << "point " << j;
    ++checked;
  }
  EXPECT_GE(checked, 2);
}

}  // namespace
}  // namespace clnerf
