// Numerical-correctness tests of front-to-back compositing: weights against
// the closed form, early termination, and CompositeBackward against central
// differences (of a double reference of eq. (1) and of the float forward).
#include "core/render/volume_rendering.h"

#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

struct Ray {
  std::vector<float> sigma, dt, rgb;
};

Ray RandomRay(int n, uint64_t seed, float sigma_lo, float sigma_hi) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> s(sigma_lo, sigma_hi), d(0.01f, 0.1f), c(0.0f, 1.0f);
  Ray r;
  for (int i = 0; i < n; ++i) {
    r.sigma.push_back(s(rng));
    r.dt.push_back(d(rng));
    for (int k = 0; k < 3; ++k) r.rgb.push_back(c(rng));
  }
  return r;
}

const float kBackground[3] = {0.2f, 0.5f, 0.9f};

// Loss of eq. (1) in double, truncated after `used` samples:
// L = g . C + d_opacity * (1 - T_used).
double ReferenceLoss(const std::vector<double>& sigma, const std::vector<double>& dt,
                     const std::vector<double>& rgb, int used, const double g[3], double d_opacity) {
  double T = 1, c[3] = {0, 0, 0};
  for (int i = 0; i < used; ++i) {
    const double w = T * (1 - std::exp(-sigma[i] * dt[i]));
    for (int k = 0; k < 3; ++k) c[k] += w * rgb[3 * i + k];
    T *= std::exp(-sigma[i] * dt[i]);
  }
  double l = d_opacity * (1 - T);
  for (int k = 0; k < 3; ++k) l += g[k] * (c[k] + T * kBackground[k]);
  return l;
}

// The same loss through the library's float forward (termination included).
double LibraryLoss(const Ray& r, const double g[3], double d_opacity, int* used_out = nullptr) {
  const int n = int(r.sigma.size());
  std::vector<float> w(n);
  float t_final;
  const int used = CompositeWeights(r.sigma.data(), r.dt.data(), n, kMinTransmittance, w.data(), &t_final);
  float c[3];
  CompositeColour(w.data(), r.rgb.data(), used, t_final, kBackground, c);
  if (used_out) *used_out = used;
  double l = d_opacity * (1 - double(t_final));
  for (int k = 0; k < 3; ++k) l += g[k] * c[k];
  return l;
}

TEST(CompositeWeightsTest, MatchesClosedForm) {
  const Ray r = RandomRay(20, 1, 0.5f, 5.0f);
  std::vector<float> w(20, -1.0f);
  float t_final = -1;
  const int used = CompositeWeights(r.sigma.data(), r.dt.data(), 20, kMinTransmittance, w.data(), &t_final);
  ASSERT_EQ(used, 20);  // Mean sigma dt ~0.15: T_final ~ exp(-3).
  double tau = 0, sum_w = 0;
  for (int i = 0; i < 20; ++i) {
    const double Ti = std::exp(-tau);
    const double wi = Ti * (1 - std::exp(-double(r.sigma[i]) * r.dt[i]));
    EXPECT_NEAR(w[i], wi, 1e-6 + 1e-5 * wi) << i;
    tau += double(r.sigma[i]) * r.dt[i];
    sum_w += w[i];
  }
  EXPECT_NEAR(t_final, std::exp(-tau), 1e-6);
  EXPECT_GT(t_final, 0.01f);
  EXPECT_NEAR(sum_w, 1.0 - t_final, 1e-6);  // Weights sum to the opacity.

  float c[3];
  CompositeColour(w.data(), r.rgb.data(), used, t_final, kBackground, c);
  for (int k = 0; k < 3; ++k) {
    double want = t_final * kBackground[k];
    for (int i = 0; i < 20; ++i) want += double(w[i]) * r.rgb[3 * i + k];
    EXPECT_NEAR(c[k], want, 1e-6) << k;
  }
}

