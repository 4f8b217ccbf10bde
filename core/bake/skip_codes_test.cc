#include "core/bake/skip_codes.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "core/bake/baked_march.h"
#include "core/bake/baked_renderer.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// A grid of R^3 cells over [-B, B]^3 whose occupied blocks hold blobs of
// dense lattice points (random colours and codes, some faint) with empty
// points between them; each brick's copy of a shared face is filled on its
// own, so copies may differ, as the fits may leave them.
// scatter: the occupied blocks picked at random in a cube of blocks around
// the centre, with empty ones between them, rather than a connected walk.
BakedAsset BlobAsset(bool contracted, int resolution, int blocks, int blobs, uint32_t seed, bool scatter = false) {
  std::mt19937 rng(seed);
  BakedAsset a;
  a.contracted = contracted;
  a.half_size = contracted ? 2.0f : 1.0f;
  a.resolution = resolution;
  a.background = Eigen::Vector3f(1, 1, 1);
  const int nb = a.blocks_per_axis();
  a.index.assign(size_t(nb) * nb * nb, 0);
  // Occupied blocks: a random walk, so that neighbours share faces.
  std::vector<std::array<int, 3>> occupied;
  std::array<int, 3> b = {nb / 2, nb / 2, nb / 2};
  std::uniform_int_distribution<int> step(-1, 1);
  std::uniform_int_distribution<int> around(nb / 2 - 3, nb / 2 + 2);
  while (int(occupied.size()) < blocks) {
    const size_t i = size_t(b[0]) + size_t(nb) * (size_t(b[1]) + size_t(nb) * size_t(b[2]));
    if (a.index[i] == 0) {
      occupied.push_back(b);
      a.index[i] = uint32_t(occupied.size());
    }
    for (int k = 0; k < 3; ++k) {
      b[size_t(k)] = scatter ? around(rng) : std::clamp(b[size_t(k)] + step(rng), 0, nb - 1);
    }
  }
  a.bricks = {int(occupied.size()), 1, 1};
  const std::array<int, 3> t = a.atlas_texels();
  a.atlas.assign(4 * size_t(t[0]) * t[1] * t[2], 0);
  std::uniform_int_distribution<int> coord(0, kBakeBrick - 1), code(1, 255), colour(0, 255), radius(0, 2);
  for (size_t k = 0; k < occupied.size(); ++k) {
    for (int n = 0; n < blobs; ++n) {
      const int cx = coord(rng), cy = coord(rng), cz = coord(rng), r = radius(rng), c = code(rng);
      for (int z = std::max(0, cz - r); z <= std::min(kBakeBrick - 1, cz + r); ++z) {
        for (int y = std::max(0, cy - r); y <= std::min(kBakeBrick - 1, cy + r); ++y) {
          for (int x = std::max(0, cx - r); x <= std::min(kBakeBrick - 1, cx + r); ++x) {
            uint8_t* p = a.atlas.data() + 4 * BrickTexel(a, uint32_t(k), x, y, z);
            for (int ch = 0; ch < 3; ++ch) p[ch] = uint8_t(colour(rng) * c / 255);  // Premultiplied.
            p[3] = uint8_t(c);
          }
        }
      }
    }
  }
  ComputeBlockDistances(&a);
  return a;
}

// The asset with every empty point's red channel cleared (no codes).
BakedAsset WithoutCodes(BakedAsset a) {
  for (size_t i = 0; i < a.atlas.size(); i += 4) {
    if (a.atlas[i + 3] == 0) a.atlas[i] = 0;
  }
  return a;
}

