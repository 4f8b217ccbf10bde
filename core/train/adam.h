// Adam: the optimiser for all trainable blocks. Dense blocks (MLPs,
// embeddings) are updated every step; the hash grid is updated lazily, only
// at entries that received a gradient this step (as tiny-cuda-nn does for
// grid parameters), which keeps a step's cost proportional to the rays
// trained rather than to the table size. Not thread-safe; the trainer owns
// one instance.
#ifndef CLNERF_CORE_TRAIN_ADAM_H_
#define CLNERF_CORE_TRAIN_ADAM_H_

#include <cstdint>
#include <vector>

#include "absl/status/status.h"

namespace clnerf {

struct AdamOptions {
  float beta1 = 0.9f;
  float beta2 = 0.99f;  // tiny-cuda-nn's choice; upstream ngp_pl uses 0.999.
  float epsilon = 1e-15f;
  absl::Status Validate() const;
};

class Adam {
 public:
  explicit Adam(const AdamOptions& options = {}) : options_(options) {}

  // Resizes the moment buffers for a block of `size` parameters (zeros new ones).
  void ResizeBlock(int block, size_t size);
  // Dense update of every entry of `block`. `step` is 1-based.
  void UpdateDense(int block, float lr, int step, float* params, const float* grad, size_t n);
  // Sparse update of the listed entries; `stride` floats per entry.
  void UpdateSparse(int block, float lr, int step, float* params, const float* grad,
                    const std::vector<uint32_t>& entries, int stride);

  // Replaces a block's moments (resuming a carried optimiser state). Sizes
  // must match the block's; call ResizeBlock first.
  void SetMoments(int block, const std::vector<float>& m, const std::vector<float>& v);

  const std::vector<float>& m(int block) const { return m_[block]; }
  const std::vector<float>& v(int block) const { return v_[block]; }

 private:
  AdamOptions options_;
  std::vector<std::vector<float>> m_, v_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_ADAM_H_
