#include "core/pose/photometric_refine.h"

#include <cmath>
#include <iostream>

#include "core/data/procedural_scene.h"
#include "core/pose/pose_test_util.h"
#include "core/pose/similarity.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

using testing_util::MakePlace;
using testing_util::Place;
using testing_util::ProceduralPlaceMap;

// `c` turned by `deg` about a fixed oblique axis and moved by `shift` world
// units sideways.
Camera Nudged(const Camera& c, double deg, float shift) {
  Camera out = c;
  const Eigen::Matrix3f r =
      Eigen::AngleAxisf(float(deg * M_PI / 180), Eigen::Vector3f(0.3f, 1.0f, -0.5f).normalized()).toRotationMatrix();
  out.c2w.leftCols<3>() = r * c.c2w.leftCols<3>();
  out.c2w.col(3) += shift * c.c2w.col(0);
  return out;
}

double RotationError(const Pose& a, const Pose& b) {
  return RotationAngleDegrees(a.leftCols<3>().cast<double>(), b.leftCols<3>().cast<double>());
}

struct Case {
  Camera truth;
  Image photo;
};

// A place camera and its photo: of the world at `step` (1: objects moved,
// added and recoloured since the map's step 0).
Case PhotoOf(const Place& p, int view, int step) {
  Case c;
  c.truth = p.cameras[size_t(view)];
  c.photo = RenderProceduralView(ProceduralWorldAt(p.options, step), c.truth, 2, 7).image;
  return c;
}

TEST(PhotometricRefineTest, PullsANudgedCameraBackOntoTheMap) {
  Place p = MakePlace(5);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  for (int view : {0, 5, 11}) {
    const Case c = PhotoOf(p, view, 0);
    const Camera start = Nudged(c.truth, 0.6, float(0.006 * p.extent));
    absl::StatusOr<PhotometricRefinement> r = RefinePosePhotometric(map, c.photo, start, p.extent);
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_TRUE(r->accepted) << r->why;
    EXPECT_LT(r->cost_after, r->cost_before);
    std::cout << "view " << view << ": " << RotationError(start.c2w, c.truth.c2w) << " deg -> "
              << RotationError(r->c2w, c.truth.c2w) << " deg, centre "
              << (start.position() - c.truth.position()).norm() / p.extent << " -> "
              << (r->c2w.col(3) - c.truth.position()).norm() / p.extent << " of the place\n";
    EXPECT_LT(RotationError(r->c2w, c.truth.c2w), 0.05) << "view " << view;
    EXPECT_LT((r->c2w.col(3) - c.truth.position()).norm() / p.extent, 0.001) << "view " << view;
  }
}

TEST(PhotometricRefineTest, HoldsWhenThePlaceChangedAndTheExposureDiffers) {
  Place p = MakePlace(6);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  Case c = PhotoOf(p, 3, 1);  // Objects moved since the map.
  for (float& v : c.photo.rgb) v = 0.8f * v + 0.05f;
  const Camera start = Nudged(c.truth, 0.5, float(0.005 * p.extent));
  absl::StatusOr<PhotometricRefinement> r = RefinePosePhotometric(map, c.photo, start, p.extent);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->accepted) << r->why;
  EXPECT_NEAR(r->gain, 1.25, 0.15);  // map = 1.25 x photo - 0.0625 where unchanged.
  std::cout << "changed place: " << RotationError(r->c2w, c.truth.c2w) << " deg, centre "
            << (r->c2w.col(3) - c.truth.position()).norm() / p.extent << " of the place, gain " << r->gain << "\n";
  EXPECT_LT(RotationError(r->c2w, c.truth.c2w), 0.05);
  EXPECT_LT((r->c2w.col(3) - c.truth.position()).norm() / p.extent, 0.001);
}

TEST(PhotometricRefineTest, APhotoWithNothingToAlignKeepsItsPose) {
  Place p = MakePlace(7);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  const Camera start = Nudged(p.cameras[2], 0.5, 0);
  const Image blank(start.intrinsics.width, start.intrinsics.height, 0.5f);
  absl::StatusOr<PhotometricRefinement> r = RefinePosePhotometric(map, blank, start, p.extent);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->accepted);
  EXPECT_FALSE(r->why.empty());
  EXPECT_TRUE(r->c2w.isApprox(start.c2w));
}

TEST(PhotometricRefineTest, RefusesBadInput) {
  Place p = MakePlace(8);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  const Image small(10, 10, 0.5f);
  EXPECT_EQ(RefinePosePhotometric(map, small, p.cameras[0], p.extent).status().code(),
            absl::StatusCode::kInvalidArgument);
  PhotometricRefineOptions o;
  o.levels = 0;
  const Case c = PhotoOf(p, 0, 0);
  EXPECT_EQ(RefinePosePhotometric(map, c.photo, c.truth, p.extent, o).status().code(),
            absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace clnerf
