#include "core/dataset.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include "core/image.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

class DatasetTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("clnerf_dataset_" + std::to_string(getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name()) /
           "my_scene";
    fs::remove_all(dir_.parent_path());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_.parent_path()); }

  void WriteRgb(const std::string& rel) {
    ASSERT_TRUE(WriteImage((dir_ / rel).string(), Image(8, 6, 0.5f)).ok());
  }
  void WriteJson(const std::string& rel, const json& j) { std::ofstream(dir_ / rel) << j.dump(); }
  static json Frame(const std::string& path) {
    return {{"file_path", path},
            {"transform_matrix", {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 4}, {0, 0, 0, 1}}}};
  }

  fs::path dir_;
};

TEST_F(DatasetTest, MissingOrEmptyDirectoryIsNotFound) {
  absl::Status s = LoadScene((dir_ / "nope").string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(s.message().find("nope"), std::string::npos) << s;
  s = LoadScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(s.message().find("transforms.json"), std::string::npos) << s;
  EXPECT_EQ(DetectDatasetFormat(dir_.string()).status().code(), absl::StatusCode::kNotFound);
}

TEST_F(DatasetTest, DetectsEachFormat) {
  fs::create_directories(dir_ / "sparse" / "0");
  std::ofstream(dir_ / "sparse" / "0" / "cameras.txt") << "";
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kColmap);
  WriteJson("transforms.json", {{"fl_x", 10}, {"frames", json::array()}});
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kInstantNgp);
  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"frames", json::array()}});
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kBlender);
  // instant-ngp style per-split files.
  WriteJson("transforms_train.json", {{"fl_x", 10}, {"frames", json::array()}});
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kInstantNgp);
  EXPECT_STREQ(DatasetFormatName(DatasetFormat::kColmap), "colmap");
}

TEST_F(DatasetTest, LoadsValidatesAndNamesTheScene) {
  WriteRgb("a.png");
  WriteRgb("b.png");
  WriteJson("transforms_train.json",
            {{"camera_angle_x", 0.7}, {"frames", {Frame("a"), Frame("b")}}});
  DatasetOptions opts;
  opts.downscale = 2;
  absl::StatusOr<Scene> scene = LoadScene(dir_.string() + "/", opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->name, "my_scene");
  ASSERT_EQ(scene->train.size(), 2u);
  EXPECT_EQ(scene->train[0].image.width, 4);

  // A frame whose rotation is not rigid is rejected by ValidateScene.
  json skewed = Frame("a");
  skewed["transform_matrix"][0][0] = 2.0;
  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"frames", {skewed}}});
  absl::Status s = LoadScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("orthonormal"), std::string::npos) << s;

  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"frames", json::array()}});
  EXPECT_EQ(LoadScene(dir_.string()).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST_F(DatasetTest, NanPoseFromColmapIsRejected) {
  WriteRgb("images/a.png");
  fs::create_directories(dir_ / "sparse");
  std::ofstream(dir_ / "sparse" / "cameras.txt") << "1 PINHOLE 8 6 10 10 4 3\n";
  std::ofstream(dir_ / "sparse" / "images.txt") << "1 1 0 0 0 nan 0 4 1 a.png\n\n";
  absl::Status s = LoadScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("NaN"), std::string::npos) << s;
  EXPECT_NE(s.message().find("colmap"), std::string::npos) << s;
}

TEST(DatasetOptionsTest, Validate) {
  EXPECT_TRUE(DatasetOptions().Validate().ok());
  DatasetOptions o;
  o.downscale = 0.5f;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.test_every = -1;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.max_images_per_split = -2;
  EXPECT_EQ(LoadScene("/nonexistent", o).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(DownscaleViewTest, ScalesIntrinsicsImageAndMask) {
  View v;
  v.camera.intrinsics = {.width = 9, .height = 6, .fx = 18, .fy = 12, .cx = 4.5f, .cy = 3};
  v.image = Image(9, 6, 1.0f);
  v.mask.width = 9;
  v.mask.height = 6;
  v.mask.keep.assign(54, 1);
  DownscaleView(3.0f, &v);
  EXPECT_EQ(v.camera.intrinsics.width, 3);
  EXPECT_EQ(v.camera.intrinsics.height, 2);
  EXPECT_FLOAT_EQ(v.camera.intrinsics.fx, 6.0f);
  EXPECT_FLOAT_EQ(v.camera.intrinsics.cy, 1.0f);
  EXPECT_EQ(v.image.width, 3);
  EXPECT_FLOAT_EQ(v.image.rgb[0], 1.0f);
  EXPECT_EQ(v.mask.keep.size(), 6u);
  EXPECT_EQ(v.mask.keep[5], 1);
  DownscaleView(1.0f, &v);  // No-op.
  EXPECT_EQ(v.camera.intrinsics.width, 3);
}

TEST(DatasetRealDataTest, LegoAndFox) {
  const fs::path root(CLNERF_SHARED_DATA_DIR);
  if (!fs::exists(root / "lego_100") || !fs::exists(root / "fox_8"))
    GTEST_SKIP() << "no data in " << root;
  EXPECT_EQ(*DetectDatasetFormat((root / "lego_100").string()), DatasetFormat::kBlender);
  EXPECT_EQ(*DetectDatasetFormat((root / "fox_8").string()), DatasetFormat::kInstantNgp);
  DatasetOptions opts;
  opts.load_images = false;
  absl::StatusOr<Scene> lego = LoadScene((root / "lego_100").string(), opts);
  ASSERT_TRUE(lego.ok()) << lego.status();
  EXPECT_EQ(lego->name, "lego_100");
  EXPECT_EQ(lego->train.size() + lego->val.size() + lego->test.size(), 400u);
  EXPECT_EQ(lego->test[0].camera.intrinsics.width, 100);
  absl::StatusOr<Scene> fox = LoadScene((root / "fox_8").string(), opts);
  ASSERT_TRUE(fox.ok()) << fox.status();
  EXPECT_EQ(fox->kind, SceneKind::kUnbounded);
  EXPECT_EQ(fox->train[0].camera.intrinsics.height, 240);
}

}  // namespace
}  // namespace clnerf
