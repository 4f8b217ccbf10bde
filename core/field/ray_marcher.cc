#include "core/field/ray_marcher.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace clnerf {

absl::Status MarchOptions::Validate() const {
  if (max_samples < 1) return absl::InvalidArgumentError("march: max_samples must be >= 1");
  if (max_samples > kMaxMarchSamples) {
    return absl::InvalidArgumentError(absl::StrCat("march: max_samples must be <= ", kMaxMarchSamples));
  }
  if (!(steps_per_diagonal >= 16 && steps_per_diagonal <= kMaxStepsPerDiagonal)) {
    return absl::InvalidArgumentError(
        absl::StrCat("march: steps_per_diagonal must be in [16, ", kMaxStepsPerDiagonal, "]"));
  }
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
// Distance along d from p to the boundary of the cell of size `cs` that
// holds p, in a grid of n cells per axis over [-h, h]. The cell is clamped
// into the grid as the occupancy lookup clamps it: a point that rounding
// puts on the far face (p + h == n cs) is in the last cell, not past it,
// whose face would lie behind the point and be ignored, so that the
// distance came from the other axes alone (a ray entering the box at that
// face skipped up to a quarter of the box). A face behind the point by
// rounding gives 0: the march then moves on by its smallest step.
inline float DistanceToCellExit(const Eigen::Vector3f& p, const Eigen::Vector3f& inv_d, float cs, float h, int n) {
  float best = 1e30f;
  for (int a = 0; a < 3; ++a) {
    const float u = (p[a] + h) / cs;
    const float cell = std::clamp(std::floor(u), 0.0f, float(n - 1));
    const float target = (inv_d[a] > 0 ? cell + 1.0f : cell) * cs - h;
    const float dist = (target - p[a]) * inv_d[a];
    if (std::isnan(dist)) continue;  // d[a] == 0 with p on a face.
    best = std::min(best, std::max(dist, 0.0f));
  }
  return best;
}

// Distance along d from p to where the ray leaves the box [lo, hi] (p inside
// it, or on a face by rounding: a face behind the point gives 0).
inline float DistanceToBoxExit(const Eigen::Vector3f& p, const Eigen::Vector3f& inv_d, const Eigen::Vector3f& lo,
                               const Eigen::Vector3f& hi) {
  float best = 1e30f;
  for (int a = 0; a < 3; ++a) {
    const float dist = ((inv_d[a] > 0 ? hi[a] : lo[a]) - p[a]) * inv_d[a];
    if (std::isnan(dist)) continue;  // d[a] == 0 with p on a face.
    best = std::min(best, std::max(dist, 0.0f));
  }
  return best;
}

// Distance along d from p (in cascade c) to the end of the empty space it is
// in: the empty box of blocks around it when there is one, else its cell.
inline float DistanceToEmptyExit(const OccupancyGrid& grid, int c, bool blocks, const Eigen::Vector3f& p,
                                 const Eigen::Vector3f& inv_d) {
  Eigen::Vector3f lo, hi;
  if (blocks && grid.EmptyBoxAround(p, c, &lo, &hi)) return DistanceToBoxExit(p, inv_d, lo, hi);
  return DistanceToCellExit(p, inv_d, grid.CellSize(c), grid.cascade_half_size(c), grid.resolution());
}
}  // namespace

float MarchRay(const OccupancyGrid& grid, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
               float t_start, float t_end, const MarchOptions& opt, float bound, int max_count,
               std::vector<RaySample>* out) {
  const float min_step = opt.min_step(), max_step = opt.max_step(bound);
  const Eigen::Vector3f inv_d = d.cwiseInverse();
  float t = t_start;
  int count = 0;
  for (int iter = 0; t < t_end && count < max_count && iter < kMaxMarchIterations; ++iter) {
    const Eigen::Vector3f p = o + t * d;
    const int c = grid.CascadeOf(p);
    const float dt = StepAt(t, opt, min_step, max_step);
    const float before = t;
    if (c < 0) {
      // Rounding can put a point on the box face just outside it; t_end
      // (the box exit) bounds the loop.
      t += dt;
    } else if (grid.OccupiedCell(grid.CellIndex(p, c))) {
      out->push_back({t, dt});
      ++count;
      t += dt;
    } else {
      // Skip to the next cell boundary (past the whole empty box of blocks
      // around it when there is one), keeping t on the step lattice.
      const float target = t + DistanceToEmptyExit(grid, c, /*blocks=*/true, p, inv_d) + 1e-5f;
      if (opt.cone_angle == 0.0f) {
        t += std::max(1.0f, std::ceil((target - t) / dt)) * dt;
      } else {
        for (int k = 0; t < target && k < kMaxMarchIterations; ++k) {
          const float next = t + StepAt(t, opt, min_step, max_step);
          if (!(next > t)) break;
          t = next;
        }
      }
    }
    // A step too small to change t (a ray starting at |t| ~ 1e30, where the
    // spacing of floats exceeds the step) would never end: stop the ray.
    if (!(t > before)) break;
  }
  return t;
}

