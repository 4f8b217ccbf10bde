// Tests of ray/box intersection and of marching through the occupancy grid.
#include "core/field/ray_marcher.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "Eigen/Dense"
#include "core/data/contraction.h"
#include "core/field/occupancy_test_util.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// Slab test in double, handling zero direction components explicitly.
bool ReferenceIntersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double s, double* t0, double* t1) {
  double lo = -std::numeric_limits<double>::infinity(), hi = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0) {
      if (o[a] < -s || o[a] > s) return false;
      continue;
    }
    double ta = (-s - o[a]) / d[a], tb = (s - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    lo = std::max(lo, ta);
    hi = std::min(hi, tb);
  }
  *t0 = lo;
  *t1 = hi;
  return hi > std::max(lo, 0.0);
}

TEST(IntersectBoxTest, KnownRays) {
  float t0, t1;
  // Axis-parallel along x, offset in y and z.
  ASSERT_TRUE(IntersectBox({-2.0f, 0.1f, 0.2f}, {1, 0, 0}, 0.5f, &t0, &t1));
  EXPECT_FLOAT_EQ(t0, 1.5f);
  EXPECT_FLOAT_EQ(t1, 2.5f);
  // Axis-parallel along -z.
  ASSERT_TRUE(IntersectBox({0.3f, -0.4f, 3.0f}, {0, 0, -1}, 0.5f, &t0, &t1));
  EXPECT_FLOAT_EQ(t0, 2.5f);
  EXPECT_FLOAT_EQ(t1, 3.5f);
  // Axis-parallel but outside the slab of another axis: miss.
  EXPECT_FALSE(IntersectBox({-2.0f, 0.7f, 0.0f}, {1, 0, 0}, 0.5f, &t0, &t1));
  EXPECT_FALSE(IntersectBox({0.0f, -0.6f, -2.0f}, {0, 0, 1}, 0.5f, &t0, &t1));
  // Grazing a face (o.y == bound, d.y == 0): the box is closed.
  EXPECT_TRUE(IntersectBox({-2.0f, 0.5f, 0.0f}, {1, 0, 0}, 0.5f, &t0, &t1));
  // Diagonal.
  const Eigen::Vector3f d = Eigen::Vector3f(1, 1, 1).normalized();
  ASSERT_TRUE(IntersectBox({-1, -1, -1}, d, 0.5f, &t0, &t1));
  EXPECT_NEAR(t0, 0.5f * std::sqrt(3.0f), 1e-6f);
  EXPECT_NEAR(t1, 1.5f * std::sqrt(3.0f), 1e-6f);
  // Origin inside: t0 < 0 < t1.
  ASSERT_TRUE(IntersectBox({0, 0, 0}, {0, 0, 1}, 0.5f, &t0, &t1));
  EXPECT_FLOAT_EQ(t0, -0.5f);
  EXPECT_FLOAT_EQ(t1, 0.5f);
  // Box behind the origin.
  EXPECT_FALSE(IntersectBox({2, 0, 0}, {1, 0, 0}, 0.5f, &t0, &t1));
  // Passing beside the box.
  EXPECT_FALSE(IntersectBox({-2, 0.9f, 0}, Eigen::Vector3f(1, 0.1f, 0).normalized(), 0.5f, &t0, &t1));
  // Larger box.
  ASSERT_TRUE(IntersectBox({0, 0, -10}, {0, 0, 1}, 4.0f, &t0, &t1));
  EXPECT_FLOAT_EQ(t0, 6.0f);
  EXPECT_FLOAT_EQ(t1, 14.0f);
}

