#include "core/bake/baked_renderer.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "core/data/contraction.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// An empty grid of R^3 cells over [-B, B]^3 with room for `bricks` bricks.
BakedAsset EmptyAsset(bool contracted, float half_size, int resolution, int bricks) {
  BakedAsset a;
  a.contracted = contracted;
  a.half_size = half_size;
  a.resolution = resolution;
  a.background = Eigen::Vector3f(1, 1, 1);
  a.bricks = {bricks, 1, 1};
  const int nb = a.blocks_per_axis();
  a.index.assign(size_t(nb) * nb * nb, 0);
  const std::array<int, 3> t = a.atlas_texels();
  a.atlas.assign(4 * size_t(t[0]) * t[1] * t[2], 0);
  return a;
}

// Fills block (bx, by, bz) with brick k of uniform colour and density code.
void FillBlock(BakedAsset* a, int bx, int by, int bz, int k, const Eigen::Vector3f& rgb, uint8_t code) {
  const int nb = a->blocks_per_axis();
  a->index[size_t(bx) + size_t(nb) * (size_t(by) + size_t(nb) * size_t(bz))] = uint32_t(k + 1);
  const std::array<int, 3> t = a->atlas_texels();
  for (int z = 0; z < kBakeBrick; ++z) {
    for (int y = 0; y < kBakeBrick; ++y) {
      for (int x = 0; x < kBakeBrick; ++x) {
        uint8_t* p = a->atlas.data() + 4 * (size_t(k * kBakeBrick + x) + size_t(t[0]) * (size_t(y) + size_t(t[1]) * z));
        for (int c = 0; c < 3; ++c) p[c] = uint8_t(std::lround(float(code) * rgb[c]));  // Premultiplied.
        p[3] = code;
      }
    }
  }
}

// Opacity of `samples` samples of `step_cells` through a uniform code, each
// covering the steps the tail rule (BakedTailSteps) gives it.
float ClosedFormOpacity(uint8_t code, int samples, float step_cells) {
  const float a = float(code) / 255.0f;
  float T = 1.0f;
  for (int i = 0; i < samples; ++i) T *= std::pow(1.0f - a * a, step_cells * float(BakedTailSteps(T)));
  return 1.0f - T;
}

// How many samples of `step_cells` start inside `cells` of a uniform code
// when the first starts `phase` steps in (0 <= phase < 1), each covering the
// steps the tail rule gives it.
int SamplesInside(uint8_t code, float cells, float step_cells, float phase) {
  const float a = float(code) / 255.0f;
  float T = 1.0f, at = phase * step_cells;
  int n = 0;
  for (; at < cells && T > kBakedMinTransmittance; ++n) {
    const int k = BakedTailSteps(T);
    T *= std::pow(1.0f - a * a, step_cells * float(k));
    at += step_cells * float(k);
  }
  return n;
}

// Where little light is left a sample covers 2 steps, then 4, then 8:
// through four uniform blocks in a row (a^2 = 0.30 per cell) the samples
// cover 1, 1, 2, 2, 4 and 8 cells (T 1, 0.70, 0.49, 0.24, 0.12, 0.028),
// each as far past the last as it covers, and their weights are those of
// runs that long; the ray then stops (T below 1/255).
TEST(BakedRendererTest, TheTailTakesLongerSteps) {
  BakedAsset a = EmptyAsset(false, 1.0f, 32, 4);
  for (int z = 0; z < 4; ++z) FillBlock(&a, 2, 2, z, z, Eigen::Vector3f(0.5f, 0.5f, 0.5f), 140);
  ComputeBlockDistances(&a);
  std::vector<float> ts, runs, weights;
  const Eigen::Vector3f o(0.26f, 0.24f, -3.0f), d(0, 0, 1);
  const float T = MarchBaked(
      a, o, d,
      [&](int, const Eigen::Vector3f&, const int b[3], Eigen::Vector4f* rgba) {
        if (BlockBrick(a, b) < 0) return false;
        *rgba = Eigen::Vector4f(0.5f, 0.5f, 0.5f, 140.0f / 255.0f);
        return true;
      },
      [&](int, float w, float t, const Eigen::Vector4f&, float run) {
        ts.push_back(t);
        runs.push_back(run);
        weights.push_back(w);
      });
  const float cell = a.cell(), q = 1.0f - (140.0f / 255.0f) * (140.0f / 255.0f);
  ASSERT_EQ(runs.size(), 6u);
  const float k[6] = {1, 1, 2, 2, 4, 8};
  float Tk = 1.0f;
  for (size_t i = 0; i < 6; ++i) {
    EXPECT_NEAR(runs[i], k[i] * cell, 1e-6f) << i;
    if (i > 0) EXPECT_NEAR(ts[i] - ts[i - 1], k[i - 1] * cell, 1e-5f) << i;
    const float alpha = 1.0f - std::pow(q, k[i]);
    EXPECT_NEAR(weights[i], Tk * alpha, 1e-5f) << i;
    Tk *= 1.0f - alpha;
  }
  EXPECT_NEAR(T, Tk, 1e-6f);
  EXPECT_LT(T, kBakedMinTransmittance);
}

