#include "core/field/proposal_field.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "absl/strings/str_cat.h"
#include "core/field/network.h"

namespace clnerf {

absl::Status ProposalFieldOptions::Validate() const {
  if (hidden < 1 || hidden > 256) return absl::InvalidArgumentError("proposal: hidden must be in [1, 256]");
  return GridOptions().Validate();
}

absl::Status ProposalOptions::Validate() const {
  if (samples0 < 2 || samples0 > kMaxProposalSamples || samples1 < 0 || samples1 == 1 ||
      samples1 > kMaxProposalSamples) {
    return absl::InvalidArgumentError(
        absl::StrCat("proposal: samples0 must be in [2, ", kMaxProposalSamples, "] and samples1 0 or in [2, ",
                     kMaxProposalSamples, "]"));
  }
  if (nerf_samples < 1 || nerf_samples > kMaxProposalSamples) {
    return absl::InvalidArgumentError(absl::StrCat("proposal: nerf_samples must be in [1, ", kMaxProposalSamples, "]"));
  }
  if (!(histogram_padding >= 0 && histogram_padding <= 1)) {
    return absl::InvalidArgumentError("proposal: histogram_padding must be in [0, 1]");
  }
  for (int k = 0; k < num_stages(); ++k) {
    if (absl::Status s = field(k).Validate(); !s.ok()) return s;
  }
  return absl::OkStatus();
}

HashGridOptions ProposalFieldOptions::GridOptions() const {
  HashGridOptions g;
  g.levels = levels;
  g.log2_table_size = log2_table_size;
  g.base_resolution = base_resolution;
  g.finest_resolution = finest_resolution;
  return g;
}

void ProposalWorkspace::Reserve(int n, int grid_dim, int hidden_width) {
  if (feat.cols() < n || feat.rows() != grid_dim || hidden.rows() != hidden_width) {
    feat.resize(grid_dim, n);
    hidden.resize(hidden_width, n);
    d_feat.resize(grid_dim, n);
  }
  if (int(h.size()) < n) h.resize(n);
}

ProposalField::ProposalField(const ProposalFieldOptions& options)
    : options_(options), grid_(options.GridOptions()) {}

void ProposalField::Initialize(float* params, uint64_t seed) const {
  grid_.Initialize(params, seed * 2 + 1);
  std::mt19937_64 rng(seed * 2 + 2);
  const int D = grid_.output_dim(), H = options_.hidden;
  float* w1 = params + mlp_offset();
  const float a1 = std::sqrt(6.0f / float(H + D));
  std::uniform_real_distribution<float> u1(-a1, a1);
  for (int i = 0; i < H * D; ++i) w1[i] = u1(rng);
  const float a2 = std::sqrt(6.0f / float(H + 1));
  std::uniform_real_distribution<float> u2(-a2, a2);
  for (int i = 0; i < H; ++i) w1[H * D + i] = u2(rng);
}

void ProposalField::Forward(const float* params, const float* pos, int n, ProposalWorkspace* ws,
                            float* sigma) const {
  if (n == 0) return;
  const int D = grid_.output_dim(), H = options_.hidden;
  ws->Reserve(n, D, H);
  grid_.Encode(params, pos, n, ws->feat.data());
  const Eigen::Map<const Eigen::MatrixXf> W1(params + mlp_offset(), H, D);
  const Eigen::Map<const Eigen::RowVectorXf> w2(params + mlp_offset() + size_t(H) * D, H);
  auto hid = ws->hidden.leftCols(n);
  hid.noalias() = W1 * ws->feat.leftCols(n);
  hid = hid.cwiseMax(0.0f);
  Eigen::Map<Eigen::RowVectorXf> h(ws->h.data(), n);
  h.noalias() = w2 * hid;
  for (int j = 0; j < n; ++j) sigma[j] = TruncExp(ws->h[j]);
}

void ProposalField::Backward(const float* params, int n, const float* d_sigma, ProposalWorkspace* ws,
                             float* grad) const {
  if (n == 0) return;
  const int D = grid_.output_dim(), H = options_.hidden;
  const Eigen::Map<const Eigen::MatrixXf> W1(params + mlp_offset(), H, D);
  const Eigen::Map<const Eigen::VectorXf> w2(params + mlp_offset() + size_t(H) * D, H);
  Eigen::Map<Eigen::MatrixXf> dW1(grad + mlp_offset(), H, D);
  Eigen::Map<Eigen::RowVectorXf> dw2(grad + mlp_offset() + size_t(H) * D, H);
  Eigen::RowVectorXf dh(n);
  for (int j = 0; j < n; ++j) dh[j] = d_sigma[j] * TruncExpGrad(ws->h[j]);
  const auto hid = ws->hidden.leftCols(n);
  dw2.noalias() += dh * hid.transpose();
  // d hidden (pre-ReLU) = w2 dh, masked by the ReLU.
  Eigen::MatrixXf dhid = w2 * dh;
  dhid = (hid.array() > 0.0f).select(dhid, 0.0f);
  dW1.noalias() += dhid * ws->feat.leftCols(n).transpose();
  ws->d_feat.leftCols(n).noalias() = W1.transpose() * dhid;
}

}  // namespace clnerf
