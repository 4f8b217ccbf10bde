#include "core/data/procedural_scene.h"

#include <unistd.h>


#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "Eigen/Dense"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

ProceduralSceneOptions SmallOptions() {
  ProceduralSceneOptions o;
  o.width = 32;
  o.height = 32;
  o.num_train_views = 4;
  o.num_test_views = 2;
  o.num_time_steps = 2;
  o.seed = 7;
  return o;
}

double MeanAbsDiff(const Image& a, const Image& b) {
  double s = 0;
  for (size_t i = 0; i < a.rgb.size(); ++i) s += std::abs(double(a.rgb[i]) - double(b.rgb[i]));
  return s / double(a.rgb.size());
}

// A fresh directory under the gtest temp dir, removed on destruction.
class ScopedTempDir {
 public:
  explicit ScopedTempDir(const std::string& tag)
      : path_(fs::path(::testing::TempDir()) /
              ("procedural_scene_test_" + tag + "_" + std::to_string(::getpid()))) {
    fs::remove_all(path_);
  }
  ~ScopedTempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  std::string str() const { return path_.string(); }
  fs::path path() const { return path_; }

 private:
  fs::path path_;
};

nlohmann::json ReadJson(const fs::path& p) {
  std::ifstream f(p);
  EXPECT_TRUE(f.good()) << p;
  return nlohmann::json::parse(f);
}

TEST(ProceduralSceneTest, OptionsValidate) {
  EXPECT_TRUE(ProceduralSceneOptions().Validate().ok());
  ProceduralSceneOptions o;
  o.width = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = ProceduralSceneOptions();
  o.num_time_steps = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = ProceduralSceneOptions();
  o.camera_radius = 1.0f;
  EXPECT_FALSE(o.Validate().ok());
  o = ProceduralSceneOptions();
  o.max_elevation_deg = 90.0f;
  EXPECT_FALSE(o.Validate().ok());
  o = ProceduralSceneOptions();
  o.samples_per_axis = 0;
  EXPECT_EQ(GenerateProceduralScene(o).status().code(), absl::StatusCode::kInvalidArgument);
}

// No timing here: unit tests are not timed (it failed at 5.1 s under
// ASan at -O1 in CI); the generator's speed shows in the benchmarks.
TEST(ProceduralSceneTest, DefaultSceneIsFastAndWellFormed) {
  ProceduralSceneOptions o;  // 50 train + 10 test views at 64x64.
  absl::StatusOr<Scene> scene = GenerateProceduralScene(o);
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_EQ(scene->train.size(), 50u);
  EXPECT_EQ(scene->test.size(), 10u);
  EXPECT_TRUE(scene->val.empty());
  EXPECT_EQ(scene->kind, SceneKind::kBounded);
  EXPECT_EQ(scene->background, Eigen::Vector3f::Ones());
  EXPECT_FLOAT_EQ(scene->world_scale_hint, 1.0f / 3.0f);
  EXPECT_EQ(scene->world_offset_hint, Eigen::Vector3f::Zero());
  EXPECT_EQ(scene->num_time_steps(), 1);
  EXPECT_TRUE(ValidateScene(*scene).ok());
  EXPECT_EQ(scene->train[3].name, "train/r_3");
  EXPECT_EQ(scene->test[0].name, "test/r_0");
  EXPECT_EQ(scene->train[0].image.width, 64);
  // The scene's normalisation puts the content into the bounded model box.
  const Normalization n = ComputeNormalization(*scene);
  EXPECT_FLOAT_EQ(n.scale, 1.0f / 3.0f);
  EXPECT_FLOAT_EQ(n.bound, 0.5f);
}

TEST(ProceduralSceneTest, SameSeedGivesIdenticalPixels) {
  auto a = GenerateProceduralDataset(SmallOptions());
  auto b = GenerateProceduralDataset(SmallOptions());
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_EQ(a->scene.train.size(), b->scene.train.size());
  for (size_t i = 0; i < a->scene.train.size(); ++i) {
    EXPECT_EQ(a->scene.train[i].image.rgb, b->scene.train[i].image.rgb);
    EXPECT_EQ(a->alpha.train[i], b->alpha.train[i]);
    EXPECT_EQ(a->scene.train[i].camera.c2w, b->scene.train[i].camera.c2w);
  }
  ProceduralSceneOptions other = SmallOptions();
  other.seed = 8;
  auto c = GenerateProceduralDataset(other);
  ASSERT_TRUE(c.ok());
  EXPECT_NE(a->scene.train[0].image.rgb, c->scene.train[0].image.rgb);
}