TEST(BakedRendererTest, AUniformBlockComposesAsItsClosedForm) {
  for (float step_cells : {1.0f, 0.5f}) {
    // 32^3 cells over [-1, 1]^3: blocks of 0.5; block (2, 2, 2) spans [0, 0.5]^3.
    BakedAsset a = EmptyAsset(false, 1.0f, 32, 1);
    a.step_cells = step_cells;
    const Eigen::Vector3f colour(0.8f, 0.2f, 0.4f);
    FillBlock(&a, 2, 2, 2, 0, colour, 100);
    ASSERT_TRUE(a.Validate().ok());
    const BakedRay r = RenderBakedRay(a, Eigen::Vector3f(0.26f, 0.24f, -3.0f), Eigen::Vector3f(0, 0, 1));
    // The block is 8 cells deep: the samples that start inside it, at
    // whatever phase the lattice has there.
    const int most = SamplesInside(100, 8.0f, step_cells, 0.0f), least = SamplesInside(100, 8.0f, step_cells, 0.999f);
    EXPECT_GE(r.samples, least);
    EXPECT_LE(r.samples, most);
    EXPECT_NEAR(r.opacity, ClosedFormOpacity(100, r.samples, step_cells), 1e-5f);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(r.rgb[c], r.opacity * colour[c] + (1.0f - r.opacity), 2e-3f);
    // Depth: the weights sit between the block's faces (z = 3 to 3.5 from the origin).
    EXPECT_GT(r.depth / r.opacity, 3.0f);
    EXPECT_LT(r.depth / r.opacity, 3.5f);
    // A ray that misses the block sees the background only.
    const BakedRay miss = RenderBakedRay(a, Eigen::Vector3f(-0.3f, 0.24f, -3.0f), Eigen::Vector3f(0, 0, 1));
    EXPECT_EQ(miss.samples, 0);
    EXPECT_FLOAT_EQ(miss.opacity, 0.0f);
    EXPECT_NEAR(miss.rgb[0], 1.0f, 1e-6f);
  }
}

// A uniform block whose colour depends on the viewing direction, c(d) = c0
// + H d. Rays along +z and -z see c0 + H_z and c0 - H_z, rays along x see
// c0 + H_x, each to the term's 1/127 quantisation, whether the term is
// applied at every sample (format 2) or once at the median (format 3).
TEST(BakedRendererTest, AViewDependentBlockShowsItsColourForEachDirection) {
  for (BakedViewTerm term : {BakedViewTerm::kAtMedian, BakedViewTerm::kPerSample}) {
  BakedAsset a = EmptyAsset(false, 1.0f, 32, 1);
  a.view_term = term;
  const Eigen::Vector3f c0(0.5f, 0.4f, 0.3f);
  const uint8_t code = 200;
  FillBlock(&a, 2, 2, 2, 0, c0, code);
  const Eigen::Vector3f hx(0.2f, 0.0f, -0.1f), hz(-0.3f, 0.25f, 0.1f);
  a.view.assign(3 * a.atlas.size(), 0);
  const size_t plane = a.atlas.size();
  for (size_t texel = 0; texel < plane / 4; ++texel) {
    const float s = float(a.atlas[4 * texel + 3]) / 255.0f;
    for (int k = 0; k < 3; ++k) {
      for (int c = 0; c < 3; ++c) {
        const float h = k == 0 ? hx[c] : (k == 2 ? hz[c] : 0.0f);
        a.view[size_t(k) * plane + 4 * texel + size_t(c)] = uint8_t(128 + std::lround(127.0f * s * h));
      }
    }
  }
  ASSERT_TRUE(a.Validate().ok());
  auto seen = [&](const Eigen::Vector3f& o, const Eigen::Vector3f& d) {
    const BakedRay r = RenderBakedRay(a, o, d);
    return Eigen::Vector3f((r.rgb - (1.0f - r.opacity) * a.background) / r.opacity);
  };
  const Eigen::Vector3f up = seen(Eigen::Vector3f(0.26f, 0.24f, -3.0f), Eigen::Vector3f(0, 0, 1));
  const Eigen::Vector3f down = seen(Eigen::Vector3f(0.26f, 0.24f, 3.0f), Eigen::Vector3f(0, 0, -1));
  const Eigen::Vector3f side = seen(Eigen::Vector3f(-3.0f, 0.24f, 0.26f), Eigen::Vector3f(1, 0, 0));
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(up[c], c0[c] + hz[c], 0.012f) << c;
    EXPECT_NEAR(down[c], c0[c] - hz[c], 0.012f) << c;
    EXPECT_NEAR(side[c], c0[c] + hx[c], 0.012f) << c;
  }
  }
}

