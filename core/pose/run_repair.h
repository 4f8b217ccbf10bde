// RunRepair: puts a run of frames that the pose check disputes
// (pose_check.h: a run that structure from motion turned about a scene that
// looks alike from opposite sides) back into the frame of the others.
//
// The run is consistent by itself; one similarity carries it into the
// others' frame. The pairs of frames in order that cross between the runs
// hold the truth: each gives its disputed frame's rotation (its partner's
// rotation composed with the photos' relative rotation) and the direction
// from its partner to it (the essential matrix's baseline). The transform's
// rotation is the consensus of the pairs' (the largest set within
// max_spread_deg of one of them, averaged), and its translation (and scale,
// unless rigid) the least-squares solution of every used pair's centre
// lying on its ray from its partner. Registering the run against a model of the others
// instead does not work: localisation is fooled by the same symmetry (beer_2:
// it turned the run by 0.9 degrees, not 180; docs/pose_check.md).
//
// Thread-safety: free functions on values; no shared state.
#ifndef CLNERF_CORE_POSE_RUN_REPAIR_H_
#define CLNERF_CORE_POSE_RUN_REPAIR_H_

#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/scene.h"
#include "core/pose/pose_check.h"
#include "core/pose/similarity.h"

namespace clnerf {

struct RunRepairOptions {
  // A crossing pair's rotation counts when within this of the consensus.
  double max_spread_deg = 10.0;
  // Crossing pairs needed (their centres fix the translation).
  int min_pairs = 3;
  // Solve a rigid turn (scale 1: both runs come from one reconstruction),
  // or a similarity. Short baselines between neighbours leave the scale
  // weakly fixed: on a rendered orbit turned by 175 degrees the similarity
  // came out at scale 1.25 and put the run 3-10 % of the orbit off.
  bool rigid = true;
  absl::Status Validate() const;
};

struct RunRepair {
  Similarity transform;            // Disputed run's poses -> the others' frame.
  int crossing_pairs = 0;          // Matched pairs between the runs.
  int pairs_used = 0;              // Those within max_spread_deg of the consensus.
  double turn_deg = 0;             // The transform's rotation.
  double rotation_spread_deg = 0;  // Median angle of the used pairs' rotations from it.
  double centre_residual = 0;      // RMS of the centre equations, world units.
  std::string Summary() const;
};

// The similarity for `report`'s disputed frames of `views` (those the report
// was made over). FAILED_PRECONDITION when nothing is disputed, too few
// pairs cross, or the solution is degenerate (scale <= 0, a frame behind
// its partner).
absl::StatusOr<RunRepair> SolveRunRepair(const PoseCheckReport& report, const std::vector<View>& views,
                                         const RunRepairOptions& options = {});

// Moves every view of `scene` (train, val, test) named in `names` by
// `repair.transform`.
void ApplyRunRepair(const RunRepair& repair, const std::set<std::string>& names, Scene* scene);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_RUN_REPAIR_H_
