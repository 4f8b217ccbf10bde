// Numerical-correctness tests of the multiresolution hash encoding: layout,
// forward (against a hand-written trilinear interpolation) and both backward
// passes (against central finite differences).
#include "core/field/hash_grid.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <set>
#include <vector>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

// levels 4, base 4, finest 32: growth b = 2, scales 3, 7, 15, 31 and
// resolutions 4, 8, 16, 32. With a 2^10 table, levels 0 and 1 are dense
// ((4+1)^3 = 125 -> 128 and 9^3 = 729 -> 736 entries) and levels 2 and 3 are
// hashed (17^3 = 4913 > 1024).
HashGridOptions SmallOptions() {
  HashGridOptions o;
  o.levels = 4;
  o.log2_table_size = 10;
  o.base_resolution = 4;
  o.finest_resolution = 32;
  return o;
}

// Parameters of order one (the default init is +-1e-4), so that the
// encoding's values and gradients are not dominated by rounding.
std::vector<float> RandomParams(const HashGrid& grid, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<float> p(grid.num_params());
  for (float& v : p) v = u(rng);
  return p;
}

std::vector<float> RandomPositions(int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<float> p(3 * size_t(n));
  for (float& v : p) v = u(rng);
  return p;
}

// Reference trilinear interpolation of level l at p, in double, using only
// the public layout (level_offset, level_scale) and Index().
void ManualLevel(const HashGrid& grid, const std::vector<float>& params, int l, const float* p, double out[2]) {
  const double scale = grid.level_scale(l);
  double frac[3];
  uint32_t base[3];
  for (int d = 0; d < 3; ++d) {
    const double x = double(p[d]) * scale + 0.5;
    base[d] = uint32_t(std::floor(x));
    frac[d] = x - std::floor(x);
  }
  out[0] = out[1] = 0;
  for (int k = 0; k < 8; ++k) {
    const int b[3] = {k & 1, (k >> 1) & 1, (k >> 2) & 1};
    double w = 1;
    for (int d = 0; d < 3; ++d) w *= b[d] ? frac[d] : 1 - frac[d];
    const uint32_t idx = grid.Index(l, base[0] + b[0], base[1] + b[1], base[2] + b[2]);
    EXPECT_LT(idx, grid.level_size(l));
    const float* e = params.data() + (grid.level_offset(l) + idx) * HashGrid::kFeatures;
    out[0] += w * e[0];
    out[1] += w * e[1];
  }
}

// L = sum_k c_k out_k, accumulated in double.
double Loss(const HashGrid& grid, const std::vector<float>& params, const std::vector<float>& pos,
            const std::vector<float>& c) {
  const int n = int(pos.size() / 3);
  std::vector<float> out(size_t(n) * grid.output_dim());
  grid.Encode(params.data(), pos.data(), n, out.data());
  double s = 0;
  for (size_t k = 0; k < out.size(); ++k) s += double(c[k]) * out[k];
  return s;
}

TEST(HashGridLayoutTest, SmallTableDenseThenHashed) {
  const HashGrid grid(SmallOptions());
  ASSERT_EQ(grid.num_levels(), 4);
  EXPECT_EQ(grid.output_dim(), 8);
  const uint32_t want_res[4] = {4, 8, 16, 32};
  const float want_scale[4] = {3, 7, 15, 31};
  const bool want_dense[4] = {true, true, false, false};
  const size_t want_size[4] = {128, 736, 1024, 1024};
  size_t offset = 0;
  for (int l = 0; l < 4; ++l) {
    SCOPED_TRACE(l);
    EXPECT_EQ(grid.level_resolution(l), want_res[l]);
    EXPECT_NEAR(grid.level_scale(l), want_scale[l], 1e-4f);
    EXPECT_EQ(grid.level_dense(l), want_dense[l]);
    EXPECT_EQ(grid.level_size(l), want_size[l]);
    EXPECT_EQ(grid.level_offset(l), offset);
    offset += want_size[l];
  }
  EXPECT_EQ(grid.num_params(), offset * HashGrid::kFeatures);
  EXPECT_EQ(grid.num_params(), size_t(2 * (128 + 736 + 1024 + 1024)));
}

