// Tests of the multi-cascade occupancy grid: cascade layout and selection,
// cell indexing, the EMA update and threshold, and the visibility mask.
#include "core/field/occupancy_grid.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "Eigen/Dense"
#include "core/field/occupancy_test_util.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

OccupancyGridOptions Options(int res, float decay = 0.95f, float threshold = 0.0f) {
  OccupancyGridOptions o;
  o.resolution = res;
  o.decay = decay;
  o.density_threshold = threshold;
  return o;
}

TEST(OccupancyGridTest, CascadeCount) {
  const float min_step = std::sqrt(3.0f) / 1024;
  EXPECT_EQ(OccupancyGrid(Options(8), 0.5f, min_step).num_cascades(), 1);
  EXPECT_EQ(OccupancyGrid(Options(8), 1.0f, min_step).num_cascades(), 2);
  EXPECT_EQ(OccupancyGrid(Options(8), 4.0f, min_step).num_cascades(), 4);
  EXPECT_EQ(OccupancyGrid(Options(8), 8.0f, min_step).num_cascades(), 5);
  EXPECT_EQ(OccupancyGrid(Options(8), 0.25f, min_step).num_cascades(), 1);
  const OccupancyGrid g4(Options(8), 4.0f, min_step);
  EXPECT_EQ(g4.cascade_half_size(0), 0.5f);
  EXPECT_EQ(g4.cascade_half_size(1), 1.0f);
  EXPECT_EQ(g4.cascade_half_size(2), 2.0f);
  EXPECT_EQ(g4.cascade_half_size(3), 4.0f);
  EXPECT_EQ(g4.num_cells(), size_t(4) * 512);
  // A box that is not a power of two: the last cascade is clipped to it.
  const OccupancyGrid g3(Options(8), 3.0f, min_step);
  EXPECT_EQ(g3.num_cascades(), 4);
  EXPECT_EQ(g3.cascade_half_size(3), 3.0f);
  const OccupancyGrid g05(Options(16), 0.5f, min_step);
  EXPECT_EQ(g05.cascade_half_size(0), 0.5f);
  EXPECT_FLOAT_EQ(g05.CellSize(0), 1.0f / 16);
}

TEST(OccupancyGridTest, CascadeSelection) {
  const float min_step = 0.01f;
  const OccupancyGrid g05(Options(8), 0.5f, min_step);
  EXPECT_EQ(g05.CascadeOf({0.0f, 0.0f, 0.0f}), 0);
  EXPECT_EQ(g05.CascadeOf({0.49f, -0.3f, 0.1f}), 0);
  EXPECT_EQ(g05.CascadeOf({0.5f, 0.5f, -0.5f}), 0);  // Box faces are inside.
  EXPECT_EQ(g05.CascadeOf({0.51f, 0.0f, 0.0f}), -1);
  EXPECT_EQ(g05.CascadeOf({0.0f, 0.0f, -0.6f}), -1);
  EXPECT_EQ(g05.CascadeOf({NAN, 0.0f, 0.0f}), -1);

  const OccupancyGrid g4(Options(8), 4.0f, min_step);
  EXPECT_EQ(g4.CascadeOf({0.1f, 0.2f, -0.3f}), 0);
  EXPECT_EQ(g4.CascadeOf({0.7f, 0.0f, 0.0f}), 1);
  EXPECT_EQ(g4.CascadeOf({0.0f, -1.5f, 0.2f}), 2);
  EXPECT_EQ(g4.CascadeOf({3.9f, 0.0f, 0.0f}), 3);
  EXPECT_EQ(g4.CascadeOf({4.0f, 4.0f, 4.0f}), 3);
  EXPECT_EQ(g4.CascadeOf({0.0f, 0.0f, 4.1f}), -1);
  // Random points: the chosen cascade is the finest that contains p.
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(-4.0f, 4.0f);
  for (int i = 0; i < 2000; ++i) {
    const float scale = std::ldexp(1.0f, -int(rng() % 4));  // Cover every cascade.
    const Eigen::Vector3f p(u(rng) * scale, u(rng) * scale, u(rng) * scale);
    const int c = g4.CascadeOf(p);
    ASSERT_GE(c, 0);
    const float m = p.cwiseAbs().maxCoeff();
    ASSERT_LE(m, g4.cascade_half_size(c)) << p.transpose();
    if (c > 0) {
      ASSERT_GE(m, g4.cascade_half_size(c - 1)) << p.transpose();
    }
  }
}