TEST(BakedRendererTest, SkippingEmptyBlocksLandsOnEveryOccupiedOne) {
  // Two thin blocks far apart on one ray, empty space between and around:
  // the skips must reach both, each with its full depth of samples, with
  // and without the distance map.
  for (bool distances : {false, true}) {
    BakedAsset a = EmptyAsset(false, 1.0f, 64, 2);
    FillBlock(&a, 5, 7, 1, 0, Eigen::Vector3f(1, 0, 0), 60);
    FillBlock(&a, 5, 7, 6, 1, Eigen::Vector3f(0, 0, 1), 60);
    if (distances) ComputeBlockDistances(&a);
    const float cell = a.cell();
    const Eigen::Vector3f o(-1.0f + (5 * 8 + 4.3f) * cell, -1.0f + (7 * 8 + 3.7f) * cell, -2.0f);
    const BakedRay r = RenderBakedRay(a, o, Eigen::Vector3f(0, 0, 1));
    EXPECT_GE(r.samples, 15);
    EXPECT_LE(r.samples, 17);
    EXPECT_NEAR(r.opacity, ClosedFormOpacity(60, r.samples, 1.0f), 1e-5f);
    EXPECT_GT(r.rgb[0], r.rgb[2]);  // The red block is in front.
    EXPECT_GT(r.rgb[2], 0.0f);
    // Oblique rays see the same total as marching without skips would: each
    // block's samples are spaced one step apart along the ray.
    const Eigen::Vector3f d = Eigen::Vector3f(0.05f, -0.03f, 1.0f).normalized();
    const BakedRay s = RenderBakedRay(a, o - 2.0f * d.cwiseProduct(Eigen::Vector3f(1, 1, 0)), d);
    EXPECT_NEAR(s.opacity, ClosedFormOpacity(60, s.samples, 1.0f), 1e-5f);
  }
}

