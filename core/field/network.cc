#include "core/field/network.h"

#include <cmath>
#include <algorithm>
#include <random>

#include "core/field/dense_layer.h"
#include "core/field/sh_encoding.h"

namespace clnerf {

absl::Status NetworkOptions::Validate() const {
  if (density_hidden < 1 || colour_hidden < 1) return absl::InvalidArgumentError("network: hidden widths must be >= 1");
  if (density_hidden_layers < 1 || colour_hidden_layers < 1) {
    return absl::InvalidArgumentError("network: at least one hidden layer per MLP");
  }
  if (density_out < 1) return absl::InvalidArgumentError("network: density_out must be >= 1");
  if (appearance_dim < 0 || geometry_dim < 0) return absl::InvalidArgumentError("network: embedding dims must be >= 0");
  return absl::OkStatus();
}

void NetworkWorkspace::Reserve(int n, const NetworkOptions& o, int grid_dim) {
  if (n <= capacity && !density_act.empty()) return;
  capacity = n;
  density_act.assign(o.density_hidden_layers, Eigen::MatrixXf(o.density_hidden, n));
  h.resize(o.density_out, n);
  colour_act.assign(o.colour_hidden_layers, Eigen::MatrixXf(o.colour_hidden, n));
  rgb.resize(3, n);
  const int w = std::max(o.density_hidden, o.colour_hidden);
  d_a.resize(w, n);
  d_b.resize(w, n);
  d_h.resize(o.density_out, n);
}

Network::Network(const NetworkOptions& options, int grid_dim) : options_(options), grid_dim_(grid_dim) {
  size_t off = 0;
  auto add = [&off](std::vector<Layer>* v, int rows, int cols) {
    v->push_back({off, rows, cols});
    off += size_t(rows) * cols;
  };
  const NetworkOptions& o = options_;
  add(&density_layers_, o.density_hidden, density_input_dim());
  for (int i = 1; i < o.density_hidden_layers; ++i) add(&density_layers_, o.density_hidden, o.density_hidden);
  add(&density_layers_, o.density_out, o.density_hidden);
  add(&colour_layers_, o.colour_hidden, colour_input_dim());
  for (int i = 1; i < o.colour_hidden_layers; ++i) add(&colour_layers_, o.colour_hidden, o.colour_hidden);
  add(&colour_layers_, 3, o.colour_hidden);
  mlp_size_ = off;
}

int Network::colour_input_dim() const { return kShDim + options_.density_out + options_.app_dim(); }

void Network::InitializeMlp(float* mlp, uint64_t seed) const {
  std::mt19937_64 rng(seed);
  for (const auto* layers : {&density_layers_, &colour_layers_}) {
    for (const Layer& l : *layers) {
      const float a = std::sqrt(6.0f / float(l.rows + l.cols));
      std::uniform_real_distribution<float> u(-a, a);
      for (size_t i = 0; i < size_t(l.rows) * l.cols; ++i) mlp[l.offset + i] = u(rng);
    }
  }
}

void Network::InitializeEmbeddings(float* emb, int rows, uint64_t seed) const {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> n(0.0f, 1.0f);
  for (size_t i = 0; i < size_t(rows) * embedding_row_size(); ++i) emb[i] = n(rng);
}

void SegmentBiasPointers(const float* bias, int rows, const int* seg, int nrays, int n,
                         std::vector<const float*>* out) {
  out->resize(n);
  for (int r = 0; r < nrays; ++r) {
    for (int j = seg[r]; j < seg[r + 1]; ++j) (*out)[j] = bias + size_t(r) * rows;
  }
}

namespace {
inline ConstMatrixMap W(const float* mlp, const Network::Layer& l) {
  return ConstMatrixMap(mlp + l.offset, l.rows, l.cols);
}
inline MatrixMap dW(float* d, const Network::Layer& l) { return MatrixMap(d + l.offset, l.rows, l.cols); }

// out = act(layer * in) on the first n columns (no bias).
void Apply(const float* mlp, const Network::Layer& l, const Eigen::MatrixXf& in, int n, Activation act,
           Eigen::MatrixXf* out) {
  DenseForward(mlp + l.offset, l.rows, l.cols, l.rows, in.data(), int(in.rows()), n, nullptr, act, out->data(),
               int(out->rows()));
}
// out.col(r) = sum of columns of segment r.
template <typename M>
void SumSegments(const M& a, const int* seg, int nrays, float* out) {
  const int rows = int(a.rows());
  for (int r = 0; r < nrays; ++r) {
    Eigen::Map<Eigen::VectorXf> o(out + size_t(r) * rows, rows);
    o.setZero();
    for (int j = seg[r]; j < seg[r + 1]; ++j) o += a.col(j);
  }
}
}  // namespace

void Network::StepBiases(const float* mlp, const float* emb, int num_steps, Eigen::MatrixXf* geo,
                         Eigen::MatrixXf* app) const {
  const int A = options_.app_dim(), G = options_.geo_dim();
  const Layer& d0 = density_layers_[0];
  const Layer& c0 = colour_layers_[0];
  geo->setZero(d0.rows, num_steps);
  app->setZero(c0.rows, num_steps);
  if (!options_.use_embeddings) return;
  const int row = embedding_row_size();
  for (int t = 0; t < num_steps; ++t) {
    const Eigen::Map<const Eigen::VectorXf> ea(emb + size_t(t) * row, A);
    const Eigen::Map<const Eigen::VectorXf> eg(emb + size_t(t) * row + A, G);
    geo->col(t).noalias() = W(mlp, d0).rightCols(G) * eg;
    app->col(t).noalias() = W(mlp, c0).rightCols(A) * ea;
  }
}

void Network::RayColourBias(const float* mlp, const float* sh, const float* app_bias, float* out) const {
  const Layer& c0 = colour_layers_[0];
  Eigen::Map<Eigen::VectorXf> o(out, c0.rows);
  o.noalias() = W(mlp, c0).leftCols(kShDim) * Eigen::Map<const Eigen::VectorXf>(sh, kShDim);
  o += Eigen::Map<const Eigen::VectorXf>(app_bias, c0.rows);
}

void Network::DensityHidden(const float* mlp, const float* feat, int n, const int* seg, int nrays,
                            const float* geo_bias, NetworkWorkspace* ws) const {
  const int L = int(density_layers_.size());
  const Layer& l0 = density_layers_[0];
  thread_local std::vector<const float*> bias;
  const bool geo = options_.geo_dim() > 0;
  if (geo) SegmentBiasPointers(geo_bias, l0.rows, seg, nrays, n, &bias);
  DenseForward(mlp + l0.offset, l0.rows, grid_dim_, l0.rows, feat, grid_dim_, n, geo ? bias.data() : nullptr,
               Activation::kRelu, ws->density_act[0].data(), l0.rows);
  for (int k = 1; k < L - 1; ++k) Apply(mlp, density_layers_[k], ws->density_act[k - 1], n, Activation::kRelu,
                                        &ws->density_act[k]);
}

void Network::DensityForward(const float* mlp, const float* feat, int n, const int* seg, int nrays,
                             const float* geo_bias, NetworkWorkspace* ws) const {
  DensityHidden(mlp, feat, n, seg, nrays, geo_bias, ws);
  const int L = int(density_layers_.size());
  Apply(mlp, density_layers_[L - 1], ws->density_act[L - 2], n, Activation::kNone, &ws->h);
}

void Network::DensityOnly(const float* mlp, const float* feat, int n, const int* seg, int nrays,
                          const float* geo_bias, NetworkWorkspace* ws, float* h0) const {
  DensityHidden(mlp, feat, n, seg, nrays, geo_bias, ws);
  const int L = int(density_layers_.size());
  const Layer& last = density_layers_[L - 1];
  // Only row 0 (sigma's pre-activation): a 1-row layer, strided weights.
  DenseForward(mlp + last.offset, 1, last.cols, last.rows, ws->density_act[L - 2].data(), last.cols, n, nullptr,
               Activation::kNone, h0, 1);
}

void Network::ColourForward(const float* mlp, int n, const int* seg, int nrays, const float* colour_bias,
                            NetworkWorkspace* ws) const {
  const int L = int(colour_layers_.size());
  const int dout = options_.density_out;
  const Layer& l0 = colour_layers_[0];
  thread_local std::vector<const float*> bias;
  SegmentBiasPointers(colour_bias, l0.rows, seg, nrays, n, &bias);
  DenseForward(mlp + l0.offset + size_t(kShDim) * l0.rows, l0.rows, dout, l0.rows, ws->h.data(), dout, n,
               bias.data(), Activation::kRelu, ws->colour_act[0].data(), l0.rows);
  for (int k = 1; k < L - 1; ++k) Apply(mlp, colour_layers_[k], ws->colour_act[k - 1], n, Activation::kRelu,
                                        &ws->colour_act[k]);
  Apply(mlp, colour_layers_[L - 1], ws->colour_act[L - 2], n, Activation::kNone, &ws->rgb);
  auto rgb = ws->rgb.leftCols(n);
  rgb = (1.0f + (-rgb.array()).exp()).inverse().matrix();
}

void Network::Backward(const float* mlp, const float* feat, int n, const int* seg, int nrays,
                       const float* d_rgb, const float* d_h0, NetworkWorkspace* ws, float* d_mlp,
                       float* d_feat, float* d_geo_bias, float* d_colour_bias) const {
  const int Lc = int(colour_layers_.size());
  const int Ld = int(density_layers_.size());
  const int dout = options_.density_out;
  const int Hc = options_.colour_hidden, Hd = options_.density_hidden;

  // Colour MLP. dz = d_rgb * s * (1 - s), kept in the first rows of d_b.
  auto dz = ws->d_b.topLeftCorner(3, n);
  const auto rgb = ws->rgb.leftCols(n).array();
  dz = (ConstMatrixMap(d_rgb, 3, n).array() * rgb * (1.0f - rgb)).matrix();
  dW(d_mlp, colour_layers_[Lc - 1]).noalias() += dz * ws->colour_act[Lc - 2].leftCols(n).transpose();
  auto da = ws->d_a.topLeftCorner(Hc, n);
  da.noalias() = W(mlp, colour_layers_[Lc - 1]).transpose() * dz;
  da = da.cwiseProduct((ws->colour_act[Lc - 2].leftCols(n).array() > 0.0f).cast<float>().matrix());
  for (int k = Lc - 2; k >= 1; --k) {
    dW(d_mlp, colour_layers_[k]).noalias() += da * ws->colour_act[k - 1].leftCols(n).transpose();
    auto db = ws->d_b.topLeftCorner(Hc, n);
    db.noalias() = W(mlp, colour_layers_[k]).transpose() * da;
    da = db.cwiseProduct((ws->colour_act[k - 1].leftCols(n).array() > 0.0f).cast<float>().matrix());
  }
  // First colour layer: weights on h, per-ray bias gradient, dL/dh.
  dW(d_mlp, colour_layers_[0]).middleCols(kShDim, dout).noalias() += da * ws->h.leftCols(n).transpose();
  SumSegments(da, seg, nrays, d_colour_bias);
  auto dh = ws->d_h.leftCols(n);
  dh.noalias() = W(mlp, colour_layers_[0]).middleCols(kShDim, dout).transpose() * da;
  dh.row(0) += Eigen::Map<const Eigen::RowVectorXf>(d_h0, n);

  // Density MLP.
  dW(d_mlp, density_layers_[Ld - 1]).noalias() += dh * ws->density_act[Ld - 2].leftCols(n).transpose();
  auto ga = ws->d_a.topLeftCorner(Hd, n);
  ga.noalias() = W(mlp, density_layers_[Ld - 1]).transpose() * dh;
  ga = ga.cwiseProduct((ws->density_act[Ld - 2].leftCols(n).array() > 0.0f).cast<float>().matrix());
  for (int k = Ld - 2; k >= 1; --k) {
    dW(d_mlp, density_layers_[k]).noalias() += ga * ws->density_act[k - 1].leftCols(n).transpose();
    auto gb = ws->d_b.topLeftCorner(Hd, n);
    gb.noalias() = W(mlp, density_layers_[k]).transpose() * ga;
    ga = gb.cwiseProduct((ws->density_act[k - 1].leftCols(n).array() > 0.0f).cast<float>().matrix());
  }
  const ConstMatrixMap x(feat, grid_dim_, n);
  dW(d_mlp, density_layers_[0]).leftCols(grid_dim_).noalias() += ga * x.transpose();
  if (options_.geo_dim() > 0) SumSegments(ga, seg, nrays, d_geo_bias);
  MatrixMap(d_feat, grid_dim_, n).noalias() = W(mlp, density_layers_[0]).leftCols(grid_dim_).transpose() * ga;
}

void Network::BackwardBiases(const float* mlp, const float* emb, int nrays, const int* ray_steps,
                             const float* ray_sh, const float* d_geo_bias, const float* d_colour_bias,
                             float* d_mlp, float* d_emb) const {
  const int A = options_.app_dim(), G = options_.geo_dim();
  const Layer& d0 = density_layers_[0];
  const Layer& c0 = colour_layers_[0];
  const int row = embedding_row_size();
  const ConstMatrixMap dgeo(d_geo_bias, d0.rows, nrays);
  const ConstMatrixMap dcol(d_colour_bias, c0.rows, nrays);
  // SH weights: dW_sh += dcol * SH^T.
  dW(d_mlp, c0).leftCols(kShDim).noalias() += dcol * ConstMatrixMap(ray_sh, kShDim, nrays).transpose();
  if (!options_.use_embeddings || nrays == 0) return;
  // Sum the per-ray bias gradients per time step first: one outer product per
  // step instead of one per ray.
  int num_steps = 0;
  for (int r = 0; r < nrays; ++r) num_steps = std::max(num_steps, ray_steps[r] + 1);
  Eigen::MatrixXf sg = Eigen::MatrixXf::Zero(d0.rows, num_steps);
  Eigen::MatrixXf sc = Eigen::MatrixXf::Zero(c0.rows, num_steps);
  std::vector<char> used(num_steps, 0);
  for (int r = 0; r < nrays; ++r) {
    sg.col(ray_steps[r]) += dgeo.col(r);
    sc.col(ray_steps[r]) += dcol.col(r);
    used[ray_steps[r]] = 1;
  }
  for (int t = 0; t < num_steps; ++t) {
    if (!used[t]) continue;
    const Eigen::Map<const Eigen::VectorXf> ea(emb + size_t(t) * row, A);
    const Eigen::Map<const Eigen::VectorXf> eg(emb + size_t(t) * row + A, G);
    dW(d_mlp, c0).rightCols(A).noalias() += sc.col(t) * ea.transpose();
    dW(d_mlp, d0).rightCols(G).noalias() += sg.col(t) * eg.transpose();
    Eigen::Map<Eigen::VectorXf>(d_emb + size_t(t) * row, A).noalias() +=
        W(mlp, c0).rightCols(A).transpose() * sc.col(t);
    Eigen::Map<Eigen::VectorXf>(d_emb + size_t(t) * row + A, G).noalias() +=
        W(mlp, d0).rightCols(G).transpose() * sg.col(t);
  }
}

}  // namespace clnerf
