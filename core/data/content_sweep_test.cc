#include "core/data/content_sweep.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include <gtest/gtest.h>
#include <unistd.h>

#include "core/data/dataset.h"
#include "core/data/procedural_scene.h"
#include "core/data/scene.h"
#include "Eigen/Geometry"

namespace clnerf {
namespace {

ProceduralSceneOptions Small(ProceduralLayout layout) {
  ProceduralSceneOptions o;
  o.layout = layout;
  o.width = 96;
  o.height = 72;
  o.num_train_views = 16;
  o.num_test_views = 2;
  o.samples_per_axis = 1;
  o.seed = 7;
  return o;
}

float Median(std::vector<float> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// Applies x -> s R x + t to every camera (a different file format's frame).
Scene Transformed(Scene scene, float s, const Eigen::Matrix3f& r, const Eigen::Vector3f& t) {
  for (std::vector<View>* split : {&scene.train, &scene.val, &scene.test}) {
    for (View& v : *split) {
      v.camera.c2w.leftCols<3>() = r * v.camera.c2w.leftCols<3>();
      v.camera.c2w.col(3) = s * (r * v.camera.c2w.col(3)) + t;
    }
  }
  return scene;
}

TEST(ContentSweepTest, RoomPointsLieOnTheRoomNotAtTheCameras) {
  const ProceduralSceneOptions o = Small(ProceduralLayout::kRoom);
  absl::StatusOr<Scene> scene = GenerateProceduralScene(o);
  ASSERT_TRUE(scene.ok()) << scene.status();
  const std::vector<Eigen::Vector3f> pts = EstimateContentPoints(scene->train);
  ASSERT_GT(pts.size(), 200u);
  const ProceduralWorld world = ProceduralWorldAt(o, 0);
  int inside = 0;
  std::vector<float> dist;
  for (const Eigen::Vector3f& p : pts) {
    inside += std::abs(p.x()) < 1.1f * world.room_half.x() && std::abs(p.y()) < 1.1f * world.room_half.y() &&
              p.z() > world.room_floor_z - 0.3f && p.z() < world.room_ceiling_z + 0.3f;
    float nearest = 1e30f;
    for (const View& v : scene->train) nearest = std::min(nearest, (p - v.camera.position()).norm());
    dist.push_back(nearest);
  }
  EXPECT_GT(inside, int(0.9 * pts.size()));
  // The walls and objects are 1-2.5 units from the walk; a sweep that found
  // nothing real would sit at its near or far planes.
  EXPECT_GT(Median(dist), 0.7f);
  EXPECT_LT(Median(dist), 3.5f);
}

TEST(ContentSweepTest, ForwardFacingPointsLieAheadAtTheContentsDepth) {
  const ProceduralSceneOptions o = Small(ProceduralLayout::kForwardFacing);
  absl::StatusOr<Scene> scene = GenerateProceduralScene(o);
  ASSERT_TRUE(scene.ok()) << scene.status();
  const std::vector<Eigen::Vector3f> pts = EstimateContentPoints(scene->train);
  ASSERT_GT(pts.size(), 200u);
  // Cameras at x = -4 look along +x: the objects are 2.8-5.2 ahead, pillars
  // and backdrop farther. The camera grid is only 1.2 wide.
  std::vector<float> ahead;
  for (const Eigen::Vector3f& p : pts) ahead.push_back(p.x() + o.camera_radius);
  EXPECT_GT(Median(ahead), 2.0f);
  EXPECT_LT(Median(ahead), 12.0f);
}

TEST(ContentSweepTest, NormalisationFollowsTheCamerasFrame) {
  // The same capture in another frame (COLMAP's arbitrary one versus a
  // transforms.json's z-up one) must give the same model box: every world
  // point maps to the same model point.
  for (ProceduralLayout layout : {ProceduralLayout::kForwardFacing, ProceduralLayout::kRoom}) {
    absl::StatusOr<Scene> a = GenerateProceduralScene(Small(layout));
    ASSERT_TRUE(a.ok());
    const float s = 0.37f;
    const Eigen::Matrix3f r =
        (Eigen::AngleAxisf(1.1f, Eigen::Vector3f(0.3f, -0.8f, 0.5f).normalized())).toRotationMatrix();
    const Eigen::Vector3f t(12.0f, -3.0f, 40.0f);
    const Scene b = Transformed(*a, s, r, t);
    const Normalization na = ComputeNormalization(*a), nb = ComputeNormalization(b);
    EXPECT_NEAR(nb.scale, na.scale / s, 0.02f * na.scale / s) << ProceduralLayoutName(layout);
    EXPECT_GT(na.scale, 0.0f);
    for (const Eigen::Vector3f& p : {Eigen::Vector3f(0, 0, 0), Eigen::Vector3f(1, -2, 0.5f), Eigen::Vector3f(-3, 1, 2)}) {
      const Eigen::Vector3f ma = na.ToModel(p), mb = nb.ToModel(s * (r * p) + t);
      // Exact for the cameras; the sweep's per-pixel plane choices can move the
      // median content point by about 1 % of a model unit.
      EXPECT_LT((ma - mb).norm(), 0.03f) << ProceduralLayoutName(layout) << " " << ma.transpose() << " vs "
                                         << mb.transpose();
    }
    // The cameras sit inside the inner cube, and the rotation is proper.
    for (const View& v : a->train) EXPECT_LE(na.ToModel(v.camera.position()).cwiseAbs().maxCoeff(), 1.0f);
    EXPECT_NEAR(na.rotation.determinant(), 1.0f, 1e-4f);
  }
}

// The box turns about the up axis to fit the cameras as tightly as it can:
// the inner cube's resolution goes to the capture, not to empty corners. A
// diamond-shaped walk (main axis 2, cross axis 1) fits best turned about 45
// degrees off its main axis (radius ~1.41 instead of 2): the main-axis choice
// this replaced kept radius 2 and, on fox_8, cost 0.7 dB.
TEST(ContentSweepTest, NormalisationTurnsTheBoxToFitTheCameras) {
  Scene base;
  base.kind = SceneKind::kUnbounded;
  for (int i = 0; i < 40; ++i) {
    const float u = float(i) / 40.0f * 4.0f;  // Walk the diamond's edges.
    const int edge = int(u);
    const float f = u - float(edge);
    const Eigen::Vector2f corners[4] = {{2, 0}, {0, 1}, {-2, 0}, {0, -1}};
    const Eigen::Vector2f p = (1 - f) * corners[edge] + f * corners[(edge + 1) % 4];
    View v;
    v.camera.intrinsics = {64, 48, 60, 60, 32, 24};
    // Every camera looks along +y, up +z (OpenCV: x right, y down, z forward).
    v.camera.c2w.setZero();
    v.camera.c2w.col(0) = Eigen::Vector3f(1, 0, 0);
    v.camera.c2w.col(1) = Eigen::Vector3f(0, 0, -1);
    v.camera.c2w.col(2) = Eigen::Vector3f(0, 1, 0);
    v.camera.c2w.col(3) = Eigen::Vector3f(p.x(), p.y(), 0.05f * float(i % 3));
    base.train.push_back(v);
  }
  const Eigen::Matrix3f r =
      (Eigen::AngleAxisf(0.7f, Eigen::Vector3f(0.2f, 0.5f, -0.6f).normalized())).toRotationMatrix();
  for (const Scene& scene : {base, Transformed(base, 3.0f, r, Eigen::Vector3f(5, -1, 2))}) {
    const Normalization n = ComputeNormalization(scene);
    float radius = 0;
    for (const View& v : scene.train) {
      radius = std::max(radius, (n.rotation * (v.camera.position() - n.center)).cwiseAbs().maxCoeff());
    }
    // The best turn over every degree, about the same centre and up axis.
    float best = 1e30f;
    for (int deg = 0; deg < 90; ++deg) {
      const Eigen::Matrix3f turn = Eigen::AngleAxisf(float(deg) * float(M_PI) / 180.0f, Eigen::Vector3f::UnitZ())
                                       .toRotationMatrix();
      float r_deg = 0;
      for (const View& v : scene.train) {
        r_deg = std::max(r_deg, (turn * n.rotation * (v.camera.position() - n.center)).cwiseAbs().maxCoeff());
      }
      best = std::min(best, r_deg);
    }
    EXPECT_LE(radius, best * 1.002f);
    // In the diamond's own units: well under the main-axis box's 2.
    // Cameras 10 and 30 sit at the cross axis's ends, one unit from the middle.
    const float unit = (scene.train[10].camera.position() - scene.train[30].camera.position()).norm() / 2;
    EXPECT_LT(radius / unit, 1.6f);
    EXPECT_NEAR(n.rotation.determinant(), 1.0f, 1e-4f);
  }
}

TEST(ContentSweepTest, NothingToMatchGivesNoPoints) {
  absl::StatusOr<Scene> scene = GenerateProceduralScene(Small(ProceduralLayout::kRoom));
  ASSERT_TRUE(scene.ok());
  EXPECT_TRUE(EstimateContentPoints({}).empty());
  EXPECT_TRUE(EstimateContentPoints({scene->train[0]}).empty());
  std::vector<View> no_images = scene->train;
  for (View& v : no_images) v.image = Image();
  EXPECT_TRUE(EstimateContentPoints(no_images).empty());
  // Every camera at one point: no baseline, no depth.
  std::vector<View> one_spot = scene->train;
  for (View& v : one_spot) v.camera.c2w.col(3) = one_spot[0].camera.c2w.col(3);
  EXPECT_TRUE(EstimateContentPoints(one_spot).empty());
  ContentSweepOptions bad;
  bad.num_depths = 1;
  EXPECT_FALSE(bad.Validate().ok());
  EXPECT_TRUE(ContentSweepOptions().Validate().ok());
}

// The real capture shipped in two forms: its transforms.json and its COLMAP
// model (sparse points, another frame and scale) must give the same box.
TEST(ContentSweepTest, Flower4TransformsAndColmapGiveTheSameBox) {
  namespace fs = std::filesystem;
  const fs::path data = fs::path(CLNERF_SHARED_DATA_DIR) / "flower_4";
  if (!fs::exists(data / "transforms.json") || !fs::exists(data / "source" / "sparse" / "0")) {
    GTEST_SKIP() << "../shared/data/flower_4 not present";
  }
  const fs::path colmap = fs::temp_directory_path() / ("clnerf_flower_colmap_" + std::to_string(::getpid()));
  fs::remove_all(colmap);
  fs::create_directories(colmap);
  fs::create_directory_symlink(data / "source" / "sparse", colmap / "sparse");
  fs::create_directory_symlink(data / "images", colmap / "images");
  absl::StatusOr<Scene> a = LoadScene(data.string()), b = LoadScene(colmap.string());
  fs::remove_all(colmap);
  ASSERT_TRUE(a.ok()) << a.status();
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(DetectDatasetFormat(data.string()).value(), DatasetFormat::kInstantNgp);
  ASSERT_EQ(a->train.size(), b->train.size());
  EXPECT_EQ(a->kind, SceneKind::kUnbounded);
  const Normalization na = ComputeNormalization(*a), nb = ComputeNormalization(*b);
  // Same cameras, so each camera centre has one model position.
  float worst = 0;
  for (size_t i = 0; i < a->train.size(); ++i) {
    worst = std::max(worst, (na.ToModel(a->train[i].camera.position()) - nb.ToModel(b->train[i].camera.position()))
                                .norm());
  }
  EXPECT_LT(worst, 0.02f);
}

}  // namespace
}  // namespace clnerf
