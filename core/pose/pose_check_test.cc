#include "core/pose/pose_check.h"

#include <cmath>
#include <iostream>
#include <string>

#include "core/data/procedural_scene.h"
#include "core/pose/pose_test_util.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// A textured procedural place filmed like a phone video: `n` frames on one
// turn around it, 20 degrees up, in order.
std::vector<View> Render(uint64_t seed, int n) {
  ProceduralSceneOptions o = testing_util::ChangingScene(seed);
  o.textured = true;
  o.num_train_views = 1;
  o.num_test_views = 0;
  o.width = 320;
  o.height = 240;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(o);
  EXPECT_TRUE(scene.ok()) << scene.status();
  const ProceduralWorld world = ProceduralWorldAt(o, 0);
  std::vector<View> views;
  for (int i = 0; i < n; ++i) {
    const float az = 2 * float(M_PI) * float(i) / float(n), el = 20 * float(M_PI) / 180;
    const Eigen::Vector3f pos =
        o.camera_radius * Eigen::Vector3f(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    const Eigen::Vector3f forward = (-pos).normalized();
    const Eigen::Vector3f right = forward.cross(Eigen::Vector3f::UnitZ()).normalized();
    View v;
    v.name = "frame_" + std::to_string(i);
    v.camera = scene->train[0].camera;
    v.camera.c2w << right, forward.cross(right), forward, pos;  // OpenCV: x right, y down, z forward.
    v.image = RenderProceduralView(world, v.camera, 1, seed).image;
    views.push_back(std::move(v));
  }
  return views;
}

// The capture the tests share (rendered once).
const std::vector<View>& Capture() {
  static const std::vector<View>* views = new std::vector<View>(Render(5, 36));
  return *views;
}

// Fewer features than a phone photo needs: these are small and sharp.
PoseCheckOptions Options() {
  PoseCheckOptions o;
  o.max_features = 1500;
  return o;
}

// Turns views [first, last] by `deg` about the capture's up axis through the
// centre of its cameras: what SfM does to a run of frames of a scene that
// looks alike from opposite sides.
void TurnAboutTheScene(std::vector<View>* views, int first, int last, double deg) {
  Eigen::Vector3f centre = Eigen::Vector3f::Zero(), up = Eigen::Vector3f::Zero();
  for (const View& v : *views) {
    centre += v.camera.position();
    up -= v.camera.c2w.col(1);  // OpenCV: y points down.
  }
  centre /= float(views->size());  // One full turn: the place's centre.
  const Eigen::Matrix3f s = Eigen::AngleAxisf(float(deg * M_PI / 180), up.normalized()).toRotationMatrix();
  for (int i = first; i <= last; ++i) {
    Pose& c2w = (*views)[i].camera.c2w;
    c2w.leftCols<3>() = s * c2w.leftCols<3>();
    c2w.col(3) = s * (c2w.col(3) - centre) + centre;
  }
}

TEST(PoseCheckTest, CorrectPosesAgree) {
  const std::vector<View> views = Capture();
  absl::StatusOr<PoseCheckReport> r = CheckPoses(views, Options(), 2);
  ASSERT_TRUE(r.ok()) << r.status();
  std::cout << r->Summary() << "\n";
  EXPECT_GE(r->pairs.size(), 36u);
  // A pair's own rotation can be wrong (few matches, a repeated texture);
  // the grouping must absorb such pairs rather than dispute frames.
  EXPECT_LE(r->disagreeing_pairs, int(r->pairs.size()) / 10);
  EXPECT_LT(r->median_agreeing_deg, 3.0);
  EXPECT_TRUE(r->disputed.empty());
  EXPECT_FALSE(r->inconclusive);
}

TEST(PoseCheckTest, RunTurnedAboutTheSceneIsDisputed) {
  std::vector<View> views = Capture();
  TurnAboutTheScene(&views, 9, 16, 175);
  absl::StatusOr<PoseCheckReport> r = CheckPoses(views, Options(), 2);
  ASSERT_TRUE(r.ok()) << r.status();
  std::cout << r->Summary() << "\n";
  EXPECT_FALSE(r->inconclusive);
  EXPECT_EQ(r->disputed, (std::vector<int>{9, 10, 11, 12, 13, 14, 15, 16}));
  const std::vector<std::string> dropped = DropDisputed(*r, &views);
  EXPECT_EQ(dropped.size(), 8u);
  EXPECT_EQ(views.size(), 28u);
}

TEST(PoseCheckTest, SingleBadFrameIsDisputed) {
  std::vector<View> views = Capture();
  Pose& c2w = views[20].camera.c2w;
  c2w.leftCols<3>() = c2w.leftCols<3>() * Eigen::AngleAxisf(1.6f, Eigen::Vector3f::UnitY()).toRotationMatrix();
  absl::StatusOr<PoseCheckReport> r = CheckPoses(views, Options(), 2);
  ASSERT_TRUE(r.ok()) << r.status();
  std::cout << r->Summary() << "\n";
  EXPECT_EQ(r->disputed, (std::vector<int>{20}));
}

TEST(PoseCheckTest, BadInputIsRefused) {
  PoseCheckOptions o;
  o.min_inliers = 2;
  EXPECT_TRUE(absl::IsInvalidArgument(o.Validate()));
  o = PoseCheckOptions();
  o.sequence_neighbours = 0;
  EXPECT_TRUE(absl::IsInvalidArgument(o.Validate()));
  std::vector<View> views = Capture();
  views[3].image = Image();
  EXPECT_TRUE(absl::IsInvalidArgument(CheckPoses(views, PoseCheckOptions()).status()));
}

}  // namespace
}  // namespace clnerf
