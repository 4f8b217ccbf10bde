#include "core/data/colmap_loader.h"

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <unistd.h>

#include "core/data/image.h"
#include "core/data/scene.h"
#include "Eigen/Geometry"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

struct Cam {
  uint32_t id;
  std::string model;
  int32_t model_id;
  uint64_t w, h;
  std::vector<double> params;
};
struct Img {
  uint32_t id;
  Eigen::Quaterniond q;  // World-to-camera rotation.
  Eigen::Vector3d t;
  uint32_t cam;
  std::string name;
};

// An image whose camera sits at `center` with camera-to-world rotation `r_c2w`.
Img MakeImg(uint32_t id, const std::string& name, const Eigen::Vector3d& center,
            const Eigen::Matrix3d& r_c2w = Eigen::Matrix3d::Identity(), uint32_t cam = 1) {
  const Eigen::Matrix3d r_w2c = r_c2w.transpose();
  return {id, Eigen::Quaterniond(r_w2c), -r_w2c * center, cam, name};
}

template <typename T>
void Put(std::string* out, T v) {
  out->append(reinterpret_cast<const char*>(&v), sizeof(T));
}

class ColmapLoaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("clnerf_colmap_" + std::to_string(getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  void WriteImages(const std::vector<Img>& imgs, int w = 8, int h = 6,
                   const std::string& folder = "images") {
    for (const Img& im : imgs) {
      ASSERT_TRUE(WriteImage((dir_ / folder / im.name).string(), Image(w, h, 0.5f)).ok());
    }
  }

  void WriteText(const std::vector<Cam>& cams, const std::vector<Img>& imgs,
                 const std::string& sub = "sparse/0") {
    fs::create_directories(dir_ / sub);
    std::ofstream c(dir_ / sub / "cameras.txt");
    c << "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, "
         "PARAMS[]\n";
    for (const Cam& cam : cams) {
      c << cam.id << " " << cam.model << " " << cam.w << " " << cam.h;
      for (double p : cam.params) c << " " << p;
      c << "\n";
    }
    std::ofstream i(dir_ / sub / "images.txt");
    i.precision(17);
    i << "# Image list with two lines of data per image:\n";
    for (size_t k = 0; k < imgs.size(); ++k) {
      const Img& im = imgs[k];
      i << im.id << " " << im.q.w() << " " << im.q.x() << " " << im.q.y() << " " << im.q.z() << " "
        << im.t.x() << " " << im.t.y() << " " << im.t.z() << " " << im.cam << " " << im.name
        << "\n";
      // Alternate empty and non-empty POINTS2D lines.
      i << (k % 2 ? "1.5 2.5 -1 3.0 4.0 7\n" : "\n");
    }
  }

  void WriteBinary(const std::vector<Cam>& cams, const std::vector<Img>& imgs,
                   const std::string& sub = "sparse/0") {
    fs::create_directories(dir_ / sub);
    std::string c;
    Put<uint64_t>(&c, cams.size());
    for (const Cam& cam : cams) {
      Put<int32_t>(&c, int32_t(cam.id));
      Put<int32_t>(&c, cam.model_id);
      Put<uint64_t>(&c, cam.w);
      Put<uint64_t>(&c, cam.h);
      for (double p : cam.params) Put<double>(&c, p);
    }
    std::ofstream(dir_ / sub / "cameras.bin", std::ios::binary) << c;
    std::string i;
    Put<uint64_t>(&i, imgs.size());
    for (const Img& im : imgs) {
      Put<uint32_t>(&i, im.id);
      for (double v : {im.q.w(), im.q.x(), im.q.y(), im.q.z(), im.t.x(), im.t.y(), im.t.z()})
        Put(&i, v);
      Put<uint32_t>(&i, im.cam);
      i.append(im.name).push_back('\0');
      Put<uint64_t>(&i, 2);  // Two 2D points.
      for (int p = 0; p < 2; ++p) {
        Put<double>(&i, 1.0 + p);
        Put<double>(&i, 2.0);
        Put<int64_t>(&i, p == 0 ? -1 : 5);
      }
    }
    images_bin_ = i;
    std::ofstream(dir_ / sub / "images.bin", std::ios::binary) << i;
  }

  static DatasetOptions NoTest() {
    DatasetOptions o;
    o.test_every = 0;
    return o;
  }

  fs::path dir_;
  std::string images_bin_;
};

const std::vector<Cam> kCams = {
    {1, "PINHOLE", 1, 8, 6, {10, 11, 4.5, 2.5}},
    {2, "OPENCV", 4, 8, 6, {12, 13, 4, 3, 0.1, 0.01, 0.001, 0.002}},
};

TEST_F(ColmapLoaderTest, TextAndBinaryGiveTheSameCamerasAndPoses) {
  const Eigen::Matrix3d r_c2w =
      Eigen::AngleAxisd(0.5 * std::numbers::pi, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const std::vector<Img> imgs = {MakeImg(1, "a.png", {1, 2, 3}, r_c2w, 1),
                                 MakeImg(2, "b.png", {0, 0, -4}, Eigen::Matrix3d::Identity(), 2)};
  WriteImages(imgs);
  WriteText(kCams, imgs);
  absl::StatusOr<Scene> text = LoadColmapScene(dir_.string(), NoTest());
  ASSERT_TRUE(text.ok()) << text.status();
  fs::remove_all(dir_ / "sparse");
  WriteBinary(kCams, imgs);
  absl::StatusOr<Scene> bin = LoadColmapScene(dir_.string(), NoTest());
  ASSERT_TRUE(bin.ok()) << bin.status();

  for (const Scene* s : {&*text, &*bin}) {
    ASSERT_EQ(s->train.size(), 2u);
    EXPECT_TRUE(s->test.empty());
    EXPECT_EQ(s->kind, SceneKind::kUnbounded);
    EXPECT_EQ(s->background, Eigen::Vector3f::Zero());
    EXPECT_EQ(s->world_scale_hint, 0.0f);
    const View& a = s->train[0];
    EXPECT_EQ(a.name, "images/a.png");
    EXPECT_EQ(a.camera.intrinsics.width, 8);
    EXPECT_FLOAT_EQ(a.camera.intrinsics.fx, 10.0f);
    EXPECT_FLOAT_EQ(a.camera.intrinsics.fy, 11.0f);
    EXPECT_FLOAT_EQ(a.camera.intrinsics.cx, 4.5f);
    EXPECT_FLOAT_EQ(a.camera.intrinsics.cy, 2.5f);
    EXPECT_FALSE(a.camera.intrinsics.has_distortion());
    // Camera centre = -R^T t, rotation = R^T.
    EXPECT_TRUE(a.camera.position().isApprox(Eigen::Vector3f(1, 2, 3), 1e-5f))
        << a.camera.position();
    EXPECT_TRUE(a.camera.c2w.leftCols<3>().isApprox(r_c2w.cast<float>(), 1e-5f));
    const Intrinsics& b = s->train[1].camera.intrinsics;
    EXPECT_FLOAT_EQ(b.fx, 12.0f);
    EXPECT_FLOAT_EQ(b.k1, 0.1f);
    EXPECT_FLOAT_EQ(b.k2, 0.01f);
    EXPECT_FLOAT_EQ(b.p1, 0.001f);
    EXPECT_FLOAT_EQ(b.p2, 0.002f);
    // Identity world-to-camera rotation: OpenCV camera at z=-4 looks along +z, at the origin.
    const Camera& cb = s->train[1].camera;
    EXPECT_NEAR(cb.c2w.col(2).dot(-cb.position().normalized()), 1.0f, 1e-6);
    EXPECT_TRUE(s->content_points.empty());  // No points3D file.
    EXPECT_TRUE(ValidateScene(*s).ok());
  }
}

TEST_F(ColmapLoaderTest, RadialModelsMapToIntrinsics) {
  const std::vector<Cam> cams = {{1, "SIMPLE_PINHOLE", 0, 8, 6, {9, 4, 3}},
                                 {2, "SIMPLE_RADIAL", 2, 8, 6, {9, 4, 3, 0.2}},
                                 {3, "RADIAL", 3, 8, 6, {9, 4, 3, 0.2, 0.03}}};
  const std::vector<Img> imgs = {MakeImg(1, "a.png", {0, 0, -4}, Eigen::Matrix3d::Identity(), 1),
                                 MakeImg(2, "b.png", {0, 0, -4}, Eigen::Matrix3d::Identity(), 2),
                                 MakeImg(3, "c.png", {0, 0, -4}, Eigen::Matrix3d::Identity(), 3)};
  WriteBinary(cams, imgs);
  DatasetOptions opts = NoTest();
  opts.load_images = false;
  absl::StatusOr<Scene> scene = LoadColmapScene(dir_.string(), opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->train.size(), 3u);
  const Intrinsics& a = scene->train[0].camera.intrinsics;
  EXPECT_FLOAT_EQ(a.fx, 9.0f);
  EXPECT_FLOAT_EQ(a.fy, 9.0f);
  EXPECT_FLOAT_EQ(a.cy, 3.0f);
  EXPECT_FALSE(a.has_distortion());
  EXPECT_FLOAT_EQ(scene->train[1].camera.intrinsics.k1, 0.2f);
  EXPECT_FLOAT_EQ(scene->train[1].camera.intrinsics.k2, 0.0f);
  EXPECT_FLOAT_EQ(scene->train[2].camera.intrinsics.k2, 0.03f);
  EXPECT_TRUE(scene->train[0].image.empty());
}

TEST_F(ColmapLoaderTest, SubfoldersAreTimeStepsAndTestSplitPerStep) {
  std::vector<Img> imgs;
  uint32_t id = 1;
  imgs.push_back(MakeImg(id++, "top.png", {0, 0, -4}));
  for (int i = 9; i >= 0; --i)
    imgs.push_back(MakeImg(id++, "2/" + std::to_string(i) + ".png", {0, 0, -4}));
  for (int i = 0; i < 3; ++i)
    imgs.push_back(MakeImg(id++, "10/" + std::to_string(i) + ".png", {0, 0, -4}));
  WriteImages(imgs, 4, 4);
  const std::vector<Cam> cams = {{1, "PINHOLE", 1, 4, 4, {5, 5, 2, 2}}};
  WriteText(cams, imgs, "sparse");                               // No "0" subfolder.
  absl::StatusOr<Scene> scene = LoadColmapScene(dir_.string());  // test_every = 8.
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->num_time_steps(), 3);
  // Test: top.png, 2/0, 2/8, 10/0.
  ASSERT_EQ(scene->test.size(), 4u);
  EXPECT_EQ(scene->test[0].name, "images/top.png");
  EXPECT_EQ(scene->test[0].camera.time_step, 0);
  EXPECT_EQ(scene->test[1].name, "images/2/0.png");
  EXPECT_EQ(scene->test[2].name, "images/2/8.png");
  EXPECT_EQ(scene->test[2].camera.time_step, 1);
  EXPECT_EQ(scene->test[3].name, "images/10/0.png");
  EXPECT_EQ(scene->test[3].camera.time_step, 2);  // Natural order: "2" < "10".
  ASSERT_EQ(scene->train.size(), 10u);
  EXPECT_EQ(scene->train[0].name, "images/2/1.png");
  EXPECT_EQ(scene->train.back().name, "images/10/2.png");
}

// Calibration for 16x12 originals; images/, images_2/, images_4/ hold them at
// full, half and quarter size, as LLFF and mip-NeRF 360 ship them.
TEST_F(ColmapLoaderTest, DownscaledFoldersScaleIntrinsicsFromTheImageSize) {
  const std::vector<Cam> cams = {{1, "PINHOLE", 1, 16, 12, {20, 22, 8, 6}}};
  const std::vector<Img> imgs = {MakeImg(1, "a.png", {0, 0, -4}), MakeImg(2, "b.png", {1, 0, -4})};
  WriteBinary(cams, imgs);
  WriteImages(imgs, 16, 12, "images");
  WriteImages(imgs, 8, 6, "images_2");
  WriteImages(imgs, 4, 3, "images_4");
  struct Case {
    float downscale;
    std::string images_dir;
    bool load_images;
    std::string name;
    int width, height;
    float fx, fy, cx, cy;
  };
  const Case cases[] = {
      {1, "", true, "images/a.png", 16, 12, 20, 22, 8, 6},
      {2, "", true, "images_2/a.png", 8, 6, 10, 11, 4, 3},
      {4, "", true, "images_4/a.png", 4, 3, 5, 5.5f, 2, 1.5f},
      {2, "", false, "images_2/a.png", 8, 6, 10, 11, 4, 3},  // Size from the header.
      {1, "images_4", true, "images_4/a.png", 4, 3, 5, 5.5f, 2, 1.5f},
      // No images_8: images/ shrunk by 8 (16x12 -> 2x2 after rounding 1.5).
      {8, "", true, "images/a.png", 2, 2, 2.5f, 22.0f / 6, 1, 1},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name + " downscale " + std::to_string(c.downscale));
    DatasetOptions opts = NoTest();
    opts.downscale = c.downscale;
    opts.images_dir = c.images_dir;
    opts.load_images = c.load_images;
    absl::StatusOr<Scene> scene = LoadColmapScene(dir_.string(), opts);
    ASSERT_TRUE(scene.ok()) << scene.status();
    ASSERT_EQ(scene->train.size(), 2u);
    const View& v = scene->train[0];
    EXPECT_EQ(v.name, c.name);
    const Intrinsics& in = v.camera.intrinsics;
    EXPECT_EQ(in.width, c.width);
    EXPECT_EQ(in.height, c.height);
    EXPECT_FLOAT_EQ(in.fx, c.fx);
    EXPECT_FLOAT_EQ(in.fy, c.fy);
    EXPECT_FLOAT_EQ(in.cx, c.cx);
    EXPECT_FLOAT_EQ(in.cy, c.cy);
    EXPECT_EQ(v.image.width, c.load_images ? c.width : 0);
    EXPECT_TRUE(ValidateScene(*scene).ok()) << ValidateScene(*scene);
  }
}