TEST(CompositeWeightsTest, EmptySpaceAndOpaqueSample) {
  // All-zero density: nothing is absorbed.
  std::vector<float> sigma(5, 0.0f), dt(5, 0.1f), w(5, -1.0f);
  float t_final;
  EXPECT_EQ(CompositeWeights(sigma.data(), dt.data(), 5, kMinTransmittance, w.data(), &t_final), 5);
  EXPECT_EQ(t_final, 1.0f);
  for (float v : w) EXPECT_EQ(v, 0.0f);
  // An opaque third sample takes everything that is left and stops the ray.
  sigma = {1.0f, 1.0f, 1e4f, 1.0f, 1.0f};
  w.assign(5, -1.0f);
  EXPECT_EQ(CompositeWeights(sigma.data(), dt.data(), 5, kMinTransmittance, w.data(), &t_final), 3);
  EXPECT_NEAR(w[2], std::exp(-0.2), 1e-6);
  EXPECT_EQ(w[3], -1.0f);  // Dropped samples are not written.
  EXPECT_EQ(w[4], -1.0f);
  EXPECT_LE(t_final, kMinTransmittance);
}

TEST(CompositeWeightsTest, EarlyTerminationAtFirstSampleBelowThreshold) {
  // Constant sigma * dt = 0.5 per sample: T_i = exp(-0.5 i) first drops to
  // <= 1e-4 after sample i = 19 (exp(-9.5) = 7.5e-5; exp(-9) = 1.2e-4).
  const int n = 40;
  std::vector<float> sigma(n, 5.0f), dt(n, 0.1f), w(n, -1.0f);
  float t_final;
  const int used = CompositeWeights(sigma.data(), dt.data(), n, kMinTransmittance, w.data(), &t_final);
  EXPECT_EQ(used, 19);
  EXPECT_NEAR(t_final, std::exp(-9.5), 1e-7);
  for (int i = used; i < n; ++i) EXPECT_EQ(w[i], -1.0f) << i;
  double sum = 0;
  for (int i = 0; i < used; ++i) sum += w[i];
  EXPECT_NEAR(sum, 1.0 - t_final, 1e-6);
  // Without a threshold every sample is used.
  EXPECT_EQ(CompositeWeights(sigma.data(), dt.data(), n, 0.0f, w.data(), &t_final), n);
  EXPECT_NEAR(t_final, std::exp(-20.0), 1e-12);
  // A higher threshold stops earlier: exp(-0.5 i) <= 0.1 first at i = 5.
  EXPECT_EQ(CompositeWeights(sigma.data(), dt.data(), n, 0.1f, w.data(), &t_final), 5);
}

