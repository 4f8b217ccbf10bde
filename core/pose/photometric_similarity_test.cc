#include "core/pose/photometric_similarity.h"

#include <cmath>
#include <iostream>

#include "core/data/procedural_scene.h"
#include "core/pose/pose_test_util.h"
#include "core/pose/registration.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

using testing_util::MakePlace;
using testing_util::Place;
using testing_util::ProceduralPlaceMap;

// Eight frames are enough for seven parameters and keep the tests fast.
SimilarityRefineOptions Fast() {
  SimilarityRefineOptions o;
  o.max_frames = 8;
  return o;
}

// A small similarity about the place's centre: what registration leaves.
Similarity Offset(const Place& p, double deg, double shift, double scale) {
  Similarity s;
  s.rotation = Eigen::AngleAxisd(deg * M_PI / 180, Eigen::Vector3d(0.4, 1.0, -0.3).normalized()).toRotationMatrix();
  s.scale = scale;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const Camera& c : p.cameras) centre += c.position().cast<double>();
  centre /= double(p.cameras.size());
  s.translation = centre - scale * (s.rotation * centre) + Eigen::Vector3d(1, -0.5, 0.3).normalized() * shift * p.extent;
  return s;
}

struct Errors {
  double rotation_deg = 0, centre = 0;  // Worst over the frames; centre in extents.
};

Errors WorstError(const Scene& got, const Scene& truth, double extent) {
  Errors e;
  for (size_t i = 0; i < got.train.size(); ++i) {
    const Camera& a = got.train[i].camera;
    const Camera& b = truth.train[i].camera;
    e.rotation_deg = std::max(e.rotation_deg, RotationAngleDegrees(a.c2w.leftCols<3>().cast<double>(),
                                                                   b.c2w.leftCols<3>().cast<double>()));
    e.centre = std::max(e.centre, double((a.position() - b.position()).norm()) / extent);
  }
  return e;
}

// The scan at time step 1 (objects removed, added and recoloured since the
// map's step 0), moved off by 0.6 deg, 1 % of the place and 1 % in scale.
TEST(PhotometricSimilarityTest, BringsAScanBackOntoTheMapAfterThePlaceChanged) {
  Place p = MakePlace(11);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  Scene scan = p.scan;
  ApplySimilarity(Offset(p, 0.6, 0.01, 1.01), &scan);
  const Errors start = WorstError(scan, p.scan, p.extent);
  absl::StatusOr<SimilarityRefinement> r = RefineSimilarityPhotometric(map, scan, p.extent, Fast());
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_TRUE(r->accepted) << r->why;
  EXPECT_LT(r->cost_after, r->cost_before);
  ApplySimilarity(r->correction, &scan);
  const Errors end = WorstError(scan, p.scan, p.extent);
  std::cout << "worst frame: " << start.rotation_deg << " deg, " << 100 * start.centre << " % -> " << end.rotation_deg
            << " deg, " << 100 * end.centre << " % (" << r->frames << " frames, " << r->pixels << " pixels, "
            << r->seconds << " s)\n";
  EXPECT_LT(end.rotation_deg, 0.05);
  EXPECT_LT(end.centre, 0.001);
}

TEST(PhotometricSimilarityTest, AScanAlreadyOnTheMapStaysWhereItIs) {
  Place p = MakePlace(12);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  absl::StatusOr<SimilarityRefinement> r = RefineSimilarityPhotometric(map, p.scan, p.extent, Fast());
  ASSERT_TRUE(r.ok()) << r.status();
  // Taken or not, the correction must not move the scan off the map.
  EXPECT_LT(r->correction.RotationDegrees(), 0.02);
  EXPECT_LT(r->max_centre, 0.0005);
}

TEST(PhotometricSimilarityTest, PhotosWithNothingToAlignKeepTheirPoses) {
  Place p = MakePlace(13);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  Scene scan = p.scan;
  for (View& v : scan.train) v.image = Image(v.image.width, v.image.height, 0.5f);
  ApplySimilarity(Offset(p, 0.5, 0.005, 1.0), &scan);
  absl::StatusOr<SimilarityRefinement> r = RefineSimilarityPhotometric(map, scan, p.extent, Fast());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->accepted);
  EXPECT_FALSE(r->why.empty());
  EXPECT_EQ(r->correction.RotationDegrees(), 0.0);
  EXPECT_EQ(r->correction.scale, 1.0);
}

