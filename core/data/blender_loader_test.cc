#include "core/data/blender_loader.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include "core/data/image.h"
#include "core/data/scene.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// A fresh directory per test, removed afterwards.
class BlenderLoaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("clnerf_blender_" + std::to_string(getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  void WriteRgb(const std::string& rel, int w, int h, float value = 0.25f) {
    ASSERT_TRUE(WriteImage((dir_ / rel).string(), Image(w, h, value)).ok());
  }
  void WriteJson(const std::string& rel, const json& j) { std::ofstream(dir_ / rel) << j.dump(2); }
  void WriteText(const std::string& rel, const std::string& text) {
    std::ofstream(dir_ / rel) << text;
  }

  // OpenGL camera at (0, 0, z) with identity rotation: it looks down -z, i.e.
  // at the origin.
  static json LookAtOriginFromZ(float z) {
    return json::array({{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, z}, {0, 0, 0, 1}});
  }
  static json Frame(const std::string& path, float z = 4.0f) {
    return {{"file_path", path}, {"transform_matrix", LookAtOriginFromZ(z)}};
  }

  fs::path dir_;
};

TEST_F(BlenderLoaderTest, IntrinsicsPoseAndSceneHints) {
  WriteRgb("train/r_0.png", 8, 6);
  WriteRgb("train/r_1.png", 8, 6);
  // The first path lacks its extension, as in NeRF-synthetic.
  WriteJson(
      "transforms_train.json",
      {{"camera_angle_x", 0.7}, {"frames", {Frame("./train/r_0"), Frame("train/r_1.png", 3)}}});
  absl::StatusOr<Scene> scene = LoadBlenderScene(dir_.string());
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->train.size(), 2u);
  EXPECT_TRUE(scene->val.empty());
  EXPECT_TRUE(scene->test.empty());
  EXPECT_EQ(scene->kind, SceneKind::kBounded);
  EXPECT_EQ(scene->background, Eigen::Vector3f::Ones());
  EXPECT_FLOAT_EQ(scene->world_scale_hint, 1.0f / 3.0f);
  EXPECT_EQ(scene->world_offset_hint, Eigen::Vector3f::Zero());

  const View& v = scene->train[0];
  EXPECT_EQ(v.name, "train/r_0.png");
  const Intrinsics& in = v.camera.intrinsics;
  EXPECT_EQ(in.width, 8);
  EXPECT_EQ(in.height, 6);
  EXPECT_NEAR(in.fx, 0.5 * 8 / std::tan(0.35), 1e-4);
  EXPECT_FLOAT_EQ(in.fy, in.fx);
  EXPECT_FLOAT_EQ(in.cx, 4.0f);
  EXPECT_FLOAT_EQ(in.cy, 3.0f);
  EXPECT_FALSE(in.has_distortion());
  EXPECT_EQ(v.image.width, 8);
  EXPECT_NEAR(v.image.rgb[0], 64.0f / 255.0f, 1e-6);

  // OpenCV +z (viewing direction) points from the camera toward the origin;
  // +y points down (OpenGL's +y was up).
  const Eigen::Vector3f to_origin = (-v.camera.position()).normalized();
  EXPECT_NEAR(v.camera.c2w.col(2).dot(to_origin), 1.0f, 1e-6);
  EXPECT_NEAR(v.camera.c2w.col(1).y(), -1.0f, 1e-6);
  EXPECT_NEAR(v.camera.position().z(), 4.0f, 1e-6);
  EXPECT_NEAR(scene->train[1].camera.position().z(), 3.0f, 1e-6);
  EXPECT_TRUE(ValidateScene(*scene).ok());
}

TEST_F(BlenderLoaderTest, RgbaIsCompositedOnWhite) {
  Image img(2, 1);
  img.pixel(0, 0)[0] = 1.0f;  // Opaque red, then fully transparent black.
  ASSERT_TRUE(WriteImageRGBA((dir_ / "a.png").string(), img, {1.0f, 0.0f}).ok());
  WriteJson("transforms_test.json", {{"camera_angle_x", 1.0}, {"frames", {Frame("a")}}});
  absl::StatusOr<Scene> scene = LoadBlenderScene(dir_.string());
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->test.size(), 1u);
  const Image& out = scene->test[0].image;
  EXPECT_FLOAT_EQ(out.pixel(0, 0)[0], 1.0f);
  EXPECT_FLOAT_EQ(out.pixel(0, 0)[1], 0.0f);
  for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(out.pixel(1, 0)[c], 1.0f);
}