TEST(IntersectBoxTest, MatchesReferenceOnRandomRays) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  int hits = 0, misses = 0;
  for (int i = 0; i < 5000; ++i) {
    Eigen::Vector3f o(1.2f * u(rng), 1.2f * u(rng), 1.2f * u(rng)), d(u(rng), u(rng), u(rng));
    // A third of the rays have one or two zero direction components.
    if (i % 3 == 1) d[rng() % 3] = 0;
    if (i % 6 == 2) {
      d[0] = 0;
      d[2] = 0;
    }
    if (d.norm() < 1e-3f) continue;
    d.normalize();
    float t0, t1;
    double r0 = 0, r1 = 0;
    const bool hit = IntersectBox(o, d, 0.5f, &t0, &t1);
    const bool ref = ReferenceIntersect(o.cast<double>(), d.cast<double>(), 0.5, &r0, &r1);
    if (ref && r1 - std::max(r0, 0.0) < 1e-4) continue;  // Numerically ambiguous grazing rays.
    ASSERT_EQ(hit, ref) << "o " << o.transpose() << " d " << d.transpose();
    if (hit) {
      ++hits;
      EXPECT_NEAR(t0, r0, 1e-5 * (1 + std::abs(r0)));
      EXPECT_NEAR(t1, r1, 1e-5 * (1 + std::abs(r1)));
      // The entry/exit points are on the box surface.
      EXPECT_NEAR((o + t1 * d).cwiseAbs().maxCoeff(), 0.5f, 1e-5f);
    } else {
      ++misses;
    }
  }
  EXPECT_GT(hits, 500);
  EXPECT_GT(misses, 500);
}

MarchOptions Opts(float steps_per_diagonal, float cone = 0.0f) {
  MarchOptions m;
  m.steps_per_diagonal = steps_per_diagonal;
  m.cone_angle = cone;
  m.max_samples = 100000;
  return m;
}

OccupancyGridOptions GridOptions(int res) {
  OccupancyGridOptions o;
  o.resolution = res;
  return o;
}

TEST(MarchRayTest, ConstantStepsThroughFullGrid) {
  const MarchOptions mo = Opts(256);
  const OccupancyGrid grid(GridOptions(16), 0.5f, mo.min_step());
  const Eigen::Vector3f o(-1.0f, 0.01f, 0.02f), d(1, 0, 0);
  float t0, t1;
  ASSERT_TRUE(IntersectBox(o, d, 0.5f, &t0, &t1));
  const float dt = mo.min_step();
  const float start = t0 + 0.37f * dt;
  std::vector<RaySample> s;
  const float end = MarchRay(grid, o, d, start, t1, mo, 0.5f, mo.max_samples, &s);
  // Every lattice point start + k dt < t1 is a sample.
  const int expected = int(std::ceil((t1 - start) / dt));
  ASSERT_NEAR(int(s.size()), expected, 1);
  for (size_t i = 0; i < s.size(); ++i) {
    EXPECT_EQ(s[i].dt, dt) << i;
    EXPECT_GE(s[i].t, start);
    EXPECT_LT(s[i].t, t1);
    EXPECT_NEAR(s[i].t, start + i * dt, 1e-4f) << i;
    if (i > 0) {
      EXPECT_GT(s[i].t, s[i - 1].t) << i;
    }
  }
  EXPECT_GE(end, t1);
  // max_count truncates, and resuming from the returned t continues the
  // same lattice.
  std::vector<RaySample> a;
  const float mid = MarchRay(grid, o, d, start, t1, mo, 0.5f, 50, &a);
  ASSERT_EQ(a.size(), 50u);
  EXPECT_NEAR(mid, a.back().t + dt, 1e-6f);
  MarchRay(grid, o, d, mid, t1, mo, 0.5f, mo.max_samples, &a);
  ASSERT_EQ(a.size(), s.size());
  for (size_t i = 0; i < s.size(); ++i) EXPECT_NEAR(a[i].t, s[i].t, 1e-5f) << i;
}

TEST(MarchRayTest, ConeStepsGrowWithDistance) {
  // Unbounded-style box with exponential steps dt = clamp(t * cone, min,
  // max); cone = 1/32 so that one ray sees all three regimes (min below
  // t = 0.054, max = 0.108 beyond t = 3.46).
  const MarchOptions mo = Opts(1024, 1.0f / 32);
  const float bound = 4.0f;
  const OccupancyGrid grid(GridOptions(16), bound, mo.min_step());
  const Eigen::Vector3f o(0.05f, -0.03f, 0.02f), d = Eigen::Vector3f(1, 0.2f, 0.1f).normalized();
  float t0, t1;
  ASSERT_TRUE(IntersectBox(o, d, bound, &t0, &t1));
  std::vector<RaySample> s;
  MarchRay(grid, o, d, 0.05f, t1, mo, bound, mo.max_samples, &s);
  ASSERT_GT(s.size(), 100u);
  const float min_step = mo.min_step(), max_step = mo.max_step(bound);
  bool saw_min = false, saw_cone = false, saw_max = false;
  for (size_t i = 0; i < s.size(); ++i) {
    EXPECT_FLOAT_EQ(s[i].dt, std::clamp(s[i].t / 32, min_step, max_step)) << i;
    if (i > 0) {
      EXPECT_NEAR(s[i].t, s[i - 1].t + s[i - 1].dt, 1e-5f) << i;
      EXPECT_GE(s[i].dt, s[i - 1].dt) << i;
    }
    saw_min |= s[i].dt == min_step;
    saw_max |= s[i].dt == max_step;
    saw_cone |= s[i].dt > min_step && s[i].dt < max_step;
  }
  EXPECT_TRUE(saw_min && saw_cone && saw_max);
  EXPECT_LT(s.back().t, t1);
}