TEST(PhotometricSimilarityTest, RefusesBadInputAndStopsWhenCancelled) {
  Place p = MakePlace(14);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  Scene scan = p.scan;
  scan.train[1].image = Image(10, 10, 0.5f);
  EXPECT_EQ(RefineSimilarityPhotometric(map, scan, p.extent).status().code(), absl::StatusCode::kInvalidArgument);
  SimilarityRefineOptions o;
  o.min_frames = o.max_frames + 1;
  EXPECT_EQ(RefineSimilarityPhotometric(map, p.scan, p.extent, o).status().code(),
            absl::StatusCode::kInvalidArgument);
  std::atomic<bool> cancel{true};
  EXPECT_EQ(RefineSimilarityPhotometric(map, p.scan, p.extent, {}, {}, &cancel).status().code(),
            absl::StatusCode::kCancelled);
}

// The residual's gradient over the similarity's increment, the gain and the
// bias against central finite differences, on a photo that is a linear ramp
// (bilinear sampling and central-difference gradients are exact there, so
// what is checked is the geometry).
TEST(PhotometricSimilarityTest, ResidualGradientMatchesFiniteDifferences) {
  using photometric_similarity_internal::Gradient;
  using photometric_similarity_internal::Increment;
  using photometric_similarity_internal::Residual;
  Image ramp(160, 120, 0.0f);
  for (int y = 0; y < ramp.height; ++y) {
    for (int x = 0; x < ramp.width; ++x) {
      for (int c = 0; c < 3; ++c) ramp.rgb[3 * (size_t(y) * ramp.width + x) + c] = 0.1f + 0.004f * x + 0.003f * y;
    }
  }
  const GreyImage photo(ramp);
  Intrinsics in;
  in.width = 160;
  in.height = 120;
  in.fx = in.fy = 150;
  in.cx = 80;
  in.cy = 60;
  Pose base = Pose::Identity();
  base.leftCols<3>() = Eigen::AngleAxisf(0.3f, Eigen::Vector3f(0.2f, 1, 0.1f).normalized()).toRotationMatrix();
  base.col(3) = Eigen::Vector3f(0.3f, -0.2f, -2.0f);
  Similarity t;
  t.scale = 1.2;
  t.rotation = Eigen::AngleAxisd(0.2, Eigen::Vector3d(1, 0.3, 0).normalized()).toRotationMatrix();
  t.translation = Eigen::Vector3d(0.1, 0.2, -0.3);
  const Eigen::Vector3d pivot(0.2, -0.1, 0.4);
  const W2C cam = W2C::FromPose(t.ApplyToPose(base));
  // Points in front of the camera, well inside the photo.
  for (const Eigen::Vector3d& xc : {Eigen::Vector3d(0.1, 0.05, 2.0), Eigen::Vector3d(-0.3, 0.2, 3.0),
                                    Eigen::Vector3d(0.25, -0.15, 1.5)}) {
    const Eigen::Vector3d x = cam.r.transpose() * (xc - cam.t);
    const double gain = 1.1, bias = -0.02;
    double r;
    Gradient j;
    ASSERT_TRUE(Residual(photo, in, cam, x, 0.4f, gain, bias, pivot, &r, &j));
    const double h = 1e-3;  // Poses are floats: smaller steps drown in their rounding.
    for (int k = 0; k < 9; ++k) {
      double rp, rm;
      if (k < 7) {
        Eigen::Matrix<double, 7, 1> d = Eigen::Matrix<double, 7, 1>::Zero();
        d(k) = h;
        const W2C plus = W2C::FromPose(Increment(d, pivot).Compose(t).ApplyToPose(base));
        const W2C minus = W2C::FromPose(Increment(-d, pivot).Compose(t).ApplyToPose(base));
        ASSERT_TRUE(Residual(photo, in, plus, x, 0.4f, gain, bias, pivot, &rp, nullptr));
        ASSERT_TRUE(Residual(photo, in, minus, x, 0.4f, gain, bias, pivot, &rm, nullptr));
      } else {
        const double dg = k == 7 ? h : 0, db = k == 8 ? h : 0;
        ASSERT_TRUE(Residual(photo, in, cam, x, 0.4f, gain + dg, bias + db, pivot, &rp, nullptr));
        ASSERT_TRUE(Residual(photo, in, cam, x, 0.4f, gain - dg, bias - db, pivot, &rm, nullptr));
      }
      const double fd = (rp - rm) / (2 * h);
      EXPECT_NEAR(j(k), fd, 1e-3 * std::max(1.0, std::abs(fd))) << "parameter " << k;
    }
  }
}

}  // namespace
}  // namespace clnerf
