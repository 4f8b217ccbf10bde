#include "core/pose/registration.h"

#include <algorithm>
#include <cmath>
#include <iostream>
#include <random>
#include <set>

#include "core/data/procedural_scene.h"
#include "core/pose/pose_test_util.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

using testing_util::ChangingScene;
using testing_util::MakePlace;
using testing_util::Place;
using testing_util::ProceduralPlaceMap;

Similarity RandomSimilarity(uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  Similarity s;
  s.rotation = Eigen::AngleAxisd(M_PI * u(rng), Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized())
                   .toRotationMatrix();
  s.scale = std::exp(u(rng));
  s.translation = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 3;
  return s;
}

void ExpectPlacedLikeTruth(const Scene& placed, const Scene& truth, double extent) {
  ASSERT_EQ(placed.train.size(), truth.train.size());
  for (size_t i = 0; i < truth.train.size(); ++i) {
    const Pose& a = placed.train[i].camera.c2w;
    const Pose& b = truth.train[i].camera.c2w;
    EXPECT_LT((a.col(3) - b.col(3)).norm() / extent, 0.01) << "frame " << i;
    EXPECT_LT(RotationAngleDegrees(a.leftCols<3>().cast<double>(), b.leftCols<3>().cast<double>()), 0.5)
        << "frame " << i;
  }
}

TEST(RegistrationTest, MovedScanOfAChangedPlaceIsRegistered) {
  Place p = MakePlace(3);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  const Similarity moved = RandomSimilarity(21);
  Scene scan = p.scan;
  ApplySimilarity(moved, &scan);  // The scan in its own frame.
  RegistrationReport r = RegisterScan(scan, map, p.cameras, p.extent, RegistrationOptions());
  ASSERT_TRUE(r.status.ok()) << r.status;
  EXPECT_FALSE(r.identity);
  EXPECT_GE(r.frames_agreeing, 8) << r.Summary();
  std::cout << r.Summary() << "\n";
  ApplySimilarity(r.transform, &scan);
  ExpectPlacedLikeTruth(scan, p.scan, p.extent);
}

TEST(RegistrationTest, ScanInThePlacesFrameGivesTheIdentity) {
  Place p = MakePlace(4);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  RegistrationReport r = RegisterScan(p.scan, map, p.cameras, p.extent, RegistrationOptions());
  ASSERT_TRUE(r.status.ok()) << r.status;
  EXPECT_TRUE(r.identity) << r.Summary();
  EXPECT_EQ(r.transform.scale, 1.0);
  EXPECT_EQ(r.transform.translation.norm(), 0.0);
}

TEST(RegistrationTest, ScanOfAnotherPlaceIsRefused) {
  Place p = MakePlace(5);
  // The map is the procedural room: walls, planks, a door and a picture.
  ProceduralSceneOptions other = ChangingScene(99);
  other.backdrop = false;
  other.layout = ProceduralLayout::kRoom;
  absl::StatusOr<Scene> object = GenerateProceduralScene(other);
  ASSERT_TRUE(object.ok());
  std::vector<Camera> cams;
  for (const View& v : object->train) cams.push_back(v.camera);
  ProceduralPlaceMap map(ProceduralWorldAt(other, 0));
  RegistrationReport r = RegisterScan(p.scan, map, cams, PlaceExtent(cams, Normalization()), RegistrationOptions());
  EXPECT_TRUE(absl::IsFailedPrecondition(r.status)) << r.status;
  EXPECT_LT(r.frames_agreeing, 3) << r.Summary();
}

// Place 8's changed scan with its focal length scaled by `focal_scale` (a
// structure-from-motion run's camera), moved into a frame of its own and
// registered back into the place's: ready for RefineAgainstPlace.
struct RegisteredScan {
  Place place = MakePlace(8, /*textured=*/true);
  Scene scan = place.scan;
  RegistrationReport report;
};

