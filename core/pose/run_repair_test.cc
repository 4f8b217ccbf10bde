#include "core/pose/run_repair.h"

#include <iostream>
#include <set>

#include "core/pose/pose_test_util.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(RunRepairTest, TurnedRunIsPutBack) {
  const std::vector<View> truth = testing_util::RenderedOrbit(5, 36);
  std::vector<View> views = truth;
  testing_util::TurnAboutTheScene(&views, 9, 16, 175);
  PoseCheckOptions po;
  po.max_features = 1500;
  // The repair takes the pairs' rotations from either estimator; USAC's
  // check of these 36 frames takes 4 s instead of RANSAC's 12 (the default
  // estimator's answer on a turned run: PoseCheckTest).
  po.estimator = "usac";
  absl::StatusOr<PoseCheckReport> check = CheckPoses(views, po, 2);
  ASSERT_TRUE(check.ok()) << check.status();
  ASSERT_EQ(check->disputed.size(), 8u) << check->Summary();
  absl::StatusOr<RunRepair> repair = SolveRunRepair(*check, views);
  ASSERT_TRUE(repair.ok()) << repair.status();
  std::cout << repair->Summary() << "\n";
  EXPECT_NEAR(repair->turn_deg, 175.0, 2.0);
  Scene scene;
  scene.train = views;
  ApplyRunRepair(*repair, DisputedNames(*check, views), &scene);
  // The run is back where it was filmed: within 2 degrees, and 3 % of the
  // orbit's diameter (8 units), from two-view poses of 320 x 240 renders.
  for (int i = 9; i <= 16; ++i) {
    EXPECT_LT(RotationAngleDegrees(scene.train[i].camera.c2w.leftCols<3>().cast<double>(),
                                   truth[i].camera.c2w.leftCols<3>().cast<double>()), 2.0) << i;
    EXPECT_LT((scene.train[i].camera.position() - truth[i].camera.position()).norm(), 0.24) << i;
  }
  for (int i : {0, 8, 17, 35}) EXPECT_EQ(scene.train[i].camera.c2w, views[i].camera.c2w) << "kept frame moved";
}

TEST(RunRepairTest, NothingDisputedIsRefused) {
  PoseCheckReport report;
  EXPECT_TRUE(absl::IsFailedPrecondition(SolveRunRepair(report, {}).status()));
  RunRepairOptions o;
  o.min_pairs = 1;
  EXPECT_TRUE(absl::IsInvalidArgument(o.Validate()));
}

}  // namespace
}  // namespace clnerf
