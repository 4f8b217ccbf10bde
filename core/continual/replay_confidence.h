// Replay confidence: how far each generative-replay label can be trusted
// (issue 23, item 2, second half). A replay label is θ_{t-1}'s render of a
// past view's pixel; where θ_{t-1} is unsure of that pixel, a full-weight
// label copies its guess into θ_t as firmly as a photo would. Two signals,
// each scaling the label's loss weight (on top of replay_weights.h's):
//   * teacher agreement: θ_{t-2} (the version before θ_{t-1}) renders the same
//     pixel at the same time step; where the two renders differ by d (mean
//     absolute RGB), the label's weight is multiplied by
//       1 / (1 + (d / agreement_tolerance)^2),
//     so a pixel the last update still moved is trusted less than one that
//     has settled. Views of the newest past scan (which θ_{t-2} never had) and
//     every label of the second update (no θ_{t-2}) keep their weight.
//   * transmittance: a ray θ_{t-1} finds neither clear (opacity near 0, the
//     background shows) nor opaque (near 1) ends on a haze, an edge or a
//     floater; its weight is multiplied by
//       1 - transmittance_weight * 4 a (1 - a)     (a = accumulated opacity),
//     1 at a = 0 or 1 and 1 - transmittance_weight at a = 1/2.
// Nothing more is stored: θ_{t-2} is the previous version, which the store
// keeps anyway.
//
// Pure functions of their inputs; the models are only read (by the rendering
// threads). Thread-safe.
#ifndef CLNERF_CORE_CONTINUAL_REPLAY_CONFIDENCE_H_
#define CLNERF_CORE_CONTINUAL_REPLAY_CONFIDENCE_H_

#include <atomic>
#include <vector>

#include "absl/status/status.h"
#include "core/continual/replay_labels.h"
#include "core/data/camera.h"
#include "core/field/ngp_model.h"

namespace clnerf {

struct ReplayConfidenceOptions {
  // Teacher agreement: the RGB difference (mean absolute, colours in [0, 1])
  // at which a label's weight halves. 0 = off.
  float agreement_tolerance = 0.0f;
  // Transmittance: how much a half-opaque label loses, in [0, 1]. 0 = off.
  float transmittance_weight = 0.0f;
  bool enabled() const { return agreement_tolerance > 0.0f || transmittance_weight > 0.0f; }
  absl::Status Validate() const;
};

struct ReplayConfidenceReport {
  long long labels = 0;       // Labels considered.
  long long compared = 0;     // Labels θ_{t-2} rendered too.
  double mean_factor = 1.0;   // Mean confidence factor over the labels.
  double seconds = 0;
};

// The weight factor of one label from the two signals (see above);
// `disagreement` < 0 means θ_{t-2} has no render of it.
float ConfidenceFactor(float disagreement, float opacity, const ReplayConfidenceOptions& options);

// Multiplies labels[v].weight (1 where empty) by each label's confidence
// factor. `older` is θ_{t-2} (null: agreement is skipped); cameras[v] (world
// space) is label view v's camera, at its own time step. Needs the labels'
// opacity (RenderReplayLabels fills it). Does nothing when options are off.
// CANCELLED when *cancel turns true.
absl::Status ApplyReplayConfidence(const NgpModel* older, const std::vector<Camera>& cameras,
                                   const ReplayConfidenceOptions& options, const std::atomic<bool>* cancel,
                                   std::vector<ReplayLabelView>* labels, ReplayConfidenceReport* report);

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_REPLAY_CONFIDENCE_H_
