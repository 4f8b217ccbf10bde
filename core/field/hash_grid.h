// HashGrid: the multiresolution hash encoding of Instant-NGP (Müller et al.
// 2022). L levels, F=2 features per level, up to 2^T entries per level. Level
// l has resolution ceil(base * b^l - 1) + 1 with growth b chosen so the last
// level reaches `finest_resolution`. A level whose res^3 grid fits its table
// is stored densely; larger levels are indexed with the XOR-prime hash
// (1, 2654435761, 805459861). Corners are interpolated trilinearly.
//
// The grid owns only its layout; parameters live in a caller-provided float
// array of num_params() values ([entry][feature] per level, levels
// concatenated), so the optimiser and checkpoints can treat them as one flat
// block. All methods are const and thread-safe; Backward* accumulate into
// caller-owned gradient buffers (the caller keeps threads apart, e.g. by
// level: see BackwardLevel).
#ifndef CLNERF_CORE_FIELD_HASH_GRID_H_
#define CLNERF_CORE_FIELD_HASH_GRID_H_

#include <cstdint>
#include <vector>

#include "absl/status/status.h"

namespace clnerf {

struct HashGridOptions {
  int levels = 16;              // L: number of resolution levels.
  int features_per_level = 2;   // F: only 2 is supported (as in the paper).
  int log2_table_size = 19;     // T: at most 2^T entries per level.
  int base_resolution = 16;     // Coarsest level resolution.
  int finest_resolution = 1024; // Resolution of the finest level (2048 * s upstream).
  absl::Status Validate() const;
};

class HashGrid {
 public:
  static constexpr int kFeatures = 2;

  explicit HashGrid(const HashGridOptions& options);

  const HashGridOptions& options() const { return options_; }
  int num_levels() const { return options_.levels; }
  int output_dim() const { return options_.levels * kFeatures; }
  // Total number of float parameters.
  size_t num_params() const { return total_entries_ * kFeatures; }
  // Per-level layout (entries, not floats).
  size_t level_offset(int l) const { return offsets_[l]; }
  size_t level_size(int l) const { return sizes_[l]; }
  float level_scale(int l) const { return scales_[l]; }
  uint32_t level_resolution(int l) const { return resolutions_[l]; }
  bool level_dense(int l) const { return dense_[l]; }

  // Uniform(-1e-4, 1e-4) initialisation, as in tiny-cuda-nn.
  void Initialize(float* params, uint64_t seed) const;

  // Encodes n positions (xyz interleaved, each coordinate in [0, 1]) into
  // out[n][L*F] (sample-major, i.e. column-major L*F x n).
  void Encode(const float* params, const float* pos, int n, float* out) const;

  // Accumulates dL/dparams for one level from dL/dout (same layout as Encode's
  // output). Entries touched for the first time are flagged in
  // touched[entry] = 1 (entry index in the whole grid) when touched != nullptr
  // and appended to touched_list.
  void BackwardLevel(int level, const float* pos, const float* dout, int n, float* grad,
                     uint8_t* touched, std::vector<uint32_t>* touched_list) const;

  // dL/dpos for each sample (n x 3), for gradient checks; positions are not
  // trained.
  void BackwardPosition(const float* params, const float* pos, const float* dout, int n,
                        float* dpos) const;

  // Index of the table entry for integer grid corner (x, y, z) at level l.
  inline uint32_t Index(int l, uint32_t x, uint32_t y, uint32_t z) const {
    if (dense_[l]) {
      const uint32_t r = strides_[l];
      return x + r * (y + r * z);
    }
    return (x ^ (y * 2654435761u) ^ (z * 805459861u)) & (uint32_t(sizes_[l]) - 1u);
  }

 private:
  HashGridOptions options_;
  std::vector<float> scales_;
  std::vector<uint32_t> resolutions_;
  std::vector<uint32_t> strides_;  // Dense levels: resolution + 1.
  std::vector<size_t> offsets_;
  std::vector<size_t> sizes_;
  std::vector<uint8_t> dense_;
  size_t total_entries_ = 0;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_HASH_GRID_H_