// beer_2's layout: the model in <scene>/source/sparse/0, calibrated for the
// originals, and halved images in <scene>/images.
TEST_F(ColmapLoaderTest, ModelInASubfolderFindsTheImagesAboveIt) {
  const std::vector<Cam> cams = {{1, "SIMPLE_RADIAL", 2, 16, 12, {20, 8, 6, 0.05}}};
  const std::vector<Img> imgs = {MakeImg(1, "a.png", {0, 0, -4}), MakeImg(2, "b.png", {1, 0, -4})};
  WriteBinary(cams, imgs, "source/sparse/0");
  const std::string source = (dir_ / "source").string();

  // Without images and without load_images: the calibration's own size.
  DatasetOptions opts = NoTest();
  opts.load_images = false;
  absl::StatusOr<Scene> scene = LoadColmapScene(source, opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->train[0].camera.intrinsics.width, 16);
  EXPECT_FLOAT_EQ(scene->train[0].camera.intrinsics.fx, 20);

  WriteImages(imgs, 8, 6, "images");
  for (bool load : {true, false}) {
    opts.load_images = load;
    scene = LoadColmapScene(source, opts);
    ASSERT_TRUE(scene.ok()) << scene.status();
    const View& v = scene->train[1];
    EXPECT_EQ(v.name, "../images/b.png");
    EXPECT_EQ(v.camera.intrinsics.width, 8);
    EXPECT_EQ(v.camera.intrinsics.height, 6);
    EXPECT_FLOAT_EQ(v.camera.intrinsics.fx, 10);
    EXPECT_FLOAT_EQ(v.camera.intrinsics.fy, 10);
    EXPECT_FLOAT_EQ(v.camera.intrinsics.cx, 4);
    EXPECT_FLOAT_EQ(v.camera.intrinsics.k1, 0.05f);
    EXPECT_TRUE(v.camera.position().isApprox(Eigen::Vector3f(1, 0, -4), 1e-6f));
  }
  // The same through an explicit folder.
  opts.images_dir = "../images";
  scene = LoadColmapScene(source, opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_FLOAT_EQ(scene->train[0].camera.intrinsics.fx, 10);

  // An image of the wrong shape (rotated) is named.
  ASSERT_TRUE(WriteImage((dir_ / "images" / "b.png").string(), Image(6, 8, 0.5f)).ok());
  opts.load_images = true;
  absl::Status s = LoadColmapScene(source, opts).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("b.png"), std::string::npos) << s;
  EXPECT_NE(s.message().find("aspect"), std::string::npos) << s;
}

