// client/camera_path: nerfstudio camera_path.json and --pose parsing.
#include "client/camera_path.h"

#include <cmath>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

// A nerfstudio-style path: two cameras at z = 4 and x = 4 looking at the
// origin (OpenGL convention), 60 degree vertical FOV, 160x90.
constexpr const char* kPath = R"({
  "keyframes": [], "camera_type": "perspective", "render_height": 90, "render_width": 160,
  "fps": 24, "seconds": 1, "smoothness_value": 0.5, "is_cycle": false,
  "camera_path": [
    {"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,4, 0,0,0,1], "fov": 60, "aspect": 1.7777778},
    {"camera_to_world": [0,0,1,4, 0,1,0,0, -1,0,0,0, 0,0,0,1], "fov": 60, "aspect": 1.7777778}
  ]})";

TEST(CameraPathTest, ParsesNerfstudioPath) {
  absl::StatusOr<std::vector<Camera>> cams = ParseNerfstudioCameraPath(kPath);
  ASSERT_TRUE(cams.ok()) << cams.status();
  ASSERT_EQ(cams->size(), 2u);
  const Camera& c = (*cams)[0];
  EXPECT_EQ(c.intrinsics.width, 160);
  EXPECT_EQ(c.intrinsics.height, 90);
  const float f = 45.0f / std::tan(30.0f * 3.14159265f / 180.0f);  // (H/2) / tan(fov/2).
  EXPECT_NEAR(c.intrinsics.fx, f, 1e-3);
  EXPECT_NEAR(c.intrinsics.fy, f, 1e-3);
  EXPECT_FLOAT_EQ(c.intrinsics.cx, 80.0f);
  EXPECT_FLOAT_EQ(c.intrinsics.cy, 45.0f);
  // Both cameras look at the origin: the centre ray goes through it.
  for (const Camera& cam : *cams) {
    Eigen::Vector3f o, d;
    cam.Ray(cam.intrinsics.cx, cam.intrinsics.cy, &o, &d);
    EXPECT_NEAR(o.norm(), 4.0f, 1e-5);
    EXPECT_NEAR((o + 4.0f * d).norm(), 0.0f, 1e-5);
  }
  // OpenGL y up = OpenCV y down: the image's "down" axis is world -y.
  EXPECT_NEAR(c.c2w(1, 1), -1.0f, 1e-6);
}

TEST(CameraPathTest, NestedMatrixAndWidthFromAspect) {
  absl::StatusOr<std::vector<Camera>> cams = ParseNerfstudioCameraPath(R"({
    "render_height": 100,
    "camera_path": [{"camera_to_world": [[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]], "fov": 50, "aspect": 1.5}]})");
  ASSERT_TRUE(cams.ok()) << cams.status();
  EXPECT_EQ((*cams)[0].intrinsics.width, 150);
}

TEST(CameraPathTest, RejectsBadInput) {
  EXPECT_FALSE(ParseNerfstudioCameraPath("not json").ok());
  EXPECT_FALSE(ParseNerfstudioCameraPath(R"({"render_height": 9, "render_width": 9, "camera_path": []})").ok());
  // Missing fov.
  EXPECT_FALSE(ParseNerfstudioCameraPath(
                   R"({"render_height": 9, "render_width": 9,
                       "camera_path": [{"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}]})")
                   .ok());
  // Not a rotation.
  EXPECT_FALSE(ParseNerfstudioCameraPath(
                   R"({"render_height": 9, "render_width": 9,
                       "camera_path": [{"camera_to_world": [2,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1], "fov": 50}]})")
                   .ok());
  // Unsupported projection.
  EXPECT_FALSE(ParseNerfstudioCameraPath(
                   R"({"camera_type": "equirectangular", "render_height": 9, "render_width": 18,
                       "camera_path": [{"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1], "fov": 50}]})")
                   .ok());
  EXPECT_EQ(LoadNerfstudioCameraPath("/nonexistent/camera_path.json").status().code(), absl::StatusCode::kNotFound);
}

TEST(CameraPathTest, PoseCamera) {
  absl::StatusOr<Camera> cam = ParsePoseCamera("1 0 0 0, 0 1 0 0, 0 0 1 4", 64, 48, 0);
  ASSERT_TRUE(cam.ok()) << cam.status();
  EXPECT_EQ(cam->intrinsics.width, 64);
  EXPECT_NEAR(cam->intrinsics.fx, 0.5f * 64 / std::tan(0.5f * 0.6911112f), 1e-3);
  EXPECT_NEAR(cam->position().z(), 4.0f, 1e-6);
  EXPECT_FALSE(ParsePoseCamera("1 0 0", 64, 48, 0).ok());
  EXPECT_FALSE(ParsePoseCamera("1 0 0 0 0 1 0 0 0 0 1 x", 64, 48, 0).ok());
  EXPECT_FALSE(ParsePoseCamera("1 0 0 0 0 1 0 0 0 0 1 0 1 0 0 1", 64, 48, 0).ok());  // Bad bottom row.
}

}  // namespace
}  // namespace clnerf
