#include "core/ray_marcher.h"

#include <algorithm>
#include <cmath>

namespace clnerf {

absl::Status MarchOptions::Validate() const {
  if (max_samples < 1) return absl::InvalidArgumentError("march: max_samples must be >= 1");
  if (!(steps_per_diagonal >= 16)) return absl::InvalidArgumentError("march: steps_per_diagonal must be >= 16");
  if (!(cone_angle >= 0 && cone_angle < 1)) return absl::InvalidArgumentError("march: cone_angle must be in [0, 1)");
  if (!(near >= 0)) return absl::InvalidArgumentError("march: near must be >= 0");
  return absl::OkStatus();
}

float MarchOptions::min_step() const { return std::sqrt(3.0f) / steps_per_diagonal; }
float MarchOptions::max_step(float bound) const {
  return std::max(min_step(), std::sqrt(3.0f) * 2.0f * bound / 128.0f);
}

bool IntersectBox(const Eigen::Vector3f& o, const Eigen::Vector3f& d, float bound, float* t0, float* t1) {
  float lo = -1e30f, hi = 1e30f;
  for (int a = 0; a < 3; ++a) {
    const float inv = 1.0f / d[a];  // +-inf for d == 0 works with IEEE.
    float ta = (-bound - o[a]) * inv, tb = (bound - o[a]) * inv;
    if (ta > tb) std::swap(ta, tb);
    if (std::isnan(ta) || std::isnan(tb)) {
      if (o[a] < -bound || o[a] > bound) return false;
      continue;
    }
    lo = std::max(lo, ta);
    hi = std::min(hi, tb);
  }
  *t0 = lo;
  *t1 = hi;
  return hi > std::max(lo, 0.0f);
}

namespace {
// Distance along d from p to the boundary of the cell of size `cs` that holds p.
inline float DistanceToCellExit(const Eigen::Vector3f& p, const Eigen::Vector3f& inv_d, float cs, float h) {
  float best = 1e30f;
  for (int a = 0; a < 3; ++a) {
    const float u = (p[a] + h) / cs;
    const float cell = std::floor(u);
    const float target = (inv_d[a] > 0 ? cell + 1.0f : cell) * cs - h;
    const float dist = (target - p[a]) * inv_d[a];
    if (dist >= 0 && dist < best) best = dist;
  }
  return best;
}
}  // namespace

float MarchRay(const OccupancyGrid& grid, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
               float t_start, float t_end, const MarchOptions& opt, float bound, int max_count,
               std::vector<RaySample>* out) {
  const float min_step = opt.min_step(), max_step = opt.max_step(bound);
  const Eigen::Vector3f inv_d = d.cwiseInverse();
  float t = t_start;
  int count = 0;
  while (t < t_end && count < max_count) {
    const Eigen::Vector3f p = o + t * d;
    const int c = grid.CascadeOf(p);
    const float dt = StepAt(t, opt, min_step, max_step);
    if (c < 0) {
      // Rounding can put a point on the box face just outside it; t_end
      // (the box exit) bounds the loop.
      t += dt;
      continue;
    }
    if (grid.OccupiedCell(grid.CellIndex(p, c))) {
      out->push_back({t, dt});
      ++count;
      t += dt;
    } else {
      // Skip to the next cell boundary, keeping t on the step lattice.
      const float target = t + DistanceToCellExit(p, inv_d, grid.CellSize(c), grid.cascade_half_size(c)) + 1e-5f;
      if (opt.cone_angle == 0.0f) {
        t += std::max(1.0f, std::ceil((target - t) / dt)) * dt;
      } else {
        do {
          t += StepAt(t, opt, min_step, max_step);
        } while (t < target);
      }
    }
  }
  return t;
}

}  // namespace clnerf
