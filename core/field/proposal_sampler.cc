#include "core/field/proposal_sampler.h"

#include <algorithm>
#include <cmath>

#include "core/field/ngp_model.h"

namespace clnerf {

namespace {
// splitmix64: a tiny counter-based stream, one per ray.
struct RayRng {
  uint64_t state;
  float Uniform() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return float(z >> 40) * (1.0f / 16777216.0f);  // [0, 1).
  }
};

constexpr float kInterlevelEps = 1e-7f;
}  // namespace

ProposalSampler::ProposalSampler(const FieldEvaluator& field) : field_(field), model_(field.model()) {}

void ProposalSampler::Weights(const float* sigma, const float* t, int n, float* w) {
  float T = 1.0f;
  for (int i = 0; i < n; ++i) {
    const float a = 1.0f - std::exp(-sigma[i] * (t[i + 1] - t[i]));
    w[i] = T * a;
    T *= 1.0f - a;
  }
}

void ProposalSampler::WeightsBackward(const float* sigma, const float* t, const float* w, const float* d_w, int n,
                                      float* d_sigma) {
  // w_i = T_i a_i, T_i = exp(-sum_{j<i} sigma_j dt_j):
  // dL/dsigma_k = dt_k (g_k T_{k+1} - sum_{j>k} g_j w_j).
  float T = 1.0f;
  float suffix = 0.0f;
  for (int i = 0; i < n; ++i) suffix += d_w[i] * w[i];
  for (int k = 0; k < n; ++k) {
    const float dt = t[k + 1] - t[k];
    const float T_next = T * std::exp(-sigma[k] * dt);
    suffix -= d_w[k] * w[k];
    d_sigma[k] = dt * (d_w[k] * T_next - suffix);
    T = T_next;
  }
}

void ProposalSampler::Resample(const float* s, const float* w, int n, float anneal, float padding, const float* u,
                               int m, float* out) {
  // cdf over the padded, annealed weights; out = inverse CDF at u (m + 1 values).
  double total = 0;
  thread_local std::vector<float> cdf;
  cdf.resize(n + 1);
  cdf[0] = 0.0f;
  for (int i = 0; i < n; ++i) {
    const float wi = std::max(w[i], 0.0f);
    total += (anneal == 1.0f ? wi : std::pow(wi, anneal)) + padding;
    cdf[i + 1] = float(total);
  }
  if (!(total > 1e-5)) {  // Nothing to go by: uniform.
    for (int i = 0; i <= n; ++i) cdf[i] = float(i) / float(n);
    total = 1.0;
  } else {
    const float inv = float(1.0 / total);
    for (int i = 1; i <= n; ++i) cdf[i] = std::min(1.0f, cdf[i] * inv);
  }
  int k = 0;
  for (int j = 0; j <= m; ++j) {
    const float uj = u[j];
    while (k < n - 1 && cdf[k + 1] <= uj) ++k;  // cdf[k] <= u < cdf[k + 1].
    const float c0 = cdf[k], c1 = cdf[k + 1];
    const float f = c1 > c0 ? std::clamp((uj - c0) / (c1 - c0), 0.0f, 1.0f) : 0.0f;
    out[j] = s[k] + f * (s[k + 1] - s[k]);
  }
  // Rounding must not break the order.
  for (int j = 1; j <= m; ++j) out[j] = std::max(out[j], out[j - 1]);
}

float ProposalSampler::Interlevel(const float* c, const float* w, int m, const float* cp, const float* wp, int n,
                                  float scale, float* d_wp, std::vector<float>* cum, std::vector<float>* diff) {
  cum->resize(n + 1);
  diff->assign(n + 1, 0.0f);
  (*cum)[0] = 0.0f;
  for (int i = 0; i < n; ++i) (*cum)[i + 1] = (*cum)[i] + wp[i];
  float loss = 0.0f;
  int lo = 0, hi = 0;
  for (int j = 0; j < m; ++j) {
    // lo: last proposal interval starting at or before c_j; hi: first one
    // ending after c_{j+1} (nerfstudio's searchsorted(side="right")), both
    // kept in [0, n - 1] by the loops.
    while (lo + 1 < n && cp[lo + 1] <= c[j]) ++lo;
    while (hi < n - 1 && cp[hi + 1] <= c[j + 1]) ++hi;
    const int a = lo, b = std::max(hi, lo);
    const float outer = (*cum)[b + 1] - (*cum)[a];
    const float excess = w[j] - outer;
    if (excess <= 0.0f) continue;
    loss += excess * excess / (w[j] + kInterlevelEps);
    const float g = -2.0f * excess / (w[j] + kInterlevelEps) * scale;
    (*diff)[a] += g;
    (*diff)[b + 1] -= g;
  }
  float run = 0.0f;
  for (int i = 0; i < n; ++i) {
    run += (*diff)[i];
    d_wp[i] += run;
  }
  return loss;
}