void CheckBackward(const Ray& ray, uint64_t seed, bool expect_termination) {
  const int n = int(ray.sigma.size());
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double g[3] = {u(rng), u(rng), u(rng)};
  const double d_opacity = u(rng);
  std::vector<float> w(n);
  float t_final;
  const int used = CompositeWeights(ray.sigma.data(), ray.dt.data(), n, kMinTransmittance, w.data(), &t_final);
  if (expect_termination) {
    ASSERT_LT(used, n);
  } else {
    ASSERT_EQ(used, n);
  }
  const float d_out[3] = {float(g[0]), float(g[1]), float(g[2])};
  std::vector<float> d_rgb(3 * size_t(n), 7.0f), d_sigma(n, 7.0f);
  CompositeBackward(ray.sigma.data(), ray.dt.data(), ray.rgb.data(), w.data(), used, t_final, kBackground, d_out,
                    float(d_opacity), d_rgb.data(), d_sigma.data());

  // (1) Double reference of eq. (1) with the same truncation, h = 1e-6:
  // FD error ~1e-10, float backward ~1e-6 relative. Tolerance 1e-5 + 1e-4 rel.
  {
    std::vector<double> s(ray.sigma.begin(), ray.sigma.end()), dt(ray.dt.begin(), ray.dt.end()),
        c(ray.rgb.begin(), ray.rgb.end());
    const double h = 1e-6;
    for (int i = 0; i < used; ++i) {
      const double s0 = s[i];
      s[i] = s0 + h;
      const double lp = ReferenceLoss(s, dt, c, used, g, d_opacity);
      s[i] = s0 - h;
      const double lm = ReferenceLoss(s, dt, c, used, g, d_opacity);
      s[i] = s0;
      const double fd = (lp - lm) / (2 * h);
      EXPECT_NEAR(d_sigma[i], fd, 1e-5 + 1e-4 * std::abs(fd)) << "d_sigma[" << i << "]";
      for (int k = 0; k < 3; ++k) {
        const double c0 = c[3 * i + k];
        c[3 * i + k] = c0 + h;
        const double cp = ReferenceLoss(s, dt, c, used, g, d_opacity);
        c[3 * i + k] = c0 - h;
        const double cm = ReferenceLoss(s, dt, c, used, g, d_opacity);
        c[3 * i + k] = c0;
        const double fdc = (cp - cm) / (2 * h);
        EXPECT_NEAR(d_rgb[3 * i + k], fdc, 1e-5 + 1e-4 * std::abs(fdc)) << "d_rgb[" << i << "][" << k << "]";
      }
    }
  }
  // (2) Float forward of the library (CompositeWeights + CompositeColour),
  // h = 1e-2 in sigma (sigma dt changes by <= 1e-3; no termination boundary
  // is crossed, checked below): FD rounding noise ~3e-7 / 2e-2 = 1.5e-5 and
  // the O(h^2 dt^3) truncation is negligible. L is linear in rgb. Tolerance
  // 1e-4 + 1e-3 relative.
  {
    Ray r = ray;
    const float h = 1e-2f;
    for (int i = 0; i < n; ++i) {
      const float s0 = r.sigma[i];
      int used_p, used_m;
      r.sigma[i] = s0 + h;
      const double lp = LibraryLoss(r, g, d_opacity, &used_p);
      r.sigma[i] = s0 - h;
      const double lm = LibraryLoss(r, g, d_opacity, &used_m);
      r.sigma[i] = s0;
      ASSERT_EQ(used_p, used);
      ASSERT_EQ(used_m, used);
      const double fd = (lp - lm) / (2.0 * h);
      if (i >= used) {
        EXPECT_EQ(fd, 0.0) << "dropped sample " << i << " must not influence the loss";
        EXPECT_EQ(d_sigma[i], 7.0f) << "dropped sample " << i << " must not be written";
        continue;
      }
      EXPECT_NEAR(d_sigma[i], fd, 1e-4 + 1e-3 * std::abs(fd)) << "float FD d_sigma[" << i << "]";
      for (int k = 0; k < 3; ++k) {
        const float c0 = r.rgb[3 * i + k];
        r.rgb[3 * i + k] = c0 + h;
        const double cp = LibraryLoss(r, g, d_opacity);
        r.rgb[3 * i + k] = c0 - h;
        const double cm = LibraryLoss(r, g, d_opacity);
        r.rgb[3 * i + k] = c0;
        EXPECT_NEAR(d_rgb[3 * i + k], (cp - cm) / (2.0 * h), 1e-4) << "float FD d_rgb[" << i << "][" << k << "]";
      }
    }
  }
}

TEST(CompositeBackwardTest, MatchesFiniteDifferencesWithoutTermination) {
  CheckBackward(RandomRay(16, 2, 0.5f, 5.0f), 3, /*expect_termination=*/false);
  // Dense samples: sum sigma dt <= 8 * 10 * 0.1 = 8 < -ln(1e-4) = 9.2.
  CheckBackward(RandomRay(8, 4, 5.0f, 10.0f), 5, /*expect_termination=*/false);
}

TEST(CompositeBackwardTest, MatchesFiniteDifferencesWithTermination) {
  // Sample 6 has sigma dt = 10: T falls from >= exp(-3) (samples 0..5 have
  // sigma dt <= 0.5 each) to <= 4.5e-5 * T_6 < 1e-4, far from the threshold
  // for any +-1e-2 perturbation; samples 7.. are dropped. T_final stays
  // nonzero in float so the opacity term keeps a (small) gradient.
  Ray r = RandomRay(12, 6, 0.5f, 5.0f);
  r.sigma[6] = 125.0f;
  r.dt[6] = 0.08f;
  CheckBackward(r, 7, /*expect_termination=*/true);
}