void RegisterWithFocal(float focal_scale, RegisteredScan* out) {
  for (View& v : out->scan.train) {
    v.camera.intrinsics.fx *= focal_scale;
    v.camera.intrinsics.fy *= focal_scale;
  }
  ApplySimilarity(RandomSimilarity(31), &out->scan);
  ProceduralPlaceMap map(ProceduralWorldAt(out->place.options, 0));
  out->report = RegisterScan(out->scan, map, out->place.cameras, out->place.extent, RegistrationOptions());
  ASSERT_TRUE(out->report.status.ok()) << out->report.status;
  ApplySimilarity(out->report.transform, &out->scan);
}

TEST(RegistrationTest, SelfCalibratedCameraIsRefinedAgainstThePlace) {
  RegisteredScan rs;
  const float true_fx = rs.scan.train[0].camera.intrinsics.fx;
  ASSERT_NO_FATAL_FAILURE(RegisterWithFocal(1.04f, &rs));  // A structure-from-motion run's focal, 4 % off.
  const Place& p = rs.place;
  const RegistrationReport& r = rs.report;
  Scene& scan = rs.scan;
  SharedCameraReport cam;
  Intrinsics refined;
  ASSERT_TRUE(RefineAgainstPlace(r, &scan, &cam, &refined).ok());
  std::cout << "refined fx " << refined.fx << " (true " << true_fx << ", started " << 1.04f * true_fx << "), rms "
            << cam.rms_guess_px << " -> " << cam.rms_refined_px << " px\n";
  EXPECT_TRUE(cam.camera_taken);
  EXPECT_NEAR(refined.fx, true_fx, 0.01f * true_fx);
  EXPECT_LT(cam.rms_refined_px, 0.95 * cam.rms_guess_px);
  EXPECT_LT(cam.rms_px, RegistrationOptions().localizer.reprojection_px);  // Inliers stay inliers.
  for (const View& v : scan.train) EXPECT_EQ(v.camera.intrinsics.fx, refined.fx);
  // Each placed frame now has its own PnP pose under the refined camera: a
  // single frame's pose is noisier than the fit over all (about 1 degree),
  // so the median holds the registration's bound and every frame a looser
  // one.
  std::vector<double> centre, rotation;
  for (size_t i = 0; i < scan.train.size(); ++i) {
    const Pose& a = scan.train[i].camera.c2w;
    const Pose& b = p.scan.train[i].camera.c2w;
    centre.push_back((a.col(3) - b.col(3)).norm() / p.extent);
    rotation.push_back(RotationAngleDegrees(a.leftCols<3>().cast<double>(), b.leftCols<3>().cast<double>()));
    EXPECT_LT(centre.back(), 0.03) << "frame " << i;
    EXPECT_LT(rotation.back(), 2.0) << "frame " << i;
  }
  std::sort(centre.begin(), centre.end());
  std::sort(rotation.begin(), rotation.end());
  EXPECT_LT(centre[centre.size() / 2], 0.01);
  EXPECT_LT(rotation[rotation.size() / 2], 0.5);
}

// A scan whose camera is already the place's (COLMAP held it) keeps it:
// the points do not clearly prefer another, so nothing drifts.
TEST(RegistrationTest, RightCameraIsKept) {
  RegisteredScan rs;
  const Intrinsics truth = rs.scan.train[0].camera.intrinsics;
  ASSERT_NO_FATAL_FAILURE(RegisterWithFocal(1.0f, &rs));
  SharedCameraReport cam;
  Intrinsics kept;
  ASSERT_TRUE(RefineAgainstPlace(rs.report, &rs.scan, &cam, &kept).ok());
  std::cout << "rms " << cam.rms_guess_px << " -> " << cam.rms_refined_px << " px\n";
  EXPECT_FALSE(cam.camera_taken);
  EXPECT_EQ(kept.fx, truth.fx);
  EXPECT_EQ(kept.k1, truth.k1);
  EXPECT_EQ(cam.rms_px, cam.rms_guess_px);
}

