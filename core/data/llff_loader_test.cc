#include "core/data/llff_loader.h"

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <unistd.h>

#include "core/data/dataset.h"
#include "core/data/image.h"
#include "core/data/scene.h"
#include "Eigen/Geometry"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

// One poses_bounds.npy row: a camera given by its OpenCV camera-to-world
// rotation and centre, written in LLFF's [down, right, backwards] axes.
struct Row {
  Eigen::Matrix3d r_opencv;
  Eigen::Vector3d centre;
  double h, w, f, near, far;
};

std::vector<double> RowValues(const Row& row) {
  Eigen::Matrix<double, 3, 5> m;
  m.col(0) = row.r_opencv.col(1);   // down
  m.col(1) = row.r_opencv.col(0);   // right
  m.col(2) = -row.r_opencv.col(2);  // backwards
  m.col(3) = row.centre;
  m.col(4) = Eigen::Vector3d(row.h, row.w, row.f);
  std::vector<double> v;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 5; ++c) v.push_back(m(r, c));  // Row-major, as numpy's C order.
  v.push_back(row.near);
  v.push_back(row.far);
  return v;
}

std::string NpyFile(const std::vector<double>& values, int rows, bool float32) {
  std::string header = "{'descr': '" + std::string(float32 ? "<f4" : "<f8") +
                       "', 'fortran_order': False, 'shape': (" + std::to_string(rows) + ", " +
                       std::to_string(rows == 0 ? 17 : values.size() / rows) + "), }";
  while ((10 + header.size() + 1) % 64 != 0) header.push_back(' ');
  header.push_back('\n');
  std::string out = "\x93NUMPY\x01";
  out.push_back(0);
  const uint16_t len = uint16_t(header.size());
  out.append(reinterpret_cast<const char*>(&len), 2);
  out += header;
  for (double v : values) {
    if (float32) {
      const float f = float(v);
      out.append(reinterpret_cast<const char*>(&f), 4);
    } else {
      out.append(reinterpret_cast<const char*>(&v), 8);
    }
  }
  return out;
}

class LlffLoaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("clnerf_llff_" + std::to_string(getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name()) /
           "fern";
    fs::remove_all(dir_.parent_path());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_.parent_path()); }

  void WritePoses(const std::vector<Row>& rows, bool float32 = false,
                  const fs::path& where = fs::path()) {
    std::vector<double> values;
    for (const Row& r : rows) {
      const std::vector<double> v = RowValues(r);
      values.insert(values.end(), v.begin(), v.end());
    }
    std::ofstream(where.empty() ? dir_ / "poses_bounds.npy" : where, std::ios::binary)
        << NpyFile(values, int(rows.size()), float32);
  }
  void WriteImages(const fs::path& folder, int n, int w, int h) {
    for (int i = 0; i < n; ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "IMG_%04d.png", 100 + i);
      ASSERT_TRUE(WriteImage((folder / name).string(), Image(w, h, 0.1f * i)).ok());
    }
  }

  fs::path dir_;
};

// Calibration for 16x12 originals (h = 12, w = 16, f = 20).
Row MakeRow(const Eigen::Matrix3d& r, const Eigen::Vector3d& c) { return {r, c, 12, 16, 20, 2, 8}; }

