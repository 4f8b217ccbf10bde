// Sparse depth: projection, the splat visibility test (a point hidden behind
// a nearer surface is not a depth target), thinning and bad input.
#include "core/data/sparse_depth.h"

#include <cmath>
#include <limits>

#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// A 64x64 camera at the origin looking down +z (OpenCV axes), 90 deg fov.
View FrontView() {
  View v;
  v.name = "front";
  v.camera.intrinsics.width = v.camera.intrinsics.height = 64;
  v.camera.intrinsics.fx = v.camera.intrinsics.fy = 32.0f;
  v.camera.intrinsics.cx = v.camera.intrinsics.cy = 32.0f;
  v.image.width = v.image.height = 64;
  v.image.rgb.assign(64 * 64 * 3, 0.5f);
  return v;
}

// A square card [-0.5, 0.5]^2 at z = 2 in front of a wall [-2, 2]^2 at z = 4,
// both sampled densely.
std::vector<Eigen::Vector3f> CardAndWall(std::vector<bool>* on_card) {
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i <= 40; ++i) {
    for (int j = 0; j <= 40; ++j) {
      pts.emplace_back(-0.5f + i / 40.0f, -0.5f + j / 40.0f, 2.0f);
      on_card->push_back(true);
      pts.emplace_back(-2.0f + 4.0f * i / 40.0f, -2.0f + 4.0f * j / 40.0f, 4.0f);
      on_card->push_back(false);
    }
  }
  return pts;
}

TEST(SparseDepthTest, ProjectPointInvertsTheCameraRay) {
  Camera c = FrontView().camera;
  c.intrinsics.k1 = -0.08f;
  c.intrinsics.p2 = 0.002f;
  c.c2w.leftCols<3>() = Eigen::AngleAxisf(0.4f, Eigen::Vector3f(0.2f, 1.0f, -0.3f).normalized()).toRotationMatrix();
  c.c2w.col(3) = Eigen::Vector3f(1.0f, -2.0f, 0.5f);
  for (const Eigen::Vector2f& px : {Eigen::Vector2f(10.3f, 50.8f), Eigen::Vector2f(32.0f, 32.0f), Eigen::Vector2f(60.1f, 3.2f)}) {
    Eigen::Vector3f o, d;
    c.Ray(px.x(), px.y(), &o, &d);
    const Eigen::Vector3f x = o + 3.0f * d;
    Eigen::Vector2f back;
    float z = 0;
    ASSERT_TRUE(ProjectPoint(c, x, &back, &z));
    EXPECT_LT((back - px).norm(), 1e-2f);
    EXPECT_NEAR(z, 3.0f * d.dot(c.c2w.col(2)), 1e-4f);
  }
  Eigen::Vector2f p;
  float z;
  EXPECT_FALSE(ProjectPoint(c, c.position() - 2.0f * c.c2w.col(2), &p, &z));  // Behind.
}

TEST(SparseDepthTest, HiddenPointsAreNotTargets) {
  std::vector<bool> on_card;
  const std::vector<Eigen::Vector3f> pts = CardAndWall(&on_card);
  std::vector<View> views = {FrontView()};
  const long long n = AttachSparseDepth(pts, SparseDepthOptions(), &views);
  ASSERT_EQ(n, (long long)views[0].depth.size());
  int card = 0, wall = 0;
  for (const DepthPoint& d : views[0].depth) {
    // The target projects into its own pixel.
    Eigen::Vector2f px;
    float z;
    ASSERT_TRUE(ProjectPoint(views[0].camera, d.world, &px, &z));
    EXPECT_EQ(d.pixel, uint32_t(int(px.y()) * 64 + int(px.x())));
    if (d.world.z() < 3.0f) {
      ++card;
      continue;
    }
    ++wall;
    // A wall point the card covers (its image is |x| <= 8 px around the
    // centre, a pixel of margin for the splats) must not be a target.
    EXPECT_FALSE(std::abs(px.x() - 32.0f) < 7.0f && std::abs(px.y() - 32.0f) < 7.0f)
        << "wall point " << d.world.transpose() << " at pixel " << px.transpose();
  }
  EXPECT_GT(card, 100);
  EXPECT_GT(wall, 500);
}

TEST(SparseDepthTest, ThinsMasksAndIgnoresBadPoints) {
  std::vector<bool> on_card;
  std::vector<Eigen::Vector3f> pts = CardAndWall(&on_card);
  pts.emplace_back(std::numeric_limits<float>::quiet_NaN(), 0.0f, 2.0f);
  pts.emplace_back(0.0f, 0.0f, std::numeric_limits<float>::infinity());
  SparseDepthOptions o;
  o.max_points_per_view = 50;
  std::vector<View> views = {FrontView(), FrontView()};
  views[1].mask.keep.assign(64 * 64, 0);  // Fully masked: no targets.
  views[1].mask.width = views[1].mask.height = 64;
  View empty = FrontView();
  empty.image = Image();
  views.push_back(empty);
  AttachSparseDepth(pts, o, &views);
  EXPECT_EQ(views[0].depth.size(), 50u);
  for (const DepthPoint& d : views[0].depth) EXPECT_TRUE(d.world.allFinite());
  EXPECT_TRUE(views[1].depth.empty());
  EXPECT_TRUE(views[2].depth.empty());
  // No points: no targets (and what was there is replaced).
  AttachSparseDepth({}, o, &views);
  EXPECT_TRUE(views[0].depth.empty());
}

TEST(SparseDepthTest, OptionsValidate) {
  EXPECT_TRUE(SparseDepthOptions().Validate().ok());
  SparseDepthOptions o;
  o.max_points_per_view = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = SparseDepthOptions();
  o.splat_radius = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(o.Validate().ok());
  o = SparseDepthOptions();
  o.min_depth_fraction = 1.0f;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace clnerf
