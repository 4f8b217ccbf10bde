#include "core/pose/frame_check.h"

#include <iostream>

#include "core/data/procedural_scene.h"
#include "core/pose/pose_test_util.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

using testing_util::MakePlace;
using testing_util::Place;
using testing_util::ProceduralPlaceMap;

// The camera mirrored through the ground plane (y = 0), as structure from
// motion poses a frame of a bare floor wrongly: below the floor, looking up.
Camera MirroredThroughFloor(const Camera& c) {
  Camera out = c;
  const Eigen::Matrix3f s = Eigen::Vector3f(1, -1, 1).asDiagonal();
  out.c2w.leftCols<3>() = s * c.c2w.leftCols<3>() * s;
  out.c2w.col(3) = s * c.c2w.col(3);
  return out;
}

// The camera turned by `deg` about the vertical axis through the origin.
Camera Orbited(const Camera& c, double deg) {
  Camera out = c;
  const Eigen::Matrix3f r = Eigen::AngleAxisf(float(deg * M_PI / 180), Eigen::Vector3f::UnitY()).toRotationMatrix();
  out.c2w.leftCols<3>() = r * c.c2w.leftCols<3>();
  out.c2w.col(3) = r * c.c2w.col(3);
  return out;
}

TEST(FrameCheckTest, PhotosOfAChangedPlaceAgreeAndWrongPosesDoNot) {
  Place p = MakePlace(5, /*textured=*/true);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  for (int i : {0, 6, 12}) {
    const View& v = p.scan.train[size_t(i)];  // Objects moved since the map.
    absl::StatusOr<double> good = FrameAgreement(map, v.image, v.camera);
    ASSERT_TRUE(good.ok()) << good.status();
    Camera off = Orbited(v.camera, 1.0);  // A degree off: still the same view.
    absl::StatusOr<double> near = FrameAgreement(map, v.image, off);
    absl::StatusOr<double> mirrored = FrameAgreement(map, v.image, MirroredThroughFloor(v.camera));
    absl::StatusOr<double> opposite = FrameAgreement(map, v.image, Orbited(v.camera, 180));
    ASSERT_TRUE(near.ok() && mirrored.ok() && opposite.ok());
    std::cout << "frame " << i << ": right " << *good << ", 1 deg off " << *near << ", mirrored " << *mirrored
              << ", other side " << *opposite << "\n";
    EXPECT_GT(*good, 0.6);
    EXPECT_GT(*near, 0.5);
    EXPECT_LT(*mirrored, 0.5 * *good);
    EXPECT_LT(*opposite, 0.5 * *good);
  }
}

TEST(FrameCheckTest, DropsOnlyTheUnverifiedFramesThatDisagree) {
  Place p = MakePlace(6, /*textured=*/true);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  Scene scan = p.scan;
  const size_t n = scan.train.size();
  std::vector<bool> verified(n, false);
  for (size_t i = 0; i < n; i += 3) verified[i] = true;
  for (int i : {4, 5, 10}) {  // Posed wrongly, unverified.
    scan.train[size_t(i)].camera = MirroredThroughFloor(scan.train[size_t(i)].camera);
  }
  absl::StatusOr<FrameCheckReport> r = CheckScanFrames(map, scan, verified);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->dropped, (std::vector<int>{4, 5, 10}));
  EXPECT_FALSE(r->capped);
  EXPECT_EQ(r->agreement.size(), n);
  const std::string name5 = scan.train[5].name, name6 = scan.train[6].name;
  DropCheckedFrames(*r, &scan);
  ASSERT_EQ(scan.train.size(), n - 3);
  EXPECT_EQ(scan.train[4].name, name6);  // Order kept.

  // A wrong pose registration verified is never dropped.
  Scene again = p.scan;
  again.train[3].camera = MirroredThroughFloor(again.train[3].camera);
  r = CheckScanFrames(map, again, verified);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->dropped.empty());
}

TEST(FrameCheckTest, KeepsEveryFrameWhenMostDisagree) {
  Place p = MakePlace(7, /*textured=*/true);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  Scene scan = p.scan;
  std::vector<bool> verified(scan.train.size(), false);
  verified[0] = true;
  for (size_t i = 1; i < scan.train.size(); ++i) scan.train[i].camera = MirroredThroughFloor(scan.train[i].camera);
  absl::StatusOr<FrameCheckReport> r = CheckScanFrames(map, scan, verified);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->capped);  // The map, not the frames, would be at fault.
  EXPECT_TRUE(r->dropped.empty());
}

TEST(FrameCheckTest, RejectsBadInput) {
  Place p = MakePlace(5, /*textured=*/true);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  const View& v = p.scan.train[0];
  Image small(10, 10);
  EXPECT_EQ(FrameAgreement(map, small, v.camera).status().code(), absl::StatusCode::kInvalidArgument);
  FrameCheckOptions o;
  o.max_side = 4;
  EXPECT_FALSE(o.Validate().ok());
  o = FrameCheckOptions();
  o.min_relative = 2;
  EXPECT_FALSE(o.Validate().ok());
  EXPECT_EQ(CheckScanFrames(map, p.scan, {}, o).status().code(), absl::StatusCode::kInvalidArgument);
  o = FrameCheckOptions();
  o.max_drop_fraction = -0.1;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace clnerf