TEST(HashGridLayoutTest, ResolutionFormulaReachesFinest) {
  struct Case {
    int levels, base, finest, log2_table;
  };
  for (const Case& c : {Case{16, 16, 1024, 19}, Case{16, 16, 2048, 19}, Case{8, 16, 512, 14},
                        Case{4, 16, 32, 10}, Case{1, 16, 16, 12}, Case{5, 2, 64, 12}}) {
    SCOPED_TRACE(testing::Message() << c.levels << " levels " << c.base << ".." << c.finest);
    HashGridOptions o;
    o.levels = c.levels;
    o.base_resolution = c.base;
    o.finest_resolution = c.finest;
    o.log2_table_size = c.log2_table;
    ASSERT_TRUE(o.Validate().ok());
    const HashGrid grid(o);
    const double b = c.levels > 1 ? std::pow(double(c.finest) / c.base, 1.0 / (c.levels - 1)) : 1.0;
    size_t total = 0;
    for (int l = 0; l < c.levels; ++l) {
      const double scale = c.base * std::pow(b, l) - 1.0;
      // Avoid ceil() flipping on a representation error at exact integers.
      const double rounded = std::round(scale);
      const uint32_t res = uint32_t(std::abs(scale - rounded) < 1e-6 ? rounded : std::ceil(scale)) + 1;
      EXPECT_EQ(grid.level_resolution(l), res) << "level " << l;
      EXPECT_NEAR(grid.level_scale(l), scale, 1e-4 * scale) << "level " << l;
      // Dense iff the (res + 1)^3 grid (rounded up to 8) fits the table.
      const size_t stride = res + 1;
      const size_t dense = (stride * stride * stride + 7) / 8 * 8;
      const size_t max_size = size_t(1) << c.log2_table;
      EXPECT_EQ(grid.level_dense(l), dense <= max_size) << "level " << l;
      EXPECT_EQ(grid.level_size(l), std::min(dense, max_size)) << "level " << l;
      if (l > 0) {
        EXPECT_GE(grid.level_resolution(l), grid.level_resolution(l - 1));
      }
      total += grid.level_size(l);
    }
    EXPECT_EQ(grid.level_resolution(c.levels - 1), uint32_t(c.finest));
    EXPECT_EQ(grid.num_params(), total * HashGrid::kFeatures);
  }
}

TEST(HashGridLayoutTest, IndicesStayInsideEachLevel) {
  const HashGrid grid(SmallOptions());
  for (int l = 0; l < grid.num_levels(); ++l) {
    // Corners of points on the box faces reach coordinate res (scale + 0.5
    // floors to res - 1, plus one).
    const uint32_t r = grid.level_resolution(l);
    for (uint32_t z = 0; z <= r; ++z) {
      for (uint32_t y = 0; y <= r; ++y) {
        for (uint32_t x = 0; x <= r; ++x) ASSERT_LT(grid.Index(l, x, y, z), grid.level_size(l)) << l;
      }
    }
  }
  // Dense levels are injective on the corners.
  for (int l = 0; l < 2; ++l) {
    std::set<uint32_t> seen;
    const uint32_t r = grid.level_resolution(l);
    for (uint32_t z = 0; z <= r; ++z) {
      for (uint32_t y = 0; y <= r; ++y) {
        for (uint32_t x = 0; x <= r; ++x) seen.insert(grid.Index(l, x, y, z));
      }
    }
    EXPECT_EQ(seen.size(), size_t(r + 1) * (r + 1) * (r + 1)) << l;
  }
}

TEST(HashGridEncodeTest, MatchesManualTrilinear) {
  const HashGrid grid(SmallOptions());
  const std::vector<float> params = RandomParams(grid, 1);
  // 71 = four blocks of the 16-wide vector path plus a 7-sample scalar tail.
  const int n = 71;
  std::vector<float> pos = RandomPositions(n, 2);
  // Include the box corners and faces (in both paths).
  for (int d = 0; d < 3; ++d) {
    pos[d] = 0.0f;
    pos[3 + d] = 1.0f;
    pos[3 * 65 + d] = 0.0f;
    pos[3 * 66 + d] = 1.0f;
  }
  std::vector<float> out(size_t(n) * grid.output_dim());
  grid.Encode(params.data(), pos.data(), n, out.data());
  for (int i = 0; i < n; ++i) {
    for (int l = 0; l < grid.num_levels(); ++l) {
      double ref[2];
      ManualLevel(grid, params, l, &pos[3 * i], ref);
      // Float vs double of an 8-term convex combination of O(1) values.
      EXPECT_NEAR(out[size_t(i) * 8 + 2 * l], ref[0], 2e-6) << "sample " << i << " level " << l;
      EXPECT_NEAR(out[size_t(i) * 8 + 2 * l + 1], ref[1], 2e-6) << "sample " << i << " level " << l;
    }
  }
}

