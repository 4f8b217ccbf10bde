#include "core/pose/pose_arbitration.h"

#include <vector>

#include "core/pose/pose_test_util.h"
#include "core/pose/similarity.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

using testing_util::MakePlace;
using testing_util::Place;
using testing_util::ProceduralPlaceMap;

double Turn(const Pose& a, const Pose& b) {
  return RotationAngleDegrees(a.leftCols<3>().cast<double>(), b.leftCols<3>().cast<double>());
}

// The scan's photos were taken after the place changed (objects moved); the
// map is the place before, as θ_{t-1} would be.
struct Fixture {
  Place place = MakePlace(41, /*textured=*/true);
  ProceduralPlaceMap map{ProceduralWorldAt(place.options, 0)};
};

TEST(MapCorrelationTest, ThePhotosOwnPoseCorrelatesFarBetterThanATurnedOne) {
  Fixture f;
  const View& v = f.place.scan.train[3];
  absl::StatusOr<double> at = MapCorrelation(f.map, v.image, v.camera, 160);
  ASSERT_TRUE(at.ok()) << at.status();
  Camera turned = v.camera;
  std::vector<View> one = {v};
  testing_util::TurnAboutTheScene(&one, 0, 0, 120.0);
  turned.c2w = one[0].camera.c2w;
  absl::StatusOr<double> off = MapCorrelation(f.map, v.image, turned, 160);
  ASSERT_TRUE(off.ok()) << off.status();
  EXPECT_GT(*at, 0.6);  // Changed objects and a soft render keep it below 1.
  EXPECT_GT(*at - *off, 0.3) << "at its pose " << *at << ", turned " << *off;
}

TEST(MapCorrelationTest, RefusesAPhotoOfTheWrongSize) {
  Fixture f;
  const View& v = f.place.scan.train[0];
  Image small = ResizeImage(v.image, v.image.width / 2, v.image.height / 2);
  EXPECT_TRUE(absl::IsInvalidArgument(MapCorrelation(f.map, small, v.camera, 160).status()));
}

// Frames 2 and 5 mirrored by the scan's own SfM (turned 170 degrees about the
// place, as COLMAP did on beer_2's floor) go back to their PnP pose; frame 7,
// whose PnP pose is the wrong one, keeps its registered pose; frames that
// agree, and frames PnP did not place, are left alone.
TEST(ArbitrateDisputedFramesTest, MirroredFramesTakeTheirPnpPoseAndWrongPnpPosesAreIgnored) {
  Fixture f;
  Scene scan = f.place.scan;
  const std::vector<View> truth = scan.train;
  std::vector<FrameLocalization> loc;
  std::vector<int> tried;
  for (size_t i = 0; i < truth.size(); ++i) {
    FrameLocalization l;
    l.placed = i != 9;
    l.c2w = truth[i].camera.c2w;
    loc.push_back(l);
    tried.push_back(int(i));
  }
  testing_util::TurnAboutTheScene(&scan.train, 2, 2, 170.0);
  testing_util::TurnAboutTheScene(&scan.train, 5, 5, 170.0);
  testing_util::TurnAboutTheScene(&scan.train, 9, 9, 170.0);  // Not placed: nothing to arbitrate with.
  std::vector<View> wrong = {truth[7]};
  testing_util::TurnAboutTheScene(&wrong, 0, 0, 150.0);
  loc[7].c2w = wrong[0].camera.c2w;

  absl::StatusOr<ArbitrationReport> r = ArbitrateDisputedFrames(loc, tried, f.map, f.place.extent, &scan);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->disputed, 3) << r->Summary();
  EXPECT_EQ(r->taken, 2) << r->Summary();
  for (size_t i = 0; i < truth.size(); ++i) {
    const double err = Turn(scan.train[i].camera.c2w, truth[i].camera.c2w);
    if (i == 9) {
      EXPECT_GT(err, 160.0) << "frame 9 was not placed and must keep its pose";
    } else {
      EXPECT_LT(err, 1e-3) << "frame " << i << ": " << r->Summary();
    }
  }
}