// A grid where only cells with x index 3 and 11 on the row (y, z) = (8, 8)
// are occupied, built through the real update path (all cells listed, high
// density on the chosen ones, threshold = min(mean, max)).
OccupancyGrid SparseGrid(float min_step) {
  OccupancyGrid grid(GridOptions(16), 0.5f, min_step);
  SetEveryCell(&grid, [](uint32_t i) { return i == 3 + 16 * (8 + 16 * 8) || i == 11 + 16 * (8 + 16 * 8) ? 100.0f : 0.0f; });
  return grid;
}

TEST(MarchRayTest, SkipsEmptyCellsAndKeepsTheLattice) {
  const MarchOptions mo = Opts(256);
  const OccupancyGrid grid = SparseGrid(mo.min_step());
  ASSERT_EQ(grid.num_occupied(), 2u);
  const float dt = mo.min_step();
  // Rays along x through the occupied row (cell 8 spans [0, 0.0625) in y, z),
  // and a slanted one.
  for (const auto& [o, d] : {std::pair{Eigen::Vector3f(-0.9f, 0.01f, 0.03f), Eigen::Vector3f(1, 0, 0)},
                             std::pair{Eigen::Vector3f(-0.9f, 0.02f, 0.01f),
                                       Eigen::Vector3f(1, 0.02f, 0.04f).normalized()}}) {
    SCOPED_TRACE(testing::Message() << "d = " << d.transpose());
    float t0, t1;
    ASSERT_TRUE(IntersectBox(o, d, 0.5f, &t0, &t1));
    const float start = t0 + 0.25f * dt;
    std::vector<RaySample> s;
    MarchRay(grid, o, d, start, t1, mo, 0.5f, mo.max_samples, &s);
    // Expected: the lattice points start + k dt in occupied cells, except
    // those within 1e-4 of a cell face (rounding may go either way there).
    std::vector<float> expected;
    int ambiguous = 0;
    for (int k = 0;; ++k) {
      const float t = start + k * dt;
      if (t >= t1) break;
      const Eigen::Vector3f p = o + t * d;
      const Eigen::Vector3f u = (p.array() + 0.5f) * 16.0f;
      const float face = (u.array() - u.array().round()).abs().minCoeff() / 16.0f;
      if (face < 1e-4f) {
        ++ambiguous;
        continue;
      }
      if (grid.Occupied(p)) expected.push_back(t);
    }
    ASSERT_GE(expected.size(), 10u);
    size_t j = 0;
    for (const RaySample& r : s) {
      const Eigen::Vector3f p = o + r.t * d;
      EXPECT_TRUE(grid.Occupied(p)) << "sample in an empty cell at t = " << r.t;
      EXPECT_EQ(r.dt, dt);
      // On the lattice.
      const float k = (r.t - start) / dt;
      EXPECT_NEAR(k, std::round(k), 2e-3f) << "t = " << r.t;
      if (j < expected.size() && std::abs(r.t - expected[j]) < 1e-4f) ++j;
    }
    EXPECT_EQ(j, expected.size()) << "an occupied lattice point was skipped";
    EXPECT_LE(s.size(), expected.size() + ambiguous);
    // Both occupied cells are visited.
    bool first = false, second = false;
    for (const RaySample& r : s) {
      const float x = o.x() + r.t * d.x();
      first |= x < 0;
      second |= x > 0;
    }
    EXPECT_TRUE(first && second);
  }
  // A ray that only crosses empty cells produces nothing.
  std::vector<RaySample> none;
  const Eigen::Vector3f o(-0.9f, -0.3f, 0.2f), d(1, 0, 0);
  float t0, t1;
  ASSERT_TRUE(IntersectBox(o, d, 0.5f, &t0, &t1));
  const float end = MarchRay(grid, o, d, t0, t1, mo, 0.5f, mo.max_samples, &none);
  EXPECT_TRUE(none.empty());
  EXPECT_GE(end, t1);
}