TEST(ProceduralSceneTest, ImagesHaveForegroundAndBackground) {
  ProceduralSceneOptions o = SmallOptions();
  o.width = o.height = 64;
  o.num_time_steps = 1;
  auto ds = GenerateProceduralDataset(o);
  ASSERT_TRUE(ds.ok());
  for (size_t v = 0; v < ds->scene.train.size(); ++v) {
    const Image& im = ds->scene.train[v].image;
    const std::vector<float>& alpha = ds->alpha.train[v];
    ASSERT_EQ(alpha.size(), im.num_pixels());
    size_t bg = 0, fg = 0, coloured = 0;
    for (size_t p = 0; p < im.num_pixels(); ++p) {
      if (alpha[p] == 0.0f) {
        ++bg;
        // Background is exactly white.
        EXPECT_EQ(im.rgb[p * 3], 1.0f);
        EXPECT_EQ(im.rgb[p * 3 + 1], 1.0f);
        EXPECT_EQ(im.rgb[p * 3 + 2], 1.0f);
      }
      if (alpha[p] == 1.0f) ++fg;
      if (alpha[p] == 1.0f && (std::abs(im.rgb[p * 3] - im.rgb[p * 3 + 2]) > 0.1f)) ++coloured;
      EXPECT_GE(alpha[p], 0.0f);
      EXPECT_LE(alpha[p], 1.0f);
    }
    EXPECT_GT(bg, im.num_pixels() / 20) << "view " << v;
    EXPECT_GT(fg, im.num_pixels() / 5) << "view " << v;
    EXPECT_GT(coloured, 20u) << "view " << v;
  }
}

TEST(ProceduralSceneTest, TimeStepsDiffer) {
  ProceduralSceneOptions o = SmallOptions();
  o.width = o.height = 48;
  const Camera cam = ProceduralCameras(o, 0, false)[1];
  auto render = [&](const ProceduralSceneOptions& opt, int t) {
    return RenderProceduralView(ProceduralWorldAt(opt, t), cam, opt.samples_per_axis, opt.seed)
        .image;
  };
  const Image base = render(o, 0);

  const double both = MeanAbsDiff(base, render(o, 1));
  EXPECT_GT(both, 0.02);

  ProceduralSceneOptions light_only = o;
  light_only.change_geometry = false;
  EXPECT_GT(MeanAbsDiff(base, render(light_only, 1)), 0.02);

  ProceduralSceneOptions geometry_only = o;
  geometry_only.change_lighting = false;
  EXPECT_GT(MeanAbsDiff(base, render(geometry_only, 1)), 0.01);

  ProceduralSceneOptions none = o;
  none.change_geometry = false;
  none.change_lighting = false;
  EXPECT_EQ(MeanAbsDiff(base, render(none, 1)), 0.0);
  EXPECT_EQ(MeanAbsDiff(base, render(none, 3)), 0.0);

  // Geometry changes: one object removed, one added (new id), count kept.
  const ProceduralWorld w0 = ProceduralWorldAt(o, 0), w1 = ProceduralWorldAt(o, 1);
  ASSERT_EQ(w0.objects.size(), w1.objects.size());
  int max_id0 = -1;
  for (const auto& obj : w0.objects) max_id0 = std::max(max_id0, obj.id);
  EXPECT_EQ(w1.objects.back().id, max_id0 + 1);
  int kept = 0;
  for (const auto& a : w0.objects) {
    for (const auto& b : w1.objects) kept += (a.id == b.id);
  }
  EXPECT_EQ(kept, int(w0.objects.size()) - 1);
  EXPECT_NE(w0.light.direction, w1.light.direction);
}