TEST_F(LlffLoaderTest, ConvertsDownRightBackToOpenCV) {
  // Row 0 by hand: LLFF columns down = +x, right = +y, backwards = +z, i.e.
  // the OpenCV camera's right = +y, down = +x, forward = -z.
  std::vector<double> row0 = {1, 0, 0, 1, 12,  //
                              0, 1, 0, 2, 16,  //
                              0, 0, 1, 3, 20,  //
                              2, 8};
  const Eigen::Matrix3d r1 = (Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()) *
                              Eigen::AngleAxisd(-1.1, Eigen::Vector3d(1, 2, 3).normalized()))
                                 .toRotationMatrix();
  const std::vector<double> row1 = RowValues(MakeRow(r1, {-1, 0.5, 4}));
  for (bool float32 : {false, true}) {
    SCOPED_TRACE(float32 ? "float32" : "float64");
    std::vector<double> values = row0;
    values.insert(values.end(), row1.begin(), row1.end());
    std::ofstream(dir_ / "poses_bounds.npy", std::ios::binary) << NpyFile(values, 2, float32);
    WriteImages(dir_ / "images", 2, 16, 12);
    DatasetOptions opts;
    opts.test_every = 0;
    absl::StatusOr<Scene> scene = LoadLlffScene(dir_.string(), opts);
    ASSERT_TRUE(scene.ok()) << scene.status();
    ASSERT_EQ(scene->train.size(), 2u);
    EXPECT_EQ(scene->kind, SceneKind::kUnbounded);
    EXPECT_EQ(scene->background, Eigen::Vector3f::Zero());
    const View& a = scene->train[0];
    EXPECT_EQ(a.name, "images/IMG_0100.png");
    Pose expected;
    expected << 0, 1, 0, 1,  //
        1, 0, 0, 2,          //
        0, 0, -1, 3;
    EXPECT_TRUE(a.camera.c2w.isApprox(expected)) << a.camera.c2w;
    const Intrinsics& in = a.camera.intrinsics;
    EXPECT_EQ(in.width, 16);
    EXPECT_EQ(in.height, 12);
    EXPECT_FLOAT_EQ(in.fx, 20);
    EXPECT_FLOAT_EQ(in.fy, 20);
    EXPECT_FLOAT_EQ(in.cx, 8);
    EXPECT_FLOAT_EQ(in.cy, 6);
    EXPECT_FALSE(in.has_distortion());
    EXPECT_EQ(a.image.width, 16);

    const Camera& b = scene->train[1].camera;
    EXPECT_TRUE(b.c2w.leftCols<3>().isApprox(r1.cast<float>(), 1e-6f)) << b.c2w;
    EXPECT_TRUE(b.position().isApprox(Eigen::Vector3f(-1, 0.5f, 4), 1e-6f));
    EXPECT_NEAR(b.c2w.leftCols<3>().determinant(), 1.0f, 1e-5f);

    // Content: on each optical axis at near = 2 and sqrt(2 * 8) = 4.
    ASSERT_EQ(scene->content_points.size(), 4u);
    EXPECT_TRUE(scene->content_points[0].isApprox(Eigen::Vector3f(1, 2, 1)));
    EXPECT_TRUE(scene->content_points[1].isApprox(Eigen::Vector3f(1, 2, -1)));
    const Eigen::Vector3f fwd = r1.col(2).cast<float>();
    EXPECT_TRUE(
        scene->content_points[3].isApprox(Eigen::Vector3f(-1, 0.5f, 4) + 4.0f * fwd, 1e-6f));
    EXPECT_TRUE(ValidateScene(*scene).ok()) << ValidateScene(*scene);
  }
}

TEST_F(LlffLoaderTest, IntrinsicsFollowTheImagesRead) {
  const int n = 10;
  std::vector<Row> rows;
  for (int i = 0; i < n; ++i) rows.push_back(MakeRow(Eigen::Matrix3d::Identity(), {0.1 * i, 0, 0}));
  WritePoses(rows);
  WriteImages(dir_ / "images", n, 8, 6);  // Half the calibrated size.
  WriteImages(dir_ / "images_4", n, 4, 3);
  struct Case {
    float downscale;
    std::string images_dir;
    bool load_images;
    std::string folder;
    int width, height;
    float f;
  };
  const Case cases[] = {
      {1, "", true, "images", 8, 6, 10},
      {1, "", false, "images", 8, 6, 10},  // Size from the headers.
      {4, "", true, "images_4", 4, 3, 5},
      {1, "images_4", false, "images_4", 4, 3, 5},
      {2, "", true, "images", 4, 3, 5},  // No images_2: images/ shrunk by 2.
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.folder + " downscale " + std::to_string(c.downscale));
    DatasetOptions opts;
    opts.downscale = c.downscale;
    opts.images_dir = c.images_dir;
    opts.load_images = c.load_images;
    absl::StatusOr<Scene> scene = LoadLlffScene(dir_.string(), opts);
    ASSERT_TRUE(scene.ok()) << scene.status();
    // Every 8th view from the first is a test view.
    ASSERT_EQ(scene->test.size(), 2u);
    ASSERT_EQ(scene->train.size(), 8u);
    EXPECT_EQ(scene->test[1].name, c.folder + "/IMG_0108.png");
    EXPECT_FLOAT_EQ(scene->test[1].camera.position().x(), 0.8f);
    EXPECT_EQ(scene->train[0].name, c.folder + "/IMG_0101.png");
    const Intrinsics& in = scene->train[0].camera.intrinsics;
    EXPECT_EQ(in.width, c.width);
    EXPECT_EQ(in.height, c.height);
    EXPECT_FLOAT_EQ(in.fx, c.f);
    EXPECT_FLOAT_EQ(in.fy, c.f);
    EXPECT_FLOAT_EQ(in.cx, 0.5f * c.width);
    EXPECT_FLOAT_EQ(in.cy, 0.5f * c.height);
    EXPECT_EQ(scene->train[0].image.width, c.load_images ? c.width : 0);
    EXPECT_TRUE(ValidateScene(*scene).ok()) << ValidateScene(*scene);
  }
}

