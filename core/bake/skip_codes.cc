#include "core/bake/skip_codes.h"

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include "core/bake/baked_march.h"

namespace clnerf {
namespace {

// A block's window: the global lattice points [8b - 7, 8b + 15] per axis,
// its brick's points at window indices 7..15. A point farther than 7 below
// or 7 above the brick is at least 8 cells from all of it: the cap.
constexpr int kBelow = kBakeBlock - 1;
constexpr int kWin = kBelow + kBakeBrick + kBakeBlock - 1;  // 23.
static_assert(kSkipCodeCap == kBakeBlock, "the window holds the points within one block of a brick");

// The lattice points with density, one byte per point, kept per owning
// block: global point g = 8 b + l (l in [0, 8) per axis) belongs to block
// b. A point is dense when any brick that holds it has a > 0 there.
class DenseLattice {
 public:
  explicit DenseLattice(const BakedAsset& a) : n_(a.blocks_per_axis() + 1) {
    slot_.assign(size_t(n_) * n_ * n_, -1);
    const int nb = a.blocks_per_axis();
    for (int bz = 0; bz < nb; ++bz) {
      for (int by = 0; by < nb; ++by) {
        for (int bx = 0; bx < nb; ++bx) {
          const int b[3] = {bx, by, bz};
          const int64_t brick = BlockBrick(a, b);
          if (brick >= 0) AddBrick(a, uint32_t(brick), b);
        }
      }
    }
  }

  // Whether global lattice point (x, y, z) is dense (false outside the grid).
  bool Dense(int x, int y, int z) const {
    if (x < 0 || y < 0 || z < 0) return false;
    const int bx = x / kBakeBlock, by = y / kBakeBlock, bz = z / kBakeBlock;
    if (bx >= n_ || by >= n_ || bz >= n_) return false;
    const int32_t s = slot_[size_t(bx) + size_t(n_) * (size_t(by) + size_t(n_) * size_t(bz))];
    if (s < 0) return false;
    const int l = (x % kBakeBlock) + kBakeBlock * ((y % kBakeBlock) + kBakeBlock * (z % kBakeBlock));
    return dense_[size_t(s) * kOwned + size_t(l)] != 0;
  }

 private:
  static constexpr int kOwned = kBakeBlock * kBakeBlock * kBakeBlock;

  void AddBrick(const BakedAsset& a, uint32_t brick, const int b[3]) {
    for (int z = 0; z < kBakeBrick; ++z) {
      for (int y = 0; y < kBakeBrick; ++y) {
        for (int x = 0; x < kBakeBrick; ++x) {
          if (a.atlas[4 * BrickTexel(a, brick, x, y, z) + 3] == 0) continue;
          const int g[3] = {kBakeBlock * b[0] + x, kBakeBlock * b[1] + y, kBakeBlock * b[2] + z};
          const size_t owner = size_t(g[0] / kBakeBlock) +
                               size_t(n_) * (size_t(g[1] / kBakeBlock) + size_t(n_) * size_t(g[2] / kBakeBlock));
          if (slot_[owner] < 0) {
            slot_[owner] = int32_t(dense_.size() / kOwned);
            dense_.resize(dense_.size() + kOwned, 0);
          }
          const int l = (g[0] % kBakeBlock) + kBakeBlock * ((g[1] % kBakeBlock) + kBakeBlock * (g[2] % kBakeBlock));
          dense_[size_t(slot_[owner]) * kOwned + size_t(l)] = 1;
        }
      }
    }
  }

  int n_;                      // Blocks per axis, one more than the grid's (its far faces).
  std::vector<int32_t> slot_;  // Per block: its owned points' slot in dense_, or -1.
  std::vector<uint8_t> dense_;
};

// min over |j - i| <= cap of max(|j - i|, f[j]) along one line of n values
// (stride s): the chessboard distance transform's step along one axis.
inline uint8_t LineMin(const uint8_t* f, int i, int n, int s) {
  int best = f[size_t(i) * size_t(s)];
  for (int j = std::max(0, i - kSkipCodeCap); j <= std::min(n - 1, i + kSkipCodeCap); ++j) {
    best = std::min(best, std::max(std::abs(j - i), int(f[size_t(j) * size_t(s)])));
  }
  return uint8_t(best);
}

// The codes of one occupied block's brick (its chessboard distances to
// density, capped), into `code` (9^3, x fastest): an exact distance
// transform of the block's window, one axis at a time.
void BrickDistances(const DenseLattice& dense, const int b[3], uint8_t code[kBrickLattice]) {
  static thread_local std::vector<uint8_t> d1, d2;
  d1.assign(size_t(kWin) * kWin * kWin, uint8_t(kSkipCodeCap));
  d2.assign(d1.size(), uint8_t(kSkipCodeCap));
  const int g0[3] = {kBakeBlock * b[0] - kBelow, kBakeBlock * b[1] - kBelow, kBakeBlock * b[2] - kBelow};
  auto at = [](int x, int y, int z) { return size_t(x) + size_t(kWin) * (size_t(y) + size_t(kWin) * size_t(z)); };
  for (int z = 0; z < kWin; ++z) {  // x: the distance along each row, two sweeps.
    for (int y = 0; y < kWin; ++y) {
      uint8_t* row = &d1[at(0, y, z)];
      int run = kSkipCodeCap;
      for (int x = 0; x < kWin; ++x) {
        run = dense.Dense(g0[0] + x, g0[1] + y, g0[2] + z) ? 0 : std::min(run + 1, kSkipCodeCap);
        row[x] = uint8_t(run);
      }
      for (int x = kWin - 2; x >= 0; --x) row[x] = uint8_t(std::min<int>(row[x], row[x + 1] + 1));
    }
  }
  for (int z = 0; z < kWin; ++z) {  // y, for the brick's columns.
    for (int y = kBelow; y < kBelow + kBakeBrick; ++y) {
      for (int x = kBelow; x < kBelow + kBakeBrick; ++x) d2[at(x, y, z)] = LineMin(&d1[at(x, 0, z)], y, kWin, kWin);
    }
  }
  for (int z = 0; z < kBakeBrick; ++z) {  // z, for the brick's points.
    for (int y = 0; y < kBakeBrick; ++y) {
      for (int x = 0; x < kBakeBrick; ++x) {
        code[x + kBakeBrick * (y + kBakeBrick * z)] =
            LineMin(&d2[at(x + kBelow, y + kBelow, 0)], z + kBelow, kWin, kWin * kWin);
      }
    }
  }
}

}  // namespace

void WriteSkipCodes(BakedAsset* asset) {
  BakedAsset& a = *asset;
  const DenseLattice dense(a);
  const int nb = a.blocks_per_axis();
  const int blocks = nb * nb * nb;
#pragma omp parallel for schedule(dynamic, 16)
  for (int i = 0; i < blocks; ++i) {
    if (a.index[size_t(i)] == 0) continue;
    const int b[3] = {i % nb, (i / nb) % nb, i / (nb * nb)};
    const uint32_t brick = a.index[size_t(i)] - 1;
    uint8_t code[kBrickLattice];
    BrickDistances(dense, b, code);
    for (int l = 0; l < kBrickLattice; ++l) {
      uint8_t* px = a.atlas.data() + 4 * BrickTexel(a, brick, l);
      if (px[3] == 0 && code[l] >= 2) px[0] = code[l];
    }
  }
}

}  // namespace clnerf
