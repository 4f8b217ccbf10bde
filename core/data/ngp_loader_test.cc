#include "core/data/ngp_loader.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include "core/data/image.h"
#include "core/data/scene.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

class NgpLoaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("clnerf_ngp_" + std::to_string(getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  void WriteRgb(const std::string& rel, int w = 8, int h = 6) {
    ASSERT_TRUE(WriteImage((dir_ / rel).string(), Image(w, h, 0.5f)).ok());
  }
  // A mask whose left `keep_cols` columns are white.
  void WriteMaskImage(const std::string& rel, int keep_cols) {
    Image m(8, 6, 0.0f);
    for (int y = 0; y < 6; ++y)
      for (int x = 0; x < keep_cols; ++x)
        m.pixel(x, y)[0] = m.pixel(x, y)[1] = m.pixel(x, y)[2] = 1;
    ASSERT_TRUE(WriteImage((dir_ / rel).string(), m).ok());
  }
  void WriteJson(const std::string& rel, const json& j) { std::ofstream(dir_ / rel) << j.dump(2); }

  static json Frame(const std::string& path, float x = 0.0f) {
    return {{"file_path", path},
            {"transform_matrix", {{1, 0, 0, x}, {0, 1, 0, 0}, {0, 0, 1, 4}, {0, 0, 0, 1}}}};
  }
  static DatasetOptions NoTest() {
    DatasetOptions o;
    o.test_every = 0;
    return o;
  }

  fs::path dir_;
};

TEST_F(NgpLoaderTest, GlobalIntrinsicsPerFrameOverridesAndDistortion) {
  WriteRgb("images/0.png");
  WriteRgb("images/1.png");
  json f1 = Frame("images/1.png");
  f1["fl_x"] = 20.0;
  f1["k1"] = 0.0;
  f1["time_step"] = 1;
  WriteJson("transforms.json", {{"fl_x", 10.0},
                                {"fl_y", 11.0},
                                {"cx", 4.5},
                                {"cy", 2.5},
                                {"w", 8},
                                {"h", 6},
                                {"k1", 0.1},
                                {"k2", 0.01},
                                {"p1", 0.001},
                                {"p2", 0.002},
                                {"aabb_scale", 4},
                                {"frames", {Frame("images/0.png"), f1}}});
  absl::StatusOr<Scene> scene = LoadNgpScene(dir_.string(), NoTest());
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->train.size(), 2u);
  EXPECT_TRUE(scene->test.empty());
  EXPECT_EQ(scene->kind, SceneKind::kUnbounded);
  EXPECT_EQ(scene->background, Eigen::Vector3f::Zero());
  EXPECT_FLOAT_EQ(scene->aabb_scale, 4.0f);
  EXPECT_FLOAT_EQ(scene->world_scale_hint, 0.33f);
  EXPECT_EQ(scene->world_offset_hint, Eigen::Vector3f::Zero());

  const Intrinsics& a = scene->train[0].camera.intrinsics;
  EXPECT_EQ(a.width, 8);
  EXPECT_EQ(a.height, 6);
  EXPECT_FLOAT_EQ(a.fx, 10.0f);
  EXPECT_FLOAT_EQ(a.fy, 11.0f);
  EXPECT_FLOAT_EQ(a.cx, 4.5f);
  EXPECT_FLOAT_EQ(a.cy, 2.5f);
  EXPECT_FLOAT_EQ(a.k1, 0.1f);
  EXPECT_FLOAT_EQ(a.k2, 0.01f);
  EXPECT_FLOAT_EQ(a.p1, 0.001f);
  EXPECT_FLOAT_EQ(a.p2, 0.002f);
  const Intrinsics& b = scene->train[1].camera.intrinsics;
  EXPECT_FLOAT_EQ(b.fx, 20.0f);
  EXPECT_FLOAT_EQ(b.fy, 11.0f);
  EXPECT_FLOAT_EQ(b.k1, 0.0f);
  EXPECT_FLOAT_EQ(b.k2, 0.01f);
  EXPECT_EQ(scene->train[1].camera.time_step, 1);
  EXPECT_EQ(scene->train[0].camera.time_step, 0);

  // OpenGL -> OpenCV: the camera at +z looks toward the origin.
  const Camera& cam = scene->train[0].camera;
  EXPECT_NEAR(cam.c2w.col(2).dot(-cam.position().normalized()), 1.0f, 1e-6);
  EXPECT_TRUE(ValidateScene(*scene).ok());
}

