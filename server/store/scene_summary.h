// SceneSummary: what a viewer needs to know to look around one model version:
// its time steps, where the cameras of each scan stood, the world's up
// direction, a point to orbit about and a sensible first camera. It is
// derived from the version's recorded cameras (the replay memory keeps every
// camera, never the images) and its scene normalisation, so it costs no
// rendering.
//
// Thread-safety: a pure function of an immutable Servable.
#ifndef CLNERF_SERVER_SCENE_SUMMARY_H_
#define CLNERF_SERVER_SCENE_SUMMARY_H_

#include <cstdint>
#include <vector>

#include "core/data/camera.h"
#include "server/store/model_registry.h"

namespace clnerf {

struct SceneSummary {
  int64_t version = 0;
  int time_steps = 0;
  bool bounded = true;  // An object in a box (vs. an unbounded real place).
  // World up: the cameras' mean up direction (unit).
  Eigen::Vector3f up = Eigen::Vector3f::UnitZ();
  // The point the cameras look at (least squares over their optical axes),
  // or the model box's centre when the axes are near-parallel.
  Eigen::Vector3f focus = Eigen::Vector3f::Zero();
  float radius = 1;  // Median camera distance to `focus`.
  // One camera per time step (the first recorded view of that scan), in
  // time-step order; `default_camera` is the latest one.
  std::vector<Camera> scan_cameras;
  Camera default_camera;
  size_t cameras = 0;  // Views recorded over all scans.
};

SceneSummary Summarize(const Servable& servable);

}  // namespace clnerf

#endif  // CLNERF_SERVER_SCENE_SUMMARY_H_