// Distortion loss in double precision, straight from its definition:
// L = sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 s_i, with w from sigma.
double ReferenceDistortion(const std::vector<double>& sigma, const std::vector<float>& dt,
                           const std::vector<float>& mid, const std::vector<float>& width, int used) {
  std::vector<double> w(used);
  double T = 1.0;
  for (int i = 0; i < used; ++i) {
    const double a = 1.0 - std::exp(-sigma[i] * dt[i]);
    w[i] = T * a;
    T *= 1.0 - a;
  }
  double l = 0;
  for (int i = 0; i < used; ++i) {
    for (int j = 0; j < used; ++j) l += w[i] * w[j] * std::abs(double(mid[i]) - mid[j]);
    l += w[i] * w[i] * width[i] / 3.0;
  }
  return l;
}

TEST(DistortionLossTest, ValueAndGradientMatchTheDefinition) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int trial = 0; trial < 5; ++trial) {
    const int n = 6 + trial * 5;
    std::vector<float> sigma(n), dt(n), mid(n), width(n);
    float pos = 0.1f;
    for (int i = 0; i < n; ++i) {
      sigma[i] = 0.5f + 20.0f * u(rng);
      dt[i] = 0.01f + 0.05f * u(rng);
      width[i] = dt[i] * (0.2f + u(rng));
      mid[i] = pos + 0.5f * width[i];
      pos += width[i];
    }
    std::vector<float> w(n);
    float t_final;
    const int used = CompositeWeights(sigma.data(), dt.data(), n, 0.0f, w.data(), &t_final);
    std::vector<float> d_sigma(n, 0.5f);  // Accumulates onto what is there.
    const float scale = 0.7f;
    const float loss = DistortionLoss(dt.data(), w.data(), mid.data(), width.data(), used, scale, d_sigma.data());
    std::vector<double> sd(sigma.begin(), sigma.end());
    const double ref = ReferenceDistortion(sd, dt, mid, width, used);
    EXPECT_NEAR(loss, ref, 1e-5 + 1e-4 * ref);
    EXPECT_GT(ref, 0.0);
    for (int i = 0; i < used; ++i) {
      const double h = 1e-5 * std::max(1.0, sd[i]);
      const double s0 = sd[i];
      sd[i] = s0 + h;
      const double lp = ReferenceDistortion(sd, dt, mid, width, used);
      sd[i] = s0 - h;
      const double lm = ReferenceDistortion(sd, dt, mid, width, used);
      sd[i] = s0;
      const double fd = scale * (lp - lm) / (2 * h);
      EXPECT_NEAR(d_sigma[i] - 0.5f, fd, 1e-5 + 1e-3 * std::abs(fd)) << "trial " << trial << " sample " << i;
    }
  }
}

TEST(DistortionLossTest, OneCompactSurfaceCostsLessThanFog) {
  // Same total opacity, concentrated in one sample vs spread over ten.
  const int n = 10;
  std::vector<float> dt(n, 0.1f), mid(n), width(n, 0.1f), w(n), d(n, 0.0f);
  for (int i = 0; i < n; ++i) mid[i] = 0.05f + 0.1f * i;
  std::vector<float> fog(n, 0.9f), surface(n, 0.0f);
  surface[5] = 9.0f;  // sigma dt = 0.9 in one sample: the same opacity.
  float tf;
  CompositeWeights(fog.data(), dt.data(), n, 0.0f, w.data(), &tf);
  const float l_fog = DistortionLoss(dt.data(), w.data(), mid.data(), width.data(), n, 1.0f, d.data());
  CompositeWeights(surface.data(), dt.data(), n, 0.0f, w.data(), &tf);
  const float l_surface = DistortionLoss(dt.data(), w.data(), mid.data(), width.data(), n, 1.0f, d.data());
  EXPECT_LT(l_surface, 0.2f * l_fog);
}

// Sparse-depth loss in double precision from its definition.
double ReferenceSparseDepth(const std::vector<double>& sigma, const std::vector<float>& dt,
                            const std::vector<float>& mid, int used, double depth, double sig) {
  double T = 1.0, l = 0;
  const double s = sig * std::max(1.0, depth);
  for (int i = 0; i < used; ++i) {
    const double a = 1.0 - std::exp(-sigma[i] * dt[i]);
    const double w = T * a;
    T *= 1.0 - a;
    const double e = mid[i] - depth;
    l += -std::log(w + kSparseDepthEps) * std::exp(-e * e / (2 * s * s)) * dt[i];
  }
  return l;
}

