// Ray marching through the occupancy grid: generates the sample points of a
// ray inside the model box, skipping cells the grid marks empty.
//
// Step rule (upstream): dt = clamp(t * cone, min_step, max_step), with
// cone = 0 for bounded synthetic scenes (constant steps) and 1/256 for large
// real scenes (exponential steps). min_step = sqrt(3) / steps_per_diagonal,
// max_step = sqrt(3) * 2s / 128. Pure functions; thread-safe.
#ifndef CLNERF_CORE_FIELD_RAY_MARCHER_H_
#define CLNERF_CORE_FIELD_RAY_MARCHER_H_

#include <vector>

#include "absl/status/status.h"
#include "core/data/contraction.h"
#include "core/field/occupancy_grid.h"
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
// (so inference can resume a ray later). The loop is bounded (at most
// kMaxMarchIterations cell visits, and it stops as soon as a step fails to
// advance t), so non-finite or absurd rays end.
float MarchRay(const OccupancyGrid& grid, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
               float t_start, float t_end, const MarchOptions& opt, float bound, int max_count,
               std::vector<RaySample>* out);

// Contracted (unbounded) scenes: the occupancy grid lives in contracted space
// (-2, 2)^3 (see contraction.h) and so do the step rules: the step in
// contracted units is clamp(t * cone * |J d|, min_step, max_step(2)), i.e. a
// pixel footprint near the cameras and about constant contracted steps far
// away (1/r^2 spacing in model space). Empty space is skipped by its exit
// distance along the ray's contracted direction J d: in the inner cube
// (where the contraction is the identity) a run of empty blocks at once, in
// the shell cell by cell; the sample after a skip lands where the skip ends.
// Same contract as MarchRay otherwise; t is in model units along the unit
// direction d.
float MarchRayContracted(const OccupancyGrid& grid, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
                         float t_start, float t_end, const MarchOptions& opt, int max_count,
                         std::vector<RaySample>* out);

// The model-space step at x = o + t d of a contracted ray; *speed (optional)
// receives |J d|, contracted units per model unit.
float ContractedStepAt(const Eigen::Vector3f& x, const Eigen::Vector3f& d, float t, const MarchOptions& opt,
                       float* speed = nullptr);

// Where a contracted ray stops: the model-space cube beyond which the
// contracted point is within one minimum step of the outer face.
float ContractedFarBound(const MarchOptions& opt);

// Minimum contracted step in the shell 1 < |q|_inf < 2 is 1 / this.
inline constexpr float kContractedShellSteps = 64.0f;

// Upper bound on loop iterations per MarchRay* call.
inline constexpr int kMaxMarchIterations = 1 << 16;
// Sanity limits of MarchOptions (real models use 128-1024 steps per diagonal
// and at most a few thousand samples per ray).
inline constexpr float kMaxStepsPerDiagonal = 65536.0f;
inline constexpr int kMaxMarchSamples = 1 << 16;

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_RAY_MARCHER_H_
