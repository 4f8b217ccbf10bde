// Photometric refinement of a whole scan's similarity: the scan's frames move
// together, by one rotation, shift and scale in the place's frame, until the
// photos agree pixel by pixel with the place's map rendered at their poses.
//
// A scan posed in its own frame (the user's COLMAP run, an AR session) comes
// with poses that agree with each other; what registration (registration.h)
// estimates is the similarity that brings them into the place's frame, from
// each frame's PnP pose against the map's renders. Those are noisy: on
// lego_100 (matched at 240 px) the fit was 0.27 deg off, which cost the
// update 2.9 dB. Aligning every frame on its own (photometric_refine.h)
// would throw away the scan's own relative poses; this refines only the 7
// parameters the scan is uncertain in, from every frame's pixels at once.
//
// Per pyramid level, coarse to fine: each frame's keyframe is the map
// rendered at its current pose (photometric_refine.h's keyframe: solid,
// textured pixels lifted to 3-D); Levenberg-Marquardt then moves the
// similarity (rotation and scale about the frames' centroid, shift) and each
// frame's gain and bias, with residuals weighed by Huber's function at each
// frame's own robust scale, so changed parts of the place do not drag it.
// The result is taken only when the robust cost over all frames fell by
// `min_improvement` and no camera moved beyond the limits.
//
// Thread-safety: RefineSimilarityPhotometric is a pure function of its
// arguments (the map is only rendered, with the calling context's threads).
#ifndef CLNERF_CORE_POSE_PHOTOMETRIC_SIMILARITY_H_
#define CLNERF_CORE_POSE_PHOTOMETRIC_SIMILARITY_H_

#include <atomic>
#include <functional>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/scene.h"
#include "core/pose/direct_alignment.h"
#include "core/pose/photometric_refine.h"
#include "core/pose/place_map.h"
#include "core/pose/similarity.h"

namespace clnerf {

struct SimilarityRefineOptions {
  // Levels, sizes, iterations, pixel selection, Huber's threshold, the move
  // limits (max_rotation_deg, max_centre: the farthest any camera may move,
  // as a fraction of the place's extent) and min_improvement, as for one
  // frame. min_pixels counts per frame: frames with fewer are left out.
  PhotometricRefineOptions alignment;
  // Frames used (spread over the scan's cameras): renders cost the most.
  int max_frames = 16;
  // At least this many frames must have enough pixels.
  int min_frames = 2;
  absl::Status Validate() const;
};

struct SimilarityRefinement {
  // Place frame -> place frame: apply it to the scan (ApplySimilarity) after
  // registration's transform. The identity when !accepted.
  Similarity correction;
  bool accepted = false;  // False: the scan keeps its poses; `why` says why.
  std::string why;
  double rotation_deg = 0;  // Of the correction.
  double scale = 1;         // Of the correction.
  double max_centre = 0;    // The farthest camera move, fraction of extent.
  double cost_before = 0;   // Mean robust cost at the finest level over all
  double cost_after = 0;    // used frames' pixels (grey values in [0, 1]).
  int frames = 0;           // Used at the finest level.
  int pixels = 0;
  double seconds = 0;
};

// (done, total) renders so far.
using SimilarityRefineProgressFn = std::function<void(int done, int total)>;

// Refines the similarity of `scene`'s train views (already in the place's
// frame, as registration placed them) against `map`. `extent`: the place's
// size (PlaceExtent). INVALID_ARGUMENT for bad options or a photo whose size
// differs from its camera; CANCELLED when `cancel` was set; the map's render
// errors pass through. `scene` is not changed.
absl::StatusOr<SimilarityRefinement> RefineSimilarityPhotometric(const PlaceMap& map, const Scene& scene,
                                                                 double extent,
                                                                 const SimilarityRefineOptions& options = {},
                                                                 const SimilarityRefineProgressFn& progress = {},
                                                                 const std::atomic<bool>* cancel = nullptr);

// The solver's parts, exposed for the gradient check.
namespace photometric_similarity_internal {

// (rotation vector, shift, log scale), and the frame's gain and bias.
using Gradient = Eigen::Matrix<double, 1, 9>;

// exp of a small (rotation vector, shift, log scale), rotating and scaling
// about `pivot`: x -> pivot + e^s R (x - pivot) + shift.
Similarity Increment(const Eigen::Matrix<double, 7, 1>& d, const Eigen::Vector3d& pivot);

// The residual gain x photo(projection of `x` by `cam`) + bias - `grey`, and
// (when `j` is not null) its gradient over a left increment (Increment about
// `pivot`) of the similarity that placed `cam`, the gain and the bias. False
// when `x` projects behind the camera or off the photo.
bool Residual(const GreyImage& photo, const Intrinsics& in, const W2C& cam, const Eigen::Vector3d& x, float grey,
              double gain, double bias, const Eigen::Vector3d& pivot, double* r, Gradient* j);

}  // namespace photometric_similarity_internal

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_PHOTOMETRIC_SIMILARITY_H_