TEST_F(BlenderLoaderTest, TimeStepMaskDownscaleAndLimits) {
  WriteRgb("a.png", 8, 6);
  WriteRgb("b.png", 8, 6);
  Image mask(8, 6, 0.0f);
  for (int y = 0; y < 6; ++y)
    for (int x = 0; x < 4; ++x) mask.pixel(x, y)[0] = 1.0f;  // Keep the left half.
  ASSERT_TRUE(WriteImage((dir_ / "a_mask.png").string(), mask).ok());
  json f0 = Frame("a.png");
  f0["time_step"] = 2;
  f0["mask_path"] = "a_mask.png";
  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"frames", {f0, Frame("b.png")}}});

  absl::StatusOr<Scene> full = LoadBlenderScene(dir_.string());
  ASSERT_TRUE(full.ok()) << full.status();
  EXPECT_EQ(full->train[0].camera.time_step, 2);
  EXPECT_EQ(full->train[1].camera.time_step, 0);
  EXPECT_EQ(full->num_time_steps(), 3);
  const Mask& m = full->train[0].mask;
  ASSERT_EQ(m.width, 8);
  EXPECT_EQ(m.keep[0], 1);
  EXPECT_EQ(m.keep[7], 0);
  EXPECT_TRUE(full->train[1].mask.empty());

  DatasetOptions opts;
  opts.downscale = 2.0f;
  opts.max_images_per_split = 1;
  absl::StatusOr<Scene> small = LoadBlenderScene(dir_.string(), opts);
  ASSERT_TRUE(small.ok()) << small.status();
  ASSERT_EQ(small->train.size(), 1u);
  const View& v = small->train[0];
  EXPECT_EQ(v.camera.intrinsics.width, 4);
  EXPECT_EQ(v.camera.intrinsics.height, 3);
  EXPECT_EQ(v.image.width, 4);
  EXPECT_EQ(v.mask.width, 4);
  EXPECT_NEAR(v.camera.intrinsics.fx, full->train[0].camera.intrinsics.fx / 2, 1e-4);
  EXPECT_FLOAT_EQ(v.camera.intrinsics.cx, 2.0f);
  EXPECT_TRUE(ValidateScene(*small).ok());

  opts = {};
  opts.load_images = false;
  absl::StatusOr<Scene> cams = LoadBlenderScene(dir_.string(), opts);
  ASSERT_TRUE(cams.ok()) << cams.status();
  EXPECT_TRUE(cams->train[0].image.empty());
  EXPECT_EQ(cams->train[1].camera.intrinsics.width, 8);
}

TEST_F(BlenderLoaderTest, Errors) {
  EXPECT_EQ(LoadBlenderScene((dir_ / "nope").string()).status().code(),
            absl::StatusCode::kNotFound);
  EXPECT_EQ(LoadBlenderScene(dir_.string()).status().code(), absl::StatusCode::kNotFound);

  DatasetOptions bad;
  bad.downscale = 0.5f;
  EXPECT_FALSE(bad.Validate().ok());
  EXPECT_EQ(LoadBlenderScene(dir_.string(), bad).status().code(),
            absl::StatusCode::kInvalidArgument);

  WriteText("transforms_train.json", "{\"camera_angle_x\": 0.7, \"frames\": [");
  absl::Status s = LoadBlenderScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("transforms_train.json"), std::string::npos) << s;

  WriteJson("transforms_train.json", {{"frames", {Frame("a.png")}}});
  s = LoadBlenderScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("camera_angle_x"), std::string::npos) << s;

  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"frames", {Frame("missing.png")}}});
  s = LoadBlenderScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(s.message().find("missing.png"), std::string::npos) << s;

  // NaN written by nlohmann becomes null; Python writes a bare NaN literal.
  WriteRgb("a.png", 4, 4);
  json f = Frame("a.png");
  f["transform_matrix"][0][0] = std::nan("");
  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"frames", {f}}});
  s = LoadBlenderScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("transform_matrix"), std::string::npos) << s;
  WriteText("transforms_train.json",
            R"({"camera_angle_x": 0.7, "frames": [{"file_path": "a.png", "transform_matrix":
               [[NaN, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]})");
  EXPECT_EQ(LoadBlenderScene(dir_.string()).status().code(), absl::StatusCode::kInvalidArgument);

  // A NaN that reaches a scene is rejected by ValidateScene.
  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"frames", {Frame("a.png")}}});
  absl::StatusOr<Scene> scene = LoadBlenderScene(dir_.string());
  ASSERT_TRUE(scene.ok()) << scene.status();
  scene->train[0].camera.c2w(1, 3) = std::nanf("");
  EXPECT_EQ(ValidateScene(*scene).code(), absl::StatusCode::kInvalidArgument);

  json bad_t = Frame("a.png");
  bad_t["time_step"] = -1;
  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"frames", {bad_t}}});
  s = LoadBlenderScene(dir_.string()).status();
  EXPECT_NE(s.message().find("time_step"), std::string::npos) << s;
}

TEST(BlenderLoaderRealDataTest, Lego100) {
  const fs::path dir = fs::path(CLNERF_SHARED_DATA_DIR) / "lego_100";
  if (!fs::exists(dir / "transforms_train.json")) GTEST_SKIP() << "no " << dir;
  absl::StatusOr<Scene> scene = LoadBlenderScene(dir.string());
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->train.size(), 100u);
  EXPECT_EQ(scene->val.size(), 100u);
  EXPECT_EQ(scene->test.size(), 200u);
  EXPECT_TRUE(ValidateScene(*scene).ok());
  const Normalization norm = ComputeNormalization(*scene);
  for (const View& v : scene->train) {
    EXPECT_EQ(v.image.width, 100);
    EXPECT_EQ(v.image.height, 100);
    EXPECT_NEAR(norm.ToModel(v.camera.position()).norm(), 4.0f / 3.0f, 0.03f) << v.name;
    // Every camera looks roughly at the object at the origin.
    EXPECT_GT(v.camera.c2w.col(2).dot(-v.camera.position().normalized()), 0.9f) << v.name;
  }
}

}  // namespace
}  // namespace clnerf