// Marches o + t d from `start` and checks the samples against a march that
// visits every step: every occupied lattice point start + k dt is sampled
// (but those within 1e-4 of a cell face, where rounding may go either way),
// and no sample lies in an empty cell away from a face. Returns the number
// of occupied lattice points checked.
size_t CheckAgainstEveryStep(const OccupancyGrid& grid, const Eigen::Vector3f& o, const Eigen::Vector3f& d, float start,
                             float t1, const MarchOptions& mo, float bound) {
  std::vector<RaySample> s;
  MarchRay(grid, o, d, start, t1, mo, bound, mo.max_samples, &s);
  const float dt = mo.min_step();
  auto on_face = [&](const Eigen::Vector3f& p, int c) {
    const Eigen::Vector3f cu = (p.array() + grid.cascade_half_size(c)) / grid.CellSize(c);
    return (cu.array() - cu.array().round()).abs().minCoeff() * grid.CellSize(c) < 1e-4f;
  };
  size_t j = 0, visited = 0;
  for (int k = 0;; ++k) {
    const float t = start + k * dt;
    if (t >= t1) break;
    const Eigen::Vector3f p = o + t * d;
    const int c = grid.CascadeOf(p);
    if (c < 0 || !grid.Occupied(p) || on_face(p, c)) continue;
    while (j < s.size() && s[j].t < t - 1e-4f) ++j;
    EXPECT_LT(j, s.size()) << "the occupied lattice point t = " << t << " was skipped";
    if (j >= s.size()) return visited;
    EXPECT_NEAR(s[j].t, t, 1e-4f);
    ++visited;
  }
  for (const RaySample& x : s) {
    const Eigen::Vector3f p = o + x.t * d;
    const int c = grid.CascadeOf(p);
    EXPECT_GE(c, 0) << "sample outside the box at t = " << x.t;
    if (c >= 0 && !grid.Occupied(p)) EXPECT_TRUE(on_face(p, c)) << "sample in an empty cell at t = " << x.t;
  }
  return visited;
}

// Random rays through a sparse grid of three cascades (most 4^3 blocks
// empty, so whole blocks are skipped) sample what a march of every step
// would.
TEST(MarchRayTest, RandomRaysThroughASparseGridVisitEveryOccupiedLatticePoint) {
  const MarchOptions mo = Opts(512);
  OccupancyGrid grid(GridOptions(32), 2.0f, mo.min_step());
  ASSERT_EQ(grid.num_cascades(), 3);
  std::mt19937_64 rng(9);
  SetEveryCell(&grid, [&](uint32_t) { return rng() % 300 == 0 ? 1e4f : 0.0f; });
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  size_t visited = 0;
  for (int r = 0; r < 200; ++r) {
    SCOPED_TRACE(testing::Message() << "ray " << r);
    const Eigen::Vector3f o = 3.0f * Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized();
    const Eigen::Vector3f d = (Eigen::Vector3f(u(rng), u(rng), u(rng)) - o).normalized();
    float t0, t1;
    if (!IntersectBox(o, d, 2.0f, &t0, &t1)) continue;
    visited += CheckAgainstEveryStep(grid, o, d, std::max(t0, 0.0f) + 0.25f * mo.min_step(), t1, mo, 2.0f);
  }
  EXPECT_GT(visited, 200u);
}