TEST(ProceduralSceneTest, EveryTimeStepHasItsOwnViews) {
  ProceduralSceneOptions o = SmallOptions();
  o.num_time_steps = 3;
  auto scene = GenerateProceduralScene(o);
  ASSERT_TRUE(scene.ok());
  ASSERT_EQ(scene->train.size(), 12u);
  ASSERT_EQ(scene->test.size(), 6u);
  EXPECT_EQ(scene->num_time_steps(), 3);
  for (size_t i = 0; i < scene->train.size(); ++i) {
    EXPECT_EQ(scene->train[i].camera.time_step, int(i) / 4);
  }
  for (size_t i = 0; i < scene->test.size(); ++i) {
    EXPECT_EQ(scene->test[i].camera.time_step, int(i) / 2);
  }
  // Cameras are rotated between steps.
  EXPECT_GT((scene->train[0].camera.position() - scene->train[4].camera.position()).norm(), 0.1f);
}

TEST(ProceduralSceneTest, CamerasAreRigidAndLookAtTheOrigin) {
  ProceduralSceneOptions o = SmallOptions();
  o.num_train_views = 20;
  o.num_test_views = 5;
  for (int t = 0; t < 2; ++t) {
    for (bool test : {false, true}) {
      const std::vector<Camera> cams = ProceduralCameras(o, t, test);
      ASSERT_EQ(cams.size(), size_t(test ? 5 : 20));
      for (const Camera& c : cams) {
        EXPECT_TRUE(ValidateCamera(c, 1e-5f).ok());
        const Eigen::Matrix3f r = c.c2w.leftCols<3>();
        EXPECT_NEAR(r.determinant(), 1.0f, 1e-5f);
        EXPECT_NEAR(c.position().norm(), o.camera_radius, 1e-4f);
        EXPECT_GT(c.position().z(), 0.0f);  // Upper hemisphere.
        // OpenCV +z (viewing direction) points at the origin.
        const Eigen::Vector3f to_origin = -c.position().normalized();
        EXPECT_LT((r.col(2) - to_origin).norm(), 1e-5f);
        // OpenCV +y (image down) points downwards in the world (z up).
        EXPECT_LT(r.col(1).z(), 0.0f);
        EXPECT_NEAR(r.col(0).z(), 0.0f, 1e-5f);  // No roll.
        // The principal ray goes through the origin.
        Eigen::Vector3f origin, dir;
        c.Ray(c.intrinsics.cx, c.intrinsics.cy, &origin, &dir);
        EXPECT_LT((origin + dir * o.camera_radius).norm(), 1e-4f);
        EXPECT_EQ(c.time_step, t);
        EXPECT_FLOAT_EQ(c.intrinsics.fx, 16.0f / std::tan(0.5f * o.camera_angle_x));
      }
    }
  }
}

TEST(ProceduralSceneTest, ContentStaysInsideTheNerfSyntheticBox) {
  ProceduralSceneOptions o = SmallOptions();
  for (int t = 0; t < 12; ++t) {
    const ProceduralWorld w = ProceduralWorldAt(o, t);
    ASSERT_EQ(int(w.objects.size()), o.num_objects);
    for (const ProceduralObject& obj : w.objects) {
      EXPECT_TRUE(w.Occupied(obj.center));
      const Eigen::Vector3f lo = obj.center - obj.half_extent, hi = obj.center + obj.half_extent;
      EXPECT_GE(lo.minCoeff(), -1.2f);
      EXPECT_LE(hi.maxCoeff(), 1.2f);
      EXPECT_GE(lo.z(), w.floor_z - 1e-5f);  // On or above the floor.
    }
  }
  const ProceduralWorld w = ProceduralWorldAt(o, 0);
  EXPECT_TRUE(w.Occupied(Eigen::Vector3f(1.1f, -1.1f, -0.51f)));  // Floor slab.
  EXPECT_FALSE(w.Occupied(Eigen::Vector3f(1.1f, -1.1f, -0.6f)));  // Below the floor.
  EXPECT_FALSE(w.Occupied(Eigen::Vector3f(0.0f, 0.0f, 1.4f)));   // Above everything.
}