// The chessboard distances match brute force, and marching with them sees
// the same samples as skipping one block at a time, over random sparse
// grids: exactly when bounded; in a contracted grid's shell, where a jump's
// end depends on the empty cube's size, the same occupied blocks with
// samples shifted by part of a step on a few rays.
TEST(BakedRendererTest, BlockDistancesSkipOnlyEmptySpace) {
  std::mt19937 rng(11);
  for (bool contracted : {false, true}) {
    BakedAsset a = EmptyAsset(contracted, contracted ? 2.0f : 1.0f, 128, 6);
    const int nb = a.blocks_per_axis();
    std::uniform_int_distribution<int> pick(0, nb - 1);
    for (int k = 0; k < 6; ++k) {
      FillBlock(&a, pick(rng), pick(rng), pick(rng), k, Eigen::Vector3f(0.2f * k, 0.5f, 0.9f), uint8_t(40 + 30 * k));
    }
    ComputeBlockDistances(&a);
    for (int i = 0; i < nb * nb * nb; ++i) {
      const int x = i % nb, y = (i / nb) % nb, z = i / (nb * nb);
      int best = 255;
      for (int j = 0; j < nb * nb * nb; ++j) {
        if (a.index[size_t(j)] == 0) continue;
        best = std::min(best, std::max({std::abs(j % nb - x), std::abs((j / nb) % nb - y), std::abs(j / (nb * nb) - z)}));
      }
      ASSERT_EQ(int(a.block_distance[size_t(i)]), best) << i;
    }
    // The occupied blocks' box (an object's rays march only across it).
    std::array<int, 3> lo = {nb, nb, nb}, hi = {-1, -1, -1};
    for (int j = 0; j < nb * nb * nb; ++j) {
      if (a.index[size_t(j)] == 0) continue;
      const int b[3] = {j % nb, (j / nb) % nb, j / (nb * nb)};
      for (int k = 0; k < 3; ++k) lo[size_t(k)] = std::min(lo[size_t(k)], b[k]), hi[size_t(k)] = std::max(hi[size_t(k)], b[k]);
    }
    EXPECT_EQ(a.occupied_lo, lo);
    EXPECT_EQ(a.occupied_hi, hi);
    // Without distances (nor the box) every empty block is stepped through:
    // the same samples and pixels.
    BakedAsset plain = a;
    plain.block_distance.clear();
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::vector<Eigen::Vector3f> centres;  // Model space (the inner cube's part when contracted).
    for (int i = 0; i < nb * nb * nb; ++i) {
      if (a.index[size_t(i)] == 0) continue;
      const Eigen::Vector3f c((i % nb + 0.5f) / nb, ((i / nb) % nb + 0.5f) / nb, (i / (nb * nb) + 0.5f) / nb);
      centres.push_back((2.0f * c.array() - 1.0f) * a.half_size);
    }
    int hits = 0, shifted = 0;
    double opacity_gap = 0.0;
    for (int r = 0; r < 400; ++r) {
      const Eigen::Vector3f o = Eigen::Vector3f(u(rng), u(rng), u(rng)) * (contracted ? 0.9f : 2.5f);
      // Half the rays aim at an occupied block (through the contraction's
      // inverse when it lies in the shell), half go anywhere.
      Eigen::Vector3f aim = centres[size_t(r) % centres.size()];
      const float q = aim.cwiseAbs().maxCoeff();
      if (contracted && q > 1.0f) aim *= (1.0f / (2.0f - q)) / q;
      const Eigen::Vector3f d = r % 2 ? Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized() : Eigen::Vector3f((aim - o).normalized());
      const BakedRay fast = RenderBakedRay(a, o, d), slow = RenderBakedRay(plain, o, d);
      hits += fast.samples > 0;
      if (contracted) {
        // In the shell the sample after a jump lands half a step past where
        // the jump ends, and a longer jump (a larger empty cube) can end
        // nearer the occupied block: the samples there may shift by part of
        // a step (one more or one fewer in a block, with another compiler's
        // rounding), but no occupied block is jumped over.
        EXPECT_EQ(fast.samples > 0, slow.samples > 0) << r;
        EXPECT_LE(std::abs(fast.samples - slow.samples), 6) << r;  // At most one per occupied block.
        shifted += fast.samples != slow.samples;
        opacity_gap += std::abs(fast.opacity - slow.opacity);
        continue;
      }
      ASSERT_EQ(fast.samples, slow.samples) << r;
      EXPECT_NEAR(fast.opacity, slow.opacity, 1e-5f);
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(fast.rgb[c], slow.rgb[c], 1e-5f);
    }
    EXPECT_GT(hits, 100) << "contracted " << contracted;
    EXPECT_LE(shifted, 8) << "of 400 rays";
    EXPECT_LT(opacity_gap / 400.0, 2e-3);
  }
}

