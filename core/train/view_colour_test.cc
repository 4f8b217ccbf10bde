#include "core/train/view_colour.h"

#include <random>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(ViewColourTest, IdentityLeavesColoursAlone) {
  const std::vector<float> p = IdentityViewColours(2);
  ASSERT_EQ(p.size(), 2u * kViewColourParams);
  const float c[3] = {0.1f, 0.5f, 0.9f};
  float out[3];
  ApplyViewColour(&p[kViewColourParams], c, out);
  for (int k = 0; k < 3; ++k) EXPECT_EQ(out[k], c[k]);
  std::vector<float> g(p.size(), 0.0f);
  EXPECT_EQ(ViewColourPrior(p, 1.0f, g.data()), 0.0f);
  for (float v : g) EXPECT_EQ(v, 0.0f);
}

TEST(ViewColourTest, AppliesMatrixThenBias) {
  std::vector<float> p = IdentityViewColours(1);
  p[0] = 2.0f;   // r' = 2 r + 0.5 g + 0.1
  p[1] = 0.5f;
  p[9] = 0.1f;
  p[11] = -0.2f;  // b' = b - 0.2
  const float c[3] = {0.25f, 0.5f, 0.75f};
  float out[3];
  ApplyViewColour(p.data(), c, out);
  EXPECT_FLOAT_EQ(out[0], 0.85f);
  EXPECT_FLOAT_EQ(out[1], 0.5f);
  EXPECT_FLOAT_EQ(out[2], 0.55f);
}

// Backward against central differences of L = w . (M c + b).
TEST(ViewColourTest, BackwardMatchesFiniteDifferences) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<float> p = IdentityViewColours(1);
  for (float& v : p) v += 0.3f * float(u(rng));
  float c[3], w[3];
  for (int k = 0; k < 3; ++k) {
    c[k] = float(0.5 + 0.4 * u(rng));
    w[k] = float(u(rng));
  }
  auto loss = [&](const std::vector<float>& q, const float* cc) {
    float out[3];
    ApplyViewColour(q.data(), cc, out);
    return double(w[0]) * out[0] + double(w[1]) * out[1] + double(w[2]) * out[2];
  };
  float dc[3];
  std::vector<float> dp(kViewColourParams, 0.0f);
  ViewColourBackward(p.data(), c, w, dc, dp.data());
  const float h = 1e-2f;  // L is linear in each input: FD is exact up to rounding.
  for (int i = 0; i < kViewColourParams; ++i) {
    std::vector<float> a = p, b = p;
    a[i] += h;
    b[i] -= h;
    EXPECT_NEAR(dp[i], (loss(a, c) - loss(b, c)) / (double(a[i]) - b[i]), 1e-4) << i;
  }
  for (int k = 0; k < 3; ++k) {
    float ca[3] = {c[0], c[1], c[2]}, cb[3] = {c[0], c[1], c[2]};
    ca[k] += h;
    cb[k] -= h;
    EXPECT_NEAR(dc[k], (loss(p, ca) - loss(p, cb)) / (double(ca[k]) - cb[k]), 1e-4) << k;
  }
}

// The prior is weight / V * sum ||p - I||^2, checked against central
// differences, and it does not depend on the number of views for the same
// per-view deviation.
TEST(ViewColourTest, PriorGradientMatchesFiniteDifferencesAndScalesWithViews) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> u(-0.2f, 0.2f);
  std::vector<float> p = IdentityViewColours(3);
  for (float& v : p) v += u(rng);
  std::vector<float> g(p.size(), 0.0f), tmp(p.size());
  const float w = 0.5f;
  ViewColourPrior(p, w, g.data());
  for (size_t i = 0; i < p.size(); ++i) {
    std::vector<float> a = p, b = p;
    a[i] += 1e-3f;
    b[i] -= 1e-3f;
    const double fd = (double(ViewColourPrior(a, w, tmp.data())) - ViewColourPrior(b, w, tmp.data())) /
                      (double(a[i]) - b[i]);
    EXPECT_NEAR(g[i], fd, 2e-3 * std::abs(fd) + 1e-4) << i;
  }
  std::vector<float> one(p.begin(), p.begin() + kViewColourParams), twice = one;
  twice.insert(twice.end(), one.begin(), one.end());
  std::vector<float> g1(one.size()), g2(twice.size());
  EXPECT_NEAR(ViewColourPrior(one, w, g1.data()), ViewColourPrior(twice, w, g2.data()), 1e-6);
}

}  // namespace
}  // namespace clnerf
