#include "core/data/dataset.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include "core/data/colmap_loader.h"
#include "core/data/image.h"
#include "core/data/llff_loader.h"
#include "core/data/ngp_loader.h"
#include "Eigen/Geometry"

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
  // colmap2nerf writes Blender's camera_angle_x beside fl_x: still instant-ngp
  // (read as Blender, a real capture became a white-backed object box).
  WriteJson("transforms_train.json",
            {{"camera_angle_x", 0.7}, {"fl_x", 10}, {"aabb_scale", 32}, {"frames", json::array()}});
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kInstantNgp);
  WriteJson("transforms_train.json", {{"camera_angle_x", 0.7}, {"aabb_scale", 16}, {"frames", json::array()}});
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kInstantNgp);
  // Per-frame intrinsics count too.
  WriteJson("transforms_train.json",
            {{"camera_angle_x", 0.7}, {"frames", {{{"file_path", "a.png"}, {"fl_x", 10}, {"w", 4}}}}});
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kInstantNgp);
  EXPECT_STREQ(DatasetFormatName(DatasetFormat::kColmap), "colmap");
}

// An LLFF folder whose sparse/0 keeps cameras and points but no images file
// loads from poses_bounds.npy; a complete COLMAP model still wins, and an
// incomplete one without poses_bounds.npy goes to the COLMAP loader (which
// names what is missing).
TEST_F(DatasetTest, AnIncompleteColmapModelFallsBackToPosesBounds) {
  fs::create_directories(dir_ / "sparse" / "0");
  std::ofstream(dir_ / "sparse" / "0" / "cameras.bin") << "x";
  std::ofstream(dir_ / "sparse" / "0" / "points3D.bin") << "x";
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kColmap);
  std::ofstream(dir_ / "poses_bounds.npy") << "x";
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kLlff);
  std::ofstream(dir_ / "sparse" / "0" / "images.txt") << "";  // Another form than the cameras': incomplete.
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kLlff);
  std::ofstream(dir_ / "sparse" / "0" / "images.bin") << "x";
  EXPECT_EQ(*DetectDatasetFormat(dir_.string()), DatasetFormat::kColmap);
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

TEST(IntrinsicsTest, ScaledUsesTheRatioOfEachAxis) {
  Intrinsics in;
  in.width = 200;
  in.height = 100;
  in.fx = 150;
  in.fy = 160;
  in.cx = 100;
  in.cy = 50;
  in.k1 = 0.1f;
  const Intrinsics s = in.Scaled(50, 50);  // x by 1/4, y by 1/2.
  EXPECT_EQ(s.width, 50);
  EXPECT_EQ(s.height, 50);
  EXPECT_FLOAT_EQ(s.fx, 37.5f);
  EXPECT_FLOAT_EQ(s.cx, 25.0f);
  EXPECT_FLOAT_EQ(s.fy, 80.0f);
  EXPECT_FLOAT_EQ(s.cy, 25.0f);
  EXPECT_FLOAT_EQ(s.k1, 0.1f);
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

// Views of a scene keyed by image file name (the loaders name them relative
// to different roots).
std::map<std::string, const View*> ByFileName(const Scene& scene) {
  std::map<std::string, const View*> out;
  for (const auto* split : {&scene.train, &scene.val, &scene.test})
    for (const View& v : *split) out[fs::path(v.name).filename().string()] = &v;
  return out;
}

// How far two loadings of the same capture are from differing by a
// similarity transform: the largest angle (radians) between their relative
// rotations R_i^T R_j, and the spread (max/min - 1) of the ratios of their
// camera-centre distances |c_i - c_j|.
struct Agreement {
  double max_rotation_error = 0;
  double distance_ratio_spread = 0;
};
Agreement Compare(const std::vector<const View*>& a, const std::vector<const View*>& b) {
  Agreement out;
  double lo = 1e30, hi = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    for (size_t j = i + 1; j < a.size(); ++j) {
      const Eigen::Matrix3d ra_i = a[i]->camera.c2w.leftCols<3>().cast<double>();
      const Eigen::Matrix3d ra_j = a[j]->camera.c2w.leftCols<3>().cast<double>();
      const Eigen::Matrix3d rb_i = b[i]->camera.c2w.leftCols<3>().cast<double>();
      const Eigen::Matrix3d rb_j = b[j]->camera.c2w.leftCols<3>().cast<double>();
      const Eigen::Matrix3d diff = (ra_i.transpose() * ra_j).transpose() * (rb_i.transpose() * rb_j);
      out.max_rotation_error =
          std::max(out.max_rotation_error, Eigen::AngleAxisd(diff).angle());
      const double da = (a[i]->camera.position() - a[j]->camera.position()).cast<double>().norm();
      const double db = (b[i]->camera.position() - b[j]->camera.position()).cast<double>().norm();
      if (da < 1e-3 * (1 + db)) continue;  // Near-coincident cameras: ratio is noise.
      lo = std::min(lo, db / da);
      hi = std::max(hi, db / da);
    }
  }
  out.distance_ratio_spread = hi > 0 ? hi / lo - 1 : 0;
  return out;
}