void ProposalSampler::Place(const float* origins, const float* dirs, int n, uint64_t seed, const uint32_t* ray_ids,
                            float anneal, ProposalContext* ctx, std::vector<RaySample>* samples,
                            std::vector<int>* seg, std::vector<int>* seg_ray, int nerf_samples) const {
  const ProposalOptions& po = model_.options().proposal;
  const int stages = po.num_stages();
  const int nf = nerf_samples > 0 ? std::min(nerf_samples, kMaxProposalSamples) : po.nerf_samples;
  ctx->ray_of.clear();
  thread_local std::vector<float> t0s, t1s;
  t0s.clear();
  t1s.clear();
  for (int i = 0; i < n; ++i) {
    float t0 = 0, t1 = 0;
    const Eigen::Map<const Eigen::Vector3f> o(origins + 3 * size_t(i)), d(dirs + 3 * size_t(i));
    if (!model_.RayInterval(o, d, &t0, &t1)) continue;
    ctx->ray_of.push_back(i);
    t0s.push_back(t0);
    t1s.push_back(t1);
  }
  const int nr = int(ctx->ray_of.size());
  ctx->num_rays = nr;
  ctx->n_final = nf;
  auto rng_of = [&](int r) {
    const uint64_t id = ray_ids ? ray_ids[ctx->ray_of[r]] : uint64_t(ctx->ray_of[r]);
    return RayRng{seed * 0xD1B54A32D192ED03ull ^ (id + 1) * 0x9E3779B97F4A7C15ull};
  };
  std::vector<RayRng> rngs;
  if (seed != 0) {
    rngs.reserve(nr);
    for (int r = 0; r < nr; ++r) rngs.push_back(rng_of(r));
  }
  thread_local std::vector<float> u;
  const float* prev_s = nullptr;
  const float* prev_w = nullptr;
  int prev_n = 0;
  for (int k = 0; k < stages; ++k) {
    ProposalStage& st = ctx->stage[k];
    const int m = po.stage_samples(k);
    st.n = m;
    st.s.resize(size_t(nr) * (m + 1));
    st.t.resize(size_t(nr) * (m + 1));
    st.pos.resize(3 * size_t(nr) * m);
    st.sigma.resize(size_t(nr) * m);
    st.w.resize(size_t(nr) * m);
    u.resize(m + 1);
    for (int r = 0; r < nr; ++r) {
      float* s = &st.s[size_t(r) * (m + 1)];
      const float s0 = ProposalSpacing(t0s[r]), s1 = ProposalSpacing(t1s[r]);
      if (k == 0) {
        // Uniform bins in s; while training each edge moves within the half
        // bins around it.
        for (int j = 0; j <= m; ++j) {
          float f = float(j) / float(m);
          if (seed != 0) {
            const float lo = j == 0 ? 0.0f : (float(j) - 0.5f) / float(m);
            const float hi = j == m ? 1.0f : (float(j) + 0.5f) / float(m);
            f = lo + (hi - lo) * rngs[r].Uniform();
          }
          s[j] = s0 + f * (s1 - s0);
        }
        s[0] = s0;
        s[m] = s1;
      } else {
        for (int j = 0; j <= m; ++j) {
          u[j] = seed != 0 ? (float(j) + rngs[r].Uniform()) / float(m + 1) : (float(j) + 0.5f) / float(m + 1);
        }
        Resample(prev_s + size_t(r) * (prev_n + 1), prev_w + size_t(r) * prev_n, prev_n, anneal,
                 po.histogram_padding, u.data(), m, s);
      }
      float* t = &st.t[size_t(r) * (m + 1)];
      for (int j = 0; j <= m; ++j) t[j] = std::clamp(ProposalSpacingInverse(s[j]), t0s[r], t1s[r]);
      const int i = ctx->ray_of[r];
      const Eigen::Map<const Eigen::Vector3f> o(origins + 3 * size_t(i)), d(dirs + 3 * size_t(i));
      for (int j = 0; j < m; ++j) {
        const Eigen::Vector3f g = field_.GridInput(o + (0.5f * (t[j] + t[j + 1])) * d);
        float* p = &st.pos[3 * (size_t(r) * m + j)];
        p[0] = g.x();
        p[1] = g.y();
        p[2] = g.z();
      }
    }
    const ProposalField& pf = model_.proposal_field(k);
    pf.Forward(model_.params().proposal.data() + model_.proposal_offset(k), st.pos.data(), nr * m, &st.ws,
               st.sigma.data());
    for (int r = 0; r < nr; ++r) {
      Weights(&st.sigma[size_t(r) * m], &st.t[size_t(r) * (m + 1)], m, &st.w[size_t(r) * m]);
    }
    prev_s = st.s.data();
    prev_w = st.w.data();
    prev_n = m;
  }
  // Final samples.
  ctx->final_s.resize(size_t(nr) * (nf + 1));
  u.resize(nf + 1);
  const size_t base = samples->size();
  if (seg->empty()) seg->push_back(int(base));
  samples->reserve(base + size_t(nr) * nf);
  for (int r = 0; r < nr; ++r) {
    for (int j = 0; j <= nf; ++j) {
      u[j] = seed != 0 ? (float(j) + rngs[r].Uniform()) / float(nf + 1) : (float(j) + 0.5f) / float(nf + 1);
    }
    float* s = &ctx->final_s[size_t(r) * (nf + 1)];
    Resample(prev_s + size_t(r) * (prev_n + 1), prev_w + size_t(r) * prev_n, prev_n, anneal, po.histogram_padding,
             u.data(), nf, s);
    float t_prev = std::clamp(ProposalSpacingInverse(s[0]), t0s[r], t1s[r]);
    for (int j = 0; j < nf; ++j) {
      const float t_next = std::clamp(ProposalSpacingInverse(s[j + 1]), t0s[r], t1s[r]);
      samples->push_back({0.5f * (t_prev + t_next), t_next - t_prev});
      t_prev = t_next;
    }
    seg->push_back(int(samples->size()));
    seg_ray->push_back(ctx->ray_of[r]);
  }
}