// Contracted (unbounded) scenes: rays from inside the inner cube out to the
// far bound through a sparse contracted grid of occupied clusters, where the
// march crosses runs of empty blocks of the inner cube in one jump. It must
// still sample every occupied cell the ray stays in for at least 2.5 of its
// steps, and put no sample in an empty cell away from a face. The reference
// walks each ray in steps of 1/20 of the smallest step it takes.
TEST(MarchRayContractedTest, SamplesEveryOccupiedCellTheRayCrosses) {
  const MarchOptions mo = Opts(1024, 1.0f / 256);
  OccupancyGrid grid(GridOptions(64), kContractedBound, mo.min_step());
  grid.set_contracted(true);
  ASSERT_EQ(grid.num_cascades(), 3);
  std::mt19937_64 rng(21);
  std::vector<uint32_t> seeds;
  for (int k = 0; k < 60; ++k) seeds.push_back(uint32_t(rng() % grid.num_cells()));
  SetEveryCell(&grid, [&](uint32_t i) {
    const int per = 64 * 64 * 64;
    const Eigen::Vector3i p(int(i % 64), int(i / 64 % 64), int(i % per / 4096));
    for (uint32_t q : seeds) {
      const Eigen::Vector3i c(int(q % 64), int(q / 64 % 64), int(q % per / 4096));
      if (int(q) / per == int(i) / per && (p - c).cwiseAbs().maxCoeff() <= 1) return 1e4f;
    }
    return 0.0f;
  });
  auto cell_of = [&](const Eigen::Vector3f& x) {
    const Eigen::Vector3f q = Contract(x);
    const int c = grid.CascadeOf(q);
    return c < 0 ? -1 : int(grid.CellIndex(q, c));
  };
  auto on_face = [&](const Eigen::Vector3f& x) {
    const Eigen::Vector3f q = Contract(x);
    const int c = grid.CascadeOf(q);
    const Eigen::Vector3f cu = (q.array() + grid.cascade_half_size(c)) / grid.CellSize(c);
    return (cu.array() - cu.array().round()).abs().minCoeff() * grid.CellSize(c) < 1e-4f;
  };
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const float far = ContractedFarBound(mo);
  int crossed = 0;
  for (int r = 0; r < 300; ++r) {
    SCOPED_TRACE(testing::Message() << "ray " << r);
    const Eigen::Vector3f o = 0.9f * Eigen::Vector3f(u(rng), u(rng), u(rng));
    // Most rays aimed at a cluster (the grid is mostly empty).
    Eigen::Vector3f d = Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized();
    if (r % 4 != 0) {
      const Eigen::Vector3f target = Uncontract(grid.CellPosition(seeds[r % seeds.size()], Eigen::Vector3f::Zero()));
      if ((target - o).norm() > 1e-3f) d = (target - o).normalized();
    }
    float t0, t1;
    ASSERT_TRUE(IntersectBox(o, d, far, &t0, &t1));
    const float start = mo.near;
    std::vector<RaySample> s;
    MarchRayContracted(grid, o, d, start, t1, mo, mo.max_samples, &s);
    for (const RaySample& x : s) {
      const Eigen::Vector3f p = o + x.t * d;
      ASSERT_GE(cell_of(p), 0) << "sample outside the contracted cube at t = " << x.t;
      if (!grid.OccupiedCell(uint32_t(cell_of(p)))) EXPECT_TRUE(on_face(p)) << "sample in an empty cell at t = " << x.t;
    }
    // Runs of the reference walk in one occupied cell.
    float t = start;
    size_t j = 0;
    while (t < t1) {
      const int cell = cell_of(o + t * d);
      if (cell < 0) break;
      const float first = t;
      float longest_step = 0.0f;
      while (t < t1 && cell_of(o + t * d) == cell) {
        const float dt = ContractedStepAt(o + t * d, d, t, mo);
        longest_step = std::max(longest_step, dt);
        t += dt / 20.0f;
      }
      if (!grid.OccupiedCell(uint32_t(cell)) || t - first < 2.5f * longest_step) continue;
      ++crossed;
      while (j < s.size() && s[j].t < first) ++j;
      EXPECT_TRUE(j < s.size() && s[j].t < t) << "occupied cell " << cell << " crossed over t in [" << first << ", "
                                               << t << ") has no sample";
    }
  }
  EXPECT_GT(crossed, 100);
}