TEST(ProceduralSceneTest, BlenderDatasetRoundTrips) {
  const ProceduralSceneOptions o = SmallOptions();
  auto ds = GenerateProceduralDataset(o);
  ASSERT_TRUE(ds.ok());
  ScopedTempDir dir("blender");
  ASSERT_TRUE(WriteBlenderDataset(*ds, dir.str()).ok());

  for (const char* split : {"train", "test", "val"}) {
    const nlohmann::json j = ReadJson(dir.path() / ("transforms_" + std::string(split) + ".json"));
    const std::vector<View>& views = std::string(split) == "train" ? ds->scene.train
                                                                   : ds->scene.test;
    const std::string image_split = std::string(split) == "val" ? "test" : split;
    EXPECT_NEAR(j.at("camera_angle_x").get<double>(), o.camera_angle_x, 1e-6);
    ASSERT_EQ(j.at("frames").size(), views.size()) << split;
    for (size_t i = 0; i < views.size(); ++i) {
      const nlohmann::json& f = j["frames"][i];
      EXPECT_EQ(f.at("file_path").get<std::string>(),
                "./" + image_split + "/r_" + std::to_string(i));
      EXPECT_EQ(f.at("time_step").get<int>(), views[i].camera.time_step);
      const Pose gl = ExportPose(views[i].camera.c2w, PoseConvention::kOpenGL);
      const nlohmann::json& m = f.at("transform_matrix");
      ASSERT_EQ(m.size(), 4u);
      for (int r = 0; r < 4; ++r) {
        ASSERT_EQ(m[r].size(), 4u);
        for (int c = 0; c < 4; ++c) {
          const float expected = r < 3 ? gl(r, c) : (c == 3 ? 1.0f : 0.0f);
          EXPECT_EQ(float(m[r][c].get<double>()), expected);
        }
      }
      // Reading back the pose gives the camera's OpenCV pose.
      Pose back;
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 4; ++c) back(r, c) = float(m[r][c].get<double>());
      }
      EXPECT_EQ(ConvertPose(back, PoseConvention::kOpenGL), views[i].camera.c2w);
    }
  }
  EXPECT_FALSE(fs::exists(dir.path() / "val"));  // val reuses the test images.

  // PNGs are straight-alpha RGBA, and compositing them on white reproduces the
  // images. (Read as stored, alpha not composited.)
  for (size_t i = 0; i < ds->scene.train.size(); ++i) {
    const fs::path png = dir.path() / "train" / ("r_" + std::to_string(i) + ".png");
    auto raw = ReadImageChannels(png.string());
    ASSERT_TRUE(raw.ok()) << raw.status();
    ASSERT_EQ(raw->channels, 4);
    ASSERT_EQ(raw->width, o.width);
    ASSERT_EQ(raw->height, o.height);
    ASSERT_FALSE(raw->premultiplied);
    const std::vector<float>& px = raw->px;
    const Image& want = ds->scene.train[i].image;
    const std::vector<float>& want_alpha = ds->alpha.train[i];
    float max_err = 0, max_alpha_err = 0;
    for (size_t p = 0; p < want.num_pixels(); ++p) {
      const float a = px[p * 4 + 3];
      max_alpha_err = std::max(max_alpha_err, std::abs(a - want_alpha[p]));
      for (int c = 0; c < 3; ++c) {
        const float composited = px[p * 4 + c] * a + (1.0f - a);
        max_err = std::max(max_err, std::abs(composited - want.rgb[p * 3 + c]));
      }
    }
    EXPECT_LE(max_alpha_err, 0.51f / 255.0f) << png;
    EXPECT_LE(max_err, 1.01f / 255.0f) << png;
  }
}

TEST(ProceduralSceneTest, ScanFoldersHoldOneTimeStepEach) {
  ProceduralSceneOptions o = SmallOptions();
  o.num_time_steps = 3;
  auto ds = GenerateProceduralDataset(o);
  ASSERT_TRUE(ds.ok());
  ScopedTempDir dir("scans");
  ASSERT_TRUE(WriteScanFolders(*ds, dir.str()).ok());
  for (int t = 0; t < 3; ++t) {
    char name[16];
    std::snprintf(name, sizeof(name), "scan_%03d", t);
    const fs::path scan = dir.path() / name;
    const nlohmann::json train = ReadJson(scan / "transforms_train.json");
    const nlohmann::json test = ReadJson(scan / "transforms_test.json");
    ASSERT_EQ(train.at("frames").size(), 4u);
    ASSERT_EQ(test.at("frames").size(), 2u);
    EXPECT_TRUE(fs::exists(scan / "transforms_val.json"));
    for (size_t i = 0; i < 4; ++i) {
      EXPECT_EQ(train["frames"][i]["time_step"].get<int>(), t);
      EXPECT_EQ(train["frames"][i]["file_path"].get<std::string>(), "./train/r_" + std::to_string(i));
      EXPECT_TRUE(fs::exists(scan / "train" / ("r_" + std::to_string(i) + ".png")));
      const Pose gl = ExportPose(ds->scene.train[t * 4 + i].camera.c2w, PoseConvention::kOpenGL);
      EXPECT_EQ(float(train["frames"][i]["transform_matrix"][0][3].get<double>()), gl(0, 3));
    }
  }
  EXPECT_FALSE(fs::exists(dir.path() / "scan_003"));
}

