// Capacity: "model no more than a scene needs". Derives the hash grid's
// finest resolution, its table size, the occupancy-grid resolution and the
// march step from the scene itself (pixel footprint at the scene centre and
// the model box), instead of the GPU defaults (finest 2048*s, 2^19 entries
// per level, 1024 steps per diagonal), which over-provision small captures.
// Pure functions; thread-safe.
#ifndef CLNERF_CORE_FIELD_CAPACITY_H_
#define CLNERF_CORE_FIELD_CAPACITY_H_

#include <optional>
#include <string>

#include "absl/status/status.h"
#include "core/field/ngp_model.h"
#include "core/data/scene.h"

namespace clnerf {

struct CapacityOptions {
  // Finest-level grid cells per pixel footprint (at the median camera's
  // distance to the box centre). 2 = Nyquist.
  float oversample = 4.0f;
  // Table entries per level ~= table_factor * finest_resolution^2 (surfaces
  // grow with the square of resolution), rounded up to a power of two.
  // Measured: on lego 2^14 matches 2^16 within 0.2 dB at a third of the
  // bytes (docs/method.md, capacity sweep), hence 1/16 rather than upstream's ~1/4.
  float table_factor = 0.0625f;
  int min_log2_table_size = 14;
  int max_log2_table_size = 16;
  // March steps per finest grid cell along a ray (bounded scenes).
  float steps_per_cell = 1.0f;
  // Unbounded scenes: pixel footprints per march step, near the cameras
  // (minimum step) and along the cone beyond. Measured on fox_8 (1500 steps):
  // 1 -> 28.99 dB, 115 samples marched per ray; 2 -> 28.63 dB, 67 per ray;
  // 3 (with 15 levels) -> 26.75 dB, 77 per ray (coarser steps grew fog).
  float unbounded_step_pixels = 2.0f;
  // Upper bound on the finest resolution over the model box (0 = upstream's
  // 2048 per unit of bound).
  int max_finest_resolution = 0;
  absl::Status Validate() const;
};

struct CapacityReport {
  float pixel_footprint = 0;   // Model units per pixel at the scene centre.
  int finest_resolution = 0;
  int log2_table_size = 0;
  int occupancy_resolution = 0;
  float steps_per_diagonal = 0;
  std::string ToString() const;
};

// Explicit sizes that win over the derived ones (`clnerf train --table-log2
// 15`). Unset fields keep what DeriveModelOptions chose; set ones are applied
// as given. Validate() refuses values that would not mean what they say
// (a zero or negative size, step or threshold; a negative cone or near
// plane); the applied options are then checked by ModelOptions::Validate.
struct CapacityOverrides {
  std::optional<int> log2_table_size;
  std::optional<int> finest_resolution;
  std::optional<int> occupancy_resolution;
  std::optional<float> steps_per_diagonal;
  std::optional<float> cone_angle;           // 0: constant steps; > 0: exponential.
  std::optional<float> near;                 // Model units from the camera.
  std::optional<float> occupancy_threshold;  // Density; derived: see DeriveModelOptions.
  bool empty() const;
  absl::Status Validate() const;
  ModelOptions ApplyTo(ModelOptions options) const;
};

// Fills grid/occupancy/march fields of `base` from the scene's training
// cameras (model space via `norm`). Other fields of `base` are kept.
ModelOptions DeriveModelOptions(const Scene& scene, const Normalization& norm, const CapacityOptions& capacity,
                                ModelOptions base, CapacityReport* report = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_CAPACITY_H_
