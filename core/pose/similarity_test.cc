#include "core/pose/similarity.h"

#include <random>

#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

Similarity RandomSimilarity(std::mt19937_64* rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Similarity s;
  s.rotation = Eigen::AngleAxisd(M_PI * u(*rng), Eigen::Vector3d(u(*rng), u(*rng), u(*rng)).normalized())
                   .toRotationMatrix();
  s.scale = std::exp(1.5 * u(*rng));
  s.translation = Eigen::Vector3d(u(*rng), u(*rng), u(*rng)) * 5;
  return s;
}

Pose RandomPose(std::mt19937_64* rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Pose p;
  p.leftCols<3>() = Eigen::AngleAxisf(float(M_PI * u(*rng)), Eigen::Vector3f(u(*rng), u(*rng), u(*rng)).normalized())
                        .toRotationMatrix();
  p.col(3) = Eigen::Vector3f(u(*rng), u(*rng), u(*rng)) * 2;
  return p;
}

TEST(SimilarityTest, InverseAndComposeUndoEachOther) {
  std::mt19937_64 rng(3);
  const Similarity s = RandomSimilarity(&rng);
  const Similarity id = s.Compose(s.Inverse());
  EXPECT_NEAR(id.scale, 1.0, 1e-12);
  EXPECT_LT(id.RotationDegrees(), 1e-6);
  EXPECT_LT(id.translation.norm(), 1e-9);
  const Eigen::Vector3d x(0.3, -2, 1);
  EXPECT_LT((s.Inverse().Apply(s.Apply(x)) - x).norm(), 1e-9);
  // A mapped pose keeps orthonormal axes.
  const Pose p = s.ApplyToPose(RandomPose(&rng));
  EXPECT_LT((p.leftCols<3>().transpose() * p.leftCols<3>() - Eigen::Matrix3f::Identity()).norm(), 1e-5f);
}

TEST(SimilarityTest, FitRecoversAnExactSimilarity) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  const Similarity truth = RandomSimilarity(&rng);
  std::vector<Eigen::Vector3d> a, b;
  for (int i = 0; i < 10; ++i) {
    a.emplace_back(u(rng), u(rng), u(rng));
    b.push_back(truth.Apply(a.back()));
  }
  absl::StatusOr<Similarity> fit = FitSimilarity(a, b);
  ASSERT_TRUE(fit.ok()) << fit.status();
  EXPECT_NEAR(fit->scale, truth.scale, 1e-9 * truth.scale);
  EXPECT_LT(RotationAngleDegrees(fit->rotation, truth.rotation), 1e-6);
  EXPECT_LT((fit->translation - truth.translation).norm(), 1e-8);
}

// A forward-facing rig: camera centres within 2 % of the place, each
// localised with a centre error of 0.3 % of the place and a rotation error
// of 0.3 deg. The centres' noise is large against the rig, so the fit must
// take its rotation from the frames' rotations, not from the centres alone.
TEST(SimilarityTest, RobustFitOfASmallRigTakesItsRotationFromTheFrames) {
  std::mt19937_64 rng(11);
  std::normal_distribution<double> g(0, 1);
  const Similarity truth = RandomSimilarity(&rng);
  const double extent = 10 * truth.scale;  // In target units.
  std::vector<PosePair> pairs;
  for (int i = 0; i < 24; ++i) {
    Pose from = Pose::Identity();
    from.col(3) = Eigen::Vector3f(0.1f * float(i % 6), 0.08f * float(i / 6), 0.0f);  // A 0.5 x 0.24 grid.
    Pose to = truth.ApplyToPose(from);
    const Eigen::Vector3d axis(g(rng), g(rng), g(rng));
    to.leftCols<3>() = (Eigen::AngleAxisd(0.3 * M_PI / 180 * std::abs(g(rng)), axis.normalized()).toRotationMatrix() *
                        to.leftCols<3>().cast<double>()).cast<float>();
    to.col(3) += (Eigen::Vector3d(g(rng), g(rng), g(rng)) * 0.003 * extent / std::sqrt(3.0)).cast<float>();
    pairs.push_back({from, to});
  }
  absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, extent, RobustSimilarityOptions());
  ASSERT_TRUE(fit.ok()) << fit.status();
  EXPECT_EQ(fit->inliers.size(), pairs.size());
  EXPECT_LT(RotationAngleDegrees(fit->transform.rotation, truth.rotation), 0.2);
  // The scale comes from the centres alone: about 2 % (one sigma) here.
  EXPECT_LT(std::abs(fit->transform.scale / truth.scale - 1), 0.1);
}

