// LocalizePhotos against an exact procedural map: photos of the changed
// place are placed where they were taken, with and without intrinsics; a
// photo of another place is not placed.
#include "core/pose/photo_localization.h"

#include "core/pose/pose_test_util.h"
#include "core/pose/similarity.h"
#include <iostream>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

using testing_util::ChangingScene;
using testing_util::MakePlace;
using testing_util::Place;
using testing_util::ProceduralPlaceMap;

TEST(PhotoLocalizationTest, PlacesPhotosOfTheChangedPlace) {
  Place p = MakePlace(6, /*textured=*/true);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  std::vector<PhotoQuery> photos;
  for (int i : {0, 5, 10}) {
    const View& v = p.scan.train[i];
    photos.push_back({v.name, v.image, v.camera.intrinsics});
  }
  photos.push_back({"no-intrinsics", p.scan.train[8].image, std::nullopt});
  photos.push_back({"with-intrinsics", p.scan.train[8].image, p.scan.train[8].camera.intrinsics});
  absl::StatusOr<PhotoLocalizationReport> r = LocalizePhotos(photos, map, p.cameras, RegistrationOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_EQ(r->photos.size(), 5u);
  for (const PhotoLocation& l : r->photos) std::cout << l.name << " placed " << l.found.placed << " matches " << l.found.matches << " inliers " << l.found.inliers << " fx " << l.camera.intrinsics.fx << "\n";
  EXPECT_GT(r->map_points, 100);
  // The guessed focal length is the one that fits best (the place's own).
  EXPECT_NEAR(r->photos[3].camera.intrinsics.fx, p.scan.train[8].camera.intrinsics.fx,
              1e-3 * p.scan.train[8].camera.intrinsics.fx);
  const int truth[] = {0, 5, 10, 8, 8};
  for (int k = 0; k < 5; ++k) {
    const PhotoLocation& l = r->photos[k];
    const Pose& want = p.scan.train[truth[k]].camera.c2w;
    ASSERT_TRUE(l.found.placed) << l.name << " matches " << l.found.matches << " inliers " << l.found.inliers;
    EXPECT_EQ(l.intrinsics_guessed, k == 3);
    // One photo on its own: a few percent and a degree or two (registration
    // averages many; this is a single PnP against renders).
    EXPECT_LT((l.camera.c2w.col(3) - want.col(3)).norm() / p.extent, 0.03) << l.name;
    EXPECT_LT(RotationAngleDegrees(l.camera.c2w.leftCols<3>().cast<double>(), want.leftCols<3>().cast<double>()),
              2.0)
        << l.name;
  }
}

TEST(PhotoLocalizationTest, PhotoOfAnotherPlaceIsNotPlacedAndBadInputIsRefused) {
  Place p = MakePlace(7);
  ProceduralPlaceMap map(ProceduralWorldAt(p.options, 0));
  ProceduralSceneOptions other = ChangingScene(99);
  other.backdrop = false;
  other.layout = ProceduralLayout::kRoom;
  absl::StatusOr<Scene> room = GenerateProceduralScene(other);
  ASSERT_TRUE(room.ok());
  absl::StatusOr<PhotoLocalizationReport> r = LocalizePhotos(
      {{"room", room->train[0].image, room->train[0].camera.intrinsics}}, map, p.cameras, RegistrationOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->photos[0].found.placed);

  Intrinsics wrong = p.scan.train[0].camera.intrinsics;
  wrong.width += 1;
  EXPECT_TRUE(absl::IsInvalidArgument(
      LocalizePhotos({{"bad", p.scan.train[0].image, wrong}}, map, p.cameras, RegistrationOptions()).status()));
  EXPECT_TRUE(absl::IsInvalidArgument(
      LocalizePhotos({{"empty", Image(), std::nullopt}}, map, p.cameras, RegistrationOptions()).status()));
  EXPECT_TRUE(absl::IsFailedPrecondition(
      LocalizePhotos({{"x", p.scan.train[0].image, std::nullopt}}, map, {}, RegistrationOptions()).status()));
}

}  // namespace
}  // namespace clnerf