TEST(SparseDepthLossTest, ValueAndGradientMatchCentralDifferences) {
  std::mt19937_64 rng(12);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int trial = 0; trial < 6; ++trial) {
    const int n = 5 + trial * 4;
    std::vector<float> sigma(n), dt(n), mid(n);
    float pos = 0.2f;
    for (int i = 0; i < n; ++i) {
      sigma[i] = 0.2f + 15.0f * u(rng);
      dt[i] = 0.02f + 0.08f * u(rng);
      mid[i] = pos + 0.5f * dt[i];
      pos += dt[i];
    }
    // Depth inside the samples' span, and (trial 5) beyond 1 where the
    // width grows.
    const float depth = trial == 5 ? 1.0f + pos : mid[n / 2] + 0.3f * dt[n / 2];
    for (float& m : mid) m += trial == 5 ? 1.0f : 0.0f;
    std::vector<float> w(n);
    float t_final;
    const int used = CompositeWeights(sigma.data(), dt.data(), n, 0.0f, w.data(), &t_final);
    std::vector<float> d_sigma(n, 0.25f);  // Accumulates onto what is there.
    const float scale = 0.6f, sig = 0.1f;
    const float loss = SparseDepthLoss(dt.data(), w.data(), mid.data(), used, depth, sig, scale, d_sigma.data());
    std::vector<double> sd(sigma.begin(), sigma.end());
    const double ref = ReferenceSparseDepth(sd, dt, mid, used, depth, sig);
    EXPECT_NEAR(loss, ref, 1e-5 + 1e-4 * std::abs(ref));
    EXPECT_GT(ref, 0.0);
    for (int i = 0; i < used; ++i) {
      const double h = 1e-4 * std::max(1.0, sd[i]);
      const double s0 = sd[i];
      sd[i] = s0 + h;
      const double lp = ReferenceSparseDepth(sd, dt, mid, used, depth, sig);
      sd[i] = s0 - h;
      const double lm = ReferenceSparseDepth(sd, dt, mid, used, depth, sig);
      sd[i] = s0;
      const double fd = scale * (lp - lm) / (2 * h);
      EXPECT_NEAR(d_sigma[i] - 0.25f, fd, 2e-5 + 2e-3 * std::abs(fd)) << "trial " << trial << " sample " << i;
    }
  }
}

TEST(SparseDepthLossTest, ASurfaceAtTheKnownDepthCostsLessThanOneElsewhere) {
  const int n = 20;
  std::vector<float> dt(n, 0.05f), mid(n), w(n), d(n, 0.0f);
  for (int i = 0; i < n; ++i) mid[i] = 0.5f + 0.05f * i;
  const float depth = mid[12];
  float tf;
  auto loss_with_surface_at = [&](int k) {
    std::vector<float> sigma(n, 0.0f);
    sigma[k] = 60.0f;
    CompositeWeights(sigma.data(), dt.data(), n, 0.0f, w.data(), &tf);
    // A Gaussian narrower than the sample spacing: DS-NeRF's loss is a KL
    // divergence, so with a wide one it prefers weight spread over the
    // Gaussian to a single surface sample.
    return SparseDepthLoss(dt.data(), w.data(), mid.data(), n, depth, 0.02f, 1.0f, d.data());
  };
  EXPECT_LT(loss_with_surface_at(12), 0.5f * loss_with_surface_at(4));
  EXPECT_LT(loss_with_surface_at(12), 0.5f * loss_with_surface_at(19));
  // No known depth: no loss, no gradient.
  std::fill(d.begin(), d.end(), 0.0f);
  EXPECT_EQ(SparseDepthLoss(dt.data(), w.data(), mid.data(), n, 0.0f, 0.05f, 1.0f, d.data()), 0.0f);
  for (float g : d) EXPECT_EQ(g, 0.0f);
}

}  // namespace
}  // namespace clnerf
