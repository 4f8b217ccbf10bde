// OccupancyGrid: Instant-NGP's multi-cascade occupancy grid that lets the ray
// marcher skip empty space. Each cascade c is a res^3 grid over
// [-min(2^(c-1), s), +min(2^(c-1), s)]^3 of the model box [-s, s]^3, with
// max(1 + ceil(log2(2s)), 1) cascades. Every cell keeps an EMA of density
// (new = max(decay * old, sigma)); a bitfield marks cells whose density
// exceeds min(mean density, threshold). Cells that no training camera sees are
// marked empty permanently. A second bitfield marks blocks of 4^3 cells with
// any cell occupied, and each block keeps its chessboard distance to the
// nearest occupied one, so that a march crosses a run of empty blocks in one
// jump (bounded scenes, and the inner cube of unbounded ones; ray_marcher.h).
//
// The grid does not evaluate the network: the trainer asks for the cells to
// refresh (CellsToUpdate), evaluates densities at jittered positions, and
// hands them back (ApplyUpdate). Readers (Occupied) may run concurrently with
// each other but not with ApplyUpdate/MarkInvisible.
#ifndef CLNERF_CORE_FIELD_OCCUPANCY_GRID_H_
#define CLNERF_CORE_FIELD_OCCUPANCY_GRID_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "absl/status/status.h"
#include "core/data/camera.h"
#include "Eigen/Core"

namespace clnerf {

struct OccupancyGridOptions {
  int resolution = 128;         // Cells per axis per cascade (power of two).
  int update_interval = 16;     // Training iterations between updates.
  int warmup_iterations = 256;  // Update every cell until this iteration.
  // EMA decay of a cell's density at each of its refreshes. Instant-NGP's
  // 0.95 is for 35k steps; over our 2000 a cell dense early stays occupied
  // for most of training (beer_2's first run: 487 samples per ray, most in
  // cells that had emptied). 0.8 forgets in ~400 steps: beer_2 at 81
  // samples per ray instead of 508, 4x faster renders (docs/render_cost.md).
  // Stored with the model, so a place keeps the decay it was trained with.
  float decay = 0.8f;
  // Occupancy threshold on sigma; <= 0 derives 0.01 / min_step (upstream:
  // 0.01 * 1024 / sqrt(3) for the synthetic step size).
  float density_threshold = 0.0f;
  absl::Status Validate() const;
};

class OccupancyGrid {
 public:
  OccupancyGrid() = default;
  OccupancyGrid(const OccupancyGridOptions& options, float bound, float min_step);

  const OccupancyGridOptions& options() const { return options_; }
  // Contracted grids (unbounded scenes) index contracted space; cell
  // positions are mapped back to model space (Uncontract) for visibility.
  void set_contracted(bool contracted) { contracted_ = contracted; }
  bool contracted() const { return contracted_; }
  int resolution() const { return res_; }
  int num_cascades() const { return cascades_; }
  size_t cells_per_cascade() const { return size_t(res_) * res_ * res_; }
  size_t num_cells() const { return cells_per_cascade() * cascades_; }
  float cascade_half_size(int c) const { return half_[c]; }
  float threshold() const { return threshold_; }

  // Cascade containing model-space point p (the finest that covers it), or -1
  // when p is outside the model box.
  int CascadeOf(const Eigen::Vector3f& p) const {
    const float m = std::max(std::abs(p.x()), std::max(std::abs(p.y()), std::abs(p.z())));
    if (!(m <= bound_)) return -1;
    int c = 0;
    while (c < cascades_ - 1 && m >= half_[c]) ++c;
    return c;
  }
  // Linear cell index (including cascade offset) of p in cascade c.
  uint32_t CellIndex(const Eigen::Vector3f& p, int c) const {
    const float h = half_[c], s = cells_per_unit_[c];
    const int x = std::clamp(int((p.x() + h) * s), 0, res_ - 1);
    const int y = std::clamp(int((p.y() + h) * s), 0, res_ - 1);
    const int z = std::clamp(int((p.z() + h) * s), 0, res_ - 1);
    return uint32_t(size_t(c) * cells_per_cascade() + x + size_t(res_) * (y + size_t(res_) * z));
  }
  bool Occupied(const Eigen::Vector3f& p) const;
  bool OccupiedCell(uint32_t cell) const { return (bits_[cell >> 6] >> (cell & 63)) & 1; }

