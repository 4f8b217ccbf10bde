#include "core/field/field.h"

#include <omp.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>

#include "core/data/contraction.h"
#include "core/field/sh_encoding.h"

namespace clnerf {

namespace {
// Bf16Mlp's per-sample biases: the column of each sample's segment.
const float* const* SegmentColumns(const float* cols, int rows, const int* seg, int nseg, int n) {
  thread_local std::vector<const float*> bias;
  SegmentBiasPointers(cols, rows, seg, nseg, n, &bias);
  return bias.data();
}

// Backward needs the hidden activations, which the bfloat16 MLPs do not
// keep: a caller that asks for them from such an evaluator is a bug.
void RequireFloatMlp(bool bf16, const char* what) {
  if (!bf16) return;
  std::fprintf(stderr, "FieldEvaluator::%s needs an evaluator built without bf16_mlp\n", what);
  std::abort();
}
}  // namespace

FieldEvaluator::FieldEvaluator(const NgpModel& model, bool bf16_mlp)
    : model_(model), contracted_(model.kind() == SceneKind::kUnbounded), bound_(model.bound()) {
  model.network().StepBiases(model.params().mlp.data(), model.params().emb.data(), model.num_time_steps(),
                             &geo_bias_, &app_bias_);
  if (bf16_mlp && Bf16TilesAvailable()) {
    bf16_ = std::make_shared<const Bf16Mlp>(model.network(), model.params().mlp.data());
  }
}

Eigen::Vector3f FieldEvaluator::GridInputFromFieldSpace(const Eigen::Vector3f& q) const {
  const Eigen::Vector3f g = (q.array() + bound_) / (2.0f * bound_);
  return g.cwiseMax(0.0f).cwiseMin(1.0f);
}

Eigen::Vector3f FieldEvaluator::GridInput(const Eigen::Vector3f& p) const {
  return GridInputFromFieldSpace(contracted_ ? Contract(p) : p);
}

void FieldEvaluator::SetRays(int nrays, const float* dirs, const int* steps, int constant_step,
                             FieldContext* ctx) const {
  const Network& net = model_.network();
  const float* mlp = model_.params().mlp.data();
  const int Hc = net.options().colour_hidden;
  const int T = model_.num_time_steps();
  ctx->num_rays = nrays;
  ctx->ray_step.resize(nrays);
  ctx->ray_sh.resize(size_t(kShDim) * nrays);
  ctx->ray_colour_bias.resize(size_t(Hc) * nrays);
  for (int i = 0; i < nrays; ++i) {
    const int t = std::clamp(steps ? steps[i] : constant_step, 0, T - 1);
    ctx->ray_step[i] = t;
    const float* d = dirs + 3 * size_t(i);
    ShEncode(d[0], d[1], d[2], &ctx->ray_sh[size_t(kShDim) * i]);
    net.RayColourBias(mlp, &ctx->ray_sh[size_t(kShDim) * i], app_bias_.col(t).data(),
                      &ctx->ray_colour_bias[size_t(Hc) * i]);
  }
}

void FieldEvaluator::ResizeSamples(int m, FieldContext* ctx) const {
  ctx->num_samples = m;
  ctx->pos.resize(3 * size_t(m));
  ctx->feat.resize(size_t(m) * model_.grid().output_dim());
  ctx->sigma.resize(m);
  ctx->ws.Reserve(std::max(m, 1), model_.network().options(), model_.grid().output_dim());
}

void FieldEvaluator::Density(int m, const int* seg, const int* seg_ray, int nseg, FieldContext* ctx) const {
  if (m == 0) return;
  const Network& net = model_.network();
  const int Hd = net.options().density_hidden;
  model_.grid().Encode(model_.params().grid.data(), ctx->pos.data(), m, ctx->feat.data());
  ScaleLevels(m, ctx->feat.data());
  ctx->seg_geo.resize(size_t(Hd) * nseg);
  for (int k = 0; k < nseg; ++k) {
    const int t = ctx->ray_step[seg_ray ? seg_ray[k] : k];
    std::copy(geo_bias_.col(t).data(), geo_bias_.col(t).data() + Hd, ctx->seg_geo.data() + size_t(Hd) * k);
  }
  if (bf16_ != nullptr) {
    const float* const* bias =
        net.options().geo_dim() > 0 ? SegmentColumns(ctx->seg_geo.data(), Hd, seg, nseg, m) : nullptr;
    bf16_->Density(ctx->feat.data(), m, bias, ctx->ws.h.data());
  } else {
    net.DensityForward(model_.params().mlp.data(), ctx->feat.data(), m, seg, nseg, ctx->seg_geo.data(), &ctx->ws);
  }
  for (int j = 0; j < m; ++j) ctx->sigma[j] = TruncExp(ctx->ws.h(0, j));
}

void FieldEvaluator::Select(const int* keep, int mk, bool for_backward, FieldContext* ctx) const {
  if (for_backward) RequireFloatMlp(bf16_ != nullptr, "Select(for_backward)");
  const int Dg = model_.grid().output_dim();
  NetworkWorkspace& ws = ctx->ws;
  for (int w = 0; w < mk; ++w) {
    const int j = keep[w];
    if (j == w) continue;
    ws.h.col(w) = ws.h.col(j);
    if (!for_backward) continue;
    ctx->sigma[w] = ctx->sigma[j];
    std::copy(&ctx->pos[3 * size_t(j)], &ctx->pos[3 * size_t(j)] + 3, &ctx->pos[3 * size_t(w)]);
    std::copy(&ctx->feat[size_t(j) * Dg], &ctx->feat[size_t(j) * Dg] + Dg, &ctx->feat[size_t(w) * Dg]);
    for (auto& act : ws.density_act) act.col(w) = act.col(j);
  }
}

void FieldEvaluator::Colour(int mk, const int* seg, const int* seg_ray, int nseg, FieldContext* ctx) const {
  if (mk == 0) return;
  const int Hc = model_.network().options().colour_hidden;
  ctx->seg_col.resize(size_t(Hc) * nseg);
  for (int k = 0; k < nseg; ++k) {
    const int r = seg_ray ? seg_ray[k] : k;
    std::copy(&ctx->ray_colour_bias[size_t(Hc) * r], &ctx->ray_colour_bias[size_t(Hc) * r] + Hc,
              ctx->seg_col.data() + size_t(Hc) * k);
  }
  if (bf16_ != nullptr) {
    bf16_->Colour(ctx->ws.h.data(), mk, SegmentColumns(ctx->seg_col.data(), Hc, seg, nseg, mk), ctx->ws.rgb.data());
    return;
  }
  model_.network().ColourForward(model_.params().mlp.data(), mk, seg, nseg, ctx->seg_col.data(), &ctx->ws);
}

void FieldEvaluator::Backward(int mk, const int* seg, const int* seg_ray, int nseg, const float* d_rgb,
                              const float* d_sigma, FieldContext* ctx, float* grad_mlp, float* grad_emb) const {
  RequireFloatMlp(bf16_ != nullptr, "Backward");
  const Network& net = model_.network();
  const int Hd = net.options().density_hidden, Hc = net.options().colour_hidden;
  const int Dg = model_.grid().output_dim();
  const float* mlp = model_.params().mlp.data();
  // sigma = exp(h0): dL/dh0 = dL/dsigma * TruncExpGrad(h0).
  ctx->d_h0.resize(mk);
  for (int j = 0; j < mk; ++j) ctx->d_h0[j] = d_sigma[j] * TruncExpGrad(ctx->ws.h(0, j));
  ctx->d_feat.resize(size_t(mk) * Dg);
  ctx->d_geo.assign(size_t(Hd) * nseg, 0.0f);
  ctx->d_col.assign(size_t(Hc) * nseg, 0.0f);
  if (mk > 0) {
    net.Backward(mlp, ctx->feat.data(), mk, seg, nseg, d_rgb, ctx->d_h0.data(), &ctx->ws, grad_mlp,
                 ctx->d_feat.data(), ctx->d_geo.data(), ctx->d_col.data());
    ScaleLevels(mk, ctx->d_feat.data());  // d(w f)/df = w.
  }
  // Per-segment time steps and SH for folding the bias gradients back.
  ctx->seg_step.resize(nseg);
  ctx->seg_sh.resize(size_t(kShDim) * nseg);
  for (int k = 0; k < nseg; ++k) {
    const int r = seg_ray ? seg_ray[k] : k;
    ctx->seg_step[k] = ctx->ray_step[r];
    std::copy(&ctx->ray_sh[size_t(kShDim) * r], &ctx->ray_sh[size_t(kShDim) * r] + kShDim,
              &ctx->seg_sh[size_t(kShDim) * k]);
  }
  net.BackwardBiases(mlp, model_.params().emb.data(), nseg, ctx->seg_step.data(), ctx->seg_sh.data(),
                     ctx->d_geo.data(), ctx->d_col.data(), grad_mlp, grad_emb);
}

void FieldEvaluator::ScaleLevels(int m, float* feat) const {
  if (level_weights_ == nullptr) return;
  const int L = model_.grid().num_levels(), F = HashGrid::kFeatures, Dg = model_.grid().output_dim();
  for (int l = 0; l < L; ++l) {
    const float w = level_weights_[l];
    if (w == 1.0f) continue;
    for (int j = 0; j < m; ++j) {
      float* f = feat + size_t(j) * Dg + size_t(l) * F;
      for (int k = 0; k < F; ++k) f[k] *= w;
    }
  }
}

void FieldEvaluator::DensityAt(const float* points, int n, int time_step, float* sigma) const {
  const int t = std::clamp(time_step, 0, model_.num_time_steps() - 1);
  const Network& net = model_.network();
  const HashGrid& grid = model_.grid();
  constexpr int kChunk = 2048;
  const int nchunks = (n + kChunk - 1) / kChunk;
#pragma omp parallel
  {
    const int cap = std::min(kChunk, n);  // Sized to the call: the baker asks for 729 points at a time.
    NetworkWorkspace ws;
    ws.Reserve(cap, net.options(), grid.output_dim());
    std::vector<float> pos(3 * size_t(cap)), feat(size_t(cap) * grid.output_dim()), h0(cap);
#pragma omp for schedule(dynamic)
    for (int ci = 0; ci < nchunks; ++ci) {
      const int begin = ci * kChunk, m = std::min(kChunk, n - begin);
      for (int i = 0; i < m; ++i) {
        const Eigen::Vector3f g =
            GridInputFromFieldSpace(Eigen::Map<const Eigen::Vector3f>(points + 3 * size_t(begin + i)));
        pos[3 * i] = g.x();
        pos[3 * i + 1] = g.y();
        pos[3 * i + 2] = g.z();
      }
      grid.Encode(model_.params().grid.data(), pos.data(), m, feat.data());
      const int seg[2] = {0, m};
      net.DensityOnly(model_.params().mlp.data(), feat.data(), m, seg, 1, geo_bias_.col(t).data(), &ws, h0.data());
      for (int i = 0; i < m; ++i) sigma[begin + i] = TruncExp(h0[i]);
    }
  }
}

}  // namespace clnerf
