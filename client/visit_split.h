// Visits cut from one capture, for the rescan benchmarks (`bench register`,
// `bench rescan`): the capture (a dataset folder or a procedural
// forward-facing scene), split into two visits by alternate frames; a
// similarity that moves a visit into a frame of its own; and the error of
// placed poses against the known ones.
// Thread-safety: pure functions.
#ifndef CLNERF_CLIENT_VISIT_SPLIT_H_
#define CLNERF_CLIENT_VISIT_SPLIT_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/dataset_options.h"
#include "core/data/scene.h"
#include "core/pose/similarity.h"

namespace clnerf {

// A dataset folder (LoadScene); "procedural": a textured forward-facing
// scene, 48 + 4 views at 240 x 180; or "procedural-moved": a textured
// object capture with its surroundings, orbited twice (32 + 4 views per
// time step at 240 x 180), with objects moved between the two (one gone,
// one recoloured, one new).
absl::StatusOr<Scene> LoadVisitScene(const std::string& data, const DatasetOptions& dataset);
// A capture of one time: even training frames into `a`, odd into `b`. A
// capture of several: time step 0's into `a`, time step 1's into `b`
// (time steps unchanged). `a` keeps the capture's held-out views, `b` none.
void SplitVisits(const Scene& all, Scene* a, Scene* b);
// The capture's held-out views (test, else val) of `time_step`; all of
// them when none is of that time (a capture of one time).
std::vector<View> HeldOutAt(const Scene& all, int time_step);
// A rotation of `rotation_deg` about a random axis, `scale`, and a random
// shift of up to `extent` per axis (seeded).
Similarity OwnFrame(double rotation_deg, double scale, uint64_t seed, double extent);

struct PoseErrors {
  double centre_median = 0, centre_max = 0;  // % of the extent.
  double rotation_median = 0, rotation_max = 0;  // Degrees.
  std::vector<double> centre, rotation;          // Per frame.
  // Frames off by more than 10 % of the extent or 5 degrees: "i (c %, r deg)".
  std::string Outliers() const;
};
// Frame i of `placed` against frame i of `truth`.
PoseErrors FrameErrors(const std::vector<View>& placed, const std::vector<View>& truth, double extent);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_VISIT_SPLIT_H_