TEST(OccupancyGridTest, CellIndexPositionRoundTrip) {
  const OccupancyGrid g(Options(8), 4.0f, 0.01f);
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<float> u(-0.49f, 0.49f);
  for (uint32_t cell = 0; cell < g.num_cells(); ++cell) {
    const int c = int(cell / g.cells_per_cascade());
    const Eigen::Vector3f centre = g.CellPosition(cell, Eigen::Vector3f::Zero());
    ASSERT_EQ(g.CellIndex(centre, c), cell);
    ASSERT_LE(centre.cwiseAbs().maxCoeff(), g.cascade_half_size(c));
    const Eigen::Vector3f jitter(u(rng), u(rng), u(rng));
    const Eigen::Vector3f p = g.CellPosition(cell, jitter);
    ASSERT_EQ(g.CellIndex(p, c), cell) << "jittered " << jitter.transpose();
    // The centre is where the cell's box says it is.
    ASSERT_NEAR((p - centre).cwiseAbs().maxCoeff(), (jitter * g.CellSize(c)).cwiseAbs().maxCoeff(), 1e-5f);
  }
  // Linear layout: x fastest, then y, then z, cascades concatenated.
  const float cs = g.CellSize(0), h = g.cascade_half_size(0);
  const Eigen::Vector3f p(-h + 2.5f * cs, -h + 5.5f * cs, -h + 1.5f * cs);
  EXPECT_EQ(g.CellIndex(p, 0), uint32_t(2 + 8 * (5 + 8 * 1)));
  EXPECT_EQ(g.CellIndex(p * 2, 1), uint32_t(512 + 2 + 8 * (5 + 8 * 1)));
  // Points on the far face are clamped into the last cell.
  EXPECT_EQ(g.CellIndex(Eigen::Vector3f(h, h, h), 0), uint32_t(7 + 8 * (7 + 8 * 7)));
}

// A block reads occupied exactly when one of its 4^3 cells is, in every
// cascade, after updates and after a restore; a box that is not a power of
// two has no blocks in its outer cascade (they would straddle the inner one).
TEST(OccupancyGridTest, BlocksMarkWhetherAnyOfTheirCellsIsOccupied) {
  for (float bound : {2.0f, 1.5f}) {
    SCOPED_TRACE(testing::Message() << "bound " << bound);
    OccupancyGrid g(Options(32), bound, 0.01f);
    std::mt19937_64 rng(5);
    SetEveryCell(&g, [&](uint32_t) { return rng() % 400 == 0 ? 1e4f : 0.0f; });
    ASSERT_GT(g.num_occupied(), 50u);
    OccupancyGrid restored(Options(32), bound, 0.01f);
    restored.Restore(g.density(), g.visible(), g.bits(), g.threshold());
    int empty_blocks = 0;
    for (int c = 0; c < g.num_cascades(); ++c) {
      const bool has_blocks = bound == 2.0f || c < g.num_cascades() - 1;
      for (int bz = 0; bz < 8; ++bz)
        for (int by = 0; by < 8; ++by)
          for (int bx = 0; bx < 8; ++bx) {
            bool any = false;
            for (int k = 0; k < 64; ++k) {
              const int x = 4 * bx + k % 4, y = 4 * by + (k / 4) % 4, z = 4 * bz + k / 16;
              any |= g.OccupiedCell(uint32_t(c * g.cells_per_cascade() + x + 32 * (y + 32 * z)));
            }
            const float h = g.cascade_half_size(c), cs = g.CellSize(c);
            const Eigen::Vector3f p(-h + (4 * bx + 1.7f) * cs, -h + (4 * by + 2.2f) * cs, -h + (4 * bz + 0.4f) * cs);
            ASSERT_EQ(g.OccupiedBlockAt(p, c), any || !has_blocks) << c << " " << bx << " " << by << " " << bz;
            ASSERT_EQ(restored.OccupiedBlockAt(p, c), any || !has_blocks);
            empty_blocks += !any;
          }
    }
    EXPECT_GT(empty_blocks, 100);
  }
}

