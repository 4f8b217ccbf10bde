// LocalizePhotos: "where was this photo taken?" in a place's frame. The
// place's model is rendered at spread-out stored cameras (the map; old
// images are never kept), and each photo is placed against those renders on
// its own (FeatureLocalizer: SIFT, PnP + RANSAC on rendered depth). Unlike
// RegisterScan there is no similarity over many frames to average the noise
// out: one photo's pose is as good as its inliers (about 1 degree on a
// forward-facing capture), and the report says how many it had.
//
// Photos without intrinsics get the place's latest camera's, scaled to the
// photo's size, and the focal length that gives the most PnP inliers among a
// few around it (a phone's own photos have its field of view).
//
// Thread-safety: a pure function; the map must allow concurrent renders.
#ifndef CLNERF_CORE_POSE_PHOTO_LOCALIZATION_H_
#define CLNERF_CORE_POSE_PHOTO_LOCALIZATION_H_

#include <atomic>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/pose/feature_localizer.h"
#include "core/pose/place_map.h"
#include "core/pose/registration.h"

namespace clnerf {

struct PhotoQuery {
  std::string name;
  Image image;
  std::optional<Intrinsics> intrinsics;  // Unset: guessed (see above).
};

struct PhotoLocation {
  std::string name;
  FrameLocalization found;  // found.placed says whether `camera` holds.
  Camera camera;            // Pose in the place's frame, with the intrinsics used.
  bool intrinsics_guessed = false;
};

struct PhotoLocalizationReport {
  std::vector<PhotoLocation> photos;  // In query order.
  int references = 0, map_points = 0;
  double render_seconds = 0, localize_seconds = 0;
};

// FAILED_PRECONDITION when the place has no cameras; INVALID_ARGUMENT for an
// empty photo or intrinsics that do not match it; CANCELLED on `cancel`.
absl::StatusOr<PhotoLocalizationReport> LocalizePhotos(const std::vector<PhotoQuery>& photos, const PlaceMap& map,
                                                       const std::vector<Camera>& place_cameras,
                                                       const RegistrationOptions& options,
                                                       const std::atomic<bool>* cancel = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_PHOTO_LOCALIZATION_H_
