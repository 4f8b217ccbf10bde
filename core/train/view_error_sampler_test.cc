// ViewErrorSampler (view_error_sampler.h): uniform until it has seen errors,
// then views in proportion to their error plus the uniform floor; bad input
// (NaN errors, unknown views) is ignored; old errors fade.
#include "core/train/view_error_sampler.h"

#include <cmath>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

std::vector<double> Frequencies(const ViewErrorSampler& s, int views, int draws, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<double> f(views, 0.0);
  for (int i = 0; i < draws; ++i) f[s.Pick(&rng)] += 1.0 / draws;
  return f;
}

// One step: `n` rays of each view with the given squared error.
void Observe(ViewErrorSampler* s, const std::vector<float>& error_per_view, int n) {
  std::vector<int> view;
  std::vector<float> err;
  for (size_t v = 0; v < error_per_view.size(); ++v) {
    for (int i = 0; i < n; ++i) {
      view.push_back(int(v));
      err.push_back(error_per_view[v]);
    }
  }
  s->Observe(view, err);
}

TEST(ViewErrorSamplerTest, OptionsAreValidated) {
  EXPECT_TRUE(ViewErrorOptions().Validate().ok());
  ViewErrorOptions o;
  o.error_share = 1.0f;
  EXPECT_FALSE(o.Validate().ok());
  o.error_share = -0.1f;
  EXPECT_FALSE(o.Validate().ok());
  o.error_share = 0.5f;
  o.decay = 1.0f;
  EXPECT_FALSE(o.Validate().ok());
  o.decay = std::nanf("");
  EXPECT_FALSE(o.Validate().ok());
  o.decay = 0.9f;
  o.tiles = 0;
  EXPECT_FALSE(o.Validate().ok());
}

TEST(ViewErrorSamplerTest, ACellThatCannotBeDrawnNeverIs) {
  ViewErrorOptions o;
  o.error_share = 0.9f;
  // Base: cell 1 is empty (no pixel), cell 2 has three times cell 0's pixels.
  ViewErrorSampler s({1.0, 0.0, 3.0}, o);
  EXPECT_EQ(s.Probabilities(), (std::vector<double>{0.25, 0.0, 0.75}));
  s.Observe({0, 1, 1, 2}, {1.0f, 9.0f, 9.0f, 0.0f});  // Errors "on" the empty cell are ignored there.
  const std::vector<double> p = s.Probabilities();
  EXPECT_EQ(p[1], 0.0);
  EXPECT_GT(p[0], 0.5);
  std::mt19937_64 rng(3);
  for (int i = 0; i < 20000; ++i) ASSERT_NE(s.Pick(&rng), 1);
}

TEST(ViewErrorSamplerTest, UniformUntilErrorsAreSeenThenProportional) {
  ViewErrorOptions o;
  o.error_share = 0.8f;
  ViewErrorSampler s({1.0, 1.0}, o);
  ASSERT_TRUE(s.enabled());
  std::vector<double> f = Frequencies(s, 2, 20000, 1);
  EXPECT_NEAR(f[0], 0.5, 0.02);
  // View 0 is already fitted (error 0), view 1 is not (error 1).
  Observe(&s, {0.0f, 1.0f}, 100);
  const std::vector<double> p = s.Probabilities();
  // e0 = (0 + 0.5) / 101, e1 = (100 + 0.5) / 101 (prior 0.5: the batch mean).
  const double e0 = 0.5 / 101, e1 = 100.5 / 101;
  EXPECT_NEAR(s.Error(0), e0, 1e-9);
  EXPECT_NEAR(s.Error(1), e1, 1e-9);
  EXPECT_NEAR(p[1], 0.1 + 0.8 * e1 / (e0 + e1), 1e-6);  // error_share is a float.
  EXPECT_NEAR(p[0] + p[1], 1.0, 1e-12);
  f = Frequencies(s, 2, 20000, 2);
  EXPECT_NEAR(f[1], p[1], 0.02);
  EXPECT_GT(f[0], 0.08) << "the uniform floor keeps the fitted view in the draws";
}

TEST(ViewErrorSamplerTest, OldErrorsFadeAndBadInputIsIgnored) {
  ViewErrorOptions o;
  o.error_share = 0.5f;
  o.decay = 0.5f;
  ViewErrorSampler s({1.0, 1.0, 1.0}, o);
  Observe(&s, {1.0f, 0.0f, 0.0f}, 50);
  EXPECT_GT(s.Probabilities()[0], 0.5);
  // The first view is learnt, the second drifts: within a few steps the
  // preference follows.
  for (int k = 0; k < 8; ++k) Observe(&s, {0.0f, 1.0f, 0.0f}, 50);
  const std::vector<double> p = s.Probabilities();
  EXPECT_GT(p[1], 0.6);
  EXPECT_LT(p[0], 0.2);
  // NaN errors and views out of range change nothing.
  s.Observe({0, 7, -1, 2}, {std::nanf(""), 5.0f, 5.0f, std::numeric_limits<float>::infinity()});
  const std::vector<double> q = s.Probabilities();
  for (int v = 0; v < 3; ++v) EXPECT_NEAR(q[v], p[v], 0.02) << v;  // Only the decay moved them.
  // Off: uniform whatever was observed.
  ViewErrorSampler off({1.0, 1.0, 1.0}, ViewErrorOptions());
  EXPECT_FALSE(off.enabled());
  Observe(&off, {1.0f, 0.0f, 0.0f}, 50);
  EXPECT_EQ(off.Probabilities(), std::vector<double>(3, 1.0 / 3));
}

}  // namespace
}  // namespace clnerf