// Every empty lattice point of an occupied brick holds its chessboard
// distance to the nearest dense point of any brick (at most 8) where that is
// 2 or more, and nothing else changes: brute force over all dense points.
TEST(SkipCodesTest, CodesAreTheChessboardDistanceToDensity) {
  for (uint32_t seed : {1u, 2u, 3u}) {
    BakedAsset a = BlobAsset(false, 64, 14, 3, seed);
    const BakedAsset before = a;
    WriteSkipCodes(&a);
    const int nb = a.blocks_per_axis();
    std::vector<std::array<int, 3>> dense;
    for (int i = 0; i < nb * nb * nb; ++i) {
      if (a.index[size_t(i)] == 0) continue;
      const int b[3] = {i % nb, (i / nb) % nb, i / (nb * nb)};
      for (int l = 0; l < kBrickLattice; ++l) {
        const int x = l % kBakeBrick, y = (l / kBakeBrick) % kBakeBrick, z = l / (kBakeBrick * kBakeBrick);
        if (before.atlas[4 * BrickTexel(a, a.index[size_t(i)] - 1, l) + 3] != 0) {
          dense.push_back({8 * b[0] + x, 8 * b[1] + y, 8 * b[2] + z});
        }
      }
    }
    int coded = 0, empty = 0;
    for (int i = 0; i < nb * nb * nb; ++i) {
      if (a.index[size_t(i)] == 0) continue;
      const int b[3] = {i % nb, (i / nb) % nb, i / (nb * nb)};
      for (int l = 0; l < kBrickLattice; ++l) {
        const size_t at = 4 * BrickTexel(a, a.index[size_t(i)] - 1, l);
        const int g[3] = {8 * b[0] + l % kBakeBrick, 8 * b[1] + (l / kBakeBrick) % kBakeBrick,
                          8 * b[2] + l / (kBakeBrick * kBakeBrick)};
        int dist = kSkipCodeCap;
        for (const auto& p : dense) {
          dist = std::min(dist, std::max({std::abs(p[0] - g[0]), std::abs(p[1] - g[1]), std::abs(p[2] - g[2])}));
        }
        const bool is_empty = before.atlas[at + 3] == 0;
        empty += is_empty;
        const int want = is_empty && dist >= 2 ? dist : before.atlas[at];
        coded += is_empty && dist >= 2;
        ASSERT_EQ(int(a.atlas[at]), want) << "seed " << seed << " block " << i << " point " << l;
        for (int c = 1; c < 4; ++c) ASSERT_EQ(a.atlas[at + size_t(c)], before.atlas[at + size_t(c)]);
      }
    }
    std::printf("seed %u: %zu dense points, %d of %d empty points coded\n", seed, dense.size(), coded, empty);
    EXPECT_GT(coded, empty / 4);
  }
}

// A jump is a multiple of the sample's steps, at least one such, passes
// only samples within the code's reach (v - 2 cells along any axis) and
// stops at the first beyond it.
TEST(SkipCodesTest, JumpsPassOnlySamplesWithinReach) {
  for (int k : {1, 2, 4, 8}) {
    for (float step_cells : {0.5f, 1.0f, 1.25f, 2.0f}) {
      for (float d_inf : {1.0f, 0.8f, 0.5774f}) {
        const float scale = 1.0f / (step_cells * d_inf);
        for (int r = 0; r <= 8 * 64; ++r) {
          const float red = float(r) / 64.0f / 255.0f, v = 255.0f * red;
          const int m = BakedCodeSteps(red, scale, k);
          ASSERT_EQ(m % k, 0);
          ASSERT_GE(m, k);
          // The last sample passed, m - k steps on, is within reach...
          if (m > k) ASSERT_LE(float(m - k) * step_cells * d_inf, v - 2.0f + 1e-4f) << k << " " << r;
          // ... and the one it lands on is the first beyond it.
          ASSERT_GT(float(m) * step_cells * d_inf, v - 2.0f - 1e-4f) << k << " " << r;
        }
      }
    }
  }
}

// Rays through blobs with gaps between them, camera outside an object or
// inside an unbounded scene's inner cube: the codes shorten the march and
// leave every pixel as it was (the same samples add to each ray; the
// tail's 2-, 4- and 8-step samples included).
// Scattered blocks: jumps pass the corners of empty blocks, whose skips
// keep to the tail's steps too.
TEST(SkipCodesTest, CodesChangeTheStepsNotThePixels) {
  for (int config = 0; config < 3; ++config) {
    const bool contracted = config == 1, scatter = config == 2;
    BakedAsset coded = BlobAsset(contracted, 128, scatter ? 90 : 60, scatter ? 3 : 1, 7, scatter);
    WriteSkipCodes(&coded);
    const BakedAsset plain = WithoutCodes(coded);
    std::mt19937 rng(11);
    std::normal_distribution<float> n(0.0f, 1.0f);
    long long steps_coded = 0, steps_plain = 0, samples_coded = 0, samples_plain = 0;
    int tail = 0;
    float worst = 0.0f;
    for (int i = 0; i < 4000; ++i) {
      Eigen::Vector3f d(n(rng), n(rng), n(rng));
      d.normalize();
      // Objects: from outside the box towards its centre region; unbounded:
      // from near the centre outwards (through the cube, then the shell).
      const Eigen::Vector3f target = 0.1f * Eigen::Vector3f(n(rng), n(rng), n(rng));
      const Eigen::Vector3f o = contracted ? target : Eigen::Vector3f(target - 3.0f * d);
      const BakedRay a = RenderBakedRay(coded, o, d), b = RenderBakedRay(plain, o, d);
      worst = std::max({worst, (a.rgb - b.rgb).cwiseAbs().maxCoeff(), std::abs(a.opacity - b.opacity)});
      steps_coded += a.steps;
      steps_plain += b.steps;
      samples_coded += a.samples;
      samples_plain += b.samples;
      tail += b.opacity > 0.7f;
    }
    std::printf(
        "%s: %lld steps (%lld samples with density) with codes, %lld (%lld) without; %d rays reach the tail; "
        "largest difference %.2g\n",
        contracted ? "unbounded" : scatter ? "scattered object" : "object", steps_coded, samples_coded, steps_plain, samples_plain, tail, worst);
    EXPECT_LT(worst, 1e-5f);
    EXPECT_EQ(samples_coded, samples_plain);  // The samples with density, composited.
    EXPECT_LT(double(steps_coded), 0.95 * double(steps_plain));
    EXPECT_GT(tail, 100);
  }
}

