// Photometric pose refinement: moves one photo's camera pose until the photo
// agrees, pixel by pixel, with the place's map rendered at that pose (direct
// image alignment, as in DSO or LSD-SLAM, with the map's render and depth as
// the keyframe). Feature-based registration (registration.h) leaves each
// frame a few tenths of a degree off (on a forward-facing capture posed by
// COLMAP: 0.23 degrees median after RefineAgainstPlace, 1.3 px at its focal),
// which costs an update most of a dB; aligning against θ_{t-1}'s own renders
// removes what the features cannot see.
//
// Per pyramid level, coarse to fine: render the map at the current pose
// (colour, median depth, opacity), lift the solid pixels to 3-D, and run
// Gauss-Newton on the photo's grey values at their projections over the
// pose's 6 degrees of freedom plus a gain and bias (exposure differs between
// visits). Residuals are weighed by Huber's function at a scale from their
// median absolute deviation, so parts of the place that changed since the
// map (moved furniture) do not drag the pose. A result is accepted only when
// the robust cost fell by min_improvement and the move stays within the limits; otherwise the
// pose is returned unchanged with the reason.
//
// Thread-safety: RefinePosePhotometric is a pure function of its arguments
// (the map is only rendered, with the calling context's OpenMP threads).
#ifndef CLNERF_CORE_POSE_PHOTOMETRIC_REFINE_H_
#define CLNERF_CORE_POSE_PHOTOMETRIC_REFINE_H_

#include <atomic>
#include <functional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/data/scene.h"
#include "core/pose/place_map.h"

namespace clnerf {

struct PhotometricRefineOptions {
  // Pyramid levels; the finest is the photo brought to max_side (long side),
  // each coarser one half the previous.
  int levels = 3;
  int max_side = 320;
  int iterations = 10;  // Gauss-Newton steps per level.
  // Pixels used: the map's opacity at least min_opacity (a solid surface
  // whose depth means something), and the render's grey gradient at least
  // min_gradient per pixel (flat regions carry no pose information).
  float min_opacity = 0.95f;
  float min_gradient = 0.01f;
  // Huber's threshold in robust standard deviations (1.4826 x MAD).
  double huber_k = 1.345;
  // A refinement that moves the camera further than this is refused (the
  // alignment slid to a wrong optimum): rotation in degrees, centre as a
  // fraction of `extent`.
  double max_rotation_deg = 2.0;
  double max_centre = 0.03;
  // At least this many pixels must be usable at the finest level.
  int min_pixels = 200;
  // The robust cost must fall by at least this fraction for the refined
  // pose to be taken (less is noise: the pose was already as good).
  double min_improvement = 0.01;
  absl::Status Validate() const;
};

struct PhotometricRefinement {
  Pose c2w;               // The refined pose (the input one when !accepted).
  bool accepted = false;  // False: kept the input pose; `why` says why.
  std::string why;
  double rotation_deg = 0;  // How far the camera turned and moved
  double centre = 0;        // (fraction of extent).
  double cost_before = 0;   // Mean robust cost at the finest level, grey
  double cost_after = 0;    // values in [0, 1].
  int pixels = 0;           // Used at the finest level.
  double gain = 1, bias = 0;  // Map ~ gain x photo + bias, as fitted.
};

// Refines `camera`'s pose (its intrinsics are the photo's, kept) so that
// `photo` matches `map` rendered there. `extent`: the place's size
// (PlaceExtent). INVALID_ARGUMENT for bad options or a photo whose size does
// not match the camera; the map's render errors pass through.
absl::StatusOr<PhotometricRefinement> RefinePosePhotometric(const PlaceMap& map, const Image& photo,
                                                            const Camera& camera, double extent,
                                                            const PhotometricRefineOptions& options = {});

struct ScanPhotometricReport {
  int frames = 0;     // Train frames tried.
  int accepted = 0;   // Whose refined pose was taken.
  double median_rotation_deg = 0;  // Of the accepted moves.
  double median_centre = 0;        // Fraction of extent.
  double seconds = 0;
  std::vector<std::string> why;    // Per frame: why its pose was kept ("" when moved).
};

// (done, total) frames refined so far.
using PhotometricProgressFn = std::function<void(int done, int total)>;

// RefinePosePhotometric for every train view of `scene` (already in the
// place's frame), taking each accepted pose. Frames run one after another,
// each render using the calling context's threads. CANCELLED when `cancel`
// was set (frames done so far keep their refined poses); errors of the map's
// renders pass through.
absl::StatusOr<ScanPhotometricReport> RefineScanPhotometric(const PlaceMap& map, Scene* scene, double extent,
                                                            const PhotometricRefineOptions& options = {},
                                                            const PhotometricProgressFn& progress = {},
                                                            const std::atomic<bool>* cancel = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_PHOTOMETRIC_REFINE_H_
