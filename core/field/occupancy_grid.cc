#include "core/field/occupancy_grid.h"

#include <algorithm>
#include <cmath>

#include "core/data/contraction.h"
#include "Eigen/Dense"

namespace clnerf {

absl::Status OccupancyGridOptions::Validate() const {
  if (resolution < 8 || resolution > 512 || (resolution & (resolution - 1)) != 0) {
    return absl::InvalidArgumentError("occupancy grid: resolution must be a power of two in [8, 512]");
  }
  if (update_interval < 1) return absl::InvalidArgumentError("occupancy grid: update_interval must be >= 1");
  if (!(decay > 0 && decay <= 1)) return absl::InvalidArgumentError("occupancy grid: decay must be in (0, 1]");
  return absl::OkStatus();
}

OccupancyGrid::OccupancyGrid(const OccupancyGridOptions& options, float bound, float min_step)
    : options_(options), bound_(bound), res_(options.resolution) {
  cascades_ = std::max(1 + int(std::ceil(std::log2(2.0f * bound))), 1);
  for (int c = 0; c < cascades_; ++c) {
    half_.push_back(std::min(std::ldexp(1.0f, c - 1), bound));
    cells_per_unit_.push_back(res_ * 0.5f / half_.back());
  }
  max_threshold_ = options.density_threshold > 0 ? options.density_threshold : 0.01f / min_step;
  threshold_ = max_threshold_;
  density_.assign(num_cells(), 0.0f);
  visible_.assign(num_cells(), 1);
  bits_.assign((num_cells() + 63) / 64, 0);
  // A block must not straddle a cascade's inner boundary (at res/4 cells
  // from each face), so blocks need res divisible by 4 * kBlockCells.
  block_res_ = res_ >= 4 * kBlockCells && res_ % (4 * kBlockCells) == 0 ? res_ / kBlockCells : 0;
  for (int c = 0; c < cascades_; ++c) {
    const float inner = c == 0 ? 0.0f : (half_[c] - half_[c - 1]) * cells_per_unit_[c] / kBlockCells;
    block_ok_.push_back(std::abs(inner - std::round(inner)) < 1e-3f);
  }
  block_bits_.assign((size_t(block_res_) * block_res_ * block_res_ * cascades_ + 63) / 64, 0);
  block_dist_.assign(size_t(block_res_) * block_res_ * block_res_ * cascades_, 0);
  SetAllOccupied();
}

void OccupancyGrid::RefreshBlocks() {
  if (block_res_ == 0) return;
  std::fill(block_bits_.begin(), block_bits_.end(), 0);
  const size_t per = cells_per_cascade(), blocks_per = size_t(block_res_) * block_res_ * block_res_;
  for (size_t w = 0; w < bits_.size(); ++w) {
    for (uint64_t b = bits_[w]; b != 0; b &= b - 1) {
      const size_t i = w * 64 + size_t(__builtin_ctzll(b));
      const size_t c = i / per, r = i % per;
      const size_t x = r % size_t(res_), y = (r / size_t(res_)) % size_t(res_), z = r / (size_t(res_) * res_);
      const size_t k = c * blocks_per + x / kBlockCells +
                       size_t(block_res_) * (y / kBlockCells + size_t(block_res_) * (z / kBlockCells));
      block_bits_[k >> 6] |= uint64_t(1) << (k & 63);
    }
  }
  for (int c = 0; c < cascades_; ++c) BlockDistances(c);
}

void OccupancyGrid::BlockDistances(int c) {
  const int n = block_res_;
  const size_t per = size_t(n) * n * n;
  uint8_t* dist = block_dist_.data() + size_t(c) * per;
  // Blocks a jump must stop at: occupied ones, and those inside the finer
  // cascade's cube (blocks align with it when block_ok_), where the march
  // reads the finer cascade instead. A cascade whose blocks do not align
  // has none to jump.
  if (!block_ok_[c]) {
    std::fill(dist, dist + per, uint8_t(0));
    return;
  }
  const int inner = c == 0 ? n : int(std::lround((half_[c] - half_[c - 1]) * cells_per_unit_[c] / kBlockCells));
  for (int z = 0; z < n; ++z) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        const size_t i = x + size_t(n) * (y + size_t(n) * z);
        const size_t k = size_t(c) * per + i;
        const bool finer = x >= inner && x < n - inner && y >= inner && y < n - inner && z >= inner && z < n - inner;
        dist[i] = ((block_bits_[k >> 6] >> (k & 63)) & 1) || finer ? 0 : 255;
      }
    }
  }
  // Chessboard distance transform: two raster passes over the 26
  // neighbours (Rosenfeld & Pfaltz), exact for this metric. The grid's
  // outside is not a stop (EmptyBoxAround clips the box to the grid).
  for (int pass = 0; pass < 2; ++pass) {
    const int step = pass == 0 ? 1 : -1, first = pass == 0 ? 0 : n - 1;
    for (int zi = 0, z = first; zi < n; ++zi, z += step) {
      for (int yi = 0, y = first; yi < n; ++yi, y += step) {
        for (int xi = 0, x = first; xi < n; ++xi, x += step) {
          uint8_t& d = dist[x + size_t(n) * (y + size_t(n) * z)];
          if (d == 0) continue;
          int best = d;
          // The 13 neighbours already visited in this pass's order.
          for (int dz = -1; dz <= 0; ++dz) {
            for (int dy = -1; dy <= (dz < 0 ? 1 : 0); ++dy) {
              for (int dx = -1; dx <= (dz < 0 || dy < 0 ? 1 : -1); ++dx) {
                const int nx = x + step * dx, ny = y + step * dy, nz = z + step * dz;
                if (nx < 0 || nx >= n || ny < 0 || ny >= n || nz < 0 || nz >= n) continue;
                best = std::min(best, dist[nx + size_t(n) * (ny + size_t(n) * nz)] + 1);
              }
            }
          }
          d = uint8_t(std::min(best, 255));
        }
      }
    }
  }
}