TEST_F(NgpLoaderTest, CameraAngleFallbackAndSizeFromImage) {
  WriteRgb("a.jpg");
  WriteJson("transforms.json",
            {{"camera_angle_x", 1.0}, {"camera_angle_y", 0.8}, {"frames", {Frame("a.jpg")}}});
  absl::StatusOr<Scene> scene = LoadNgpScene(dir_.string(), NoTest());
  ASSERT_TRUE(scene.ok()) << scene.status();
  const Intrinsics& in = scene->train[0].camera.intrinsics;
  EXPECT_EQ(in.width, 8);
  EXPECT_NEAR(in.fx, 0.5 * 8 / std::tan(0.5), 1e-4);
  EXPECT_NEAR(in.fy, 0.5 * 6 / std::tan(0.4), 1e-4);
  EXPECT_FLOAT_EQ(in.cx, 4.0f);
  EXPECT_FLOAT_EQ(in.cy, 3.0f);
}

TEST_F(NgpLoaderTest, TestEverySplitSortsByPath) {
  json frames = json::array();
  for (int i : {4, 2, 0, 3, 1}) {
    WriteRgb("f" + std::to_string(i) + ".png");
    frames.push_back(Frame("f" + std::to_string(i) + ".png", float(i)));
  }
  WriteJson("transforms.json", {{"fl_x", 10.0}, {"frames", frames}});
  DatasetOptions opts;
  opts.test_every = 2;
  absl::StatusOr<Scene> scene = LoadNgpScene(dir_.string(), opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->test.size(), 3u);
  EXPECT_EQ(scene->test[0].name, "f0.png");
  EXPECT_EQ(scene->test[1].name, "f2.png");
  EXPECT_EQ(scene->test[2].name, "f4.png");
  ASSERT_EQ(scene->train.size(), 2u);
  EXPECT_EQ(scene->train[0].name, "f1.png");
  EXPECT_FLOAT_EQ(scene->train[1].camera.position().x(), 3.0f);
}

TEST_F(NgpLoaderTest, ExplicitSplitKeyAndSplitFiles) {
  WriteRgb("a.png");
  WriteRgb("b.png");
  WriteRgb("c.png");
  json a = Frame("a.png"), b = Frame("b.png"), c = Frame("c.png");
  b["split"] = "test";
  c["split"] = "val";
  WriteJson("transforms.json", {{"fl_x", 10.0}, {"frames", {a, b, c}}});
  absl::StatusOr<Scene> scene = LoadNgpScene(dir_.string());  // test_every ignored.
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->train.size(), 1u);
  EXPECT_EQ(scene->val.size(), 1u);
  ASSERT_EQ(scene->test.size(), 1u);
  EXPECT_EQ(scene->test[0].name, "b.png");

  c["split"] = "holdout";
  WriteJson("transforms.json", {{"fl_x", 10.0}, {"frames", {a, b, c}}});
  absl::Status s = LoadNgpScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("split"), std::string::npos) << s;

  // Per-split instant-ngp files take precedence over transforms.json.
  WriteJson("transforms_train.json", {{"fl_x", 10.0}, {"scale", 0.5}, {"frames", {a, b}}});
  WriteJson("transforms_test.json", {{"fl_x", 12.0}, {"frames", {c}}});
  scene = LoadNgpScene(dir_.string());
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->train.size(), 2u);
  ASSERT_EQ(scene->test.size(), 1u);
  EXPECT_FLOAT_EQ(scene->test[0].camera.intrinsics.fx, 12.0f);
  EXPECT_FLOAT_EQ(scene->world_scale_hint, 0.5f);
}

TEST_F(NgpLoaderTest, MaskPathAndDynamicMasksCombine) {
  WriteRgb("images/a.png");
  WriteRgb("images/b.png");
  WriteMaskImage("masks/a.png", 6);                // keep x < 6
  WriteMaskImage("images/dynamic_mask_a.png", 2);  // exclude x < 2
  WriteMaskImage("images/dynamic_mask_b.png", 3);  // exclude x < 3
  json a = Frame("images/a.png");
  a["mask_path"] = "masks/a.png";
  WriteJson("transforms.json", {{"fl_x", 10.0}, {"frames", {a, Frame("images/b.png")}}});
  absl::StatusOr<Scene> scene = LoadNgpScene(dir_.string(), NoTest());
  ASSERT_TRUE(scene.ok()) << scene.status();
  const Mask& ma = scene->train[0].mask;
  ASSERT_EQ(ma.width, 8);
  for (int x = 0; x < 8; ++x) EXPECT_EQ(ma.keep[x], x >= 2 && x < 6) << x;
  const Mask& mb = scene->train[1].mask;
  ASSERT_EQ(mb.width, 8);
  for (int x = 0; x < 8; ++x) EXPECT_EQ(mb.keep[8 + x], x >= 3) << x;
}

