// Contraction: identity inside the unit cube, inverse, range, Jacobian and
// directional derivative against central finite differences.
#include "core/data/contraction.h"

#include <random>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

std::vector<Eigen::Vector3f> Points(int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> g(0.0f, 1.0f);
  std::uniform_real_distribution<float> u(-1.0f, 2.5f);
  std::vector<Eigen::Vector3f> out;
  for (int i = 0; i < n; ++i) {
    // Radii from 0.1 to ~300 (log-uniform), random directions.
    out.push_back(Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized() * std::pow(10.0f, u(rng)));
  }
  return out;
}

TEST(ContractionTest, IdentityInsideAndInsideTheCubeOutside) {
  const Eigen::Vector3f in(0.3f, -0.99f, 0.5f);
  EXPECT_EQ(Contract(in), in);
  for (const Eigen::Vector3f& x : Points(500, 1)) {
    const Eigen::Vector3f q = Contract(x);
    EXPECT_LT(InfNorm(q), kContractedBound);
    if (InfNorm(x) > 1.0f) {
      EXPECT_GT(InfNorm(q), 1.0f);
      EXPECT_NEAR(InfNorm(q), 2.0f - 1.0f / InfNorm(x), 1e-5f);
      // Direction is preserved.
      EXPECT_NEAR(q.normalized().dot(x.normalized()), 1.0f, 1e-5f);
    }
  }
}

TEST(ContractionTest, UncontractInvertsContract) {
  for (const Eigen::Vector3f& x : Points(500, 2)) {
    const Eigen::Vector3f back = Uncontract(Contract(x));
    // Relative precision degrades like r^2 * eps near the outer face.
    const float r = std::max(1.0f, InfNorm(x));
    EXPECT_LT((back - x).norm(), 1e-5f * r * r + 1e-6f) << x.transpose();
  }
  // Contract(Uncontract(q)) = q on the open cube.
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(-1.99f, 1.99f);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3f q(u(rng), u(rng), u(rng));
    EXPECT_LT((Contract(Uncontract(q)) - q).norm(), 2e-5f) << q.transpose();
  }
}

TEST(ContractionTest, JacobianAndDirectionalDerivativeMatchFiniteDifferences) {
  std::mt19937_64 rng(4);
  std::normal_distribution<float> g(0.0f, 1.0f);
  int outside = 0;
  for (const Eigen::Vector3f& xf : Points(300, 5)) {
    const Eigen::Vector3d x = xf.cast<double>();
    const double r = x.cwiseAbs().maxCoeff();
    // Skip points within h of a kink (the unit cube's faces, or two axes
    // tied for the maximum).
    Eigen::Vector3d a = x.cwiseAbs();
    std::sort(a.data(), a.data() + 3);
    const double h = 1e-3 * std::max(1.0, r);
    if (std::abs(r - 1.0) < 4 * h || a[2] - a[1] < 4 * h) continue;
    outside += r > 1.0;
    // Reference in double precision.
    auto contract = [](const Eigen::Vector3d& p) -> Eigen::Vector3d {
      const double rr = p.cwiseAbs().maxCoeff();
      return rr <= 1.0 ? p : Eigen::Vector3d(p * ((2.0 - 1.0 / rr) / rr));
    };
    Eigen::Matrix3d fd;
    for (int j = 0; j < 3; ++j) {
      Eigen::Vector3d e = Eigen::Vector3d::Zero();
      e[j] = h;
      fd.col(j) = (contract(x + e) - contract(x - e)) / (2 * h);
    }
    const Eigen::Matrix3f jac = ContractJacobian(xf);
    EXPECT_LT((jac.cast<double>() - fd).cwiseAbs().maxCoeff(), 1e-4 * std::max(1.0, fd.cwiseAbs().maxCoeff()))
        << "x = " << xf.transpose() << "\n" << jac << "\nvs\n" << fd;
    const Eigen::Vector3f d = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    EXPECT_LT((ContractDirectional(xf, d) - jac * d).norm(), 1e-5f * std::max(1.0f, jac.norm()));
  }
  EXPECT_GT(outside, 100);
}

}  // namespace
}  // namespace clnerf