bool OccupancyGrid::Occupied(const Eigen::Vector3f& p) const {
  const int c = CascadeOf(p);
  if (c < 0) return false;
  return OccupiedCell(CellIndex(p, c));
}

Eigen::Vector3f OccupancyGrid::CellPosition(uint32_t cell, const Eigen::Vector3f& jitter) const {
  const size_t per = cells_per_cascade();
  const int c = int(cell / per);
  size_t r = cell % per;
  const int x = int(r % res_);
  r /= res_;
  const int y = int(r % res_);
  const int z = int(r / res_);
  const float h = cascade_half_size(c);
  const float cs = 2.0f * h / res_;
  return Eigen::Vector3f((x + 0.5f + jitter.x()) * cs - h, (y + 0.5f + jitter.y()) * cs - h,
                         (z + 0.5f + jitter.z()) * cs - h);
}

std::vector<uint32_t> OccupancyGrid::CellsToUpdate(int iter, std::mt19937_64* rng) const {
  std::vector<uint32_t> cells;
  const size_t n = num_cells();
  if (iter < options_.warmup_iterations) {
    cells.reserve(n);
    for (size_t i = 0; i < n; ++i) {
      if (visible_[i]) cells.push_back(uint32_t(i));
    }
    return cells;
  }
  const size_t quarter = n / 4;
  cells.reserve(2 * quarter);
  std::uniform_int_distribution<uint32_t> any(0, uint32_t(n - 1));
  for (size_t i = 0; i < quarter; ++i) {
    const uint32_t c = any(*rng);
    if (visible_[c]) cells.push_back(c);
  }
  std::vector<uint32_t> occupied;
  for (size_t w = 0; w < bits_.size(); ++w) {
    uint64_t b = bits_[w];
    while (b) {
      const int k = __builtin_ctzll(b);
      occupied.push_back(uint32_t(w * 64 + k));
      b &= b - 1;
    }
  }
  if (!occupied.empty()) {
    std::uniform_int_distribution<size_t> pick(0, occupied.size() - 1);
    for (size_t i = 0; i < quarter; ++i) cells.push_back(occupied[pick(*rng)]);
  }
  return cells;
}

void OccupancyGrid::ApplyUpdate(const std::vector<uint32_t>& cells, const std::vector<float>& sigma) {
  const float decay = options_.decay;
  // A cell may be listed twice: take the max of its new samples first, then
  // decay it once. fresh_ is kept at -1 outside this function.
  if (fresh_.size() != density_.size()) fresh_.assign(density_.size(), -1.0f);
  for (size_t i = 0; i < cells.size(); ++i) fresh_[cells[i]] = std::max(fresh_[cells[i]], sigma[i]);
  for (uint32_t c : cells) {
    if (fresh_[c] >= 0.0f) {
      density_[c] = std::max(density_[c] * decay, fresh_[c]);
      fresh_[c] = -1.0f;
    }
  }
  RefreshBits();
}

