// Pose arbitration: after a scan is registered (registration.h), each frame
// tried has two poses in the place's frame: the scan's own (its structure
// from motion, moved by the fitted similarity) and, when PnP placed it
// against the place's renders, its own localisation. For most frames the two
// agree within the fit's tolerances. Where they do not, one of them is
// wrong, and the place's map says which: the map is rendered at both poses
// and the photo compared with each (zero-mean normalised cross-correlation
// of grey values at a small size, which ignores exposure), and the frame
// takes the pose whose render the photo resembles clearly better.
//
// Structure from motion over a scan alone goes wrong this way on flat
// scenes: on beer_2's tiled floor COLMAP put 3 of 14 frames mirrored
// (turned 110-172 degrees, 85 % of the place away), a two-view ambiguity
// its own epipolar checks cannot see, while PnP against the place's rendered
// depth had them within a degree. The similarity fit rejected them, but they
// trained as posed.
//
// Thread-safety: ArbitrateDisputedFrames is a pure function of its arguments
// (the map is only rendered, with the calling context's OpenMP threads).
#ifndef CLNERF_CORE_POSE_POSE_ARBITRATION_H_
#define CLNERF_CORE_POSE_POSE_ARBITRATION_H_

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/data/scene.h"
#include "core/pose/place_map.h"
#include "core/pose/feature_localizer.h"

namespace clnerf {

struct ArbitrationOptions {
  // A frame is disputed when its two poses differ by more than this turn or
  // this centre move (fraction of the place's extent): the similarity fit's
  // own inlier tolerances (RegistrationOptions::fit).
  double rotation_deg = 5.0;
  double centre = 0.05;
  // Photo and renders are compared at this long side (pixels; smaller
  // photos keep their size).
  int max_side = 160;
  // The localised pose is taken when the photo's correlation with its render
  // exceeds the correlation with the registered pose's render by at least
  // this (correlations lie in [-1, 1]).
  double margin = 0.1;
  absl::Status Validate() const;
};

struct FrameArbitration {
  int frame = 0;               // Index in scene->train.
  double rotation_deg = 0;     // How far apart the two poses were,
  double centre = 0;           // (fraction of the place's extent).
  double ncc_registered = 0;   // The photo against the map at each pose.
  double ncc_localized = 0;
  bool took_localized = false;
  bool suspect = false;        // Its own pose was distrusted (see below).
  bool weak = false;           // Its PnP pose was a weak one (feature_localizer.h).
};

struct ArbitrationReport {
  int disputed = 0;  // Frames whose two poses disagreed.
  int taken = 0;     // Of them, moved to their localised pose.
  int confirmed = 0;          // Suspect frames whose two poses agreed (kept).
  std::vector<int> dropped;   // Suspect frames the map did not vouch for.
  double seconds = 0;
  std::vector<FrameArbitration> frames;  // The disputed ones.
  // One line for logs: "2 of 3 disputed frames moved to their PnP pose (...)"
  // and, where frames were suspect, how many were confirmed and dropped.
  std::string Summary() const;
};

// Zero-mean normalised cross-correlation of grey values between `photo` and
// `map` rendered at `camera` (whose intrinsics are the photo's), both brought
// to `max_side`: 1 when the render is the photo up to gain and bias.
// INVALID_ARGUMENT when the photo does not match the camera's size or either
// image is flat; the map's render errors pass through.
absl::StatusOr<double> MapCorrelation(const PlaceMap& map, const Image& photo, const Camera& camera, int max_side);

// For `scene` already moved into the place's frame by the registration's
// similarity: every frame of `localized` that PnP placed (scene->train
// index tried[k] for localized[k], as RegistrationReport holds them) whose
// pose in `scene` disagrees with its PnP pose is arbitrated by
// MapCorrelation, and moved to the PnP pose when that wins by the margin.
// `extent`: PlaceExtent. INVALID_ARGUMENT for bad options; a frame whose
// correlation cannot be computed (a flat render) keeps its pose; other
// errors of the map pass through.
//
// `suspect` (indices in scene->train): frames whose own pose is distrusted
// already (the pose check disputed them: pose_check.h). Such a frame is kept
// only where the map vouches for a pose: its PnP pose agrees with its own
// (counted in `confirmed`), or wins the correlation by the margin (it is
// moved there); for these frames a weak PnP pose (FrameLocalization::weak)
// counts too, the correlation being the check its few inliers are not. Every other suspect frame (not tried, not placed by PnP, or
// its PnP pose no better) is listed in `dropped`, for the caller to remove:
// what the pose check alone would have dropped, less what the map rescued.
absl::StatusOr<ArbitrationReport> ArbitrateDisputedFrames(const std::vector<FrameLocalization>& localized,
                                                          const std::vector<int>& tried, const PlaceMap& map,
                                                          double extent, Scene* scene,
                                                          const ArbitrationOptions& options = {},
                                                          const std::vector<int>& suspect = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_POSE_ARBITRATION_H_