// Frames the pose check disputed (suspect): kept only where the map vouches
// for a pose. 1: posed right, PnP agrees (confirmed); 2: mirrored, PnP right
// (moved); 4: mirrored, PnP right but weak (moved: the map is the check);
// 6: mirrored, PnP as wrong (dropped: no pose wins); 8: mirrored, not posed
// by PnP (dropped). 9: mirrored but not suspect, with a weak PnP pose: a
// weak pose alone is no case for moving it. 3: untouched.
TEST(ArbitrateDisputedFramesTest, SuspectFramesAreKeptOnlyWhereTheMapVouchesForAPose) {
  Fixture f;
  Scene scan = f.place.scan;
  const std::vector<View> truth = scan.train;
  ASSERT_GE(truth.size(), 10u);
  std::vector<FrameLocalization> loc(truth.size());
  std::vector<int> tried;
  for (size_t i = 0; i < truth.size(); ++i) {
    loc[i].placed = i != 4 && i != 8 && i != 9;
    loc[i].weak = i == 4 || i == 9;
    loc[i].c2w = truth[i].camera.c2w;
    tried.push_back(int(i));
  }
  for (int i : {2, 4, 6, 8, 9}) testing_util::TurnAboutTheScene(&scan.train, i, i, 170.0);
  std::vector<View> other = {scan.train[6]};
  testing_util::TurnAboutTheScene(&other, 0, 0, 10.0);
  loc[6].c2w = other[0].camera.c2w;  // PnP as wrong: 10 degrees from the mirrored pose.

  absl::StatusOr<ArbitrationReport> r =
      ArbitrateDisputedFrames(loc, tried, f.map, f.place.extent, &scan, {}, /*suspect=*/{1, 2, 4, 6, 8});
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->confirmed, 1) << r->Summary();
  EXPECT_EQ(r->taken, 2) << r->Summary();
  EXPECT_EQ(r->dropped, (std::vector<int>{6, 8})) << r->Summary();
  for (int i : {2, 4}) EXPECT_LT(Turn(scan.train[i].camera.c2w, truth[i].camera.c2w), 1e-3) << i << r->Summary();
  EXPECT_GT(Turn(scan.train[9].camera.c2w, truth[9].camera.c2w), 160.0) << r->Summary();
  EXPECT_EQ(scan.train[1].camera.c2w, truth[1].camera.c2w);
  EXPECT_EQ(scan.train[3].camera.c2w, truth[3].camera.c2w);
}

TEST(ArbitrateDisputedFramesTest, AScanWhosePosesAgreeIsUntouched) {
  Fixture f;
  Scene scan = f.place.scan;
  std::vector<FrameLocalization> loc(scan.train.size());
  std::vector<int> tried;
  for (size_t i = 0; i < scan.train.size(); ++i) {
    loc[i].placed = true;
    std::vector<View> near = {scan.train[i]};
    testing_util::TurnAboutTheScene(&near, 0, 0, 2.0);  // PnP's noise: within the fit's 5 degrees.
    loc[i].c2w = near[0].camera.c2w;
    tried.push_back(int(i));
  }
  const Scene before = scan;
  absl::StatusOr<ArbitrationReport> r = ArbitrateDisputedFrames(loc, tried, f.map, f.place.extent, &scan);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->disputed, 0);
  for (size_t i = 0; i < scan.train.size(); ++i) EXPECT_EQ(scan.train[i].camera.c2w, before.train[i].camera.c2w);
}

TEST(ArbitrateDisputedFramesTest, RefusesBadOptions) {
  Fixture f;
  Scene scan = f.place.scan;
  ArbitrationOptions o;
  o.max_side = 4;
  EXPECT_TRUE(absl::IsInvalidArgument(ArbitrateDisputedFrames({}, {}, f.map, 1.0, &scan, o).status()));
  o = ArbitrationOptions();
  o.rotation_deg = 0;
  EXPECT_TRUE(absl::IsInvalidArgument(ArbitrateDisputedFrames({}, {}, f.map, 1.0, &scan, o).status()));
}

}  // namespace
}  // namespace clnerf