// In the contracted shell an empty cube of blocks is skipped by
// ShellEmptyRun: over random rays and boxes, everything the ray crosses
// over the run contracts into the cube (nothing occupied is skipped), and
// the skip is not short: on average it covers most of the
// way to where the contracted point really leaves the cube (marched finely;
// what is left is skipped from the next sample).
TEST(BakedRendererTest, ShellEmptyRunSkipsOnlyWhatContractsIntoTheCube) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), size(0.02f, 0.6f), far(1.05f, 12.0f);
  double covered = 0.0;
  int cases = 0;
  for (int i = 0; i < 300; ++i) {
    // A point in the shell on a ray from a camera inside the inner cube;
    // every fourth ray is turned back towards the centre instead (a camera
    // out in the shell): no skip is offered for those.
    Eigen::Vector3f x = Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized();
    x *= far(rng) / InfNorm(x);
    const Eigen::Vector3f camera = 0.9f * Eigen::Vector3f(u(rng), u(rng), u(rng));
    const bool inwards = i % 4 == 0;
    const Eigen::Vector3f d = ((inwards ? -1.0f : 1.0f) * (x - camera)).normalized();
    const Eigen::Vector3f c = Contract(x);
    Eigen::Vector3f lo, hi;
    for (int k = 0; k < 3; ++k) lo[k] = std::max(-2.0f, c[k] - size(rng)), hi[k] = std::min(2.0f, c[k] + size(rng));
    auto inside = [&](const Eigen::Vector3f& p, float tol) {
      const Eigen::Vector3f q = Contract(p);
      return (q.array() >= lo.array() - tol).all() && (q.array() <= hi.array() + tol).all();
    };
    // Where the contracted point really leaves the cube (or 1e4).
    float exact = 0.0f;
    while (exact < 1e4f && inside(x + exact * d, 0.0f)) exact += 1e-3f * std::max(1.0f, InfNorm(x + exact * d));
    const float run = std::min(ShellEmptyRun(x, d, lo, hi), 1e4f);
    if (inwards) {
      EXPECT_EQ(run, 0.0f) << i;
      continue;
    }
    ++cases;
    for (int j = 0; j <= 1000; ++j) {
      ASSERT_TRUE(inside(x + (run * float(j) / 1000.0f) * d, 1e-4f)) << i << " at " << j;
    }
    covered += std::min(1.0, double(run) / std::max(double(exact), 1e-9));
  }
  std::printf("ShellEmptyRun covers %.0f %% of the way out of the cube on average\n", 100.0 * covered / cases);
  EXPECT_GT(covered / cases, 0.5);
}

TEST(BakedRendererTest, TheFarShellIsReachedThroughTheContraction) {
  // Contracted grid: block (7, 3, 3) of 8^3 lies at contracted x in [1.5, 2),
  // model-space distance 2 to about 64 along +x.
  BakedAsset a = EmptyAsset(true, 2.0f, 64, 1);
  FillBlock(&a, 7, 3, 3, 0, Eigen::Vector3f(0, 1, 0), 255);
  ASSERT_TRUE(a.Validate().ok());
  const Eigen::Vector3f o(0.0f, -0.25f, -0.25f);
  const BakedRay hit = RenderBakedRay(a, o, Eigen::Vector3f(1, 0, 0));
  EXPECT_GT(hit.opacity, 0.99f);
  EXPECT_NEAR(hit.rgb[1], 1.0f, 0.01f);
  const float depth = hit.depth / hit.opacity;
  // Where contract(x) = 1.5: x = 2; the first sample lands within a step
  // (cell r^2 = 0.25 there) past it.
  EXPECT_GT(depth, 1.9f);
  EXPECT_LT(depth, 2.3f);
  const BakedRay miss = RenderBakedRay(a, o, Eigen::Vector3f(-1, 0, 0));
  EXPECT_FLOAT_EQ(miss.opacity, 0.0f);
}

TEST(BakedRendererTest, ViewsHonourTheNormalisation) {
  BakedAsset a = EmptyAsset(false, 1.0f, 32, 1);
  FillBlock(&a, 2, 2, 2, 0, Eigen::Vector3f(0, 0, 0), 255);
  a.normalization.center = Eigen::Vector3f(10, 0, 0);
  a.normalization.scale = 0.5f;  // World block: x in [10, 11].
  Camera cam;
  cam.intrinsics = {8, 8, 8, 8, 4, 4};
  cam.c2w = Pose::Identity();
  cam.c2w.col(3) = Eigen::Vector3f(10.5f, 0.5f, -6.0f);
  absl::StatusOr<RenderedView> v = RenderBakedView(a, cam);
  ASSERT_TRUE(v.ok()) << v.status();
  // The black block fills the middle of the image.
  EXPECT_LT(v->rgb.pixel(4, 4)[0], 0.05f);
  EXPECT_GT(v->rgb.pixel(0, 0)[0], 0.95f);
  EXPECT_GT(v->samples, 0);
  cam.c2w(0, 0) = std::nanf("");
  EXPECT_EQ(RenderBakedView(a, cam).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace clnerf
