// ProposalField: a small density-only field (a coarse hash grid and a
// one-hidden-layer MLP, sigma = trunc_exp(w2 . relu(W1 feat))) whose only
// job is to say where along a ray the radiance field's surfaces are, so the
// full field is evaluated at a few dozen samples per ray instead of every
// occupied step (mip-NeRF 360's proposal MLP, nerfacto's
// HashMLPDensityField). It has no time-step embedding: it proposes for every
// scan of a place at once, which is what the continual update's replay needs.
//
// Parameters live in a caller-owned flat array: the hash tables
// (HashGrid layout) followed by W1 (hidden x L*2, column-major) and w2
// (1 x hidden). Methods are const and thread-safe; activations live in a
// caller-owned ProposalWorkspace, one per thread.
#ifndef CLNERF_CORE_FIELD_PROPOSAL_FIELD_H_
#define CLNERF_CORE_FIELD_PROPOSAL_FIELD_H_

#include <cstdint>
#include <vector>

#include "absl/status/status.h"
#include "core/field/hash_grid.h"
#include "Eigen/Core"

namespace clnerf {

struct ProposalFieldOptions {
  int levels = 5;               // Hash-grid levels (nerfacto: 5).
  int log2_table_size = 16;     // At most 2^T entries per level (nerfacto: 17).
  int base_resolution = 16;     // Coarsest level.
  int finest_resolution = 128;  // Finest level (nerfacto: 128 and 256 for its two fields).
  int hidden = 16;              // Width of the one hidden layer.
  absl::Status Validate() const;
  HashGridOptions GridOptions() const;
};

// The proposal stages of a model: one or two proposal fields, how many
// samples each places, and how many reach the full field.
struct ProposalOptions {
  int samples0 = 64;      // First stage: stratified in the ray's spacing, proposal field 0.
  int samples1 = 64;      // Second stage: resampled from stage 0's weights, proposal field 1 (0 = one stage).
  int nerf_samples = 48;  // Resampled from the last stage's weights; the full field sees only these.
  float histogram_padding = 0.01f;  // Added to each proposal weight before resampling (nerfacto).
  ProposalFieldOptions field0;      // finest_resolution 128.
  ProposalFieldOptions field1 = [] {
    ProposalFieldOptions o;
    o.finest_resolution = 256;
    return o;
  }();
  int num_stages() const { return samples1 > 0 ? 2 : 1; }
  int stage_samples(int k) const { return k == 0 ? samples0 : samples1; }
  const ProposalFieldOptions& field(int k) const { return k == 0 ? field0 : field1; }
  absl::Status Validate() const;
};

inline constexpr int kMaxProposalSamples = 1024;

struct ProposalWorkspace {
  Eigen::MatrixXf feat;    // L*2 x n hash features.
  Eigen::MatrixXf hidden;  // hidden x n, post-ReLU.
  std::vector<float> h;    // Pre-activation of sigma per sample.
  Eigen::MatrixXf d_feat;  // L*2 x n after Backward.
  void Reserve(int n, int grid_dim, int hidden_width);
};

class ProposalField {
 public:
  explicit ProposalField(const ProposalFieldOptions& options);

  const ProposalFieldOptions& options() const { return options_; }
  const HashGrid& grid() const { return grid_; }
  size_t num_params() const { return grid_.num_params() + mlp_size(); }
  size_t mlp_offset() const { return grid_.num_params(); }
  size_t mlp_size() const { return size_t(options_.hidden) * (grid_.output_dim() + 1); }

  // Hash grid as in tiny-cuda-nn (uniform +-1e-4), Xavier-uniform MLP.
  void Initialize(float* params, uint64_t seed) const;

  // sigma at n positions (3 x n, each coordinate in [0, 1]); keeps the
  // activations in ws for Backward.
  void Forward(const float* params, const float* pos, int n, ProposalWorkspace* ws, float* sigma) const;
  // From dL/dsigma (n values, for the samples of the last Forward):
  // accumulates dL/dW1, dL/dw2 into grad (same layout as params; only the MLP
  // part is written) and leaves dL/dfeat in ws->d_feat for
  // HashGrid::BackwardLevel with the same positions.
  void Backward(const float* params, int n, const float* d_sigma, ProposalWorkspace* ws, float* grad) const;

 private:
  ProposalFieldOptions options_;
  HashGrid grid_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_PROPOSAL_FIELD_H_