// beer_2's layout: <scene>/source/poses_bounds.npy with <scene>/images; and
// LoadScene() detecting the format.
TEST_F(LlffLoaderTest, ImagesAboveThePosesAndDetection) {
  fs::create_directories(dir_ / "source");
  WritePoses({MakeRow(Eigen::Matrix3d::Identity(), {0, 0, 0}),
              MakeRow(Eigen::Matrix3d::Identity(), {1, 0, 0})},
             false, dir_ / "source" / "poses_bounds.npy");
  WriteImages(dir_ / "images", 2, 16, 12);
  const std::string source = (dir_ / "source").string();
  EXPECT_EQ(*DetectDatasetFormat(source), DatasetFormat::kLlff);
  EXPECT_STREQ(DatasetFormatName(DatasetFormat::kLlff), "llff");
  DatasetOptions opts;
  opts.test_every = 0;
  absl::StatusOr<Scene> scene = LoadScene(source, opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->name, "source");
  ASSERT_EQ(scene->train.size(), 2u);
  EXPECT_EQ(scene->train[1].name, "../images/IMG_0101.png");
  EXPECT_EQ(scene->train[1].image.width, 16);
  // A complete COLMAP model beside it takes precedence (cameras alone, as
  // LLFF's sparse/0 often keeps, do not: issue 39); a transforms.json even more.
  fs::create_directories(dir_ / "source" / "sparse" / "0");
  std::ofstream(dir_ / "source" / "sparse" / "0" / "cameras.bin") << "";
  EXPECT_EQ(*DetectDatasetFormat(source), DatasetFormat::kLlff);
  std::ofstream(dir_ / "source" / "sparse" / "0" / "images.bin") << "";
  EXPECT_EQ(*DetectDatasetFormat(source), DatasetFormat::kColmap);
  std::ofstream(dir_ / "source" / "transforms.json") << "{}";
  EXPECT_EQ(*DetectDatasetFormat(source), DatasetFormat::kInstantNgp);
}

TEST_F(LlffLoaderTest, Errors) {
  const std::string dir = dir_.string();
  EXPECT_EQ(LoadLlffScene((dir_ / "nope").string()).status().code(), absl::StatusCode::kNotFound);
  absl::Status s = LoadLlffScene(dir).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(s.message().find("poses_bounds.npy"), std::string::npos) << s;
  DatasetOptions bad;
  bad.test_every = -1;
  EXPECT_FALSE(bad.Validate().ok());

  const auto expect_invalid = [&](const std::string& what) {
    absl::Status st = LoadLlffScene(dir).status();
    EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << what;
    EXPECT_NE(st.message().find(what), std::string::npos) << st;
  };
  // Wrong shape: 15 columns (no bounds).
  std::ofstream(dir_ / "poses_bounds.npy", std::ios::binary)
      << NpyFile(std::vector<double>(30, 1.0), 2, false);
  expect_invalid("(N, 17)");
  // Bad dtype.
  std::string npy = NpyFile(RowValues(MakeRow(Eigen::Matrix3d::Identity(), {0, 0, 0})), 1, false);
  std::string int_npy = npy;
  int_npy.replace(int_npy.find("<f8"), 3, "<i8");
  std::ofstream(dir_ / "poses_bounds.npy", std::ios::binary) << int_npy;
  expect_invalid("poses_bounds.npy");

  // Missing images folder, then a count mismatch.
  WritePoses({MakeRow(Eigen::Matrix3d::Identity(), {0, 0, 0}),
              MakeRow(Eigen::Matrix3d::Identity(), {1, 0, 0})});
  EXPECT_EQ(LoadLlffScene(dir).status().code(), absl::StatusCode::kNotFound);
  WriteImages(dir_ / "images", 3, 16, 12);
  expect_invalid("3 images");
  fs::remove(dir_ / "images" / "IMG_0102.png");
  EXPECT_TRUE(LoadLlffScene(dir).ok());

  // Non-positive focal length or bounds.
  Row r = MakeRow(Eigen::Matrix3d::Identity(), {0, 0, 0});
  r.f = 0;
  WritePoses({r, r});
  expect_invalid("h, w, f");
  r = MakeRow(Eigen::Matrix3d::Identity(), {0, 0, 0});
  r.near = 5;
  r.far = 1;
  WritePoses({r, r});
  expect_invalid("bounds");

  // Images of the wrong aspect ratio.
  WritePoses({MakeRow(Eigen::Matrix3d::Identity(), {0, 0, 0}),
              MakeRow(Eigen::Matrix3d::Identity(), {1, 0, 0})});
  ASSERT_TRUE(WriteImage((dir_ / "images" / "IMG_0101.png").string(), Image(12, 16)).ok());
  expect_invalid("aspect");
}

}  // namespace
}  // namespace clnerf
