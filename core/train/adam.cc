#include "core/train/adam.h"

#include <algorithm>
#include <cmath>

namespace clnerf {

absl::Status AdamOptions::Validate() const {
  if (!(beta1 >= 0 && beta1 < 1) || !(beta2 >= 0 && beta2 < 1)) {
    return absl::InvalidArgumentError("adam: betas must be in [0, 1)");
  }
  if (!(epsilon > 0)) return absl::InvalidArgumentError("adam: epsilon must be > 0");
  return absl::OkStatus();
}

void Adam::ResizeBlock(int block, size_t size) {
  if (int(m_.size()) <= block) {
    m_.resize(block + 1);
    v_.resize(block + 1);
  }
  m_[block].resize(size, 0.0f);
  v_[block].resize(size, 0.0f);
}

void Adam::SetMoments(int block, const std::vector<float>& m, const std::vector<float>& v) {
  std::copy(m.begin(), m.begin() + std::min(m.size(), m_[block].size()), m_[block].begin());
  std::copy(v.begin(), v.begin() + std::min(v.size(), v_[block].size()), v_[block].begin());
}

namespace {
// Bias-corrected step size and epsilon for 1-based step `step`.
struct Corrected {
  float step_size, eps_hat;
};
inline Corrected Correct(const AdamOptions& o, float lr, int step) {
  const float c1 = 1.0f - std::pow(o.beta1, float(step)), c2 = 1.0f - std::pow(o.beta2, float(step));
  return {lr * std::sqrt(c2) / c1, o.epsilon * std::sqrt(c2)};
}

inline void AdamOne(float& p, float g, float& m, float& v, float b1, float b2, float step_size, float eps_hat) {
  m = b1 * m + (1.0f - b1) * g;
  v = b2 * v + (1.0f - b2) * g * g;
  p -= step_size * m / (std::sqrt(v) + eps_hat);
}
}  // namespace

void Adam::UpdateDense(int block, float lr, int step, float* params, const float* grad, size_t n) {
  const float b1 = options_.beta1, b2 = options_.beta2;
  // Plain locals: OpenMP (and clang) cannot capture structured bindings.
  const auto corrected = Correct(options_, lr, step);
  const float step_size = corrected.step_size, eps_hat = corrected.eps_hat;
  float* m = m_[block].data();
  float* v = v_[block].data();
#pragma omp simd
  for (size_t i = 0; i < n; ++i) AdamOne(params[i], grad[i], m[i], v[i], b1, b2, step_size, eps_hat);
}

void Adam::UpdateSparse(int block, float lr, int step, float* params, const float* grad,
                        const std::vector<uint32_t>& entries, int stride) {
  const float b1 = options_.beta1, b2 = options_.beta2;
  // Plain locals: OpenMP (and clang) cannot capture structured bindings.
  const auto corrected = Correct(options_, lr, step);
  const float step_size = corrected.step_size, eps_hat = corrected.eps_hat;
  float* m = m_[block].data();
  float* v = v_[block].data();
  for (uint32_t e : entries) {
    for (int k = 0; k < stride; ++k) {
      const size_t i = size_t(e) * stride + k;
      AdamOne(params[i], grad[i], m[i], v[i], b1, b2, step_size, eps_hat);
    }
  }
}

}  // namespace clnerf