float ProposalSampler::InterlevelBackward(const float* nerf_w, float scale, ProposalContext* ctx, float* grad,
                                          ProposalGridStore* store) const {
  const ProposalOptions& po = model_.options().proposal;
  const int nr = ctx->num_rays, nf = ctx->n_final;
  float loss = 0.0f;
  for (int k = 0; k < po.num_stages(); ++k) {
    ProposalStage& st = ctx->stage[k];
    const int m = st.n;
    ctx->d_w.assign(size_t(nr) * m, 0.0f);
    ctx->d_sigma.resize(size_t(nr) * m);
    for (int r = 0; r < nr; ++r) {
      const float* sp = &st.s[size_t(r) * (m + 1)];
      loss += scale * Interlevel(&ctx->final_s[size_t(r) * (nf + 1)], nerf_w + size_t(r) * nf, nf, sp,
                                 &st.w[size_t(r) * m], m, scale, &ctx->d_w[size_t(r) * m], &ctx->cum, &ctx->diff);
      WeightsBackward(&st.sigma[size_t(r) * m], &st.t[size_t(r) * (m + 1)], &st.w[size_t(r) * m],
                      &ctx->d_w[size_t(r) * m], m, &ctx->d_sigma[size_t(r) * m]);
    }
    const ProposalField& pf = model_.proposal_field(k);
    const size_t off = model_.proposal_offset(k);
    pf.Backward(model_.params().proposal.data() + off, nr * m, ctx->d_sigma.data(), &st.ws, grad + off);
    const int D = pf.grid().output_dim();
    store->pos[k].insert(store->pos[k].end(), st.pos.begin(), st.pos.begin() + 3 * size_t(nr) * m);
    store->d_feat[k].insert(store->d_feat[k].end(), st.ws.d_feat.data(), st.ws.d_feat.data() + size_t(D) * nr * m);
  }
  return loss;
}

}  // namespace clnerf
