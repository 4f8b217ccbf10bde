// Frame check: whether each frame of a scan, once placed in the place's
// frame, shows what the place's map shows from its pose. Structure from
// motion over one scan can pose a few frames consistently with its own
// points and still wrongly: on a bare tiled floor COLMAP put 8 of 31 frames
// of a phone video at the mirror image of their true pose (about 178
// degrees off, the plane's two-fold ambiguity), and registration cannot see
// them, because PnP against the place's renders places none of those
// frames (too little texture); trained as posed, they teach the update
// views that never existed.
//
// The check renders the map at each frame's pose at a small size and
// correlates it with the photo (grey values, both slightly blurred, zero
// mean and unit variance: exposure, white balance and a pixel of pose
// error do not matter; a mirrored view correlates near zero). Frames
// registration verified (PnP placed them where the similarity put them)
// set the reference; a frame that correlates far less than they do is
// dropped from the scan's training views. Frames of a changed part of the
// place (moved furniture) still correlate with what did not change.
//
// Thread-safety: pure functions of their arguments; the map is rendered
// with the calling context's OpenMP threads.
#ifndef CLNERF_CORE_POSE_FRAME_CHECK_H_
#define CLNERF_CORE_POSE_FRAME_CHECK_H_

#include <atomic>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/data/scene.h"
#include "core/pose/place_map.h"

namespace clnerf {

struct FrameCheckOptions {
  // Photo and render compared at this long side (pixels).
  int max_side = 96;
  // Gaussian blur of both, in pixels at that size.
  float blur_sigma = 1.0f;
  // A frame is dropped when its correlation is below min_relative times the
  // median over the verified frames (the reference)...
  double min_relative = 0.5;
  // ... and below this absolute correlation (a reference that is itself
  // low, e.g. a hazy map, must not drop frames that agree as well as it
  // allows).
  double max_drop_correlation = 0.3;
  // Never drop more than this fraction of the scan's frames (more means the
  // map, not the frames, is at fault: keep them all).
  double max_drop_fraction = 0.5;
  absl::Status Validate() const;
};

// Correlation in [-1, 1] between `photo` and the map rendered at `camera`
// (see above). INVALID_ARGUMENT when the photo's size does not match the
// camera's; the map's render errors pass through.
absl::StatusOr<double> FrameAgreement(const PlaceMap& map, const Image& photo, const Camera& camera,
                                      const FrameCheckOptions& options = {});

struct FrameCheckReport {
  std::vector<double> agreement;  // Per train view of the scene.
  std::vector<int> dropped;       // Indices into the train views.
  double reference = 0;           // Median agreement of the verified frames.
  double seconds = 0;
  bool capped = false;            // More would have been dropped than allowed.
};

// Checks every train view of `scene` (already in the place's frame).
// `verified[i]`: registration confirmed frame i (their median agreement is
// the reference; with none verified, the median over all frames is). Only
// unverified frames are dropped. CANCELLED on `cancel`.
absl::StatusOr<FrameCheckReport> CheckScanFrames(const PlaceMap& map, const Scene& scene,
                                                 const std::vector<bool>& verified,
                                                 const FrameCheckOptions& options = {},
                                                 const std::atomic<bool>* cancel = nullptr);

// Removes report.dropped from scene->train (order kept).
void DropCheckedFrames(const FrameCheckReport& report, Scene* scene);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_FRAME_CHECK_H_
