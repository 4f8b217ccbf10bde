// CameraRefiner's own arithmetic: the Adam step on per-photo corrections,
// the turn about the camera's centre, the bounds, and that only the named
// photos move. (The ray gradients it consumes are checked against central
// differences in trainer_test.cc; an update that refines a scan's cameras is
// tested in core/continual/continual_update_test.cc.)
#include "core/train/camera_refiner.h"

#include <cmath>
#include <vector>

#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

Camera CameraAt(const Eigen::Vector3f& c, float turn_deg) {
  Camera cam;
  cam.intrinsics.width = cam.intrinsics.height = 32;
  cam.intrinsics.fx = cam.intrinsics.fy = 30;
  cam.intrinsics.cx = cam.intrinsics.cy = 16;
  cam.c2w.leftCols<3>() = Eigen::AngleAxisf(turn_deg * float(M_PI) / 180, Eigen::Vector3f::UnitY()).toRotationMatrix();
  cam.c2w.col(3) = c;
  return cam;
}

double AngleDeg(const Eigen::Matrix3f& a, const Eigen::Matrix3f& b) {
  return Eigen::AngleAxisd((a.transpose() * b).cast<double>()).angle() * 180.0 / M_PI;
}

TEST(CameraRefinerTest, ValidatesItsOptions) {
  EXPECT_TRUE(CameraRefineOptions().Validate().ok());
  CameraRefineOptions o;
  o.learning_rate = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = CameraRefineOptions();
  o.max_rotation_deg = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = CameraRefineOptions();
  o.max_translation = NAN;
  EXPECT_FALSE(o.Validate().ok());
  o = CameraRefineOptions();
  o.start_iteration = -1;
  EXPECT_FALSE(o.Validate().ok());
}

// Gradients of L = |c - c*|^2 / 2 + |d - d*|^2 / 2 for one ray per photo
// (its axis d): the refiner walks photo 0 to c* and turns its axis onto d*
// about its own centre; photo 1 is not refined and never moves.
TEST(CameraRefinerTest, DescendsToTheTargetPoseAndMovesOnlyRefinedPhotos) {
  const std::vector<Camera> cams = {CameraAt({0.1f, 0, 0.5f}, 0), CameraAt({-0.2f, 0, 0.4f}, 10)};
  CameraRefineOptions o;
  o.learning_rate = 2e-3f;
  CameraRefiner r(cams, {1, 0}, o);
  EXPECT_EQ(r.num_refined(), 1);
  EXPECT_TRUE(r.Refines(0));
  EXPECT_FALSE(r.Refines(1));
  EXPECT_FALSE(r.Refines(7));
  const Eigen::Vector3f c_target = cams[0].position() + Eigen::Vector3f(0.01f, -0.005f, 0.008f);
  const Eigen::Matrix3f R_target =
      Eigen::AngleAxisf(0.8f * float(M_PI) / 180, Eigen::Vector3f(1, 2, 0).normalized()) *
      cams[0].c2w.leftCols<3>();
  const Eigen::Vector3f axis_cam(0.3f, -0.2f, 1.0f);  // Two rays: their axes fix the turn.
  const Eigen::Vector3f axis_cam2(-0.4f, 0.1f, 1.0f);
  for (int step = 1; step <= 1500; ++step) {
    r.ZeroGradients();
    const Camera& now = r.camera(0);
    for (const Eigen::Vector3f& a : {axis_cam, axis_cam2}) {
      const Eigen::Vector3f d = (now.c2w.leftCols<3>() * a).normalized();
      const Eigen::Vector3f d_star = (R_target * a).normalized();
      r.AddRayGradient(0, d, now.position() - c_target, d - d_star);
      r.AddRayGradient(1, d, Eigen::Vector3f::Ones(), Eigen::Vector3f::Ones());  // Ignored.
    }
    ASSERT_TRUE(r.Step(step, step < 1000 ? 1.0f : 0.1f));
  }
  EXPECT_LT((r.camera(0).position() - c_target).norm(), 2e-4);
  EXPECT_LT(AngleDeg(r.camera(0).c2w.leftCols<3>(), R_target), 0.02);
  // The turn is about the camera's centre: the rotation changes nothing else.
  EXPECT_NEAR(r.rotation_deg(0), 0.8, 0.02);
  EXPECT_NEAR(r.translation(0), (c_target - cams[0].position()).norm(), 2e-4);
  EXPECT_EQ(r.camera(1).c2w, cams[1].c2w);
  EXPECT_EQ(r.rotation_deg(1), 0.0);
  EXPECT_EQ(r.clamped(), 0);
  EXPECT_NE(r.Summary().find("1 photos"), std::string::npos);
}

TEST(CameraRefinerTest, CorrectionsStopAtTheirBoundsAndSayIt) {
  const std::vector<Camera> cams = {CameraAt({0, 0, 0.5f}, 0)};
  CameraRefineOptions o;
  o.learning_rate = 1e-2f;
  o.max_rotation_deg = 1.0f;
  o.max_translation = 0.02f;
  CameraRefiner r(cams, {1}, o);
  for (int step = 1; step <= 200; ++step) {
    r.ZeroGradients();
    // Always pushes the same way: +x shift and a turn about y, without end.
    r.AddRayGradient(0, Eigen::Vector3f::UnitZ(), Eigen::Vector3f(-1, 0, 0), Eigen::Vector3f(-1, 0, 0));
    ASSERT_TRUE(r.Step(step, 1.0f));
  }
  EXPECT_NEAR(r.rotation_deg(0), 1.0, 1e-6);
  EXPECT_NEAR(r.translation(0), 0.02, 1e-6);
  EXPECT_EQ(r.clamped(), 1);
  EXPECT_GT(r.camera(0).position().x(), 0.0f);
}

TEST(CameraRefinerTest, NonFiniteGradientMovesNothing) {
  const std::vector<Camera> cams = {CameraAt({0, 0, 0.5f}, 0)};
  CameraRefiner r(cams, {1}, CameraRefineOptions());
  r.ZeroGradients();
  r.AddRayGradient(0, Eigen::Vector3f::UnitZ(), Eigen::Vector3f(NAN, 0, 0), Eigen::Vector3f::Zero());
  EXPECT_FALSE(r.Step(1, 1.0f));
  EXPECT_EQ(r.camera(0).c2w, cams[0].c2w);
}

}  // namespace
}  // namespace clnerf