TEST(RegistrationTest, ApplySimilarityMovesEverySplitAndPoint) {
  Scene s;
  View v;
  v.camera.c2w = Pose::Identity();
  v.depth.push_back({0, Eigen::Vector3f(1, 0, 0)});
  s.train.push_back(v);
  s.test.push_back(v);
  s.sparse_points.push_back(Eigen::Vector3f(0, 1, 0));
  Similarity m;
  m.scale = 2;
  m.translation = Eigen::Vector3d(1, 2, 3);
  ApplySimilarity(m, &s);
  EXPECT_TRUE(s.train[0].camera.position().isApprox(Eigen::Vector3f(1, 2, 3)));
  EXPECT_TRUE(s.test[0].camera.position().isApprox(Eigen::Vector3f(1, 2, 3)));
  EXPECT_TRUE(s.train[0].depth[0].world.isApprox(Eigen::Vector3f(3, 2, 3)));
  EXPECT_TRUE(s.sparse_points[0].isApprox(Eigen::Vector3f(1, 4, 3)));
}

// A scan in the place's frame that PnP's noise placed 0.66 deg off, and the
// photometric refinement brought back to 0.1 deg: put back as uploaded. The
// same refinement of a scan that really was moved, or one left 1 deg off,
// is not.
TEST(RegistrationTest, ARefinementBackToTheIdentityKeepsTheScanAsUploaded) {
  const std::vector<Eigen::Vector3d> centres = {{2, 0, 0}, {0, 2, 0.5}, {-2, 0, 0}, {0, -2, 0.2}};
  const double extent = 4;
  RegistrationOptions o;
  auto turn = [](double deg) {
    Similarity s;
    s.rotation = Eigen::AngleAxisd(deg * M_PI / 180, Eigen::Vector3d(0.3, 1, 0.2).normalized()).toRotationMatrix();
    return s;
  };
  RegistrationReport noisy;  // What registration found: 0.66 deg, 0.4 % larger.
  noisy.transform = turn(0.66);
  noisy.transform.scale = 1.004;
  noisy.place_extent = extent;
  Similarity back = noisy.transform.Inverse();  // The refinement, leaving 0.1 deg.
  back = turn(0.1).Compose(back);
  EXPECT_TRUE(WithinIdentityHair(back.Compose(noisy.transform), centres, extent, o));
  EXPECT_TRUE(RefinedToIdentity(noisy, back, centres, o));
  EXPECT_FALSE(RefinedToIdentity(noisy, Similarity(), centres, o));  // Still 0.66 deg off.
  EXPECT_FALSE(RefinedToIdentity(noisy, turn(0.34).Compose(noisy.transform.Inverse()), centres, o));
  Similarity shifted = back;  // Centres moved by 1 % of the place.
  shifted.translation += Eigen::Vector3d(0.04, 0, 0);
  EXPECT_FALSE(RefinedToIdentity(noisy, shifted, centres, o));
  RegistrationReport own = noisy;  // A scan in its own frame.
  own.transform = RandomSimilarity(3);
  EXPECT_FALSE(RefinedToIdentity(own, turn(0.1), centres, o));
  // ApplyRefinedSimilarity on a scan registration moved: put back as
  // uploaded, or the correction applied.
  Scene uploaded;
  for (const Eigen::Vector3d& c : centres) {
    View v;
    v.camera.c2w = Pose::Identity();
    v.camera.c2w.col(3) = c.cast<float>();
    uploaded.train.push_back(v);
  }
  Scene placed = uploaded;
  ApplySimilarity(noisy.transform, &placed);
  Scene refined = placed;
  EXPECT_TRUE(ApplyRefinedSimilarity(noisy, back, o, &refined));
  for (size_t i = 0; i < centres.size(); ++i) {
    EXPECT_LT((refined.train[i].camera.c2w - uploaded.train[i].camera.c2w).norm(), 1e-5) << "frame " << i;
  }
  const Similarity far = turn(0.34).Compose(noisy.transform.Inverse());
  refined = placed;
  EXPECT_FALSE(ApplyRefinedSimilarity(noisy, far, o, &refined));
  for (size_t i = 0; i < centres.size(); ++i) {
    EXPECT_LT((refined.train[i].camera.c2w - far.ApplyToPose(placed.train[i].camera.c2w)).norm(), 1e-5)
        << "frame " << i;
  }
  noisy.identity = true;  // Already snapped by registration: nothing to put back.
  EXPECT_FALSE(RefinedToIdentity(noisy, back, centres, o));
}

