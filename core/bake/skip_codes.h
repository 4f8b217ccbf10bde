// Empty-space codes: how far a ray may jump through the empty cells of an
// occupied block. A baked asset's lattice points that hold no density carry
// no colour either, so their red channel is free; WriteSkipCodes stores
// there the chessboard distance, in cells, from the point to the nearest
// lattice point with density (any brick's copy of it), capped at
// kSkipCodeCap, wherever that distance is at least 2 (a point at distance 1
// can be the corner of a cell that also has a dense corner, so its red
// channel must stay 0 to keep that cell's colour what it was).
//
// A sample whose eight corners hold no density (interpolated a == 0) then
// reads, interpolated the same way, v = sum_k w_k code_k in red. Since the
// distance to density D is 1-Lipschitz and every corner is within one cell
// of the sample u, D(u) >= code_k - 1 for each corner, so D(u) >= v - 1, and
// every point within v - 2 cells of u (chessboard) samples no density: a
// ray with model-space direction d may skip the lattice points within
// (v - 2) / (step_cells |d|_inf) steps (BakedCodeSteps). The renderers
// jump by a multiple of the sample's steps (BakedTailSteps), so they visit
// a subset of the very lattice points they visit without the codes and
// skip only samples that add nothing: the image is the same, the loop
// shorter. Assets without codes (red 0 where a is 0) march as before.
//
// Pure functions; WriteSkipCodes writes the asset it is given and may run
// its blocks on OpenMP threads.
#ifndef CLNERF_CORE_BAKE_SKIP_CODES_H_
#define CLNERF_CORE_BAKE_SKIP_CODES_H_

#include <algorithm>

#include "core/bake/baked_asset.h"

namespace clnerf {

// The largest code: a block's own lattice points and those of its 26
// neighbours are all the distance transform looks at, and they hold every
// point within 8 cells of it.
inline constexpr int kSkipCodeCap = 8;

// Writes the codes into `asset`'s atlas: red = the distance (2..8) at every
// lattice point with a == 0 that far from density; other texels unchanged.
// Needs the index and the atlas's density codes.
void WriteSkipCodes(BakedAsset* asset);

// The lattice steps a sample with no density and red channel `red` (0..1,
// interpolated) may advance: a multiple of `k` (its BakedTailSteps), at
// least k, such that every sample it passes (every k-th lattice point) is
// at most (v - 2) cells (chessboard) from it. scale: 1 / (step_cells
// |d|_inf), d the unit ray direction (a step moves the sample at most
// step_cells |d|_inf cells along any axis).
inline int BakedCodeSteps(float red, float scale, int k) {
  const float reach = (255.0f * red - 2.0f) * scale;  // In steps.
  if (!(reach >= float(k))) return k;
  return k * (int(std::min(reach, 4096.0f)) / k + 1);
}

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_SKIP_CODES_H_