TEST(ProceduralSceneTest, WriterRejectsUnsupportedCameras) {
  ProceduralSceneOptions o = SmallOptions();
  o.num_time_steps = 1;
  auto scene = GenerateProceduralScene(o);
  ASSERT_TRUE(scene.ok());
  ScopedTempDir dir("errors");

  Scene distorted = *scene;
  distorted.train[1].camera.intrinsics.k1 = 0.1f;
  EXPECT_EQ(WriteBlenderDataset(distorted, dir.str()).code(), absl::StatusCode::kInvalidArgument);

  Scene no_image = *scene;
  no_image.test[0].image = Image();
  EXPECT_EQ(WriteBlenderDataset(no_image, dir.str()).code(), absl::StatusCode::kInvalidArgument);

  ViewAlphas wrong;
  wrong.train.resize(1);
  EXPECT_EQ(WriteBlenderDataset(*scene, dir.str(), &wrong).code(),
            absl::StatusCode::kInvalidArgument);

  // Without alpha the writer still works (alpha = 1).
  EXPECT_TRUE(WriteBlenderDataset(*scene, dir.str()).ok());
  auto img = ReadImage((dir.path() / "train" / "r_0.png").string());
  ASSERT_TRUE(img.ok());
  EXPECT_NEAR(img->rgb[5], scene->train[0].image.rgb[5], 0.51f / 255.0f);
}

// --- Backdrop (unbounded) and thin structures ----------------------------------

ProceduralSceneOptions BackdropOptions() {
  ProceduralSceneOptions o;
  o.width = o.height = 48;
  o.num_train_views = 6;
  o.num_test_views = 2;
  o.seed = 11;
  o.min_elevation_deg = 5.0f;
  o.max_elevation_deg = 30.0f;
  o.backdrop = true;
  return o;
}

bool IsWhite(const float* p) { return p[0] == 1.0f && p[1] == 1.0f && p[2] == 1.0f; }

TEST(ProceduralSceneTest, DefaultWorldHasNoBackdropOrRods) {
  const ProceduralWorld w = ProceduralWorldAt(SmallOptions(), 0);
  EXPECT_TRUE(w.rods.empty());
  EXPECT_TRUE(w.pillars.empty());
  EXPECT_EQ(w.backdrop_radius, 0.0f);
  ProceduralSceneOptions o;
  o.backdrop = true;
  o.camera_radius = 30.0f;
  EXPECT_EQ(o.Validate().code(), absl::StatusCode::kInvalidArgument);
  o.camera_radius = 20.0f;
  EXPECT_TRUE(o.Validate().ok());
}