// Rays from haze deep enough for two-step samples (T < 0.5) towards a
// diagonal neighbour, past the corners of the two empty blocks beside
// both: a jump that passes through an empty block's corner lands where
// that block's skip would have (the skip keeps to the tail's steps), so
// the same samples of the far block add to every ray.
TEST(SkipCodesTest, AJumpPastAnEmptyBlocksCornerKeepsTheSamples) {
  BakedAsset a;
  a.resolution = 32;
  a.background = Eigen::Vector3f(1, 1, 1);
  a.bricks = {2, 1, 1};
  a.index.assign(4 * 4 * 4, 0);
  a.index[1 + 4 * (1 + 4 * 1)] = 1;  // A = (1, 1, 1): haze in its near half.
  a.index[2 + 4 * (2 + 4 * 1)] = 2;  // C = (2, 2, 1): dense in its far half.
  const std::array<int, 3> t = a.atlas_texels();
  a.atlas.assign(4 * size_t(t[0]) * t[1] * t[2], 0);
  for (int z = 0; z < kBakeBrick; ++z) {
    for (int y = 0; y < kBakeBrick; ++y) {
      for (int x = 0; x < kBakeBrick; ++x) {
        uint8_t* haze = a.atlas.data() + 4 * BrickTexel(a, 0, x, y, z);
        uint8_t* dense = a.atlas.data() + 4 * BrickTexel(a, 1, x, y, z);
        if (x + y <= 6) haze[0] = 80, haze[1] = 40, haze[2] = 120, haze[3] = 170;
        if (x + y >= 8) dense[0] = 150, dense[1] = 100, dense[2] = 20, dense[3] = 200;
      }
    }
  }
  ComputeBlockDistances(&a);
  BakedAsset coded = a;
  WriteSkipCodes(&coded);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  const float cell = a.cell();  // The grid spans [-1, 1]^3: cell c starts at -1 + c cell.
  int tail = 0;
  float worst = 0.0f;
  long long steps_coded = 0, steps_plain = 0;
  for (int i = 0; i < 20000; ++i) {
    // From A's haze (cells 8.5-11) along (1, 1, small z) give or take.
    const Eigen::Vector3f o(-1.0f + (8.5f + 2.5f * u01(rng)) * cell, -1.0f + (8.5f + 2.5f * u01(rng)) * cell,
                            -1.0f + (10.0f + 4.0f * u01(rng)) * cell);
    const Eigen::Vector3f d = Eigen::Vector3f(1.0f + 0.3f * (u01(rng) - 0.5f), 1.0f + 0.3f * (u01(rng) - 0.5f),
                                              0.1f * (u01(rng) - 0.5f)).normalized();
    const BakedRay x = RenderBakedRay(coded, o, d), y = RenderBakedRay(a, o, d);
    worst = std::max({worst, (x.rgb - y.rgb).cwiseAbs().maxCoeff(), std::abs(x.opacity - y.opacity)});
    tail += y.opacity > 0.7f;
    steps_coded += x.steps;
    steps_plain += y.steps;
  }
  std::printf("%d of 20000 rays reach the tail; %lld steps with codes, %lld without; largest difference %.2g\n", tail,
              steps_coded, steps_plain, worst);
  EXPECT_GT(tail, 1000);
  EXPECT_LT(steps_coded, steps_plain);
  EXPECT_LT(worst, 1e-5f);
}

}  // namespace
}  // namespace clnerf