// Frames around an object (an orbit of radius 4 looking in): each frame's
// PnP centre within 0.2 % of the place, its rotation within 1.5 degrees (per
// axis), as small photos give. An orbit's centres fix the rotation far
// better than the frames' own rotations; the fit must weigh each by its
// noise, not by the inlier tolerances (5 % of the place, 5 degrees), which
// gave 0.33 degrees here (this fit: 0.11).
std::vector<PosePair> NoisyOrbit(const Similarity& truth, double extent, double centre_noise, double rot_noise_deg,
                                 std::mt19937_64* rng) {
  std::normal_distribution<double> g(0, 1);
  std::vector<PosePair> pairs;
  for (int i = 0; i < 30; ++i) {
    const double a = 2 * M_PI * i / 30, e = 0.3 + 0.4 * (i % 3);
    const Eigen::Vector3f c(float(4 * std::cos(a) * std::cos(e)), float(4 * std::sin(a) * std::cos(e)),
                            float(4 * std::sin(e)));
    Pose from = Pose::Identity();
    const Eigen::Vector3f back = c.normalized();  // OpenGL: the camera looks down -z.
    const Eigen::Vector3f right = Eigen::Vector3f::UnitZ().cross(back).normalized();
    from.col(0) = right;
    from.col(1) = back.cross(right);
    from.col(2) = back;
    from.col(3) = c;
    Pose to = truth.ApplyToPose(from);
    const Eigen::Vector3d rv(g(*rng), g(*rng), g(*rng));
    to.leftCols<3>() = (Eigen::AngleAxisd(rv.norm() * rot_noise_deg * M_PI / 180, rv.normalized()).toRotationMatrix() *
                        to.leftCols<3>().cast<double>()).cast<float>();
    to.col(3) += (Eigen::Vector3d(g(*rng), g(*rng), g(*rng)) * centre_noise * extent).cast<float>();
    pairs.push_back({from, to});
  }
  return pairs;
}

TEST(SimilarityTest, RobustFitWeighsCentresAndRotationsByTheirNoise) {
  std::mt19937_64 rng(5);
  const Similarity truth = RandomSimilarity(&rng);
  const double extent = 8 * truth.scale;
  const std::vector<PosePair> pairs = NoisyOrbit(truth, extent, 0.002, 1.5, &rng);
  absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, extent, RobustSimilarityOptions());
  ASSERT_TRUE(fit.ok()) << fit.status();
  EXPECT_GE(fit->inliers.size(), 28u);
  EXPECT_LT(RotationAngleDegrees(fit->transform.rotation, truth.rotation), 0.2);
  EXPECT_LT(std::abs(fit->transform.scale / truth.scale - 1), 0.005);
  // The noise it estimated, per axis: 0.2 % of the place and 1.5 degrees
  // (rotation_sigma carries the chordal term's sqrt(2)).
  EXPECT_NEAR(fit->centre_sigma / (0.002 * extent), 1.0, 0.35);
  EXPECT_NEAR(fit->rotation_sigma / (std::sqrt(2.0) * 1.5 * M_PI / 180), 1.0, 0.35);
}