TEST(HashGridEncodeTest, EqualsTableEntryAtGridVertex) {
  const HashGrid grid(SmallOptions());
  const std::vector<float> params = RandomParams(grid, 3);
  // Level l's vertex (i, j, k) sits at p = (v - 0.5) / scale_l; vertices of
  // different levels differ, so check each level at its own vertices.
  int checked = 0;
  for (int l = 0; l < grid.num_levels(); ++l) {
    const float scale = grid.level_scale(l);
    for (uint32_t v : {1u, 2u, 3u}) {
      const uint32_t vx = v, vy = v + 1 > grid.level_resolution(l) ? v : v + 1, vz = 1;
      // Choose p so that p * scale + 0.5 is exactly the integer vertex.
      const float p[3] = {(float(vx) - 0.5f) / scale, (float(vy) - 0.5f) / scale, (float(vz) - 0.5f) / scale};
      float q[3];
      for (int d = 0; d < 3; ++d) {
        q[d] = p[d] * scale + 0.5f;
      }
      // Skip if float rounding does not land exactly on the vertex.
      if (q[0] != float(vx) || q[1] != float(vy) || q[2] != float(vz)) continue;
      std::vector<float> out(grid.output_dim());
      grid.Encode(params.data(), p, 1, out.data());
      const float* e = params.data() + (grid.level_offset(l) + grid.Index(l, vx, vy, vz)) * 2;
      EXPECT_EQ(out[2 * l], e[0]) << "level " << l << " vertex " << v;
      EXPECT_EQ(out[2 * l + 1], e[1]) << "level " << l << " vertex " << v;
      ++checked;
    }
  }
  EXPECT_GE(checked, 6);
}

TEST(HashGridEncodeTest, ContinuousAcrossCellBoundaries) {
  const HashGrid grid(SmallOptions());
  const std::vector<float> params = RandomParams(grid, 4);
  // Sweep a line that crosses every cell boundary of every level. With
  // entries in [-1, 1], each output is Lipschitz in x with constant
  // <= scale * 2 <= 62, so a step of 1e-4 changes it by at most 6.2e-3;
  // a wrong corner index at a boundary would jump by O(1).
  const int n = 10001;
  std::vector<float> pos(3 * size_t(n));
  for (int i = 0; i < n; ++i) {
    pos[3 * i] = float(i) / (n - 1);
    pos[3 * i + 1] = 0.3137f;
    pos[3 * i + 2] = 0.7291f;
  }
  std::vector<float> out(size_t(n) * grid.output_dim());
  grid.Encode(params.data(), pos.data(), n, out.data());
  float max_jump = 0;
  for (int i = 1; i < n; ++i) {
    for (int k = 0; k < grid.output_dim(); ++k) {
      const float lip = 2.0f * grid.level_scale(k / 2) * (pos[3 * i] - pos[3 * (i - 1)]);
      const float jump = std::abs(out[size_t(i) * 8 + k] - out[size_t(i - 1) * 8 + k]);
      max_jump = std::max(max_jump, jump);
      ASSERT_LE(jump, lip + 1e-5f) << "x=" << pos[3 * i] << " output " << k;
    }
  }
  EXPECT_GT(max_jump, 1e-3f);  // The sweep does see the table vary.
}