void OccupancyGrid::RefreshBits() {
  double sum = 0;
  long long count = 0;
  const long long n = (long long)density_.size();
#pragma omp parallel for reduction(+ : sum, count) schedule(static)
  for (long long i = 0; i < n; ++i) {
    if (visible_[i]) {
      sum += density_[i];
      ++count;
    }
  }
  const float mean = count ? float(sum / count) : 0.0f;
  threshold_ = std::min(mean, max_threshold_);
  const long long words = (long long)bits_.size();
#pragma omp parallel for schedule(static)
  for (long long w = 0; w < words; ++w) {
    uint64_t b = 0;
    for (int k = 0; k < 64; ++k) {
      const long long i = w * 64 + k;
      if (i < n && visible_[i] && density_[i] > threshold_) b |= uint64_t(1) << k;
    }
    bits_[w] = b;
  }
  RefreshBlocks();
}

void OccupancyGrid::MarkInvisible(const std::vector<Camera>& cameras, float near) {
  if (cameras.empty()) return;
  std::vector<Eigen::Matrix3f> rt;
  std::vector<Eigen::Vector3f> pos;
  for (const Camera& c : cameras) {
    rt.push_back(c.c2w.leftCols<3>().transpose());
    pos.push_back(c.c2w.col(3));
  }
  const size_t n = num_cells();
  std::vector<uint8_t> fresh_seen(n, 0);
#pragma omp parallel for schedule(static)
  for (long long i = 0; i < (long long)n; ++i) {
    const Eigen::Vector3f cell = CellPosition(uint32_t(i), Eigen::Vector3f::Zero());
    const Eigen::Vector3f p = contracted_ ? Uncontract(cell) : cell;
    // Half a cell, in model units (a contracted cell at |x| = r spans ~r^2 times more).
    const float stretch = contracted_ ? std::max(1.0f, InfNorm(p)) : 1.0f;
    const float half = 0.5f * CellSize(int(i / cells_per_cascade())) * stretch * stretch;
    bool seen = false;
    for (size_t k = 0; k < cameras.size() && !seen; ++k) {
      const Eigen::Vector3f q = rt[k] * (p - pos[k]);
      // A cell is seen if its centre projects into the image (with a margin
      // of half a cell's footprint) in front of the near plane.
      if (q.z() <= near) continue;
      const Intrinsics& in = cameras[k].intrinsics;
      const float mx = half * in.fx / q.z() * 1.8f, my = half * in.fy / q.z() * 1.8f;
      const float u = in.fx * q.x() / q.z() + in.cx, v = in.fy * q.y() / q.z() + in.cy;
      seen = u >= -mx && u <= in.width + mx && v >= -my && v <= in.height + my;
    }
    // Cells that become visible again (a warm-started model seeing a new
    // region) start occupied, like cells of a fresh grid.
    fresh_seen[i] = seen && !visible_[i];
    visible_[i] = seen;
  }
  for (size_t i = 0; i < n; ++i) {
    if (!visible_[i]) bits_[i >> 6] &= ~(uint64_t(1) << (i & 63));
    if (fresh_seen[i]) bits_[i >> 6] |= uint64_t(1) << (i & 63);
  }
  RefreshBlocks();
}

void OccupancyGrid::SetAllOccupied() {
  for (size_t i = 0; i < num_cells(); ++i) {
    if (visible_[i]) bits_[i >> 6] |= uint64_t(1) << (i & 63);
  }
  RefreshBlocks();
}

size_t OccupancyGrid::num_occupied() const {
  size_t n = 0;
  for (uint64_t b : bits_) n += __builtin_popcountll(b);
  return n;
}

size_t OccupancyGrid::num_visible() const {
  size_t n = 0;
  for (uint8_t v : visible_) n += v;
  return n;
}

void OccupancyGrid::Restore(std::vector<float> density, std::vector<uint8_t> visible,
                            std::vector<uint64_t> bits, float threshold) {
  density_ = std::move(density);
  visible_ = std::move(visible);
  bits_ = std::move(bits);
  threshold_ = threshold;
  RefreshBlocks();
}

}  // namespace clnerf
