#include "core/colmap_loader.h"

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <unistd.h>

#include "core/image.h"
#include "core/scene.h"
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

  void WriteImages(const std::vector<Img>& imgs, int w = 8, int h = 6) {
    for (const Img& im : imgs) {
      ASSERT_TRUE(WriteImage((dir_ / "images" / im.name).string(), Image(w, h, 0.5f)).ok());
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

  static ColmapLoadOptions NoTest() {
    ColmapLoadOptions o;
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
  ColmapLoadOptions opts = NoTest();
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

TEST_F(ColmapLoaderTest, Errors) {
  EXPECT_EQ(LoadColmapScene((dir_ / "nope").string()).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(LoadColmapScene(dir_.string()).status().code(), absl::StatusCode::kNotFound);
  ColmapLoadOptions bad;
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
