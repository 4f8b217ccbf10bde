#include "core/pose/feature_localizer.h"

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

using Vec6 = Eigen::Matrix<double, 6, 1>;

// Normalised projections of `points` moved by x' = exp(omega) x + delta t.
Eigen::VectorXd Project(const std::vector<Eigen::Vector3d>& points, const Vec6& p) {
  const Eigen::Vector3d w = p.head<3>();
  const Eigen::Matrix3d r =
      w.norm() > 0 ? Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix() : Eigen::Matrix3d::Identity();
  Eigen::VectorXd out(2 * points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d x = r * points[i] + p.tail<3>();
    out(2 * i) = x.x() / x.z();
    out(2 * i + 1) = x.y() / x.z();
  }
  return out;
}

// Least squares for (omega, delta t) from zero by Gauss-Newton on a central
// finite-difference Jacobian: independent of the product's analytic one.
Vec6 Solve(const std::vector<Eigen::Vector3d>& points, const Eigen::VectorXd& observed, double* squared_error) {
  Vec6 p = Vec6::Zero();
  for (int it = 0; it < 6; ++it) {
    Eigen::MatrixXd j(observed.size(), 6);
    for (int k = 0; k < 6; ++k) {
      Vec6 d = Vec6::Zero();
      d(k) = 1e-6;
      j.col(k) = (Project(points, p + d) - Project(points, p - d)) / 2e-6;
    }
    const Eigen::VectorXd r = observed - Project(points, p);
    p += (j.transpose() * j).ldlt().solve(j.transpose() * r);
  }
  *squared_error = (observed - Project(points, p)).squaredNorm();
  return p;
}

std::vector<Eigen::Vector3d> Points(int n, double spread, double depth_min, double depth_max, bool planar,
                                    std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-spread, spread), z(depth_min, depth_max);
  std::vector<Eigen::Vector3d> out;
  for (int i = 0; i < n; ++i) {
    const double x = u(*rng), y = u(*rng);
    out.emplace_back(x, y, planar ? 0.5 * (depth_min + depth_max) + 0.3 * y : z(*rng));
  }
  return out;
}

// Over repeated noisy observations of `points`, the covariance of the fitted
// rotations (measured) and the mean of PnPRotationCovariance at each fit
// (predicted).
void MonteCarlo(const std::vector<Eigen::Vector3d>& points, double noise_sigma, int trials, std::mt19937* rng,
                Eigen::Matrix3d* measured, Eigen::Matrix3d* predicted) {
  const Eigen::VectorXd exact = Project(points, Vec6::Zero());
  std::normal_distribution<double> noise(0.0, noise_sigma);
  measured->setZero();
  predicted->setZero();
  for (int t = 0; t < trials; ++t) {
    Eigen::VectorXd observed = exact;
    for (int i = 0; i < observed.size(); ++i) observed(i) += noise(*rng);
    double sq = 0;
    const Vec6 p = Solve(points, observed, &sq);
    *measured += p.head<3>() * p.head<3>().transpose();
    // The covariance at the fitted pose: the points as that pose sees them.
    const Eigen::Vector3d w = p.head<3>();
    const Eigen::Matrix3d r = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
    std::vector<Eigen::Vector3d> seen;
    for (const Eigen::Vector3d& x : points) seen.push_back(r * x + p.tail<3>());
    *predicted += PnPRotationCovariance(seen, sq);
  }
  *measured /= trials;
  *predicted /= trials;
}

// The spread of fitted rotations is what the covariance predicts from each
// fit's own residuals, axis by axis, for points spread in depth and for a
// few points on one plane (where rotation trades for translation).
TEST(PnPRotationCovarianceTest, PredictsTheSpreadOfFittedRotations) {
  std::mt19937 rng(3);
  for (bool planar : {false, true}) {
    std::vector<Eigen::Vector3d> points =
        planar ? Points(16, 0.6, 8.0, 8.0, true, &rng) : Points(40, 1.5, 2.0, 6.0, false, &rng);
    // Off the optical axis, so that the rotation's cross terms matter.
    for (Eigen::Vector3d& x : points) x += Eigen::Vector3d(0.3, 0.15, 0.0) * x.z();
    Eigen::Matrix3d measured, predicted;
    MonteCarlo(points, planar ? 2e-4 : 2e-3, 400, &rng, &measured, &predicted);
    for (int a = 0; a < 3; ++a) {
      const double m = std::sqrt(measured(a, a)), q = std::sqrt(predicted(a, a));
      std::printf("%s, axis %d: rotation std predicted %.3g rad, measured %.3g rad\n",
                  planar ? "16 points on a plane" : "40 points in depth", a, q, m);
      EXPECT_NEAR(q / m, 1.0, 0.15) << (planar ? "planar" : "spread") << " axis " << a;
    }
    EXPECT_NEAR(RotationStdDeg(predicted), std::sqrt(predicted.eigenvalues().real().maxCoeff()) * 180 / M_PI, 1e-9);
  }
}

// A few far points on one plane seen nearly head-on fix the orientation far
// less than many points spread in depth at the same residual.
TEST(PnPRotationCovarianceTest, FewPointsOnAPlaneAreUncertain) {
  std::mt19937 rng(5);
  const double sq_per_point = 2 * 1e-6;
  const std::vector<Eigen::Vector3d> spread = Points(100, 1.5, 2.0, 6.0, false, &rng);
  const std::vector<Eigen::Vector3d> plane = Points(16, 0.6, 8.0, 8.0, true, &rng);
  const double a = RotationStdDeg(PnPRotationCovariance(spread, sq_per_point * spread.size()));
  const double b = RotationStdDeg(PnPRotationCovariance(plane, sq_per_point * plane.size()));
  std::printf("rotation std: %.3f deg (100 spread points), %.3f deg (16 far points on a plane)\n", a, b);
  EXPECT_GT(b, 5 * a) << a << " " << b;
  // Doubling the residuals' RMS doubles the standard deviation.
  EXPECT_NEAR(RotationStdDeg(PnPRotationCovariance(spread, 4 * sq_per_point * spread.size())), 2 * a, 1e-9);
  // Two points cannot fix a pose.
  EXPECT_TRUE(std::isinf(RotationStdDeg(PnPRotationCovariance({spread[0], spread[1]}, 1e-6))));
}

}  // namespace
}  // namespace clnerf
