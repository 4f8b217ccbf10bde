#include "core/bake/density_fit.h"

#include <cmath>
#include <random>

#include "core/bake/baked_renderer.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace density_fit_test {  // Its own names: the bake tests build as one unity file.
namespace {


// A 32^3 grid over [-1, 1]^3 with 8 occupied blocks around the centre (or,
// `contracted`, over the contracted cube with the 8 blocks of its positive
// octant, half in the shell), translucent random density codes and
// premultiplied colours in [0.3, 0.7].
BakedAsset RandomAsset(uint32_t seed, bool contracted = false) {
  std::mt19937 rng(seed);
  BakedAsset a;
  a.contracted = contracted;
  a.half_size = contracted ? 2.0f : 1.0f;
  a.resolution = 32;
  a.background = Eigen::Vector3f(0.9f, 0.8f, 0.7f);
  const int blocks = 8;
  a.bricks = {blocks, 1, 1};
  const int nb = a.blocks_per_axis();
  a.index.assign(size_t(nb) * nb * nb, 0);
  for (int k = 0; k < blocks; ++k) {
    const int first = contracted ? 2 : 1;
    const int b[3] = {first + k % 2, first + (k / 2) % 2, first + k / 4};
    a.index[size_t(b[0]) + size_t(nb) * (size_t(b[1]) + size_t(nb) * size_t(b[2]))] = uint32_t(k + 1);
  }
  const std::array<int, 3> t = a.atlas_texels();
  a.atlas.resize(4 * size_t(t[0]) * t[1] * t[2]);
  std::uniform_int_distribution<int> byte(0, 255);
  for (size_t i = 0; i < a.atlas.size(); i += 4) {
    const int code = 10 + byte(rng) / 3;
    for (int c = 0; c < 3; ++c) a.atlas[i + size_t(c)] = uint8_t(code * (77 + byte(rng) * 102 / 255) / 255);
    a.atlas[i + 3] = uint8_t(code);
  }
  EXPECT_TRUE(a.Validate().ok()) << a.Validate();
  return a;
}

// The asset's codes and colours as floats (colour = premultiplied / code).
void Unpack(const BakedAsset& a, std::vector<float>* codes, std::vector<float>* rgb) {
  const size_t points = size_t(kBrickLattice) * size_t(a.num_bricks());
  codes->resize(points);
  rgb->resize(3 * points);
  for (size_t i = 0; i < points; ++i) {
    const uint8_t* px = a.atlas.data() + 4 * LatticeTexel(a, uint32_t(i));
    (*codes)[i] = float(px[3]) / 255.0f;
    for (int c = 0; c < 3; ++c) (*rgb)[3 * i + size_t(c)] = px[3] > 0 ? float(px[c]) / float(px[3]) : 0.0f;
  }
}

// A ray towards the occupied blocks: from a random point on a sphere of
// radius 3, or (contracted) from near the centre through the inner cube's
// positive octant into the shell.
void RandomRay(std::mt19937* rng, Eigen::Vector3f* o, Eigen::Vector3f* d, bool contracted = false) {
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  if (contracted) {
    *o = 0.3f * Eigen::Vector3f(u(*rng), u(*rng), u(*rng));
    *d = (Eigen::Vector3f(1.5f + 0.5f * u(*rng), 1.5f + 0.5f * u(*rng), 1.5f + 0.5f * u(*rng)) - *o).normalized();
    return;
  }
  const Eigen::Vector3f target(0.5f + 0.4f * u(*rng), 0.5f + 0.4f * u(*rng), 0.5f + 0.4f * u(*rng));
  *o = Eigen::Vector3f(u(*rng), u(*rng), u(*rng)).normalized() * 3.0f;
  *d = (target - *o).normalized();
}

// With the atlas's own codes and colours, the fit's pixel is the reference
// renderer's (which reads the same bytes), objects and contracted scenes.
TEST(DensityFitTest, PixelsAreTheReferenceRenderers) {
  for (bool contracted : {false, true}) {
    const BakedAsset a = RandomAsset(3, contracted);
    std::vector<float> codes, rgb;
    Unpack(a, &codes, &rgb);
    std::mt19937 rng(9);
    int rays = 0;
    for (int i = 0; i < 200; ++i) {
      Eigen::Vector3f o, d;
      RandomRay(&rng, &o, &d, contracted);
      float T = 1.0f;
      const Eigen::Vector3f px = BakedRayDensityJacobian(a, codes.data(), rgb.data(), o, d, nullptr, &T);
      const BakedRay r = RenderBakedRay(a, o, d);
      EXPECT_NEAR(T, 1.0f - r.opacity, 1e-5f);
      if (T > 0.999f) continue;
      ++rays;
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(px[c], r.rgb[c], 2e-3f) << "ray " << i;
    }
    EXPECT_GT(rays, 60) << "contracted " << contracted;
  }
}

// The Jacobian is the pixel's derivative: central finite differences over
// each code a ray depends on, in objects and in the contracted shell (whose
// steps are longer than a cell).
TEST(DensityFitTest, JacobianIsThePixelsDerivativeByCentralDifferences) {
  for (bool contracted : {false, true}) {
    const BakedAsset a = RandomAsset(5, contracted);
    std::vector<float> codes, rgb;
    Unpack(a, &codes, &rgb);
    for (float& c : codes) c *= 0.5f;  // Rays cross several blocks before they stop.
    std::mt19937 rng(17);
    int checked = 0, rays = 0;
    for (int i = 0; i < 40 && rays < 8; ++i) {
      Eigen::Vector3f o, d;
      RandomRay(&rng, &o, &d, contracted);
      std::vector<std::pair<uint32_t, Eigen::Vector3f>> J;
      float T = 1.0f;
      BakedRayDensityJacobian(a, codes.data(), rgb.data(), o, d, &J, &T);
      if (J.size() < 16 || T < 0.02f) continue;  // Far from the early stop, so +-h keeps the samples.
      ++rays;
      for (size_t k = 1; k < J.size(); ++k) EXPECT_LT(J[k - 1].first, J[k].first);  // Sorted, merged.
      for (size_t k = 0; k < J.size(); k += 3) {
        const uint32_t id = J[k].first;
        const float saved = codes[id], h = 1e-3f;
        codes[id] = saved + h;
        const Eigen::Vector3f plus = BakedRayDensityJacobian(a, codes.data(), rgb.data(), o, d, nullptr);
        codes[id] = saved - h;
        const Eigen::Vector3f minus = BakedRayDensityJacobian(a, codes.data(), rgb.data(), o, d, nullptr);
        codes[id] = saved;
        const Eigen::Vector3f fd = (plus - minus) / (2.0f * h);
        for (int c = 0; c < 3; ++c) {
          EXPECT_NEAR(fd[c], J[k].second[c], 2e-3f + 0.01f * std::abs(J[k].second[c]))
              << "point " << id << " channel " << c << " contracted " << contracted;
        }
        ++checked;
      }
    }
    EXPECT_GE(rays, 8);
    EXPECT_GT(checked, 100);
  }
}

// Rays rendered from the true codes are the targets; from codes disturbed
// (scaled by 0.6 in one half of the blocks, 1.4 in the other) the fit must
// bring the rays' residual and the codes back towards the truth, and leave
// codes no ray sees alone.
TEST(DensityFitTest, RecoversDisturbedCodesFromTheirRenders) {
  const BakedAsset truth = RandomAsset(11);
  std::vector<float> true_codes, rgb;
  Unpack(truth, &true_codes, &rgb);
  FitTargets targets;
  std::mt19937 rng(23);
  for (int i = 0; i < 20000; ++i) {
    Eigen::Vector3f o, d;
    RandomRay(&rng, &o, &d);
    const Eigen::Vector3f px = BakedRayDensityJacobian(truth, true_codes.data(), rgb.data(), o, d, nullptr);
    targets.origins.insert(targets.origins.end(), o.data(), o.data() + 3);
    targets.dirs.insert(targets.dirs.end(), d.data(), d.data() + 3);
    targets.rgb.insert(targets.rgb.end(), px.data(), px.data() + 3);
  }
  BakedAsset a = truth;
  for (size_t i = 0; i < true_codes.size(); ++i) {
    const float scale = (i / kBrickLattice) % 2 == 0 ? 0.6f : 1.4f;
    a.atlas[4 * LatticeTexel(a, uint32_t(i)) + 3] =
        uint8_t(std::lround(std::min(255.0f, 255.0f * true_codes[i] * scale)));
  }
  const auto code_error = [&](const BakedAsset& x) {
    double sum = 0;
    for (size_t i = 0; i < true_codes.size(); ++i) {
      sum += std::abs(x.atlas[4 * LatticeTexel(x, uint32_t(i)) + 3] / 255.0 - true_codes[i]);
    }
    return sum / double(true_codes.size());
  };
  const double before = code_error(a);
  DensityFitOptions o;
  o.rays = 1 << 14;
  o.steps = 3;
  o.prior = 0.1f;
  DensityFitReport rep;
  ASSERT_TRUE(FitBakedDensities(targets, o, rgb, &a, &rep).ok());
  const double after = code_error(a);
  std::printf("rays %lld, unknowns %lld, steps %d: rms %.4f -> %.4f, mean code error %.4f -> %.4f\n", rep.rays,
              rep.unknowns, rep.accepted_steps, rep.rms_before, rep.rms_after, before, after);
  EXPECT_GE(rep.accepted_steps, 1);
  EXPECT_LT(rep.rms_after, 0.5 * rep.rms_before);
  EXPECT_LT(after, 0.7 * before);
  for (size_t i = 0; i < a.atlas.size(); i += 4) {  // Colours are not touched.
    for (int c = 0; c < 3; ++c) EXPECT_EQ(a.atlas[i + size_t(c)], truth.atlas[i + size_t(c)]);
  }
}

TEST(DensityFitTest, BadOptionsAndArraysAreRefused) {
  BakedAsset a = RandomAsset(1);
  std::vector<float> codes, rgb;
  Unpack(a, &codes, &rgb);
  FitTargets targets;
  DensityFitOptions o;
  o.prior = 0.0f;
  EXPECT_EQ(FitBakedDensities(targets, o, rgb, &a).code(), absl::StatusCode::kInvalidArgument);
  o = DensityFitOptions();
  o.steps = -1;
  EXPECT_EQ(FitBakedDensities(targets, o, rgb, &a).code(), absl::StatusCode::kInvalidArgument);
  o = DensityFitOptions();
  rgb.pop_back();
  EXPECT_EQ(FitBakedDensities(targets, o, rgb, &a).code(), absl::StatusCode::kInvalidArgument);
  rgb.push_back(0.5f);
  o.rays = 1 << 14;
  EXPECT_TRUE(FitBakedDensities(targets, o, rgb, &a).ok());  // No targets: nothing to do.
}

}  // namespace
}  // namespace density_fit_test
}  // namespace clnerf
