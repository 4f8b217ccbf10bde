// MarchBaked: the one march over a baked grid that the reference renderer
// (baked_renderer.h, where the rule is spelled out) and the baker's
// visibility pass share, templated on where the lattice values come from.
//
// Pure function template; thread-safe.
#ifndef CLNERF_CORE_BAKE_BAKED_MARCH_H_
#define CLNERF_CORE_BAKE_BAKED_MARCH_H_

#include <algorithm>
#include <array>
#include <cmath>

#include "core/bake/baked_asset.h"
#include "core/bake/skip_codes.h"
#include "core/data/contraction.h"
#include "core/field/ray_marcher.h"
#include "Eigen/Core"

namespace clnerf {

// Rays stop once the transmittance falls to this.
inline constexpr float kBakedMinTransmittance = 1.0f / 255.0f;
// A texel's opacity per cell is capped here (a = 255 is a solid cell).
inline constexpr float kBakedMaxAlpha = 0.9999f;
// At most this many samples per ray.
inline constexpr int kBakedMaxSteps = 4096;
// Where little light is left the steps are longer: a sample taken while
// the transmittance is below kBakedTail2 covers two steps, below kBakedTail4
// four, below kBakedTail8 eight (its opacity that of the longer run at its
// density). The light those samples add is at most T, and the colour fit
// is fitted through the same samples: on session 76's assets fox_8,
// flower_4 and beer_2 scored within 0.01 dB of one-step sampling with 20,
// 22 and 16 % fewer steps (2 below 0.3, 4 below 0.1; session 77), and since
// session 79 (these thresholds) within 0.03 dB of that with another 8-10 %
// fewer (docs/baking.md).
inline constexpr float kBakedTail2 = 0.5f;
inline constexpr float kBakedTail4 = 0.2f;
inline constexpr float kBakedTail8 = 0.05f;
// The steps a sample covers at transmittance T (1, 2, 4 or 8).
inline int BakedTailSteps(float T) {
  return T < kBakedTail8 ? 8 : T < kBakedTail4 ? 4 : T < kBakedTail2 ? 2 : 1;
}

// The model-space interval to march; false when the ray misses the grid.
inline bool BakedRayInterval(const BakedAsset& a, const Eigen::Vector3f& o, const Eigen::Vector3f& d, float* t0,
                             float* t1) {
  // Unbounded: |contract(x)|_inf = 2 - 1/r reaches 2 - cell/2 at r = 2/cell.
  const float box = a.contracted ? 2.0f / a.cell() : a.half_size;
  if (!IntersectBox(o, d, box, t0, t1)) return false;
  *t0 = std::max(*t0, a.near);
  return *t1 > *t0;
}

// The interval [*ta, *tb] of ray o + t d inside the box [lo, hi] (any t);
// false when it misses the box (or the box is empty).
inline bool IntersectAabb(const Eigen::Vector3f& o, const Eigen::Vector3f& d, const Eigen::Vector3f& lo,
                          const Eigen::Vector3f& hi, float* ta, float* tb) {
  float a = -1e30f, b = 1e30f;
  for (int k = 0; k < 3; ++k) {
    if (std::abs(d[k]) < 1e-12f) {
      if (o[k] < lo[k] || o[k] > hi[k]) return false;
      continue;
    }
    const float inv = 1.0f / d[k];
    const float u = (lo[k] - o[k]) * inv, v = (hi[k] - o[k]) * inv;
    a = std::max(a, std::min(u, v));
    b = std::min(b, std::max(u, v));
  }
  *ta = a;
  *tb = b;
  return b > a;
}

// The reciprocals of a ray direction's components that BakedExitT uses:
// 1 / d_k where |d_k| > 1e-12, else 0 (an axis the ray does not move along).
inline Eigen::Vector3f BakedInverseDirection(const Eigen::Vector3f& d) {
  Eigen::Vector3f inv;
  for (int k = 0; k < 3; ++k) inv[k] = std::abs(d[k]) > 1e-12f ? 1.0f / d[k] : 0.0f;
  return inv;
}

// Model-space t at which a ray leaves the box [lo, hi] it is in (inv_d:
// BakedInverseDirection(d); multiplications, as the shader does them).
inline float BakedExitT(const Eigen::Vector3f& o, const Eigen::Vector3f& d, const Eigen::Vector3f& inv_d,
                        const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
  float t = 1e30f;
  for (int k = 0; k < 3; ++k) {
    if (inv_d[k] != 0.0f) t = std::min(t, ((d[k] > 0.0f ? hi[k] : lo[k]) - o[k]) * inv_d[k]);
  }
  return t;
}

// How far (model units) a ray o + t d, now at x beyond the inner cube
// (r = |x|_inf > 1) and heading outwards, stays where every point contracts
// into the box [lo, hi] of contracted coordinates: at most that far, and
// exactly that far along a ray from the centre. Beyond the inner cube,
// with x's dominant axis m and sign s, contract(x)_m = s rho(r) and
// contract(x)_k = q_k rho(r) for q_k = x_k / r, rho(r) = 2 - 1/r. So while
// rho stays in [rho(r), rho_hi] (rho_hi: where axis m leaves [lo_m, hi_m],
// or sooner, so that x's own q_k keep inside) and each q_k stays in a range
// that keeps q_k rho in [lo_k, hi_k] for every such rho (inside [-1, 1], so
// m stays dominant), the point is inside; r and r q_k = x_k are linear in
// t, so each bound is crossed where a linear function is. 0 for a ray
// heading inwards (rays from cameras inside the inner cube never do there).
// Pure function.
inline float ShellEmptyRun(const Eigen::Vector3f& x, const Eigen::Vector3f& d, const Eigen::Vector3f& lo,
                           const Eigen::Vector3f& hi) {
  int m = 0;
  for (int k = 1; k < 3; ++k) {
    if (std::abs(x[k]) > std::abs(x[m])) m = k;
  }
  const float s = x[m] < 0.0f ? -1.0f : 1.0f, r = s * x[m], r1 = s * d[m];
  if (r1 <= 0.0f) return 0.0f;
  const float rho_lo = 2.0f - 1.0f / r;
  float rho_hi = std::min(2.0f, s > 0.0f ? hi[m] : -lo[m]);
  for (int k = 0; k < 3; ++k) {
    const float q = x[k] / r;
    if (k != m && q > 0.0f && hi[k] >= 0.0f) rho_hi = std::min(rho_hi, hi[k] / q);
    if (k != m && q < 0.0f && lo[k] <= 0.0f) rho_hi = std::min(rho_hi, lo[k] / q);
  }
  float run = rho_hi >= 2.0f ? INFINITY : (1.0f / (2.0f - rho_hi) - r) / r1;
  for (int k = 0; k < 3; ++k) {
    if (k == m) continue;
    const float q_lo = std::max(-1.0f, lo[k] / (lo[k] <= 0.0f ? rho_hi : rho_lo));
    const float q_hi = std::min(1.0f, hi[k] / (hi[k] >= 0.0f ? rho_hi : rho_lo));
    // x_k - q_lo r >= 0 and q_hi r - x_k >= 0, each linear in the distance.
    const float f1 = d[k] - q_lo * r1, g1 = q_hi * r1 - d[k];
    if (f1 < 0.0f) run = std::min(run, (x[k] - q_lo * r) / -f1);
    if (g1 < 0.0f) run = std::min(run, (q_hi * r - x[k]) / -g1);
  }
  return std::max(run, 0.0f);
}

// Marches ray o + t d (unit d, model space) over the grid of `a` (only its
// geometry fields are read). sample(block, u, &rgba) returns false for an
// empty block, else the lattice's RGBA in [0, 1] at cell coordinates u;
// visit(block, weight, t, rgba, dt) sees every sample's compositing weight
// and the length it covers (model units; BakedTailSteps of a step).
// skip_codes: the red channel of a sample with no density is an empty-space
// code (skip_codes.h; the asset's atlas as stored), and the march jumps by
// it over samples with no density, which are then not visited; the samples
// that add to the ray are the same. Returns the final transmittance.
template <class Sample, class Visit>
float MarchBaked(const BakedAsset& a, const Eigen::Vector3f& o, const Eigen::Vector3f& d, Sample&& sample,
                 Visit&& visit, bool skip_codes = false) {
  float t0 = 0, t1 = 0, T = 1.0f;
  if (!BakedRayInterval(a, o, d, &t0, &t1)) return T;
  // Jumps by codes stay in the inner cube of an unbounded scene (the shell's
  // samples are not on its lattice): they stop at the first lattice point
  // of their phase at or past where the ray leaves it.
  float cube_exit = 1e30f, cube_entry = 0.0f;
  if (a.contracted && !IntersectBox(o, d, 1.0f, &cube_entry, &cube_exit)) cube_exit = -1e30f;
  const float skip_scale = 1.0f / (a.step_cells * InfNorm(d));  // Cells of a code to steps.
  const Eigen::Vector3f inv_d = BakedInverseDirection(d);
  const int nb = a.blocks_per_axis();
  const float step = a.step(), cell = a.cell(), B = a.half_size, to_cells = float(a.resolution) / (2.0f * B);
  const float inv_step = 1.0f / step;
  const float block_size = float(kBakeBlock) / to_cells;  // Field units.
  float t = t0 + 0.5f * step;
  if (!a.contracted && !a.block_distance.empty()) {
    // An object: only the box of occupied blocks can add to the ray, so
    // the march starts at the lattice point before the ray enters it and
    // ends one step after it leaves (the same samples that can show).
    if (a.occupied_hi[0] < a.occupied_lo[0]) return T;  // Nothing occupied.
    Eigen::Vector3f lo, hi;
    for (int k = 0; k < 3; ++k) {
      lo[k] = float(a.occupied_lo[size_t(k)]) * block_size - B;
      hi[k] = float(a.occupied_hi[size_t(k)] + 1) * block_size - B;
    }
    float ta = 0, tb = 0;
    if (!IntersectAabb(o, d, lo, hi, &ta, &tb) || tb <= t0 || ta >= t1) return T;
    t += std::max(0.0f, std::floor((ta - t0) / step - 0.5f)) * step;
    t1 = std::min(t1, tb + step);
  }
  for (int it = 0; it < kBakedMaxSteps && t < t1 && T > kBakedMinTransmittance; ++it) {
    const Eigen::Vector3f x = o + t * d;
    const float r = InfNorm(x);
    const float dt = a.contracted && r > 1.0f ? step * r * r : step;
    const Eigen::Vector3f u = ((a.contracted ? Contract(x) : x).array() + B) * to_cells;
    int b[3];
    for (int k = 0; k < 3; ++k) b[k] = std::clamp(int(std::floor(u[k] / float(kBakeBlock))), 0, nb - 1);
    const int block = b[0] + nb * (b[1] + nb * b[2]);
    Eigen::Vector4f rgba;
    if (!sample(block, u, b, &rgba)) {
      // An empty block, and every block within its distance D - 1 (cube of
      // blocks around it) is empty too: skipped at once. Where the cube lies
      // in model space unchanged (for unbounded scenes: clipped to the inner
      // cube) by whole multiples of the tail's steps, so samples stay on
      // t0 + (j + 1/2) step; in the contracted shell past where the ray
      // leaves it (ShellEmptyRun).
      const float D = float(a.block_distance.empty() ? 1 : std::max<int>(1, a.block_distance[size_t(block)])) - 1.0f;
      Eigen::Vector3f lo, hi;
      for (int k = 0; k < 3; ++k) {
        lo[k] = (float(b[k]) - D) * block_size - B;
        hi[k] = (float(b[k]) + D + 1.0f) * block_size - B;
      }
      if (!a.contracted || r <= 1.0f) {
        if (a.contracted) {
          lo = lo.cwiseMax(-1.0f);
          hi = hi.cwiseMin(1.0f);
        }
        // By whole multiples of the tail's steps (BakedTailSteps), so that
        // a code's jump over an empty block lands where this skip does.
        const float k = float(BakedTailSteps(T));
        t += k * std::max(1.0f, std::ceil((BakedExitT(o, d, inv_d, lo, hi) - t) * inv_step * (1.0f / k))) * step;
      } else {
        // In the shell the cube is one in contracted space: the ray is
        // inside it for ShellEmptyRun at least; the next sample is half a
        // step past that point.
        const float te = std::min(t + ShellEmptyRun(x, d, lo, hi), t1);
        const float re = InfNorm(o + te * d);
        t = std::max(t + dt, te + 0.5f * step * re * re);
      }
      continue;
    }
    if (skip_codes && rgba[3] == 0.0f && (!a.contracted || r <= 1.0f)) {
      const int k = BakedTailSteps(T);
      int m = BakedCodeSteps(rgba[0], skip_scale, k);
      if (a.contracted) {
        const float to_exit = std::ceil((cube_exit - t) * inv_step * (1.0f / float(k)));
        m = std::min(m, k * int(std::clamp(to_exit, 1.0f, float(kBakedMaxSteps))));
      }
      t += float(m) * step;
      continue;
    }
    const float run = dt * float(BakedTailSteps(T));
    const float alpha0 = std::min(rgba[3] * rgba[3], kBakedMaxAlpha);
    const float alpha = 1.0f - std::exp(std::log(1.0f - alpha0) * (run / cell));
    visit(block, T * alpha, t, rgba, run);
    T *= 1.0f - alpha;
    t += run;
  }
  return T;
}

// The colour of an interpolated sample: the atlas holds colour times the
// density code (premultiplied), so interpolation weighs each corner's colour
// by its density; this divides it back out.
inline Eigen::Vector3f BakedColour(const Eigen::Vector4f& rgba) {
  return (rgba.head<3>() / std::max(rgba[3], 1.0f / 255.0f)).cwiseMax(0.0f).cwiseMin(1.0f);
}

// Local coordinates l (lattice units, [0, 8] inside the block) of cell
// coordinates u in block b.
inline void LocalInBlock(const Eigen::Vector3f& u, const int b[3], float l[3]) {
  for (int k = 0; k < 3; ++k) l[k] = u[k] - float(kBakeBlock * b[k]);
}

// Finds a ray's median sample (format 3's view term is read there): fed
// each sample's compositing weight in order, Step returns true exactly
// once, at the first sample after which the transmittance is below 1/2.
// The reference renderer and the colour fit share it, so the fit's rows
// are the renderer's pixels.
class BakedMedian {
 public:
  bool Step(float weight) {
    const float next = T_ - weight;
    const bool median = !found_ && T_ >= 0.5f && next < 0.5f;
    found_ = found_ || median;
    T_ = next;
    return median;
  }
  bool found() const { return found_; }