TEST(HashGridBackwardTest, TableGradientMatchesFiniteDifferences) {
  const HashGrid grid(SmallOptions());
  std::vector<float> params = RandomParams(grid, 5);
  const int n = 24;
  const std::vector<float> pos = RandomPositions(n, 6);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<float> c(size_t(n) * grid.output_dim());
  for (float& v : c) v = u(rng);
  // Sample 0 has dL/dout = 0 at every level: its corners must not be touched
  // (unless another sample shares them).
  for (int k = 0; k < grid.output_dim(); ++k) c[k] = 0.0f;

  const size_t entries = grid.num_params() / HashGrid::kFeatures;
  std::vector<float> grad(grid.num_params(), 0.0f);
  std::vector<uint8_t> touched(entries, 0);
  std::vector<uint32_t> list;
  for (int l = 0; l < grid.num_levels(); ++l) {
    grid.BackwardLevel(l, pos.data(), c.data(), n, grad.data(), touched.data(), &list);
  }

  // L is linear in the parameters, so the central difference is exact up to
  // float rounding of the outputs: each perturbation changes at most ~8
  // outputs by ~1 ulp (6e-8) -> error <~ 8 * 6e-8 * |c| / (2h) ~ 2.4e-4 for
  // h = 1e-3; allow 1e-3 absolute plus 1e-3 relative.
  const float h = 1e-3f;
  int nonzero = 0;
  for (size_t i = 0; i < params.size(); ++i) {
    const float p0 = params[i];
    params[i] = p0 + h;
    const float hi = params[i];
    const double lp = Loss(grid, params, pos, c);
    params[i] = p0 - h;
    const float lo = params[i];
    const double lm = Loss(grid, params, pos, c);
    params[i] = p0;
    const double fd = (lp - lm) / (double(hi) - double(lo));
    if (grad[i] == 0.0f) {
      // An entry no sample reads cannot change the loss at all.
      ASSERT_EQ(fd, 0.0) << "param " << i;
    } else {
      ++nonzero;
      ASSERT_NEAR(grad[i], fd, 1e-3 + 1e-3 * std::abs(fd)) << "param " << i;
    }
  }
  EXPECT_GT(nonzero, 200);

  // The touched list holds exactly the entries with a nonzero gradient,
  // once each, and agrees with the flags.
  std::set<uint32_t> in_list(list.begin(), list.end());
  EXPECT_EQ(in_list.size(), list.size()) << "duplicates in touched list";
  for (size_t e = 0; e < entries; ++e) {
    const bool nz = grad[2 * e] != 0.0f || grad[2 * e + 1] != 0.0f;
    EXPECT_EQ(in_list.count(uint32_t(e)) == 1, nz) << "entry " << e;
    EXPECT_EQ(touched[e] == 1, nz) << "entry " << e;
  }
  // A second pass accumulates (doubles the gradient) without re-listing.
  std::vector<float> grad2 = grad;
  for (int l = 0; l < grid.num_levels(); ++l) {
    grid.BackwardLevel(l, pos.data(), c.data(), n, grad2.data(), touched.data(), &list);
  }
  EXPECT_EQ(list.size(), in_list.size());
  for (size_t i = 0; i < grad.size(); ++i) ASSERT_NEAR(grad2[i], 2 * grad[i], 1e-6f + 1e-6f * std::abs(grad[i]));
  // Without a touched array the gradient is the same.
  std::vector<float> grad3(grid.num_params(), 0.0f);
  for (int l = 0; l < grid.num_levels(); ++l) {
    grid.BackwardLevel(l, pos.data(), c.data(), n, grad3.data(), nullptr, nullptr);
  }
  EXPECT_EQ(grad3, grad);
}

TEST(HashGridBackwardTest, PositionGradientMatchesFiniteDifferences) {
  const HashGrid grid(SmallOptions());
  const std::vector<float> params = RandomParams(grid, 8);
  // Points whose fractional cell coordinate is in [0.1, 0.9] at every level,
  // so x +- h (h * 31 = 0.031 cells) stays in one cell, where the encoding is
  // linear in each coordinate and the central difference is exact up to
  // rounding (~8 outputs * 6e-8 / 2e-3 ~ 2.4e-4 on gradients of O(10)).
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<float> u(0.02f, 0.98f);
  std::vector<float> pos;
  while (pos.size() < 3 * 16) {
    float p[3] = {u(rng), u(rng), u(rng)};
    bool ok = true;
    for (int l = 0; l < grid.num_levels() && ok; ++l) {
      for (int d = 0; d < 3; ++d) {
        const float x = p[d] * grid.level_scale(l) + 0.5f;
        const float f = x - std::floor(x);
        if (f < 0.1f || f > 0.9f) ok = false;
      }
    }
    if (ok) pos.insert(pos.end(), p, p + 3);
  }
  const int n = int(pos.size() / 3);
  std::vector<float> c(size_t(n) * grid.output_dim());
  std::uniform_real_distribution<float> uc(-1.0f, 1.0f);
  for (float& v : c) v = uc(rng);
  std::vector<float> dpos(3 * size_t(n));
  grid.BackwardPosition(params.data(), pos.data(), c.data(), n, dpos.data());

  const float h = 1e-3f;
  float max_abs = 0;
  for (int i = 0; i < n; ++i) {
    for (int d = 0; d < 3; ++d) {
      // Perturb one coordinate of one sample; the loss of the others is
      // unchanged, so evaluate sample i alone.
      std::vector<float> one(pos.begin() + 3 * i, pos.begin() + 3 * i + 3);
      const std::vector<float> ci(c.begin() + size_t(i) * 8, c.begin() + size_t(i + 1) * 8);
      const float p0 = one[d];
      one[d] = p0 + h;
      const float hi = one[d];
      const double lp = Loss(grid, params, one, ci);
      one[d] = p0 - h;
      const float lo = one[d];
      const double lm = Loss(grid, params, one, ci);
      const double fd = (lp - lm) / (double(hi) - double(lo));
      EXPECT_NEAR(dpos[3 * i + d], fd, 1e-3 + 1e-3 * std::abs(fd)) << "sample " << i << " axis " << d;
      max_abs = std::max(max_abs, std::abs(dpos[3 * i + d]));
    }
  }
  EXPECT_GT(max_abs, 1.0f);
}

}  // namespace
}  // namespace clnerf