// The empty box around each block is the cube of the block's chessboard
// distance D to the nearest block with an occupied cell or inside the finer
// cascade's cube (brute force here), clipped to the grid: (2D - 1) blocks a
// side, every cell in it empty, none of it in the finer cascade. Occupied
// clusters leave runs of empty blocks several blocks long to measure.
TEST(OccupancyGridTest, EmptyBoxesAreTheChessboardDistanceToTheNearestStop) {
  for (float bound : {2.0f, 1.5f}) {
    SCOPED_TRACE(testing::Message() << "bound " << bound);
    OccupancyGrid g(Options(64), bound, 0.01f);
    std::mt19937_64 rng(11);
    std::vector<Eigen::Vector3i> seeds;
    for (int k = 0; k < 6; ++k) seeds.push_back(Eigen::Vector3i(rng() % 64, rng() % 64, rng() % 64));
    SetEveryCell(&g, [&](uint32_t i) {
      const Eigen::Vector3i p(int(i % 64), int(i / 64 % 64), int(i / 4096 % 64));
      for (const Eigen::Vector3i& q : seeds) {
        if ((p - q).cwiseAbs().maxCoeff() <= 2) return 1e4f;
      }
      return 0.0f;
    });
    const int nb = 16;
    int boxes = 0, largest = 0;
    for (int c = 0; c < g.num_cascades(); ++c) {
      const bool has_blocks = bound == 2.0f || c < g.num_cascades() - 1;
      const float h = g.cascade_half_size(c), bs = g.BlockSize(c);
      // Blocks inside the finer cascade's cube: [inner, nb - inner) per axis.
      const int inner = c == 0 ? nb : int(std::lround((h - g.cascade_half_size(c - 1)) / bs));
      std::vector<Eigen::Vector3i> stops;
      for (int z = 0; z < nb; ++z)
        for (int y = 0; y < nb; ++y)
          for (int x = 0; x < nb; ++x) {
            const Eigen::Vector3f centre((x + 0.5f) * bs - h, (y + 0.5f) * bs - h, (z + 0.5f) * bs - h);
            const bool finer = x >= inner && x < nb - inner && y >= inner && y < nb - inner && z >= inner && z < nb - inner;
            if (finer || g.OccupiedBlockAt(centre, c)) stops.push_back(Eigen::Vector3i(x, y, z));
          }
      for (int z = 0; z < nb; ++z)
        for (int y = 0; y < nb; ++y)
          for (int x = 0; x < nb; ++x) {
            int dist = 255;
            for (const Eigen::Vector3i& q : stops) {
              dist = std::min(dist, (q - Eigen::Vector3i(x, y, z)).cwiseAbs().maxCoeff());
            }
            const Eigen::Vector3f p((x + 0.3f) * bs - h, (y + 0.6f) * bs - h, (z + 0.9f) * bs - h);
            Eigen::Vector3f lo, hi;
            const bool box = g.EmptyBoxAround(p, c, &lo, &hi);
            ASSERT_EQ(box, has_blocks && dist > 0) << c << " " << x << " " << y << " " << z;
            if (!box) continue;
            const int r = dist - 1;
            const Eigen::Vector3i b(x, y, z);
            for (int a = 0; a < 3; ++a) {
              ASSERT_NEAR(lo[a], std::max(b[a] - r, 0) * bs - h, 1e-5f);
              ASSERT_NEAR(hi[a], (std::min(b[a] + r, nb - 1) + 1) * bs - h, 1e-5f);
            }
            ++boxes;
            largest = std::max(largest, r);
          }
    }
    EXPECT_GT(boxes, 1000);
    EXPECT_GE(largest, 3);
  }
}