  // Blocks of kBlockCells^3 cells, each marked when any of its cells is
  // occupied, so that a march skips a run of empty cells in one step. A
  // cascade whose blocks would straddle the next finer cascade's boundary
  // (a model box that is not a power of two) has none: its blocks all read
  // occupied, and its cells are skipped one by one.
  static constexpr int kBlockCells = 4;
  float BlockSize(int c) const { return kBlockCells / cells_per_unit_[c]; }
  bool OccupiedBlockAt(const Eigen::Vector3f& p, int c) const {
    if (block_res_ == 0 || !block_ok_[c]) return true;
    int b[3];
    const size_t k = BlockOf(p, c, b);
    return (block_bits_[k >> 6] >> (k & 63)) & 1;
  }
  // The empty space around p's block that a march may cross in one jump:
  // the box of cascade-c blocks centred on it, (2D - 1) blocks a side for
  // the block's chessboard distance D to the nearest block that has an
  // occupied cell or lies in the finer cascade's region (clipped to the
  // grid), as [lo, hi] in the cascade's coordinates (model space, or
  // contracted space). False, with lo and hi untouched, when p's block is
  // such a block or the cascade has no blocks.
  bool EmptyBoxAround(const Eigen::Vector3f& p, int c, Eigen::Vector3f* lo, Eigen::Vector3f* hi) const {
    if (block_res_ == 0) return false;
    int b[3];
    const int r = int(block_dist_[BlockOf(p, c, b)]) - 1;
    if (r < 0) return false;
    const float bs = BlockSize(c), h = half_[c];
    for (int a = 0; a < 3; ++a) {
      (*lo)[a] = float(std::max(b[a] - r, 0)) * bs - h;
      (*hi)[a] = float(std::min(b[a] + r, block_res_ - 1) + 1) * bs - h;
    }
    return true;
  }
  // Side length of a cell of cascade c.
  float CellSize(int c) const { return 1.0f / cells_per_unit_[c]; }

  // Model-space position of a cell (centre + jitter in [-0.5, 0.5) cells).
  Eigen::Vector3f CellPosition(uint32_t cell, const Eigen::Vector3f& jitter) const;

  // Cells to refresh at training iteration `iter`: all cells during warm-up,
  // otherwise a quarter at random plus a quarter drawn from occupied cells.
  std::vector<uint32_t> CellsToUpdate(int iter, std::mt19937_64* rng) const;
  // new = max(decay * old, sigma) for the given cells, then refreshes bits.
  void ApplyUpdate(const std::vector<uint32_t>& cells, const std::vector<float>& sigma);
  // Recomputes visibility: cells outside every camera frustum (model-space
  // cameras) are empty until the next call; cells that become visible start
  // occupied.
  void MarkInvisible(const std::vector<Camera>& cameras, float near);
  // Marks all visible cells occupied (initial state before any update).
  void SetAllOccupied();

  size_t num_occupied() const;
  size_t num_visible() const;
  // Raw state for checkpoints.
  // Bytes the grid holds (training state included: densities, visibility).
  size_t resident_bytes() const {
    return density_.capacity() * sizeof(float) + visible_.capacity() + bits_.capacity() * sizeof(uint64_t) +
           block_bits_.capacity() * sizeof(uint64_t) + block_dist_.capacity() + fresh_.capacity() * sizeof(float);
  }
  const std::vector<float>& density() const { return density_; }
  const std::vector<uint8_t>& visible() const { return visible_; }
  const std::vector<uint64_t>& bits() const { return bits_; }
  void Restore(std::vector<float> density, std::vector<uint8_t> visible, std::vector<uint64_t> bits,
               float threshold);

 private:
  void RefreshBits();
  // Recomputes block_bits_ and block_dist_ from bits_ (after every change
  // to bits_).
  void RefreshBlocks();
  // block_dist_ of cascade c from block_bits_.
  void BlockDistances(int c);
  // The block of cascade c that holds p (clamped into the grid, as cells
  // are): its coordinates in b and its index into block_bits_/block_dist_.
  size_t BlockOf(const Eigen::Vector3f& p, int c, int b[3]) const {
    const float h = half_[c], s = cells_per_unit_[c] / kBlockCells;
    for (int a = 0; a < 3; ++a) b[a] = std::clamp(int((p[a] + h) * s), 0, block_res_ - 1);
    return size_t(c) * block_res_ * block_res_ * block_res_ + b[0] + size_t(block_res_) * (b[1] + size_t(block_res_) * b[2]);
  }

  OccupancyGridOptions options_;
  bool contracted_ = false;
  float bound_ = 0.5f;
  float max_threshold_ = 0;
  float threshold_ = 0;
  int res_ = 0;
  int cascades_ = 0;
  std::vector<float> density_;
  std::vector<uint8_t> visible_;
  std::vector<uint64_t> bits_;
  int block_res_ = 0;                 // res_ / kBlockCells, or 0 (no blocks).
  std::vector<uint64_t> block_bits_;  // One bit per block, cascades in order.
  // Per block: chessboard distance (in blocks, capped at 255) to the nearest
  // block the march may not jump (EmptyBoxAround); 0 for such blocks.
  std::vector<uint8_t> block_dist_;
  std::vector<uint8_t> block_ok_;     // Per cascade: its blocks align with the finer cascade.
  std::vector<float> fresh_;
  std::vector<float> half_;           // Half-size of each cascade.
  std::vector<float> cells_per_unit_; // res / (2 * half) per cascade.  // Scratch for ApplyUpdate (-1 = untouched).
};

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_OCCUPANCY_GRID_H_