TEST_F(ColmapLoaderTest, Points3DBecomeContentPoints) {
  const std::vector<Img> imgs = {MakeImg(1, "a.png", {0, 0, -4})};
  const std::vector<Eigen::Vector3d> pts = {{1.5, -2, 3}, {0.25, 0, -1e3}};
  DatasetOptions opts = NoTest();
  opts.load_images = false;

  WriteBinary(kCams, imgs);
  std::string bin;
  Put<uint64_t>(&bin, pts.size());
  for (size_t i = 0; i < pts.size(); ++i) {
    Put<uint64_t>(&bin, 10 + i);
    for (int k = 0; k < 3; ++k) Put<double>(&bin, pts[i][k]);
    bin.append("\x10\x20\x30", 3);  // RGB.
    Put<double>(&bin, 0.5);        // Reprojection error.
    Put<uint64_t>(&bin, i + 1);    // Track: (image id, point2D index) pairs.
    for (size_t t = 0; t <= i; ++t) {
      Put<uint32_t>(&bin, 1);
      Put<uint32_t>(&bin, uint32_t(t));
    }
  }
  std::ofstream(dir_ / "sparse/0/points3D.bin", std::ios::binary) << bin;
  absl::StatusOr<Scene> scene = LoadColmapScene(dir_.string(), opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->content_points.size(), 2u);
  for (size_t i = 0; i < pts.size(); ++i) {
    EXPECT_TRUE(scene->content_points[i].isApprox(pts[i].cast<float>())) << i;
  }
  // Truncated: INVALID_ARGUMENT naming the file.
  std::ofstream(dir_ / "sparse/0/points3D.bin", std::ios::binary) << bin.substr(0, bin.size() - 3);
  absl::Status s = LoadColmapScene(dir_.string(), opts).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("points3D.bin"), std::string::npos) << s;

  // Text model with points3D.txt.
  fs::remove_all(dir_ / "sparse");
  WriteText(kCams, imgs);
  std::ofstream(dir_ / "sparse/0/points3D.txt")
      << "# 3D point list with one line of data per point:\n"
      << "10 1.5 -2 3 16 32 48 0.5 1 0\n"
      << "11 0.25 0 -1000 0 0 0 0.1 1 0 1 1\n";
  scene = LoadColmapScene(dir_.string(), opts);
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->content_points.size(), 2u);
  EXPECT_TRUE(scene->content_points[1].isApprox(Eigen::Vector3f(0.25f, 0, -1000)));
  std::ofstream(dir_ / "sparse/0/points3D.txt") << "10 1.5 -2\n";
  s = LoadColmapScene(dir_.string(), opts).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("points3D.txt"), std::string::npos) << s;
}