TEST(OccupancyGridTest, FreshGridIsFullyOccupiedWithDerivedThreshold) {
  const OccupancyGrid g(Options(8), 0.5f, 0.02f);
  EXPECT_EQ(g.num_occupied(), g.num_cells());
  EXPECT_EQ(g.num_visible(), g.num_cells());
  EXPECT_FLOAT_EQ(g.threshold(), 0.01f / 0.02f);  // density_threshold <= 0: 0.01 / min_step.
  const OccupancyGrid g2(Options(8, 0.95f, 3.0f), 0.5f, 0.02f);
  EXPECT_FLOAT_EQ(g2.threshold(), 3.0f);
}

TEST(OccupancyGridTest, ApplyUpdateEmaAndThreshold) {
  // 512 cells, decay 0.5, max threshold 100 (so threshold = mean here).
  OccupancyGrid g(Options(8, 0.5f, 100.0f), 0.5f, 0.01f);
  const uint32_t a = 10, b = 200, c = 300;
  g.ApplyUpdate({a, b}, {10.0f, 8.0f});
  EXPECT_EQ(g.density()[a], 10.0f);
  EXPECT_EQ(g.density()[b], 8.0f);
  EXPECT_EQ(g.density()[c], 0.0f);
  EXPECT_FLOAT_EQ(g.threshold(), 18.0f / 512);  // min(mean, 100).
  EXPECT_EQ(g.num_occupied(), 2u);
  EXPECT_TRUE(g.OccupiedCell(a));
  EXPECT_TRUE(g.OccupiedCell(b));
  EXPECT_FALSE(g.OccupiedCell(c));

  // a: max(0.5 * 10, 1) = 5 (decayed). b listed twice with 1 and 2: the new
  // value is max(1, 2) and the cell decays once: max(0.5 * 8, 2) = 4 (decaying
  // per listing would give max(0.5 * max(4, 1), 2) = 2). c: max(0, 3) = 3.
  // Cells that are not listed keep their value.
  g.ApplyUpdate({a, b, c, b}, {1.0f, 1.0f, 3.0f, 2.0f});
  EXPECT_EQ(g.density()[a], 5.0f);
  EXPECT_EQ(g.density()[b], 4.0f);
  EXPECT_EQ(g.density()[c], 3.0f);
  g.ApplyUpdate({c}, {0.0f});
  EXPECT_EQ(g.density()[a], 5.0f);  // Not listed: no decay.
  EXPECT_EQ(g.density()[c], 1.5f);
  const float mean = (5.0f + 4.0f + 1.5f) / 512;
  EXPECT_FLOAT_EQ(g.threshold(), mean);
  EXPECT_EQ(g.num_occupied(), 3u);

  // A cell exactly at the threshold is empty (strictly greater is occupied).
  OccupancyGrid g2(Options(8, 0.5f, 2.0f), 0.5f, 0.01f);
  std::vector<uint32_t> all(512);
  for (uint32_t i = 0; i < 512; ++i) all[i] = i;
  std::vector<float> sigma(512, 2.0f);
  sigma[7] = 50.0f;
  g2.ApplyUpdate(all, sigma);
  // mean = (511 * 2 + 50) / 512 > 2, so the threshold is the maximum, 2.
  EXPECT_FLOAT_EQ(g2.threshold(), 2.0f);
  EXPECT_EQ(g2.num_occupied(), 1u);
  EXPECT_TRUE(g2.OccupiedCell(7));
}

TEST(OccupancyGridTest, CellsToUpdate) {
  OccupancyGridOptions o = Options(8);
  o.warmup_iterations = 10;
  const OccupancyGrid g(o, 0.5f, 0.01f);
  std::mt19937_64 rng(3);
  const std::vector<uint32_t> warm = g.CellsToUpdate(0, &rng);
  ASSERT_EQ(warm.size(), g.num_cells());
  for (uint32_t i = 0; i < warm.size(); ++i) EXPECT_EQ(warm[i], i);
  const std::vector<uint32_t> later = g.CellsToUpdate(10, &rng);
  EXPECT_EQ(later.size(), 2 * (g.num_cells() / 4));  // All visible and occupied.
  for (uint32_t c : later) EXPECT_LT(c, g.num_cells());
}