TEST(ProceduralSceneTest, BackdropSceneIsUnboundedAndOpaque) {
  const ProceduralSceneOptions o = BackdropOptions();
  auto ds = GenerateProceduralDataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status();
  const Scene& scene = ds->scene;
  EXPECT_EQ(scene.kind, SceneKind::kUnbounded);
  EXPECT_EQ(scene.background, Eigen::Vector3f::Zero());
  EXPECT_TRUE(ValidateScene(scene).ok());
  for (const auto* split : {&ds->alpha.train, &ds->alpha.test}) {
    for (const std::vector<float>& alpha : *split) {
      for (float a : alpha) ASSERT_EQ(a, 1.0f);
    }
  }
  for (const View& v : scene.train) {
    size_t white = 0;
    for (size_t p = 0; p < v.image.num_pixels(); ++p) white += IsWhite(&v.image.rgb[p * 3]);
    EXPECT_LT(white, v.image.num_pixels() / 100) << v.name;
  }
  // Contracted space centred on the cameras' look-at point, the origin.
  const Normalization n = ComputeNormalization(scene);
  EXPECT_FLOAT_EQ(n.bound, 2.0f);
  EXPECT_LT(n.center.norm(), 0.05f);
  // Pillars stand outside the camera ring, inside the backdrop sphere; the
  // world has content from the slab out to the backdrop.
  const ProceduralWorld w = ProceduralWorldAt(o, 0);
  EXPECT_FLOAT_EQ(w.backdrop_radius, 5.0f * o.camera_radius);
  ASSERT_GE(w.pillars.size(), 3u);
  for (const ProceduralObject& p : w.pillars) {
    const Eigen::Vector2f lo = (p.center - p.half_extent).head<2>();
    const Eigen::Vector2f hi = (p.center + p.half_extent).head<2>();
    const Eigen::Vector2f nearest = Eigen::Vector2f::Zero().cwiseMax(lo).cwiseMin(hi);
    EXPECT_GE(nearest.norm(), o.camera_radius + 1.0f - 1e-4f);
    EXPECT_LE((p.center.head<2>()).norm() + p.half_extent.head<2>().norm(), 2.5f * o.camera_radius + 1e-3f);
    EXPECT_NEAR(p.center.z() - p.half_extent.z(), w.ground_z, 1e-5f);
    EXPECT_GE(p.center.z() + p.half_extent.z(), 1.5f - 1e-4f);
    EXPECT_TRUE(w.Occupied(p.center));
  }
  EXPECT_TRUE(w.Occupied(Eigen::Vector3f(8.0f, -6.0f, w.ground_z - 0.1f)));  // Below the ground.
  EXPECT_FALSE(w.Occupied(Eigen::Vector3f(8.0f, -6.0f, 4.0f)));  // Above everything.
  EXPECT_FALSE(w.Occupied(Eigen::Vector3f(30.0f, 0.0f, w.ground_z - 0.1f)));  // Beyond the backdrop.
}

TEST(ProceduralSceneTest, BackdropShowsAboveTheHorizonAndIsTextured) {
  ProceduralSceneOptions o = BackdropOptions();
  o.min_elevation_deg = o.max_elevation_deg = 8.0f;
  o.num_train_views = 4;
  ProceduralSceneOptions plain = o;
  plain.backdrop = false;
  const ProceduralWorld with = ProceduralWorldAt(o, 0), without = ProceduralWorldAt(plain, 0);
  float lo = 1.0f, hi = 0.0f;
  int sky = 0;
  for (const Camera& cam : ProceduralCameras(o, 0, /*test_split=*/false)) {
    const ProceduralRender a = RenderProceduralView(with, cam, o.samples_per_axis, o.seed);
    const ProceduralRender b = RenderProceduralView(without, cam, o.samples_per_axis, o.seed);
    // The top rows look above the horizon: the backdrop (or a pillar) there,
    // white without it.
    for (int py = 0; py < 3; ++py) {
      for (int px = 0; px < o.width; ++px) {
        Eigen::Vector3f origin, dir;
        cam.Ray(px + 0.5f, py + 0.5f, &origin, &dir);
        if (dir.z() < 0.02f) continue;
        ++sky;
        EXPECT_TRUE(IsWhite(b.image.pixel(px, py)));
        EXPECT_FALSE(IsWhite(a.image.pixel(px, py)));
        EXPECT_EQ(a.alpha[size_t(py) * o.width + px], 1.0f);
        const float* p = a.image.pixel(px, py);
        lo = std::min(lo, p[0] + p[1] + p[2]);
        hi = std::max(hi, p[0] + p[1] + p[2]);
      }
    }
    // Where the plain world covers a pixel (slab and objects), the backdrop
    // changes nothing: it lies behind, and the pillars shadow nothing there.
    int covered = 0;
    for (size_t p = 0; p < b.alpha.size(); ++p) {
      if (b.alpha[p] < 1.0f) continue;
      ++covered;
      for (int c = 0; c < 3; ++c) ASSERT_EQ(a.image.rgb[p * 3 + c], b.image.rgb[p * 3 + c]);
    }
    EXPECT_GT(covered, o.width * o.height / 10);
  }
  EXPECT_GT(sky, 4 * o.width);
  EXPECT_GT(hi - lo, 0.3f) << "the backdrop should be clearly textured";
}