// A ray that enters the box where p + h rounds to the far face (lego_100's
// test view 100, from above): the empty cell it starts in must be left by
// the nearest face, not by the other axes' (it skipped 0.95 of its 1.0
// through the box, and with it the whole object, in a 128^3 grid).
TEST(MarchRayTest, ARayStartingOnTheFarFaceSkipsOnlyItsEmptyCell) {
  const MarchOptions mo = Opts(512);
  OccupancyGrid grid(GridOptions(128), 0.5f, mo.min_step());
  // Empty above y = 0.375: 4 blocks, 16 cells.
  SetEveryCell(&grid, [](uint32_t i) { return int(i / 128) % 128 < 112 ? 1e4f : 0.0f; });
  const Eigen::Vector3f o(-2.7762e-06f, 1.3333f, 0.166897f), d(0.0106744f, -0.999521f, 0.0290475f);
  float t0, t1;
  ASSERT_TRUE(IntersectBox(o, d, 0.5f, &t0, &t1));
  int on_face = 0;
  for (int k = -4; k <= 4; ++k) {
    const float start = t0 + float(k) * 3e-8f;
    if ((o + start * d).y() > 0.5f) continue;
    on_face += (o + start * d).y() + 0.5f == 1.0f;
    SCOPED_TRACE(testing::Message() << "start " << start);
    EXPECT_GT(CheckAgainstEveryStep(grid, o, d, start, t1, mo, 0.5f), 100u);
  }
  EXPECT_GT(on_face, 0) << "no start put p + h on the face: the case is not tested";
}

TEST(MarchRayTest, StopsOutsideTheBox) {
  const MarchOptions mo = Opts(64);
  const OccupancyGrid grid(GridOptions(8), 0.5f, mo.min_step());
  std::vector<RaySample> s;
  // t_end beyond the box: no sample lies outside it.
  MarchRay(grid, Eigen::Vector3f(-0.4f, 0, 0), Eigen::Vector3f(1, 0, 0), 0.0f, 100.0f, mo, 0.5f, 1000, &s);
  ASSERT_FALSE(s.empty());
  for (const RaySample& r : s) EXPECT_LE(-0.4f + r.t, 0.5f);
  EXPECT_GT(-0.4f + s.back().t, 0.5f - mo.min_step());
}

TEST(MarchRayTest, RaysStartingOnTheBoxFaceAreMarched) {
  // Marching from the entry distance t0 of IntersectBox: rounding can put
  // o + t0 d a hair outside the box; the ray must still be marched through
  // the (fully occupied) box: every lattice point up to t1 but the last.
  const MarchOptions mo = Opts(128);
  const OccupancyGrid grid(GridOptions(16), 0.5f, mo.min_step());
  std::mt19937_64 rng(5);
  std::normal_distribution<float> g(0.0f, 1.0f);
  int marched = 0;
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector3f o = 1.3f * Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector3f aim = (0.2f * Eigen::Vector3f(g(rng), g(rng), g(rng))).cwiseMax(-0.45f).cwiseMin(0.45f);
    const Eigen::Vector3f d = (aim - o).normalized();
    float t0, t1;
    if (!IntersectBox(o, d, 0.5f, &t0, &t1) || t1 - t0 < 4 * mo.min_step()) continue;
    std::vector<RaySample> s;
    MarchRay(grid, o, d, t0, t1, mo, 0.5f, mo.max_samples, &s);
    const int lattice = int(std::ceil((t1 - t0) / mo.min_step()));
    ASSERT_GE(int(s.size()), lattice - 1) << "o " << o.transpose() << " d " << d.transpose() << " t0 " << t0;
    for (const RaySample& r : s) ASSERT_LE((o + r.t * d).cwiseAbs().maxCoeff(), 0.5f);
    ++marched;
  }
  EXPECT_GT(marched, 1500);
}

TEST(MarchRayTest, RaysWhoseStepCannotMoveTEnd) {
  // A camera 3e30 units away (finite, so it passes pose validation): at
  // t ~ 3e30 adding a step of ~0.01 leaves t unchanged. The march must end
  // after one sample instead of repeating it (or spinning) up to the caps.
  const MarchOptions mo = Opts(64);
  const OccupancyGrid grid(GridOptions(8), 0.5f, mo.min_step());  // Fully occupied.
  const Eigen::Vector3f o(-3e30f, 0, 0), d(1, 0, 0);
  std::vector<RaySample> s;
  const float t = MarchRay(grid, o, d, 3e30f, 3e30f + 1e25f, mo, 0.5f, 1000, &s);
  EXPECT_LE(s.size(), 1u);
  EXPECT_EQ(t, 3e30f);
  MarchOptions cone = mo;
  cone.cone_angle = 1.0f / 256;
  s.clear();
  MarchRay(grid, o, d, 3e30f, 3e30f + 1e25f, cone, 0.5f, 1000, &s);
  EXPECT_LE(s.size(), 1u);
}

}  // namespace
}  // namespace clnerf