TEST_F(ColmapLoaderTest, Errors) {
  EXPECT_EQ(LoadColmapScene((dir_ / "nope").string()).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(LoadColmapScene(dir_.string()).status().code(), absl::StatusCode::kNotFound);
  DatasetOptions bad;
  bad.downscale = 0;
  EXPECT_FALSE(bad.Validate().ok());

  const std::vector<Img> imgs = {MakeImg(1, "a.png", {0, 0, -4}), MakeImg(2, "b.png", {0, 0, -4})};
  // Missing image file.
  WriteBinary(kCams, imgs);
  absl::Status s = LoadColmapScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(s.message().find("a.png"), std::string::npos) << s;

  // Truncated images.bin, cut at several places.
  for (size_t cut : {size_t(4), size_t(20), images_bin_.size() - 5}) {
    std::ofstream(dir_ / "sparse/0/images.bin", std::ios::binary) << images_bin_.substr(0, cut);
    s = LoadColmapScene(dir_.string(), NoTest()).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << cut;
    EXPECT_NE(s.message().find("truncated"), std::string::npos) << s;
    EXPECT_NE(s.message().find("images.bin"), std::string::npos) << s;
  }

  // Unsupported camera model.
  fs::remove_all(dir_ / "sparse");
  WriteText({{1, "OPENCV_FISHEYE", 5, 8, 6, {9, 9, 4, 3, 0, 0, 0, 0}}}, imgs);
  s = LoadColmapScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("OPENCV_FISHEYE"), std::string::npos) << s;

  // Unknown camera id and a malformed line.
  WriteText(kCams, {MakeImg(1, "a.png", {0, 0, -4}, Eigen::Matrix3d::Identity(), 7)});
  EXPECT_EQ(LoadColmapScene(dir_.string()).status().code(), absl::StatusCode::kInvalidArgument);
  std::ofstream(dir_ / "sparse/0/cameras.txt") << "1 PINHOLE 8 6 10 11\n";
  s = LoadColmapScene(dir_.string()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("cameras.txt"), std::string::npos) << s;

  // NaN in a pose parses, and ValidateScene rejects it.
  WriteImages(imgs);
  WriteText(kCams, imgs);
  std::ofstream(dir_ / "sparse/0/images.txt") << "1 nan 0 0 0 0 0 4 1 a.png\n\n";
  absl::StatusOr<Scene> scene = LoadColmapScene(dir_.string(), NoTest());
  ASSERT_TRUE(scene.ok()) << scene.status();
  s = ValidateScene(*scene);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("NaN"), std::string::npos) << s;
}

}  // namespace
}  // namespace clnerf
