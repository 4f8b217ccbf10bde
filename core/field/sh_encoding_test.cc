// Numerical-correctness tests of the degree-4 real spherical-harmonics
// encoding: Jacobian vs central differences, orthonormality by an exact
// product quadrature, known values at the pole, and the addition theorem.
#include "core/field/sh_encoding.h"

#include <cmath>
#include <random>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

// Band l of coefficient k (0: k = 0, 1: k = 1..3, 2: 4..8, 3: 9..15).
int Band(int k) { return k == 0 ? 0 : (k < 4 ? 1 : (k < 9 ? 2 : 3)); }

TEST(ShEncodingTest, JacobianMatchesCentralDifferences) {
  // The basis functions are polynomials of degree <= 3 in (x, y, z), so the
  // central difference has truncation error h^2 / 6 * |f'''| <= h^2 / 6 *
  // 6 * 5 * 0.3732 ~ 1.1 h^2 = 4.5e-6 at h = 2e-3, plus rounding
  // ~2 * 6e-8 * 2.9 / (2h) ~ 9e-5 on values of up to ~2.9. Tolerance 2e-4.
  // The Jacobian is of the polynomial in R^3 (not tangent to the sphere), so
  // points off the sphere are checked too.
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const float h = 2e-3f;
  for (int it = 0; it < 100; ++it) {
    float p[3] = {u(rng), u(rng), u(rng)};
    if (it % 2 == 0) {  // Unit directions half of the time.
      const float n = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
      for (float& v : p) v /= n;
    }
    float jac[kShDim * 3];
    ShJacobian(p[0], p[1], p[2], jac);
    for (int d = 0; d < 3; ++d) {
      float plus[3] = {p[0], p[1], p[2]}, minus[3] = {p[0], p[1], p[2]};
      plus[d] += h;
      minus[d] -= h;
      float op[kShDim], om[kShDim];
      ShEncode(plus[0], plus[1], plus[2], op);
      ShEncode(minus[0], minus[1], minus[2], om);
      const double step = double(plus[d]) - double(minus[d]);
      for (int k = 0; k < kShDim; ++k) {
        const double fd = (double(op[k]) - double(om[k])) / step;
        ASSERT_NEAR(jac[3 * k + d], fd, 2e-4) << "coefficient " << k << " axis " << d << " at (" << p[0] << ", "
                                              << p[1] << ", " << p[2] << ")";
      }
    }
  }
}

TEST(ShEncodingTest, OrthonormalUnderExactQuadrature) {
  // Product rule: 4-point Gauss-Legendre in z (exact for polynomials of
  // degree <= 7 in z) times 16 equispaced azimuths (exact for trigonometric
  // polynomials of degree <= 15 in phi). Y_i * Y_j has total degree <= 6,
  // so the rule integrates it exactly; the only error is float rounding.
  const double nodes[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526};
  const double weights[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538};
  constexpr int kPhi = 16;
  double gram[kShDim][kShDim] = {};
  for (int a = 0; a < 4; ++a) {
    const double z = nodes[a], r = std::sqrt(1 - z * z);
    for (int b = 0; b < kPhi; ++b) {
      const double phi = 2 * M_PI * (b + 0.37) / kPhi;  // Any offset works.
      float y[kShDim];
      ShEncode(float(r * std::cos(phi)), float(r * std::sin(phi)), float(z), y);
      const double w = weights[a] * 2 * M_PI / kPhi;
      for (int i = 0; i < kShDim; ++i) {
        for (int j = 0; j < kShDim; ++j) gram[i][j] += w * double(y[i]) * y[j];
      }
    }
  }
  for (int i = 0; i < kShDim; ++i) {
    for (int j = 0; j < kShDim; ++j) {
      EXPECT_NEAR(gram[i][j], i == j ? 1.0 : 0.0, 2e-6) << "<Y_" << i << ", Y_" << j << ">";
    }
  }
}

TEST(ShEncodingTest, MonteCarloNorms) {
  // Monte Carlo over uniform directions (fixed seed): the mean of Y_k^2 times
  // 4 pi is 1 for every k. Standard error ~ 4 pi * std(Y^2) / sqrt(N) <
  // 0.01 for N = 20000; tolerance 0.05.
  std::mt19937_64 rng(2);
  std::normal_distribution<double> g(0.0, 1.0);
  constexpr int kN = 20000;
  double sum[kShDim] = {};
  for (int i = 0; i < kN; ++i) {
    double v[3] = {g(rng), g(rng), g(rng)};
    const double n = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    float y[kShDim];
    ShEncode(float(v[0] / n), float(v[1] / n), float(v[2] / n), y);
    for (int k = 0; k < kShDim; ++k) sum[k] += double(y[k]) * y[k];
  }
  for (int k = 0; k < kShDim; ++k) EXPECT_NEAR(4 * M_PI * sum[k] / kN, 1.0, 0.05) << k;
  EXPECT_NEAR(4 * M_PI * sum[0] / kN, 1.0, 1e-6);  // Y_0 is constant.
}

TEST(ShEncodingTest, KnownValuesAtThePole) {
  // At d = +z only the m = 0 functions are nonzero: Y_l0 = sqrt((2l+1)/4pi).
  float y[kShDim];
  ShEncode(0, 0, 1, y);
  for (int k = 0; k < kShDim; ++k) {
    double want = 0;
    if (k == 0 || k == 2 || k == 6 || k == 12) want = std::sqrt((2 * Band(k) + 1) / (4 * M_PI));
    EXPECT_NEAR(y[k], want, 1e-6) << k;
  }
  // At -z the odd bands flip sign.
  ShEncode(0, 0, -1, y);
  EXPECT_NEAR(y[2], -std::sqrt(3 / (4 * M_PI)), 1e-6);
  EXPECT_NEAR(y[6], std::sqrt(5 / (4 * M_PI)), 1e-6);
  EXPECT_NEAR(y[12], -std::sqrt(7 / (4 * M_PI)), 1e-6);
}

TEST(ShEncodingTest, AdditionTheorem) {
  // sum_m Y_lm(d)^2 = (2l + 1) / (4 pi) for every unit d.
  std::mt19937_64 rng(3);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int it = 0; it < 200; ++it) {
    double v[3] = {g(rng), g(rng), g(rng)};
    const double n = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    float y[kShDim];
    ShEncode(float(v[0] / n), float(v[1] / n), float(v[2] / n), y);
    double band[4] = {};
    for (int k = 0; k < kShDim; ++k) band[Band(k)] += double(y[k]) * y[k];
    for (int l = 0; l < 4; ++l) EXPECT_NEAR(band[l], (2 * l + 1) / (4 * M_PI), 2e-6) << "band " << l;
  }
}

}  // namespace
}  // namespace clnerf