TEST(RegistrationTest, DroppedFramesLeaveTheReportIndexingTheScanWithoutThem) {
  RegistrationReport r;
  r.tried = {0, 2, 3, 5, 7};
  for (int i : r.tried) {
    FrameLocalization l;
    l.inliers = 100 + i;  // Tags each entry with its frame.
    r.localized.push_back(l);
  }
  r.DropFrames({1, 3, 7});  // 1 was not tried; 3 and 7 were.
  EXPECT_EQ(r.tried, (std::vector<int>{0, 1, 3}));  // Frames 0, 2, 5 of the scan without 1, 3, 7.
  ASSERT_EQ(r.localized.size(), 3u);
  EXPECT_EQ(r.localized[0].inliers, 100);
  EXPECT_EQ(r.localized[1].inliers, 102);
  EXPECT_EQ(r.localized[2].inliers, 105);
}

// Step 5½ through the report: of two mirrored frames the pose check
// disputed, the one PnP placed goes back to its PnP pose and the other is
// named for dropping and forgotten by the report; an arbitration that fails
// names every suspect frame.
TEST(RegistrationTest, ArbitratedScanNamesTheFramesToDropAndTheReportForgetsThem) {
  Place p = MakePlace(41, /*textured=*/true);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  Scene scan = p.scan;
  const std::vector<View> truth = scan.train;
  RegistrationReport r;
  for (size_t i = 0; i < truth.size(); ++i) {
    FrameLocalization l;
    l.placed = i != 4;
    l.c2w = truth[i].camera.c2w;
    r.localized.push_back(l);
    r.tried.push_back(int(i));
  }
  for (int i : {2, 4}) testing_util::TurnAboutTheScene(&scan.train, i, i, 170.0);
  const std::set<std::string> suspect = {truth[2].name, truth[4].name};
  std::set<std::string> drop;
  RegistrationReport failing = r;
  ArbitrationOptions bad;
  bad.max_side = 4;
  Scene untouched = scan;
  EXPECT_FALSE(ArbitrateRegisteredScan(map, p.extent, bad, suspect, &failing, &untouched, &drop).ok());
  EXPECT_EQ(drop, suspect);
  EXPECT_EQ(failing.tried.size(), truth.size() - 2);

  absl::StatusOr<ArbitrationReport> a = ArbitrateRegisteredScan(map, p.extent, {}, suspect, &r, &scan, &drop);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(drop, (std::set<std::string>{truth[4].name})) << a->Summary();
  EXPECT_EQ(a->taken, 1) << a->Summary();
  EXPECT_EQ(scan.train[2].camera.c2w, truth[2].camera.c2w);
  ASSERT_EQ(r.tried.size(), truth.size() - 1);
  EXPECT_EQ(r.tried[4], 4);  // Frame 5 of the scan, 4 once frame 4 is removed.
  EXPECT_EQ(r.localized[4].c2w, truth[5].camera.c2w);
}

TEST(RegistrationTest, OptionsAreValidated) {
  RegistrationOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.min_frames = 1;
  EXPECT_FALSE(o.Validate().ok());
  o = RegistrationOptions();
  o.localizer.ratio = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = RegistrationOptions();
  o.camera.min_rms_gain = 1;  // No camera could ever be taken.
  EXPECT_FALSE(o.Validate().ok());
  o = RegistrationOptions();
  o.camera.max_focal_change = -0.1;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace clnerf