// beer_2 ships one capture three ways (see its README): transforms.json
// (instant-ngp, OpenGL, normalised), source/sparse/0 (COLMAP, OpenCV,
// calibrated for 2x larger originals) and source/poses_bounds.npy (LLFF,
// down-right-back). Each loader's conversion must give the same cameras up to
// a similarity transform, and the same intrinsics for the 360x640 images.
TEST(DatasetRealDataTest, Beer2LoadersAgree) {
  const fs::path dir = fs::path(CLNERF_SHARED_DATA_DIR) / "beer_2";
  if (!fs::exists(dir / "transforms.json") || !fs::exists(dir / "source" / "poses_bounds.npy") ||
      !fs::exists(dir / "source" / "sparse" / "0"))
    GTEST_SKIP() << "no " << dir;
  EXPECT_EQ(*DetectDatasetFormat(dir.string()), DatasetFormat::kInstantNgp);
  EXPECT_EQ(*DetectDatasetFormat((dir / "source").string()), DatasetFormat::kColmap);

  DatasetOptions ngp_opts;
  ngp_opts.load_images = false;
  ngp_opts.test_every = 0;
  absl::StatusOr<Scene> ngp = LoadNgpScene(dir.string(), ngp_opts);
  ASSERT_TRUE(ngp.ok()) << ngp.status();
  DatasetOptions colmap_opts;
  colmap_opts.load_images = false;  // Sizes from the image headers.
  colmap_opts.test_every = 0;
  absl::StatusOr<Scene> colmap = LoadColmapScene((dir / "source").string(), colmap_opts);
  ASSERT_TRUE(colmap.ok()) << colmap.status();
  DatasetOptions llff_opts;
  llff_opts.load_images = false;
  llff_opts.test_every = 0;
  absl::StatusOr<Scene> llff = LoadLlffScene((dir / "source").string(), llff_opts);
  ASSERT_TRUE(llff.ok()) << llff.status();
  for (const Scene* s : {&*ngp, &*colmap, &*llff}) EXPECT_TRUE(ValidateScene(*s).ok());
  EXPECT_GT(colmap->content_points.size(), 1000u);  // points3D.bin.
  EXPECT_EQ(llff->content_points.size(), 2 * llff->train.size());

  const auto by_ngp = ByFileName(*ngp), by_colmap = ByFileName(*colmap),
             by_llff = ByFileName(*llff);
  ASSERT_EQ(by_ngp.size(), 71u);
  ASSERT_EQ(by_colmap.size(), by_ngp.size());
  ASSERT_EQ(by_llff.size(), by_ngp.size());
  std::vector<const View*> vn, vc, vl;
  double max_fx_ngp_colmap = 0, max_fx_llff_colmap = 0;
  for (const auto& [name, v] : by_ngp) {
    ASSERT_TRUE(by_colmap.count(name) && by_llff.count(name)) << name;
    vn.push_back(v);
    vc.push_back(by_colmap.at(name));
    vl.push_back(by_llff.at(name));
    const Intrinsics &n = v->camera.intrinsics, &c = vc.back()->camera.intrinsics,
                     &l = vl.back()->camera.intrinsics;
    for (const Intrinsics* in : {&n, &c, &l}) {
      EXPECT_EQ(in->width, 360) << name;
      EXPECT_EQ(in->height, 640) << name;
      EXPECT_NEAR(in->cx, 180, 0.5) << name;
      EXPECT_NEAR(in->cy, 320, 0.5) << name;
    }
    EXPECT_FLOAT_EQ(c.k1, n.k1) << name;
    max_fx_ngp_colmap = std::max(max_fx_ngp_colmap, std::abs(double(n.fx) / c.fx - 1));
    max_fx_llff_colmap = std::max(max_fx_llff_colmap, std::abs(double(l.fx) / c.fx - 1));
  }
  // Same frame, same focal length. LLFF's imgs2poses.py stores the first
  // camera's f for every row, while this COLMAP model has one camera per frame
  // (f spread 1102..1155 px at full size): only frame 0 must match there.
  EXPECT_LT(max_fx_ngp_colmap, 1e-5);
  EXPECT_NEAR(vl[0]->camera.intrinsics.fx / vc[0]->camera.intrinsics.fx, 1.0, 0.01);
  EXPECT_LT(max_fx_llff_colmap, 0.06);

  const Agreement cn = Compare(vc, vn), cl = Compare(vc, vl), nl = Compare(vn, vl);
  std::printf(
      "beer_2 agreement (max relative-rotation angle [rad], centre distance ratio spread):\n"
      "  colmap vs ngp : %.3g, %.3g\n  colmap vs llff: %.3g, %.3g\n  ngp vs llff   : %.3g, %.3g\n"
      "  fx: max |ngp/colmap - 1| = %.3g, llff/colmap frame 0 = %.6f, max |llff/colmap - 1| = "
      "%.3g\n",
      cn.max_rotation_error, cn.distance_ratio_spread, cl.max_rotation_error,
      cl.distance_ratio_spread, nl.max_rotation_error, nl.distance_ratio_spread,
      max_fx_ngp_colmap, vl[0]->camera.intrinsics.fx / vc[0]->camera.intrinsics.fx,
      max_fx_llff_colmap);
  // The measure itself: turning one camera by 0.01 rad and scaling the
  // centres by 3 shows up as a 0.01 rad error and no distance spread.
  std::vector<View> turned;
  for (const View* v : vc) turned.push_back(*v);
  for (View& v : turned) v.camera.c2w.col(3) *= 3.0f;
  turned[5].camera.c2w.leftCols<3>() =
      turned[5].camera.c2w.leftCols<3>() *
      Eigen::AngleAxisf(0.01f, Eigen::Vector3f(1, 2, 2).normalized()).toRotationMatrix();
  std::vector<const View*> vt;
  for (const View& v : turned) vt.push_back(&v);
  const Agreement ct = Compare(vc, vt);
  EXPECT_NEAR(ct.max_rotation_error, 0.01, 1e-4);
  EXPECT_LT(ct.distance_ratio_spread, 1e-5);
  for (const Agreement& g : {cn, cl, nl}) {
    EXPECT_LT(g.max_rotation_error, 1e-3);
    EXPECT_LT(g.distance_ratio_spread, 1e-3);
  }
  // An OpenGL/OpenCV mix-up would flip the viewing direction: each camera
  // must look at the content (COLMAP's points are in front of it on average).
  Eigen::Vector3f mean = Eigen::Vector3f::Zero();
  for (const Eigen::Vector3f& p : colmap->content_points) mean += p;
  mean /= float(colmap->content_points.size());
  double max_llff_colmap_pose = 0;
  for (size_t i = 0; i < vc.size(); ++i) {
    EXPECT_GT(vc[i]->camera.c2w.col(2).dot(mean - vc[i]->camera.position()), 0) << vc[i]->name;
    // LLFF's poses are COLMAP's with permuted axes, in the same world.
    max_llff_colmap_pose =
        std::max(max_llff_colmap_pose, double((vl[i]->camera.c2w - vc[i]->camera.c2w).norm()));
  }
  std::printf("  max |c2w_llff - c2w_colmap| = %.3g\n", max_llff_colmap_pose);
  EXPECT_LT(max_llff_colmap_pose, 1e-4);
}

TEST(DatasetNameTest, IsTheFolderNameWithOrWithoutATrailingSlash) {
  EXPECT_EQ(DatasetName("data/lego"), "lego");
  EXPECT_EQ(DatasetName("data/lego/"), "lego");
  EXPECT_EQ(DatasetName("./data/../scans/scan_001//"), "scan_001");
  EXPECT_EQ(DatasetName("/abs/path/beer_2"), "beer_2");
}

}  // namespace
}  // namespace clnerf