TEST(ProceduralSceneTest, ThinStructuresAreVisibleButSparse) {
  ProceduralSceneOptions o = SmallOptions();
  o.width = o.height = 64;
  o.num_time_steps = 1;
  o.num_train_views = 8;
  o.thin_structures = true;
  ProceduralSceneOptions plain = o;
  plain.thin_structures = false;
  const ProceduralWorld with = ProceduralWorldAt(o, 0), without = ProceduralWorldAt(plain, 0);
  ASSERT_GE(with.rods.size(), 6u);
  ASSERT_LE(with.rods.size(), 9u);
  EXPECT_EQ(with.objects.size(), without.objects.size());
  for (const ProceduralObject& r : with.rods) {
    const Eigen::Vector3f size = 2.0f * r.half_extent;
    std::array<float, 3> s = {size.x(), size.y(), size.z()};
    std::sort(s.begin(), s.end());
    EXPECT_GE(s[0], 0.025f - 1e-5f);
    EXPECT_LE(s[1], 0.04f + 1e-5f);  // Square cross-section, thin.
    EXPECT_GE(s[2], 0.5f);           // Long.
    EXPECT_LE(s[2], 1.3f);
    EXPECT_LE((r.center - r.half_extent).head<2>().minCoeff(), 1.2f);
    EXPECT_GE((r.center - r.half_extent).head<2>().minCoeff(), -1.2f);
    EXPECT_LE((r.center + r.half_extent).head<2>().maxCoeff(), 1.2f);
    EXPECT_GE(r.center.z() - r.half_extent.z(), with.floor_z - 1e-5f);
    EXPECT_TRUE(with.Occupied(r.center));
  }
  size_t changed = 0, total = 0;
  for (const Camera& cam : ProceduralCameras(o, 0, /*test_split=*/false)) {
    const Image a = RenderProceduralView(with, cam, o.samples_per_axis, o.seed).image;
    const Image b = RenderProceduralView(without, cam, o.samples_per_axis, o.seed).image;
    size_t view_changed = 0;
    for (size_t p = 0; p < a.num_pixels(); ++p) {
      float d = 0;
      for (int c = 0; c < 3; ++c) d = std::max(d, std::abs(a.rgb[p * 3 + c] - b.rgb[p * 3 + c]));
      view_changed += d > 0.05f;
    }
    EXPECT_GT(view_changed, 10u);
    changed += view_changed;
    total += a.num_pixels();
  }
  const double coverage = double(changed) / double(total);
  RecordProperty("rod_coverage", std::to_string(coverage));
  EXPECT_GT(coverage, 0.005);
  EXPECT_LT(coverage, 0.08);  // Rods (and their shadows) are a small part of the image.
}

TEST(ProceduralSceneTest, BackdropAndThinScenesAreDeterministic) {
  ProceduralSceneOptions o = BackdropOptions();
  o.thin_structures = true;
  o.num_time_steps = 2;
  auto a = GenerateProceduralDataset(o);
  auto b = GenerateProceduralDataset(o);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_EQ(a->scene.train.size(), b->scene.train.size());
  for (size_t i = 0; i < a->scene.train.size(); ++i) {
    EXPECT_EQ(a->scene.train[i].image.rgb, b->scene.train[i].image.rgb);
  }
  // Rods and pillars are fixed over time steps; another seed moves them.
  const ProceduralWorld w0 = ProceduralWorldAt(o, 0), w1 = ProceduralWorldAt(o, 1);
  ASSERT_EQ(w0.rods.size(), w1.rods.size());
  for (size_t i = 0; i < w0.rods.size(); ++i) EXPECT_EQ(w0.rods[i].center, w1.rods[i].center);
  ASSERT_EQ(w0.pillars.size(), w1.pillars.size());
  for (size_t i = 0; i < w0.pillars.size(); ++i) EXPECT_EQ(w0.pillars[i].center, w1.pillars[i].center);
  ProceduralSceneOptions other = o;
  other.seed = o.seed + 1;
  const ProceduralWorld w2 = ProceduralWorldAt(other, 0);
  EXPECT_NE(w0.rods[0].center, w2.rods[0].center);
  EXPECT_NE(w0.pillars[0].center, w2.pillars[0].center);
}

}  // namespace
}  // namespace clnerf