// A scan already in the place's frame, localised with that noise, cannot
// be told from the identity (a chi-square with 7 degrees of freedom: under
// 18.5 in 99 % of cases); a scan turned by 0.5 degrees and shifted by 1 %
// of the place can.
TEST(SimilarityTest, IdentityLikelihoodRatioTellsANoisyIdentityFromASmallMove) {
  int below = 0;
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    std::mt19937_64 rng(seed);
    const std::vector<PosePair> pairs = NoisyOrbit(Similarity(), 8, 0.004, 1.0, &rng);
    absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, 8, RobustSimilarityOptions());
    ASSERT_TRUE(fit.ok()) << fit.status();
    const double ratio = IdentityLikelihoodRatio(*fit, pairs);
    EXPECT_GE(ratio, 0.0);
    below += ratio <= 18.5;
  }
  EXPECT_GE(below, 18);
  Similarity moved;
  moved.rotation = Eigen::AngleAxisd(0.5 * M_PI / 180, Eigen::Vector3d(1, 2, 0).normalized()).toRotationMatrix();
  moved.translation = Eigen::Vector3d(0.08, 0, 0);
  std::mt19937_64 rng(1);
  const std::vector<PosePair> pairs = NoisyOrbit(moved, 8, 0.004, 1.0, &rng);
  absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, 8, RobustSimilarityOptions());
  ASSERT_TRUE(fit.ok()) << fit.status();
  EXPECT_GT(IdentityLikelihoodRatio(*fit, pairs), 100.0);
  // Without a noise estimate (fewer than 3 frames) the ratio is infinite.
  RobustSimilarity none;
  EXPECT_TRUE(std::isinf(IdentityLikelihoodRatio(none, pairs)));
}

TEST(SimilarityTest, FitRefusesCollinearAndMismatchedPoints) {
  std::vector<Eigen::Vector3d> line = {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}, {3, 3, 3}};
  EXPECT_TRUE(absl::IsFailedPrecondition(FitSimilarity(line, line).status()));
  EXPECT_TRUE(absl::IsInvalidArgument(FitSimilarity(line, {{0, 0, 0}}).status()));
}

// Frames known in both frames, 30% of them localised wrongly (as frames of a
// part of the place that changed can be): the robust fit ignores them.
TEST(SimilarityTest, RobustFitIgnoresWronglyPlacedFrames) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  const Similarity truth = RandomSimilarity(&rng);
  std::vector<PosePair> pairs;
  std::vector<bool> bad;
  for (int i = 0; i < 20; ++i) {
    PosePair p;
    p.from = RandomPose(&rng);
    p.to = truth.ApplyToPose(p.from);
    const bool wrong = i % 10 < 3;
    if (wrong) p.to = RandomPose(&rng);
    pairs.push_back(p);
    bad.push_back(wrong);
  }
  absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, 4.0 * truth.scale, RobustSimilarityOptions());
  ASSERT_TRUE(fit.ok()) << fit.status();
  EXPECT_EQ(fit->inliers.size(), 14u);
  for (int i : fit->inliers) EXPECT_FALSE(bad[i]) << i;
  EXPECT_NEAR(fit->transform.scale, truth.scale, 1e-4 * truth.scale);
  EXPECT_LT(RotationAngleDegrees(fit->transform.rotation, truth.rotation), 1e-3);
}

// A straight walk: every centre on one line, which fixes no rotation about
// it; the cameras' own axes do.
TEST(SimilarityTest, RobustFitHoldsForCollinearCentres) {
  std::mt19937_64 rng(13);
  const Similarity truth = RandomSimilarity(&rng);
  std::vector<PosePair> pairs;
  for (int i = 0; i < 8; ++i) {
    PosePair p;
    p.from = RandomPose(&rng);
    p.from.col(3) = Eigen::Vector3f(0.25f * i, 0, 1);
    p.to = truth.ApplyToPose(p.from);
    pairs.push_back(p);
  }
  absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, 2.0 * truth.scale, RobustSimilarityOptions());
  ASSERT_TRUE(fit.ok()) << fit.status();
  EXPECT_EQ(fit->inliers.size(), 8u);
  EXPECT_LT(RotationAngleDegrees(fit->transform.rotation, truth.rotation), 1e-3);
  EXPECT_NEAR(fit->transform.scale, truth.scale, 1e-4 * truth.scale);
}

TEST(SimilarityTest, RobustFitNeedsTwoAgreeingFrames) {
  std::mt19937_64 rng(17);
  std::vector<PosePair> pairs;
  for (int i = 0; i < 3; ++i) pairs.push_back({RandomPose(&rng), RandomPose(&rng)});
  EXPECT_TRUE(absl::IsFailedPrecondition(FitSimilarityRobust(pairs, 1.0, RobustSimilarityOptions()).status()));
  EXPECT_TRUE(absl::IsFailedPrecondition(FitSimilarityRobust({pairs[0]}, 1.0, RobustSimilarityOptions()).status()));
}

}  // namespace
}  // namespace clnerf