 private:
  float T_ = 1.0f;
  bool found_ = false;
};

// The brick block b names (its index entry - 1), or -1 for an empty block.
inline int64_t BlockBrick(const BakedAsset& a, const int b[3]) {
  const int nb = a.blocks_per_axis();
  return int64_t(a.index[size_t(b[0]) + size_t(nb) * (size_t(b[1]) + size_t(nb) * size_t(b[2]))]) - 1;
}

// The atlas texel (RGBA8: bytes 4 x this) of lattice point (x, y, z) of
// `brick`.
inline size_t BrickTexel(const BakedAsset& a, uint32_t brick, int x, int y, int z) {
  const uint32_t bx = uint32_t(a.bricks[0]), by = uint32_t(a.bricks[1]);
  const std::array<int, 3> dims = a.atlas_texels();
  const size_t ox = size_t(brick % bx) * kBakeBrick, oy = size_t((brick / bx) % by) * kBakeBrick,
               oz = size_t(brick / (bx * by)) * kBakeBrick;
  return (ox + size_t(x)) + size_t(dims[0]) * ((oy + size_t(y)) + size_t(dims[1]) * (oz + size_t(z)));
}

// The lattice cell holding local coordinates l in [0, 8]^3 (clamped) and the
// trilinear weights of its 8 corners: corner bits 0, 1, 2 step x, y, z.
struct BrickCell {
  int i0[3];
  float f[3];
  int x(int corner) const { return i0[0] + (corner & 1); }
  int y(int corner) const { return i0[1] + ((corner >> 1) & 1); }
  int z(int corner) const { return i0[2] + (corner >> 2); }
  float weight(int corner) const {
    const int dx = corner & 1, dy = (corner >> 1) & 1, dz = corner >> 2;
    return (dx ? f[0] : 1.0f - f[0]) * (dy ? f[1] : 1.0f - f[1]) * (dz ? f[2] : 1.0f - f[2]);
  }
};

inline BrickCell LocateInBrick(const float l_in[3]) {
  BrickCell cell;
  for (int k = 0; k < 3; ++k) {
    const float l = std::clamp(l_in[k], 0.0f, float(kBakeBlock));
    cell.i0[k] = std::min(int(l), kBakeBlock - 1);
    cell.f[k] = l - float(cell.i0[k]);
  }
  return cell;
}

// Lattice points are numbered brick * 9^3 + x + 9 (y + 9 z) over all bricks
// (the colour and density fits' unknowns, their arrays brick-major).
inline constexpr int kBrickLattice = kBakeBrick * kBakeBrick * kBakeBrick;

// The number of corner `corner` of `cell` in `brick`.
inline uint32_t LatticeId(uint32_t brick, const BrickCell& cell, int corner) {
  return brick * uint32_t(kBrickLattice) +
         uint32_t(cell.x(corner) + kBakeBrick * (cell.y(corner) + kBakeBrick * cell.z(corner)));
}

// The atlas texel of lattice point `local` (x + 9 (y + 9 z)) of `brick`.
inline size_t BrickTexel(const BakedAsset& a, uint32_t brick, int local) {
  return BrickTexel(a, brick, local % kBakeBrick, (local / kBakeBrick) % kBakeBrick, local / (kBakeBrick * kBakeBrick));
}

// The atlas texel of lattice point `id` (numbered as LatticeId numbers it).
inline size_t LatticeTexel(const BakedAsset& a, uint32_t id) {
  return BrickTexel(a, id / uint32_t(kBrickLattice), int(id % uint32_t(kBrickLattice)));
}

// Trilinear RGBA (0..255 per channel) of a 9^3 RGBA8 lattice `texel(x, y,
// z, c)` at local coordinates l in [0, 8]^3.
template <class Texel>
Eigen::Vector4f TrilinearBrick(const float l_in[3], Texel&& texel) {
  const BrickCell cell = LocateInBrick(l_in);
  Eigen::Vector4f acc = Eigen::Vector4f::Zero();
  for (int corner = 0; corner < 8; ++corner) {
    const float w = cell.weight(corner);
    for (int c = 0; c < 4; ++c) acc[c] += w * texel(cell.x(corner), cell.y(corner), cell.z(corner), c);
  }
  return acc;
}

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_BAKED_MARCH_H_