float ContractedFarBound(const MarchOptions& opt) {
  // |q|_inf = 2 - 1/r reaches 2 - min_step at r = 1 / min_step.
  return 1.0f / std::max(opt.min_step(), 1e-4f);
}

namespace {
// The contracted step's limits, computed once per ray: the clamp of
// ContractedStepFromSpeed near the cameras (lo_inner) and in the shell
// (lo_shell), and its upper end.
struct ContractedStepLimits {
  explicit ContractedStepLimits(const MarchOptions& opt)
      : lo_inner(opt.min_step()),
        lo_shell(std::max(lo_inner, 1.0f / kContractedShellSteps)),
        hi(opt.max_step(kContractedBound)),
        cone(opt.cone_angle) {}
  float lo_inner, lo_shell, hi, cone;
};

// The contracted step at x for a ray whose contracted direction J d has
// length `speed` (contracted units per model unit). Near the cameras: the
// pixel cone, clamped like MarchRay's steps but in contracted units. Beyond
// the inner cube the far field gets at most about kContractedShellSteps
// samples across the shell.
inline float ContractedStepFromSpeed(bool in_shell, float speed, float t, const ContractedStepLimits& lim) {
  const float lo = in_shell ? lim.lo_shell : lim.lo_inner;
  return std::clamp(t * lim.cone * speed, lo, std::max(lo, lim.hi)) / speed;
}
}  // namespace

float ContractedStepAt(const Eigen::Vector3f& x, const Eigen::Vector3f& d, float t, const MarchOptions& opt,
                       float* speed_out) {
  const float speed = std::max(ContractDirectional(x, d).norm(), 1e-12f);
  if (speed_out) *speed_out = speed;
  return ContractedStepFromSpeed(InfNorm(x) > 1.0f, speed, t, ContractedStepLimits(opt));
}

float MarchRayContracted(const OccupancyGrid& grid, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
                         float t_start, float t_end, const MarchOptions& opt, int max_count,
                         std::vector<RaySample>* out) {
  const ContractedStepLimits lim(opt);
  // Inside the inner cube the contraction is the identity: q = p, J d = d.
  const float inner_speed = std::max(d.norm(), 1e-12f);
  const Eigen::Vector3f inner_inv_d = d.cwiseInverse();
  float t = t_start;
  int count = 0;
  for (int iter = 0; t < t_end && count < max_count && iter < kMaxMarchIterations; ++iter) {
    const Eigen::Vector3f p = o + t * d;
    const bool in_shell = InfNorm(p) > 1.0f;
    const Eigen::Vector3f q = in_shell ? Contract(p) : p;
    // J d once per shell step: the step and the cell exit use it.
    const Eigen::Vector3f dq = in_shell ? ContractDirectional(p, d) : d;
    const float speed = in_shell ? std::max(dq.norm(), 1e-12f) : inner_speed;
    const float dt = ContractedStepFromSpeed(in_shell, speed, t, lim);
    const int c = grid.CascadeOf(q);
    if (c < 0) break;  // Past the outer face.
    if (grid.OccupiedCell(grid.CellIndex(q, c))) {
      out->push_back({t, dt});
      ++count;
      t += dt;
    } else {
      // In cascades within the inner cube (half-size <= 1) the ray is
      // straight, so empty blocks are crossed in one jump as in MarchRay
      // (fox_8: 70 % of the inner cube's march iterations were in empty
      // blocks); in the shell, cell by cell. The sample after a jump lands
      // where the jump ends, not on the step lattice of a cell-by-cell march.
      const Eigen::Vector3f inv_dq = in_shell ? Eigen::Vector3f(dq.cwiseInverse()) : inner_inv_d;
      const float exit = DistanceToEmptyExit(grid, c, grid.cascade_half_size(c) <= 1.0f, q, inv_dq);
      const float next = t + std::max(dt, exit + 1e-5f / speed);
      if (!(next > t)) break;  // See MarchRay.
      t = next;
    }
  }
  return t;
}

}  // namespace clnerf