TEST_F(NgpLoaderTest, HintsBoundedAndDownscale) {
  WriteRgb("a.png");
  WriteJson(
      "transforms.json",
      {{"fl_x", 10.0}, {"scale", 0.5}, {"offset", {0.6, 0.5, 0.5}}, {"frames", {Frame("a.png")}}});
  DatasetOptions opts = NoTest();
  opts.ngp_bounded = true;
  opts.downscale = 2;
  absl::StatusOr<Scene> scene = LoadNgpScene(dir_.string(), opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->kind, SceneKind::kBounded);
  EXPECT_EQ(scene->background, Eigen::Vector3f::Ones());
  EXPECT_FLOAT_EQ(scene->aabb_scale, 1.0f);
  EXPECT_FLOAT_EQ(scene->world_scale_hint, 0.5f);
  // x_ngp = x * 0.5 + 0.6 is the box centre 0.5 at x = -0.2.
  EXPECT_NEAR(scene->world_offset_hint.x(), -0.2f, 1e-6);
  EXPECT_NEAR(scene->world_offset_hint.y(), 0.0f, 1e-6);
  const Intrinsics& in = scene->train[0].camera.intrinsics;
  EXPECT_EQ(in.width, 4);
  EXPECT_FLOAT_EQ(in.fx, 5.0f);
  EXPECT_EQ(scene->train[0].image.height, 3);
}

TEST_F(NgpLoaderTest, Errors) {
  EXPECT_EQ(LoadNgpScene((dir_ / "nope").string()).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(LoadNgpScene(dir_.string()).status().code(), absl::StatusCode::kNotFound);
  DatasetOptions bad;
  bad.test_every = -1;
  EXPECT_FALSE(bad.Validate().ok());

  std::ofstream(dir_ / "transforms.json") << "{\"frames\": [}";
  absl::Status s = LoadNgpScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("transforms.json"), std::string::npos) << s;

  WriteJson("transforms.json", {{"fl_x", 10.0}, {"frames", {Frame("missing.png")}}});
  s = LoadNgpScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(s.message().find("missing.png"), std::string::npos) << s;

  WriteRgb("a.png");
  const auto expect_invalid = [&](const json& doc, const std::string& word) {
    WriteJson("transforms.json", doc);
    absl::Status st = LoadNgpScene(dir_.string()).status();
    EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << word;
    EXPECT_NE(st.message().find(word), std::string::npos) << st;
  };
  expect_invalid({{"frames", {Frame("a.png")}}}, "focal");
  expect_invalid({{"fl_x", "ten"}, {"frames", {Frame("a.png")}}}, "fl_x");
  expect_invalid({{"fl_x", 10.0}, {"k3", 0.1}, {"frames", {Frame("a.png")}}}, "k3");
  expect_invalid({{"fl_x", 10.0}, {"camera_model", "OPENCV_FISHEYE"}, {"frames", {Frame("a.png")}}},
                 "camera_model");
  expect_invalid({{"fl_x", 10.0}, {"w", 16}, {"h", 6}, {"frames", {Frame("a.png")}}}, "'w'/'h'");
  json nan_frame = Frame("a.png");
  nan_frame["transform_matrix"][2][3] = std::nan("");  // Serialised as null.
  expect_invalid({{"fl_x", 10.0}, {"frames", {nan_frame}}}, "transform_matrix");
}

TEST(NgpLoaderRealDataTest, Fox8) {
  const fs::path dir = fs::path(CLNERF_SHARED_DATA_DIR) / "fox_8";
  if (!fs::exists(dir / "transforms.json")) GTEST_SKIP() << "no " << dir;
  json doc = json::parse(std::ifstream(dir / "transforms.json"));
  const size_t num_frames = doc["frames"].size();
  absl::StatusOr<Scene> scene = LoadNgpScene(dir.string());
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->train.size() + scene->test.size(), num_frames);
  EXPECT_EQ(scene->test.size(), (num_frames + 7) / 8);
  EXPECT_EQ(scene->kind, SceneKind::kUnbounded);
  EXPECT_FLOAT_EQ(scene->aabb_scale, doc["aabb_scale"].get<float>());
  for (const View& v : scene->train) {
    EXPECT_EQ(v.image.width, 135);
    EXPECT_EQ(v.image.height, 240);
    EXPECT_TRUE(v.camera.intrinsics.has_distortion());
    EXPECT_FLOAT_EQ(v.camera.intrinsics.fx, doc["fl_x"].get<float>());
  }
  EXPECT_TRUE(ValidateScene(*scene).ok()) << ValidateScene(*scene);
}

}  // namespace
}  // namespace clnerf