Camera MakeCamera(const Eigen::Vector3f& position, float focal, int size) {
  Camera cam;
  cam.intrinsics.width = cam.intrinsics.height = size;
  cam.intrinsics.fx = cam.intrinsics.fy = focal;
  cam.intrinsics.cx = cam.intrinsics.cy = size / 2.0f;
  cam.c2w = Pose::Identity();  // OpenCV: looks along +z.
  cam.c2w.col(3) = position;
  return cam;
}

TEST(OccupancyGridTest, MarkInvisibleBehindCamera) {
  // A wide camera (half-angle ~63 degrees) at the centre looking along +z:
  // everything with z <= near behind it is never seen.
  OccupancyGrid g(Options(16), 0.5f, 0.01f);
  const float near = 0.05f;
  g.MarkInvisible({MakeCamera(Eigen::Vector3f::Zero(), 4.0f, 16)}, near);
  int behind = 0, in_view = 0;
  for (uint32_t cell = 0; cell < g.num_cells(); ++cell) {
    const Eigen::Vector3f p = g.CellPosition(cell, Eigen::Vector3f::Zero());
    if (p.z() <= near) {
      ++behind;
      ASSERT_EQ(g.visible()[cell], 0) << p.transpose();
      ASSERT_FALSE(g.OccupiedCell(cell)) << p.transpose();
    } else if (std::abs(p.x()) < p.z() && std::abs(p.y()) < p.z()) {
      // Well inside the 2 * atan(2) field of view.
      ++in_view;
      ASSERT_EQ(g.visible()[cell], 1) << p.transpose();
      ASSERT_TRUE(g.OccupiedCell(cell)) << p.transpose();
    }
  }
  EXPECT_EQ(behind, 16 * 16 * 9);  // Centre z in {-0.47, ..., -0.03, 0.03}.
  EXPECT_GT(in_view, 100);
  EXPECT_EQ(g.num_occupied(), g.num_visible());
  EXPECT_LT(g.num_visible(), g.num_cells() / 2);

  // Invisible cells stay empty whatever density they are given.
  std::vector<uint32_t> all(g.num_cells());
  for (uint32_t i = 0; i < all.size(); ++i) all[i] = i;
  g.ApplyUpdate(all, std::vector<float>(all.size(), 1e3f));
  const uint32_t back = g.CellIndex(Eigen::Vector3f(0.0f, 0.0f, -0.3f), 0);
  EXPECT_FALSE(g.OccupiedCell(back));
  EXPECT_TRUE(g.Occupied(Eigen::Vector3f(0.0f, 0.0f, 0.3f)));
}

TEST(OccupancyGridTest, MarkInvisibleOutsideNarrowFrustum) {
  // A narrow camera at z = -1.3 looking at the origin (half-angle
  // atan(8 / 100) ~ 4.6 degrees): the axis is seen, the box corners are not.
  OccupancyGrid g(Options(16), 0.5f, 0.01f);
  g.MarkInvisible({MakeCamera(Eigen::Vector3f(0, 0, -1.3f), 100.0f, 16)}, 0.05f);
  EXPECT_TRUE(g.Occupied(Eigen::Vector3f(0.01f, 0.01f, 0.0f)));
  EXPECT_TRUE(g.Occupied(Eigen::Vector3f(0.01f, -0.01f, 0.45f)));
  EXPECT_FALSE(g.Occupied(Eigen::Vector3f(0.45f, 0.45f, 0.0f)));
  EXPECT_FALSE(g.Occupied(Eigen::Vector3f(-0.4f, 0.0f, -0.45f)));
  EXPECT_LT(g.num_visible(), g.num_cells() / 4);
  EXPECT_GT(g.num_visible(), 16u);
  // With no cameras nothing changes.
  OccupancyGrid g2(Options(8), 0.5f, 0.01f);
  g2.MarkInvisible({}, 0.05f);
  EXPECT_EQ(g2.num_visible(), g2.num_cells());
}

}  // namespace
}  // namespace clnerf
