// Replay weights: how much each generative-replay label should teach, given
// what the new scan already shows (issue 23, item 2).
//
// A replay label is θ_{t-1}'s render of a past view's pixel. Where the new
// scan's cameras see the same, unchanged surface, the real images teach it
// better than θ_{t-1}'s render does, and a full-weight replay label would
// copy θ_{t-1}'s errors back into θ_t. So a label counts as "seen" when its
// surface point (θ_{t-1}'s expected depth along the pixel's ray, on a ray
// θ_{t-1} finds opaque) projects into some new camera,
//   * in front of that camera and inside its image (and not under its mask),
//   * not occluded there: no nearer than θ_{t-1}'s own depth of that new
//     pixel allows (rendered once per new view at a reduced resolution, at
//     θ_{t-1}'s newest time step), and
//   * photo-consistent: the new image's colour there matches the label
//     within `colour_tolerance` (mean absolute over RGB). A surface that
//     changed since (a moved object, new paint) fails this test and keeps its
//     full replay weight, because only replay remembers how it was.
// Seen labels get `seen_weight` (0 drops them from the draws altogether);
// the rest keep weight 1.
//
// Pure functions of their inputs; the model is only read (by the rendering
// threads). Thread-safe.
#ifndef CLNERF_CORE_CONTINUAL_REPLAY_WEIGHTS_H_
#define CLNERF_CORE_CONTINUAL_REPLAY_WEIGHTS_H_

#include <atomic>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "core/continual/replay_labels.h"
#include "core/data/camera.h"
#include "core/data/scene.h"
#include "core/field/ngp_model.h"

namespace clnerf {

struct ReplayWeightOptions {
  // Weight of a label the new scan sees (see above). 1 = off (every label
  // teaches fully, the paper's replay); 0 = seen labels are never drawn.
  float seen_weight = 1.0f;
  // Mean absolute RGB difference (colours in [0, 1]) under which the new
  // image agrees with the label.
  float colour_tolerance = 0.1f;
  // Occlusion test: the label's point is visible from a new camera when its
  // distance is at most θ_{t-1}'s depth there × (1 + depth_tolerance).
  float depth_tolerance = 0.05f;
  // Labels whose ray θ_{t-1} finds less opaque than this have no surface to
  // see (sky, background) and keep weight 1.
  float min_opacity = 0.5f;
  // The new views' depth maps for the occlusion test are rendered with at
  // most this many pixels on their longer side.
  int depth_map_max_side = 64;
  // A seen label takes the new photo's colour at its surface point instead
  // of θ_{t-1}'s render (a real measurement of an unchanged surface, moved
  // into the past view), with `seen_weight` as its weight.
  bool seen_label_from_photo = false;
  absl::Status Validate() const;
};

struct ReplayWeightReport {
  long long labels = 0;  // Labels considered.
  long long seen = 0;    // Labels that got seen_weight.
  double seconds = 0;
};

// The new views' depth maps (θ_{t-1} at its newest time step, model units,
// at most max_side pixels on the longer side).
struct NewViewDepth {
  Camera small;  // Model space, reduced resolution.
  std::vector<float> depth;
};

// Whether a model-space point `x` (θ_{t-1}'s surface along a past pixel with
// label colour `rgb`) is seen by the new view `view` (world camera and photo).
// When seen and `photo_rgb` is not null, the photo's colour there is written
// to it.
bool SeenByNewView(const Eigen::Vector3f& x, const float* rgb, const View& view, const Camera& view_model_camera,
                   const NewViewDepth& dm, const ReplayWeightOptions& options, float* photo_rgb = nullptr);

// Fills labels[v].weight for every past view v (cameras[v], world space)
// from θ_{t-1} (`prev`) and the new scan's training views. Needs the labels'
// depth and opacity (RenderReplayLabels fills them). With seen_weight 1 (and no
// seen_label_from_photo) it does nothing. CANCELLED when *cancel turns true.
absl::Status WeightReplayLabels(const NgpModel& prev, const std::vector<Camera>& cameras,
                                const std::vector<View>& new_views, const ReplayWeightOptions& options,
                                const std::atomic<bool>* cancel, std::vector<ReplayLabelView>* labels,
                                ReplayWeightReport* report);

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_REPLAY_WEIGHTS_H_
