// Ray marching through the occupancy grid: generates the sample points of a
// ray inside the model box, skipping cells the grid marks empty.
//
// Step rule (upstream): dt = clamp(t * cone, min_step, max_step), with
// cone = 0 for bounded synthetic scenes (constant steps) and 1/256 for large
// real scenes (exponential steps). min_step = sqrt(3) / steps_per_diagonal,
// max_step = sqrt(3) * 2s / 128. Pure functions; thread-safe.
#ifndef CLNERF_CORE_RAY_MARCHER_H_
#define CLNERF_CORE_RAY_MARCHER_H_

#include <vector>

#include "absl/status/status.h"
#include "core/occupancy_grid.h"
#include "Eigen/Core"

namespace clnerf {

struct MarchOptions {
  int max_samples = 1024;           // Per ray.
  float steps_per_diagonal = 1024;  // min_step = sqrt(3) / steps_per_diagonal.
  float cone_angle = 0.0f;          // 0: constant steps; 1/256: exponential.
  float near = 0.05f;               // Model units from the camera.
  absl::Status Validate() const;
  float min_step() const;
  float max_step(float bound) const;
};

struct RaySample {
  float t;   // Distance along the (unit) direction.
  float dt;  // Step length represented by the sample.
};

// Intersects the ray with [-bound, bound]^3. Returns false if it misses.
bool IntersectBox(const Eigen::Vector3f& o, const Eigen::Vector3f& d, float bound, float* t0, float* t1);

// The step length at distance t.
inline float StepAt(float t, const MarchOptions& opt, float min_step, float max_step) {
  const float dt = t * opt.cone_angle;
  return dt < min_step ? min_step : (dt > max_step ? max_step : dt);
}

// Marches from t_start (e.g. t0 + jitter * dt) to t_end, appending up to
// `max_count` samples in occupied cells. Returns the t where marching stopped
// (so inference can resume a ray later).
float MarchRay(const OccupancyGrid& grid, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
               float t_start, float t_end, const MarchOptions& opt, float bound, int max_count,
               std::vector<RaySample>* out);

}  // namespace clnerf

#endif  // CLNERF_CORE_RAY_MARCHER_H_
