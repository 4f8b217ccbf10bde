#include "core/train/trainer.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "absl/strings/str_format.h"
#include "core/data/contraction.h"
#include "core/field/field.h"
#include "core/field/proposal_sampler.h"
#include "core/field/sh_encoding.h"
#include "core/render/volume_rendering.h"
#include "core/train/view_colour.h"
#include "spdlog/spdlog.h"

namespace clnerf {

absl::StatusOr<LrSchedule> ParseLrSchedule(const std::string& name) {
  if (name == "cosine") return LrSchedule::kCosine;
  if (name == "inverse-sqrt") return LrSchedule::kInverseSqrt;
  if (name == "inverse-sqrt-cosine") return LrSchedule::kInverseSqrtCosine;
  return absl::InvalidArgumentError(
      absl::StrCat("unknown learning-rate schedule '", name, "' (cosine|inverse-sqrt|inverse-sqrt-cosine)"));
}

const char* LrScheduleName(LrSchedule s) {
  switch (s) {
    case LrSchedule::kInverseSqrt:
      return "inverse-sqrt";
    case LrSchedule::kInverseSqrtCosine:
      return "inverse-sqrt-cosine";
    default:
      return "cosine";
  }
}

absl::Status TrainOptions::Validate() const {
  if (iterations < 0) return absl::InvalidArgumentError("train: iterations must be >= 0");
  if (batch_rays < 1 || max_batch_rays < batch_rays) {
    return absl::InvalidArgumentError("train: need 1 <= batch_rays <= max_batch_rays");
  }
  if (target_samples < 0) return absl::InvalidArgumentError("train: target_samples must be >= 0");
  if (!(learning_rate > 0) || !(lr_final_ratio > 0 && lr_final_ratio <= 1)) {
    return absl::InvalidArgumentError("train: learning_rate must be > 0 and lr_final_ratio in (0, 1]");
  }
  if (!(opacity_reg >= 0)) return absl::InvalidArgumentError("train: opacity_reg must be >= 0");
  if (!std::isfinite(distortion_reg) || !std::isfinite(near_density_reg)) {
    return absl::InvalidArgumentError("train: distortion_reg and near_density_reg must be finite");
  }
  if (!(distortion_warmup >= 0) || !std::isfinite(distortion_warmup)) {
    return absl::InvalidArgumentError("train: distortion_warmup must be finite and >= 0");
  }
  if (!(near_density_fade >= 0) || !std::isfinite(near_density_fade)) {
    return absl::InvalidArgumentError("train: near_density_fade must be finite and >= 0");
  }
  if (!(near_density_distance >= 0) || !std::isfinite(near_density_distance)) {
    return absl::InvalidArgumentError("train: near_density_distance must be finite and >= 0");
  }
  if (!(depth_weight >= 0) || !std::isfinite(depth_weight) || !(depth_sigma > 0) || !std::isfinite(depth_sigma)) {
    return absl::InvalidArgumentError("train: depth_weight must be finite and >= 0, depth_sigma finite and > 0");
  }
  if (!(grid_decay >= 0) || !std::isfinite(grid_decay)) {
    return absl::InvalidArgumentError("train: grid_decay must be finite and >= 0");
  }
  if (!(coarse_to_fine >= 0 && coarse_to_fine <= 1)) {
    return absl::InvalidArgumentError("train: coarse_to_fine must be in [0, 1]");
  }
  if (!(view_colour_prior >= 0) || !std::isfinite(view_colour_prior) || !(view_colour_lr_scale > 0) ||
      !std::isfinite(view_colour_lr_scale)) {
    return absl::InvalidArgumentError("train: view_colour_prior must be finite and >= 0, view_colour_lr_scale finite and > 0");
  }
  if (threads < 0) return absl::InvalidArgumentError("train: threads must be >= 0");
  if (lr_timescale < 0) return absl::InvalidArgumentError("train: lr_timescale must be >= 0");
  if (!(interlevel_weight >= 0) || !std::isfinite(interlevel_weight)) {
    return absl::InvalidArgumentError("train: interlevel_weight must be finite and >= 0");
  }
  if (max_bad_batches < 0 || inject_nan_gradient_at_step < 0) {
    return absl::InvalidArgumentError("train: max_bad_batches and inject_nan_gradient_at_step must be >= 0");
  }
  return adam.Validate();
}

// One marching wave of a block: the samples its live rays marched, their
// field context, and which of them were kept (up to early termination).
struct TrainWave {
  FieldContext fc;
  std::vector<RaySample> samples;
  std::vector<int> seg, seg_ray;      // Marched segments (one per live ray).
  std::vector<int> keep, kseg, kray;  // Kept samples (ascending) and their segments.
  std::vector<int> ray_kseg;          // Per ray of the block: its kept segment, or -1.
  std::vector<float> kt, kdt;         // t and dt of kept samples.
  std::vector<float> d_rgb, d_sigma;  // Per kept sample.
};

struct Trainer::ThreadScratch {
  static constexpr int kMaxWaves = 3;
  TrainWave waves[kMaxWaves];
  // Per ray of the block.
  std::vector<float> ray_t, ray_t1, ray_T;
  std::vector<uint8_t> ray_alive;
  // Kept samples gathered per ray across waves (gseg: ray offsets).
  std::vector<int> gseg, gwave, gcol;
  std::vector<float> gsigma, gt, gdt, gw, grgb, gmid, gwidth, gdrgb, gdsigma, t_final, gdepth_mid;
  std::vector<float> grad_mlp, grad_emb, grad_view_colour;
  std::vector<float> store_pos, store_dfeat;  // For the grid backward phase.
  // Proposal models: placement state, MLP gradients (full proposal layout,
  // only the MLP ranges used), grid-backward store, per-ray used counts.
  ProposalContext prop;
  ProposalGridStore prop_store;
  std::vector<float> grad_prop, nerf_w;
  std::vector<uint32_t> ray_ids;
  std::vector<int> used;
  double sq_err = 0, loss = 0;
  long long samples_marched = 0, samples_used = 0;
};

namespace {
constexpr int kBlockRays = 128;

// Adds one wave's gradients with respect to its rays' origins and unit
// directions (model space) to g_o / g_d (3 per ray of the block), for the
// rays with wants[i] != 0, after FieldEvaluator::Backward left dL/dfeature
// in W.fc.d_feat and the per-segment colour-bias gradient in W.fc.d_col.
// A sample at x = o + t d (t held fixed, as the marcher or the proposals
// placed it) reaches the grid through the contraction and the grid's
// [0, 1]^3 mapping; the colour's SH view encoding adds the direction's
// second path. Explicit geometric terms of regularisers (the distortion
// loss's interval positions) are not included.
void WaveRayGradients(const NgpModel& model, const TrainWave& W, const float* origin, const float* dir,
                      const uint8_t* wants, float* g_o, float* g_d) {
  const HashGrid& grid = model.grid();
  const int Dg = grid.output_dim();
  const float* params = model.params().grid.data();
  const Network& net = model.network();
  const Network::Layer& c0 = net.colour_layers()[0];
  const Eigen::Map<const Eigen::MatrixXf> w_col(model.params().mlp.data() + c0.offset, c0.rows, c0.cols);
  const float b = model.bound(), inv2b = 0.5f / b;
  for (size_t k = 0; k < W.kray.size(); ++k) {
    const int i = W.kray[k];
    if (!wants[i]) continue;
    const Eigen::Map<const Eigen::Vector3f> o(origin + 3 * size_t(i)), d(dir + 3 * size_t(i));
    Eigen::Vector3f go = Eigen::Vector3f::Zero(), gd = Eigen::Vector3f::Zero();
    for (int c = W.kseg[k]; c < W.kseg[k + 1]; ++c) {
      float dpos[3];
      grid.BackwardPosition(params, &W.fc.pos[3 * size_t(c)], &W.fc.d_feat[size_t(c) * Dg], 1, dpos);
      const Eigen::Vector3f x = o + W.kt[c] * d;
      const Eigen::Vector3f q = model.contracted() ? Contract(x) : x;
      Eigen::Vector3f gq;
      for (int a = 0; a < 3; ++a) gq[a] = std::abs(q[a]) < b ? dpos[a] * inv2b : 0.0f;  // Clamped outside.
      const Eigen::Vector3f gx = model.contracted() ? Eigen::Vector3f(ContractJacobian(x).transpose() * gq) : gq;
      go += gx;
      gd += W.kt[c] * gx;
    }
    // View dependence: colour bias = W_sh SH(d) + ...; dL/dSH = W_sh^T dL/dbias.
    const Eigen::Map<const Eigen::VectorXf> dbias(&W.fc.d_col[size_t(c0.rows) * k], c0.rows);
    const Eigen::Matrix<float, kShDim, 1> dsh = w_col.leftCols(kShDim).transpose() * dbias;
    float jac[kShDim * 3];
    ShJacobian(d.x(), d.y(), d.z(), jac);
    for (int s = 0; s < kShDim; ++s) {
      for (int a = 0; a < 3; ++a) gd[a] += dsh[s] * jac[3 * s + a];
    }
    for (int a = 0; a < 3; ++a) {
      g_o[3 * size_t(i) + a] += go[a];
      g_d[3 * size_t(i) + a] += gd[a];
    }
  }
}

// A regulariser weight where < 0 means "auto": `auto_weight` for unbounded
// (contracted) scenes, 0 for bounded ones.
float ResolveAutoWeight(float weight, float auto_weight, bool contracted) {
  return weight >= 0 ? weight : contracted ? auto_weight : 0.0f;
}

template <typename V>
bool AllFinite(const V& v) {
  for (float x : v) {
    if (!std::isfinite(x)) return false;
  }
  return true;
}
}  // namespace

float TrainOptions::DistortionWeightAt(int step, bool contracted) const {
  float w = ResolveAutoWeight(distortion_reg, kAutoDistortion, contracted);
  if (distortion_warmup > 0 && iterations > 0) w *= std::min(1.0f, float(step) / (distortion_warmup * float(iterations)));
  return w;
}

float TrainOptions::NearDensityWeightAt(int step, bool contracted) const {
  float w = ResolveAutoWeight(near_density_reg, kAutoNearDensity, contracted);
  if (near_density_fade > 0 && iterations > 0) {
    w *= std::max(0.0f, 1.0f - float(step) / (near_density_fade * float(iterations)));
  }
  return w;
}

Trainer::Trainer(NgpModel* model, RaySampler* sampler, const TrainOptions& options)
    : model_(model), sampler_(sampler), options_(options), adam_(options.adam), rng_(options.seed) {
  threads_ = options.threads > 0 ? options.threads : omp_get_max_threads();
  batch_rays_ = options.batch_rays;
  grad_grid_.assign(model->params().grid.size(), 0.0f);
  touched_.assign(model->grid().num_params() / HashGrid::kFeatures, 0);
  touched_lists_.resize(model->grid().num_levels());
  adam_.ResizeBlock(0, model->params().grid.size());
  adam_.ResizeBlock(1, model->params().mlp.size());
  adam_.ResizeBlock(2, model->params().emb.size());
  adam_.ResizeBlock(3, model->params().proposal.size());
  grad_prop_.assign(model->params().proposal.size(), 0.0f);
  if (options.view_colour && sampler->NumPhotoViews() > 0) {
    view_colour_ = IdentityViewColours(sampler->NumPhotoViews());
    grad_view_colour_.assign(view_colour_.size(), 0.0f);
    adam_.ResizeBlock(4, view_colour_.size());
  }
  if (options.resume != nullptr) {
    if (absl::Status s = options.resume->CompatibleWith(model->params()); s.ok()) {
      for (int b = 0; b < OptimizerState::kBlocks; ++b) adam_.SetMoments(b, options.resume->m[b], options.resume->v[b]);
      adam_base_ = options.resume->step;
    } else {
      spdlog::warn("trainer: not resuming the optimiser: {}", std::string(s.message()));
    }
  }
  for (int i = 0; i < threads_; ++i) scratch_.push_back(std::make_unique<ThreadScratch>());
  model->mutable_occupancy().MarkInvisible(sampler->Cameras(), model->options().march.near);
}

Trainer::~Trainer() = default;

float Trainer::CurrentLearningRate() const {
  const double tau = options_.lr_timescale > 0 ? options_.lr_timescale : std::max(1, options_.iterations);
  const auto inv_sqrt = [&](double s) { return float(double(options_.learning_rate) * std::sqrt(tau / (tau + s))); };
  if (options_.lr_schedule == LrSchedule::kInverseSqrt) return inv_sqrt(double(adam_base_) + step_);
  const float lr = options_.lr_schedule == LrSchedule::kInverseSqrtCosine ? inv_sqrt(double(adam_base_))
                                                                           : options_.learning_rate;
  const float lo = lr * options_.lr_final_ratio;
  const float p = options_.iterations > 0 ? std::min(1.0f, float(step_) / options_.iterations) : 1.0f;
  return lo + 0.5f * (lr - lo) * (1.0f + std::cos(float(M_PI) * p));
}

OptimizerState Trainer::ExportOptimizerState() const {
  OptimizerState s;
  s.step = adam_base_ + uint64_t(step_);
  for (int b = 0; b < OptimizerState::kBlocks; ++b) {
    s.m[b] = adam_.m(b);
    s.v[b] = adam_.v(b);
  }
  return s;
}

float Trainer::ProposalAnneal() const {
  int n = options_.proposal_anneal_iterations;
  if (n < 0) n = std::min(1000, options_.iterations / 4);
  if (n <= 0) return 1.0f;
  const float x = std::min(1.0f, float(step_) / float(n));
  constexpr float kSlope = 10.0f;  // nerfacto's proposal_weights_anneal_slope.
  return kSlope * x / ((kSlope - 1.0f) * x + 1.0f);
}

bool Trainer::LevelWeights() {
  const int L = model_->grid().num_levels();
  const float span = options_.coarse_to_fine * float(options_.iterations);
  if (!(span > 0) || float(step_) >= span) {
    level_weights_.clear();
    return false;
  }
  const float first = std::max(1.0f, std::round(0.25f * float(L)));
  const float on = first + (float(L) - first) * float(step_) / span;  // Levels on, fractional.
  level_weights_.resize(L);
  for (int l = 0; l < L; ++l) {
    const float x = std::clamp(on - float(l), 0.0f, 1.0f);
    level_weights_[l] = 0.5f * (1.0f - std::cos(float(M_PI) * x));  // BARF's smooth fade-in.
  }
  return true;
}

float Trainer::ForwardBackward(const RayBatch& batch, const float* jitter, const float* ray_bg,
                               bool track_touched) {
  const NgpModel& model = *model_;
  FieldEvaluator field(model);
  const bool annealing = LevelWeights();
  if (annealing) field.SetLevelWeights(level_weights_.data());
  const HashGrid& grid = model.grid();
  const MarchOptions& mo = model.options().march;
  const int Dg = grid.output_dim();
  const int nrays = batch.size();
  const float inv_n = 1.0f / float(std::max(nrays, 1));
  const float lambda = options_.opacity_reg;
  const Eigen::Vector3f bg = model.background();
  const float dist_reg = options_.DistortionWeightAt(step_, model.contracted());
  const float inv_box = 1.0f / (2.0f * model.bound());
  const float near_reg = options_.NearDensityWeightAt(step_, model.contracted());
  const float near_dist = options_.near_density_distance;
  const float depth_w = options_.depth_weight;

  const int nblocks = (nrays + kBlockRays - 1) / kBlockRays;
  ray_sq_err_.assign(size_t(nrays), 0.0f);
  const bool ray_grads = WantRayGradients(batch);
  // Reset every scratch, not only those of the threads that run: the OpenMP
  // runtime may grant fewer threads than requested (OMP_THREAD_LIMIT, nested
  // regions), and the reductions below read all of them.
  for (const auto& sp : scratch_) {
    ThreadScratch& s = *sp;
    s.grad_mlp.assign(model.params().mlp.size(), 0.0f);
    s.grad_emb.assign(model.params().emb.size(), 0.0f);
    s.grad_view_colour.assign(view_colour_.size(), 0.0f);
    s.store_pos.clear();
    s.store_dfeat.clear();
    if (model.uses_proposals()) {
      s.grad_prop.resize(model.params().proposal.size());
      for (int k = 0; k < model.options().proposal.num_stages(); ++k) {
        const ProposalField& pf = model.proposal_field(k);
        std::fill_n(s.grad_prop.begin() + model.proposal_offset(k) + pf.mlp_offset(), pf.mlp_size(), 0.0f);
      }
      s.prop_store.Clear();
    }
    s.sq_err = s.loss = 0;
    s.samples_marched = s.samples_used = 0;
  }
  // Rays march in waves: the first covers about what a ray composites on
  // average, and only rays still above the termination threshold march on,
  // so samples behind early termination are rarely marched or evaluated.
  const int first_wave = std::clamp(int(1.5 * mean_used_per_ray_) + 8, 16, mo.max_samples);
  const bool proposals = model.uses_proposals();
  const ProposalSampler proposer(field);
  const float anneal = ProposalAnneal();
  const uint64_t seed = batch_seed_;
  const float interlevel_scale =
      proposals ? options_.interlevel_weight * inv_n / float(model.options().proposal.nerf_samples) : 0.0f;
#pragma omp parallel num_threads(threads_)
  {
    ThreadScratch& s = *scratch_[omp_get_thread_num()];
#pragma omp for schedule(static, 1)
    for (int b = 0; b < nblocks; ++b) {
      const int r0 = b * kBlockRays, nr = std::min(kBlockRays, nrays - r0);
      auto origin = [&](int i) { return Eigen::Map<const Eigen::Vector3f>(&batch.origin[3 * size_t(r0 + i)]); };
      auto dir = [&](int i) { return Eigen::Map<const Eigen::Vector3f>(&batch.dir[3 * size_t(r0 + i)]); };
      s.ray_t.resize(nr);
      s.ray_t1.resize(nr);
      s.ray_T.assign(nr, 1.0f);
      s.ray_alive.resize(nr);
      for (int i = 0; i < nr; ++i) {
        float t0 = 0, t1 = 0;
        s.ray_alive[i] = model.RayInterval(origin(i), dir(i), &t0, &t1);
        // First sample jittered.
        s.ray_t[i] = s.ray_alive[i] ? t0 + jitter[r0 + i] * model.StepAt(origin(i), dir(i), t0) : 0.0f;
        s.ray_t1[i] = t1;
      }
      // 1. March, evaluate density and composite, wave by wave.
      int nwaves = 0;
      for (int wv = 0; wv < ThreadScratch::kMaxWaves; ++wv) {
        TrainWave& W = s.waves[wv];
        const int budget = wv + 1 == ThreadScratch::kMaxWaves ? mo.max_samples : first_wave << wv;
        W.samples.clear();
        W.seg.assign(1, 0);
        W.seg_ray.clear();
        if (proposals) {
          // One wave: the proposal fields place every ray's samples at once.
          if (wv > 0) break;
          s.ray_ids.resize(nr);
          for (int i = 0; i < nr; ++i) s.ray_ids[i] = uint32_t(r0 + i);
          proposer.Place(&batch.origin[3 * size_t(r0)], &batch.dir[3 * size_t(r0)], nr, seed, s.ray_ids.data(), anneal,
                         &s.prop, &W.samples, &W.seg, &W.seg_ray);
        }
        for (int i = 0; i < nr && !proposals; ++i) {
          if (!s.ray_alive[i]) continue;
          const size_t before = W.samples.size();
          s.ray_t[i] = model.March(origin(i), dir(i), s.ray_t[i], s.ray_t1[i], budget, &W.samples);
          if (W.samples.size() == before) {
            s.ray_alive[i] = 0;
            continue;
          }
          W.seg.push_back(int(W.samples.size()));
          W.seg_ray.push_back(i);
        }
        const int m = int(W.samples.size());
        W.ray_kseg.assign(nr, -1);
        if (m == 0) break;
        nwaves = wv + 1;
        s.samples_marched += m;
        const int nseg = int(W.seg_ray.size());
        if (wv == 0) {
          field.SetRays(nr, &batch.dir[3 * size_t(r0)], &batch.time_step[r0], 0, &W.fc);
        } else {  // The per-ray inputs are the same for every wave: copy, don't recompute.
          const FieldContext& first = s.waves[0].fc;
          W.fc.num_rays = first.num_rays;
          W.fc.ray_step = first.ray_step;
          W.fc.ray_sh = first.ray_sh;
          W.fc.ray_colour_bias = first.ray_colour_bias;
        }
        field.ResizeSamples(m, &W.fc);
        for (int k = 0; k < nseg; ++k) {
          const int i = W.seg_ray[k];
          for (int j = W.seg[k]; j < W.seg[k + 1]; ++j) field.SetSample(j, origin(i) + W.samples[j].t * dir(i), &W.fc);
        }
        field.Density(m, W.seg.data(), W.seg_ray.data(), nseg, &W.fc);
        // Keep samples up to early termination (the sample that crosses the
        // threshold included, as CompositeWeights does).
        W.keep.clear();
        W.kseg.assign(1, 0);
        W.kray.clear();
        W.kt.clear();
        W.kdt.clear();
        for (int k = 0; k < nseg; ++k) {
          const int i = W.seg_ray[k];
          float T = s.ray_T[i];
          for (int j = W.seg[k]; j < W.seg[k + 1]; ++j) {
            W.keep.push_back(j);
            W.kt.push_back(W.samples[j].t);
            W.kdt.push_back(W.samples[j].dt);
            const float alpha = 1.0f - std::exp(-W.fc.sigma[j] * W.samples[j].dt);  // As CompositeWeights.
            T *= 1.0f - alpha;
            if (T <= kMinTransmittance) {
              s.ray_alive[i] = 0;
              break;
            }
          }
          s.ray_T[i] = T;
          W.ray_kseg[i] = int(W.kray.size());
          W.kseg.push_back(int(W.keep.size()));
          W.kray.push_back(i);
        }
        field.Select(W.keep.data(), int(W.keep.size()), /*for_backward=*/true, &W.fc);
        // 2. Colour on the kept samples.
        field.Colour(int(W.keep.size()), W.kseg.data(), W.kray.data(), int(W.kray.size()), &W.fc);
      }
      // 3. Gather each ray's kept samples across waves, in order.
      s.gseg.assign(1, 0);
      s.gwave.clear();
      s.gcol.clear();
      for (int i = 0; i < nr; ++i) {
        for (int wv = 0; wv < nwaves; ++wv) {
          const TrainWave& W = s.waves[wv];
          const int k = W.ray_kseg[i];
          if (k < 0) continue;
          for (int c = W.kseg[k]; c < W.kseg[k + 1]; ++c) {
            s.gwave.push_back(wv);
            s.gcol.push_back(c);
          }
        }
        s.gseg.push_back(int(s.gwave.size()));
      }
      const int m2 = int(s.gwave.size());
      s.samples_used += m2;
      s.gsigma.resize(m2);
      s.gt.resize(m2);
      s.gdt.resize(m2);
      s.gw.resize(m2);
      s.grgb.resize(3 * size_t(m2));
      s.gmid.resize(m2);
      s.gwidth.resize(m2);
      s.gdrgb.assign(3 * size_t(m2), 0.0f);
      s.gdsigma.assign(m2, 0.0f);
      s.t_final.resize(nr);
      for (int j = 0; j < m2; ++j) {
        const TrainWave& W = s.waves[s.gwave[j]];
        const int c = s.gcol[j];
        s.gsigma[j] = W.fc.sigma[c];
        s.gt[j] = W.kt[c];
        s.gdt[j] = W.kdt[c];
        for (int k = 0; k < 3; ++k) s.grgb[3 * size_t(j) + k] = W.fc.ws.rgb(k, c);
      }
      // 4. Loss and compositing backward per ray.
      s.used.assign(nr, 0);
      for (int i = 0; i < nr; ++i) {
        const int r = r0 + i;
        const int a = s.gseg[i], n_i = s.gseg[i + 1] - a;
        s.t_final[i] = 1.0f;
        const int used =
            n_i > 0 ? CompositeWeights(&s.gsigma[a], &s.gdt[a], n_i, kMinTransmittance, &s.gw[a], &s.t_final[i]) : 0;
        s.used[i] = used;
        const float* rgb = &s.grgb[3 * size_t(a)];
        float c[3];
        const float* bgr = ray_bg ? &ray_bg[3 * size_t(r)] : bg.data();
        CompositeColour(&s.gw[a], rgb, used, s.t_final[i], bgr, c);
        // The photo's own colour transform (view_colour.h), if it has one.
        const int pv = view_colour_.empty() || batch.view.empty() ? -1 : batch.view[r];
        const float* vc = pv >= 0 ? &view_colour_[size_t(pv) * kViewColourParams] : nullptr;
        float c_field[3] = {c[0], c[1], c[2]};
        if (vc != nullptr) ApplyViewColour(vc, c_field, c);
        const float* gt = &batch.target[3 * size_t(r)];
        const float wr = batch.weight[r];
        const bool robust = !batch.robust.empty() && batch.robust[r] != 0;
        float dc[3], se = 0, data_loss = 0;
        for (int k = 0; k < 3; ++k) {
          const float e = c[k] - gt[k];
          se += e * e;
          if (robust) {  // Charbonnier (MEIL-NeRF's replay loss).
            const float ch = std::sqrt(e * e + 1e-6f);
            data_loss += ch;
            dc[k] = wr * e / ch / 3.0f * inv_n;
          } else {
            data_loss += e * e;
            dc[k] = wr * 2.0f * e / 3.0f * inv_n;
          }
        }
        const float o = 1.0f - s.t_final[i] + 1e-10f;
        s.sq_err += se / 3.0f;
        ray_sq_err_[r] = se / 3.0f;
        s.loss += (wr * data_loss / 3.0f + lambda * (-o * std::log(o))) * inv_n;
        const float d_opacity = lambda * -(std::log(o) + 1.0f) * inv_n;
        if (vc != nullptr) {
          float dc_field[3];
          ViewColourBackward(vc, c_field, dc, dc_field, &s.grad_view_colour[size_t(pv) * kViewColourParams]);
          for (int k = 0; k < 3; ++k) dc[k] = dc_field[k];
        }
        if (used == 0) continue;
        CompositeBackward(&s.gsigma[a], &s.gdt[a], rgb, &s.gw[a], used, s.t_final[i], bgr, dc, d_opacity,
                          &s.gdrgb[3 * size_t(a)], &s.gdsigma[a]);
        if (near_reg > 0) {  // Occlusion penalty: sum of sigma * dt close to the camera.
          for (int j = a; j < a + used; ++j) {
            if (s.gt[j] >= near_dist) break;  // Samples are in ray order.
            s.loss += near_reg * inv_n * s.gsigma[j] * s.gdt[j];
            s.gdsigma[j] += near_reg * inv_n * s.gdt[j];
          }
        }
        if (dist_reg > 0) {
          // Interval midpoints and widths in normalised ray distance.
          const Eigen::Vector3f o3 = origin(i), d3 = dir(i);
          const Eigen::Vector3f q0 = model.contracted() ? Contract(o3) : o3;
          for (int j = a; j < a + used; ++j) {
            // Marched samples sit at their interval's start, proposal
            // samples at its midpoint.
            const float tm = proposals ? s.gt[j] : s.gt[j] + 0.5f * s.gdt[j];
            if (model.contracted()) {
              const Eigen::Vector3f x = o3 + tm * d3;
              s.gmid[j] = (Contract(x) - q0).norm() * inv_box;
              s.gwidth[j] = s.gdt[j] * ContractDirectional(x, d3).norm() * inv_box;
            } else {
              s.gmid[j] = tm * inv_box;
              s.gwidth[j] = s.gdt[j] * inv_box;
            }
          }
          s.loss += dist_reg * inv_n *
                    DistortionLoss(&s.gdt[a], &s.gw[a], &s.gmid[a], &s.gwidth[a], used, dist_reg * inv_n,
                                   &s.gdsigma[a]);
        }
        const float known_depth = batch.depth.empty() ? 0.0f : batch.depth[r];
        if (depth_w > 0 && known_depth > 0) {
          // Ray distances of the samples, as for the distortion loss.
          s.gdepth_mid.resize(used);
          for (int j = 0; j < used; ++j) s.gdepth_mid[j] = proposals ? s.gt[a + j] : s.gt[a + j] + 0.5f * s.gdt[a + j];
          // Scaled by the ray's weight, as its colour loss is (a replay
          // label's depth target carries the label's weight).
          const float dw = depth_w * batch.weight[r] * inv_n;
          s.loss += dw * SparseDepthLoss(&s.gdt[a], &s.gw[a], s.gdepth_mid.data(), used, known_depth,
                                         options_.depth_sigma, dw, &s.gdsigma[a]);
        }
      }
      // 4b. Interlevel loss: the proposal histograms must cover the full
      // field's weights (constants here).
      if (proposals && s.prop.num_rays > 0) {
        const int nf = s.prop.n_final;
        s.nerf_w.assign(size_t(s.prop.num_rays) * nf, 0.0f);
        for (int q = 0; q < s.prop.num_rays; ++q) {
          const int i = s.prop.ray_of[q];
          const int a = s.gseg[i];
          for (int j = 0; j < std::min(s.used[i], nf); ++j) s.nerf_w[size_t(q) * nf + j] = s.gw[a + j];
        }
        s.loss += proposer.InterlevelBackward(s.nerf_w.data(), interlevel_scale, &s.prop, s.grad_prop.data(),
                                              &s.prop_store);
      }
      // 5. Scatter the gradients back to the waves; field backward per wave;
      // stash grid-input gradients for phase 2.
      for (int wv = 0; wv < nwaves; ++wv) {
        TrainWave& W = s.waves[wv];
        W.d_rgb.assign(3 * W.keep.size(), 0.0f);
        W.d_sigma.assign(W.keep.size(), 0.0f);
      }
      for (int j = 0; j < m2; ++j) {
        TrainWave& W = s.waves[s.gwave[j]];
        const int c = s.gcol[j];
        for (int k = 0; k < 3; ++k) W.d_rgb[3 * size_t(c) + k] = s.gdrgb[3 * size_t(j) + k];
        W.d_sigma[c] = s.gdsigma[j];
      }
      for (int wv = 0; wv < nwaves; ++wv) {
        TrainWave& W = s.waves[wv];
        const int mk = int(W.keep.size());
        field.Backward(mk, W.kseg.data(), W.kray.data(), int(W.kray.size()), W.d_rgb.data(), W.d_sigma.data(), &W.fc,
                       s.grad_mlp.data(), s.grad_emb.data());
        if (ray_grads) {
          WaveRayGradients(model, W, &batch.origin[3 * size_t(r0)], &batch.dir[3 * size_t(r0)], &ray_wants_[r0],
                           &ray_grad_origin_[3 * size_t(r0)], &ray_grad_dir_[3 * size_t(r0)]);
        }
        s.store_pos.insert(s.store_pos.end(), W.fc.pos.begin(), W.fc.pos.begin() + 3 * size_t(mk));
        s.store_dfeat.insert(s.store_dfeat.end(), W.fc.d_feat.begin(), W.fc.d_feat.begin() + size_t(mk) * Dg);
      }
    }
  }
  // Phase 2: hash-grid backward, levels partitioned over threads.
  const int L = grid.num_levels();
#pragma omp parallel num_threads(threads_)
  {
    const int tid = omp_get_thread_num(), nt = omp_get_num_threads();
    for (int l = tid; l < L; l += nt) {
      if (annealing && level_weights_[l] == 0.0f) continue;  // Off: its gradient is 0.
      for (const auto& sp : scratch_) {
        const int n = int(sp->store_pos.size() / 3);
        grid.BackwardLevel(l, sp->store_pos.data(), sp->store_dfeat.data(), n, grad_grid_.data(),
                           track_touched ? touched_.data() : nullptr, &touched_lists_[l]);
      }
    }
  }
  // Proposal fields: hash-grid backward with (stage, level) pairs split over
  // threads (disjoint ranges), then the per-thread MLP gradients.
  if (proposals) {
    const int stages = model.options().proposal.num_stages();
    std::vector<std::pair<int, int>> tasks;
    for (int k = 0; k < stages; ++k) {
      for (int l = 0; l < model.proposal_field(k).grid().num_levels(); ++l) tasks.emplace_back(k, l);
    }
#pragma omp parallel for schedule(dynamic) num_threads(threads_)
    for (int q = 0; q < int(tasks.size()); ++q) {
      const auto [k, l] = tasks[q];
      const HashGrid& pg = model.proposal_field(k).grid();
      for (const auto& sp : scratch_) {
        const int n = int(sp->prop_store.pos[k].size() / 3);
        pg.BackwardLevel(l, sp->prop_store.pos[k].data(), sp->prop_store.d_feat[k].data(), n,
                         grad_prop_.data() + model.proposal_offset(k), nullptr, nullptr);
      }
    }
    for (int k = 0; k < stages; ++k) {
      const ProposalField& pf = model.proposal_field(k);
      const size_t begin = model.proposal_offset(k) + pf.mlp_offset(), end = begin + pf.mlp_size();
      for (size_t i = begin; i < end; ++i) grad_prop_[i] = 0.0f;
      for (const auto& sp : scratch_) {
        if (sp->grad_prop.size() != grad_prop_.size()) continue;
        for (size_t i = begin; i < end; ++i) grad_prop_[i] += sp->grad_prop[i];
      }
    }
  }
  // Reduce the small per-thread gradients in a fixed order (deterministic).
  grad_mlp_.assign(model.params().mlp.size(), 0.0f);
  grad_emb_.assign(model.params().emb.size(), 0.0f);
  grad_view_colour_.assign(view_colour_.size(), 0.0f);
  double loss = 0, sq = 0;
  batch_samples_ = batch_composited_ = 0;
  for (const auto& sp : scratch_) {
    for (size_t i = 0; i < grad_mlp_.size(); ++i) grad_mlp_[i] += sp->grad_mlp[i];
    for (size_t i = 0; i < grad_emb_.size(); ++i) grad_emb_[i] += sp->grad_emb[i];
    for (size_t i = 0; i < grad_view_colour_.size(); ++i) grad_view_colour_[i] += sp->grad_view_colour[i];
    loss += sp->loss;
    sq += sp->sq_err;
    batch_samples_ += sp->samples_marched;
    batch_composited_ += sp->samples_used;
  }
  batch_mse_ = sq * inv_n;
  loss += ViewColourPrior(view_colour_, options_.view_colour_prior, grad_view_colour_.data());
  return float(loss);
}

bool Trainer::WantRayGradients(const RayBatch& batch) {
  const int n = batch.size();
  ray_wants_.assign(size_t(n), 0);
  bool any = false;
  for (int r = 0; r < n; ++r) {
    const int v = batch.view.empty() ? -1 : batch.view[r];
    ray_wants_[r] = all_ray_gradients_ || (refiner_ != nullptr && step_ >= refiner_->options().start_iteration &&
                                           refiner_->Refines(v));
    any = any || ray_wants_[r];
  }
  ray_grad_origin_.assign(any ? 3 * size_t(n) : 0, 0.0f);
  ray_grad_dir_.assign(any ? 3 * size_t(n) : 0, 0.0f);
  return any;
}

absl::Status Trainer::RefineCameras(const CameraRefineOptions& options, std::vector<uint8_t> refine) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  refiner_ = std::make_unique<CameraRefiner>(sampler_->Cameras(), std::move(refine), options);
  return absl::OkStatus();
}

void Trainer::StepCameras(const RayBatch& batch, float lr) {
  if (refiner_ == nullptr || ray_grad_origin_.empty()) return;
  refiner_->ZeroGradients();
  for (int r = 0; r < batch.size(); ++r) {
    if (!ray_wants_[r]) continue;
    refiner_->AddRayGradient(batch.view[r], Eigen::Map<const Eigen::Vector3f>(&batch.dir[3 * size_t(r)]),
                             Eigen::Map<const Eigen::Vector3f>(&ray_grad_origin_[3 * size_t(r)]),
                             Eigen::Map<const Eigen::Vector3f>(&ray_grad_dir_[3 * size_t(r)]));
  }
  ++camera_steps_;
  if (!refiner_->Step(camera_steps_, lr / options_.learning_rate)) {
    spdlog::warn("step {}: camera-refinement gradient has NaN/Inf; cameras not moved", step_);
    return;
  }
  std::vector<uint8_t> moved(size_t(sampler_->Cameras().size()), 0);
  for (int r = 0; r < batch.size(); ++r) {
    if (ray_wants_[r]) moved[size_t(batch.view[r])] = 1;
  }
  for (size_t v = 0; v < moved.size(); ++v) {
    if (moved[v]) sampler_->SetCamera(int(v), refiner_->camera(int(v)));
  }
}

float Trainer::ComputeLossAndGradients(const RayBatch& batch, const std::vector<float>& jitter, Gradients* g,
                                       bool ray_gradients) {
  std::fill(grad_grid_.begin(), grad_grid_.end(), 0.0f);
  std::fill(grad_prop_.begin(), grad_prop_.end(), 0.0f);
  batch_seed_ = 0;  // Proposal placement at bin centres: the same batch gives the same loss.
  all_ray_gradients_ = ray_gradients;
  float loss = ForwardBackward(batch, jitter.data(), /*ray_bg=*/nullptr, /*track_touched=*/false);
  all_ray_gradients_ = false;
  g->ray_origin = ray_grad_origin_;
  g->ray_dir = ray_grad_dir_;
  if (options_.ewc != nullptr) loss += ApplyEwc(/*track_touched=*/false);
  if (options_.grid_decay > 0) loss += ApplyGridDecay(/*touched_only=*/false);
  g->grid = grad_grid_;
  g->mlp = grad_mlp_;
  g->emb = grad_emb_;
  g->proposal = grad_prop_;
  g->view_colour = grad_view_colour_;
  std::fill(grad_grid_.begin(), grad_grid_.end(), 0.0f);
  std::fill(grad_prop_.begin(), grad_prop_.end(), 0.0f);
  return loss;
}

void Trainer::ClearLevelGradients(int level) {
  for (uint32_t e : touched_lists_[level]) {
    grad_grid_[2 * size_t(e)] = 0.0f;
    grad_grid_[2 * size_t(e) + 1] = 0.0f;
    touched_[e] = 0;
  }
  touched_lists_[level].clear();
}

float Trainer::ApplyEwc(bool track_touched) {
  const EwcPenalty& e = *options_.ewc;
  const ModelParams& p = model_->params();
  double loss = 0;
  auto dense = [&](const std::vector<float>& theta, const std::vector<float>& f, const std::vector<float>& a,
                   std::vector<float>* g) {
    const size_t n = std::min({theta.size(), f.size(), a.size()});
    for (size_t i = 0; i < n; ++i) {
      const float d = theta[i] - a[i];
      (*g)[i] += e.lambda * f[i] * d;
      loss += 0.5 * double(e.lambda) * f[i] * d * d;
    }
  };
  dense(p.mlp, e.fisher.mlp, e.anchor.mlp, &grad_mlp_);
  dense(p.emb, e.fisher.emb, e.anchor.emb, &grad_emb_);
  // Grid: every entry with Fisher information gets a gradient (dense, which
  // is what makes EWC expensive on hash grids).
  const HashGrid& grid = model_->grid();
  const int L = grid.num_levels();
  if (e.fisher.grid.size() != p.grid.size() || e.anchor.grid.size() != p.grid.size()) return float(loss);
  double grid_loss = 0;
#pragma omp parallel for schedule(dynamic) reduction(+ : grid_loss) num_threads(threads_)
  for (int l = 0; l < L; ++l) {
    const size_t begin = grid.level_offset(l), end = begin + grid.level_size(l);
    for (size_t entry = begin; entry < end; ++entry) {
      const float f0 = e.fisher.grid[2 * entry], f1 = e.fisher.grid[2 * entry + 1];
      if (f0 == 0.0f && f1 == 0.0f) continue;
      const float d0 = p.grid[2 * entry] - e.anchor.grid[2 * entry];
      const float d1 = p.grid[2 * entry + 1] - e.anchor.grid[2 * entry + 1];
      grad_grid_[2 * entry] += e.lambda * f0 * d0;
      grad_grid_[2 * entry + 1] += e.lambda * f1 * d1;
      grid_loss += 0.5 * double(e.lambda) * (f0 * d0 * d0 + f1 * d1 * d1);
      if (track_touched && !touched_[entry]) {
        touched_[entry] = 1;
        touched_lists_[l].push_back(uint32_t(entry));
      }
    }
  }
  return float(loss + grid_loss);
}

float Trainer::ApplyGridDecay(bool touched_only) {
  const HashGrid& grid = model_->grid();
  const std::vector<float>& v = model_->params().grid;
  const double w = options_.grid_decay;
  const int L = grid.num_levels();
  double loss = 0;
#pragma omp parallel for schedule(dynamic) reduction(+ : loss) num_threads(threads_)
  for (int l = 0; l < L; ++l) {
    // A level coarse_to_fine holds off gives no feature and gets no
    // gradient, its decay's included (training never touches its entries).
    if (!level_weights_.empty() && level_weights_[l] == 0.0f) continue;
    // d/dv of w * mean(v^2) over the level's floats.
    const double n = double(grid.level_size(l)) * HashGrid::kFeatures;
    const float scale = float(2.0 * w / n);
    double sum = 0;
    auto decay = [&](size_t entry) {
      for (int f = 0; f < HashGrid::kFeatures; ++f) {
        const size_t i = HashGrid::kFeatures * entry + f;
        grad_grid_[i] += scale * v[i];
        sum += double(v[i]) * v[i];
      }
    };
    if (touched_only) {
      for (uint32_t e : touched_lists_[l]) decay(e);
    } else {
      const size_t begin = grid.level_offset(l), end = begin + grid.level_size(l);
      for (size_t e = begin; e < end; ++e) decay(e);
    }
    loss += w * sum / n;
  }
  return float(loss);
}

absl::Status Trainer::Step() {
  const auto start = std::chrono::steady_clock::now();
  NgpModel& model = *model_;
  const int mo_interval = model.options().occupancy.update_interval;
  if (step_ % mo_interval == 0 && !model.uses_proposals()) model.UpdateOccupancy(step_, &rng_);

  RayBatch batch;
  sampler_->SetProgress(options_.iterations > 0 ? float(step_) / options_.iterations : 1.0f);
  sampler_->Sample(batch_rays_, &rng_, &batch);
  std::vector<float> jitter(batch.size());
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (float& j : jitter) j = u(rng_);
  if (model.uses_proposals()) batch_seed_ = rng_() | 1;  // Marching models keep their random stream.
  std::vector<float> ray_bg;
  if (options_.random_background && model.kind() == SceneKind::kUnbounded) {
    ray_bg.resize(3 * size_t(batch.size()));
    for (float& c : ray_bg) c = u(rng_);
  }

  float loss = ForwardBackward(batch, jitter.data(), ray_bg.empty() ? nullptr : ray_bg.data(), /*track_touched=*/true);
  if (options_.ewc != nullptr) loss += ApplyEwc(/*track_touched=*/true);
  if (options_.grid_decay > 0) loss += ApplyGridDecay(/*touched_only=*/true);
  const int next = step_ + 1;
  if (next == options_.inject_nan_gradient_at_step && !grad_mlp_.empty()) grad_mlp_[0] = NAN;

  const int L = int(touched_lists_.size());
  auto clear_grid_grads = [this, L]() {
    std::fill(grad_prop_.begin(), grad_prop_.end(), 0.0f);
#pragma omp parallel for schedule(dynamic) num_threads(threads_)
    for (int l = 0; l < L; ++l) ClearLevelGradients(l);
  };
  // Stability checks before anything is applied.
  std::string bad;
  if (!std::isfinite(loss)) bad = absl::StrFormat("loss is %f", loss);
  else if (!AllFinite(grad_mlp_)) bad = "MLP gradient has NaN/Inf";
  else if (!AllFinite(grad_emb_)) bad = "embedding gradient has NaN/Inf";
  else if (!AllFinite(grad_prop_)) bad = "proposal-field gradient has NaN/Inf";
  else if (!AllFinite(grad_view_colour_)) bad = "view-colour gradient has NaN/Inf";
  else {
    int grid_bad = 0;
#pragma omp parallel for schedule(dynamic) reduction(+ : grid_bad) num_threads(threads_)
    for (int l = 0; l < L; ++l) {
      for (uint32_t e : touched_lists_[l]) {
        if (!std::isfinite(grad_grid_[2 * size_t(e)]) || !std::isfinite(grad_grid_[2 * size_t(e) + 1])) {
          ++grid_bad;
          break;
        }
      }
    }
    if (grid_bad > 0) bad = "hash-grid gradient has NaN/Inf";
  }
  if (!bad.empty()) {
    clear_grid_grads();
    // A transient bad batch (finite parameters) is skipped; a persistent one,
    // or a non-finite parameter, is divergence.
    if (consecutive_bad_ < options_.max_bad_batches && model.AllFinite()) {
      ++consecutive_bad_;
      ++skipped_batches_;
      spdlog::warn("step {}: {}; batch skipped ({} in a row, at most {})", next, bad, consecutive_bad_,
                   options_.max_bad_batches);
      step_ = next;
      last_ = StepStats{};
      last_.step = step_;
      last_.loss = loss;
      last_.rays = batch.size();
      return absl::OkStatus();
    }
    return absl::InternalError(absl::StrFormat("training diverged at step %d: %s", next, bad));
  }
  consecutive_bad_ = 0;

  const float lr = CurrentLearningRate();
  // Adam's step count runs on across resumed runs (bias correction).
  const int adam_step = int(std::min<uint64_t>(adam_base_ + uint64_t(next), uint64_t(INT32_MAX)));
  ModelParams& p = model.mutable_params();
  // Keep a copy of the small blocks so a non-finite update can be undone.
  const std::vector<float> mlp_before = p.mlp, emb_before = p.emb, view_colour_before = view_colour_;
  adam_.UpdateDense(1, lr, adam_step, p.mlp.data(), grad_mlp_.data(), p.mlp.size());
  adam_.UpdateDense(2, lr, adam_step, p.emb.data(), grad_emb_.data(), p.emb.size());
  if (!p.proposal.empty()) {
    adam_.UpdateDense(3, lr, adam_step, p.proposal.data(), grad_prop_.data(), p.proposal.size());
    std::fill(grad_prop_.begin(), grad_prop_.end(), 0.0f);
  }
  if (!view_colour_.empty()) {
    adam_.UpdateDense(4, lr * options_.view_colour_lr_scale, next,  // Fresh per run.
                      view_colour_.data(), grad_view_colour_.data(),
                      view_colour_.size());
  }
  bool finite = AllFinite(p.mlp) && AllFinite(p.emb) && AllFinite(p.proposal) && AllFinite(view_colour_);
  if (finite) {
    // Sparse grid update, one level per task (levels own disjoint entries);
    // gradients are cleared in the same pass.
    int grid_bad = 0;
#pragma omp parallel for schedule(dynamic) reduction(+ : grid_bad) num_threads(threads_)
    for (int l = 0; l < L; ++l) {
      adam_.UpdateSparse(0, lr, adam_step, p.grid.data(), grad_grid_.data(), touched_lists_[l], HashGrid::kFeatures);
      for (uint32_t e : touched_lists_[l]) {
        if (!std::isfinite(p.grid[2 * size_t(e)]) || !std::isfinite(p.grid[2 * size_t(e) + 1])) ++grid_bad;
      }
      ClearLevelGradients(l);
    }
    finite = grid_bad == 0;
  } else {
    clear_grid_grads();
  }
  if (!finite) {
    p.mlp = mlp_before;
    p.emb = emb_before;
    view_colour_ = view_colour_before;
    return absl::InternalError(absl::StrFormat(
        "training diverged at step %d: parameters became NaN/Inf after the update", next));
  }
  step_ = next;
  StepCameras(batch, lr);
  sampler_->ObserveErrors(batch, ray_sq_err_);

  // Adapt the batch so it marches about target_samples samples.
  const double spr = batch.size() > 0 ? double(batch_samples_) / batch.size() : 0.0;
  const double upr = batch.size() > 0 ? double(batch_composited_) / batch.size() : 0.0;
  mean_used_per_ray_ = mean_used_per_ray_ == 0 ? upr : 0.9 * mean_used_per_ray_ + 0.1 * upr;
  mean_samples_per_ray_ = mean_samples_per_ray_ == 0 ? spr : 0.9 * mean_samples_per_ray_ + 0.1 * spr;
  if (options_.target_samples > 0 && mean_samples_per_ray_ > 0) {
    const int want = int(options_.target_samples / mean_samples_per_ray_);
    batch_rays_ = std::clamp((want + 127) / 128 * 128, 256, options_.max_batch_rays);
  }
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  last_.step = step_;
  last_.loss = loss;
  last_.mse = float(batch_mse_);
  last_.psnr = batch_mse_ > 0 ? float(-10.0 * std::log10(batch_mse_)) : 99.0f;
  last_.rays = batch.size();
  last_.samples = batch_samples_;
  last_.samples_composited = batch_composited_;
  last_.seconds = secs;
  total_seconds_ += secs;
  total_samples_ += batch_samples_;
  total_rays_ += batch.size();
  total_composited_ += batch_composited_;
  spdlog::trace("step {}: {} rays, {} samples ({} composited), lr {:.3g}, batch psnr {:.2f}, {:.3f}s", step_,
                batch.size(), batch_samples_, batch_composited_, lr, last_.psnr, secs);
  return absl::OkStatus();
}

absl::Status Trainer::Run(const std::function<void(const StepStats&)>& on_step, const std::atomic<bool>* cancel) {
  while (step_ < options_.iterations) {
    if (cancel != nullptr && cancel->load()) {
      return absl::CancelledError(absl::StrFormat("training cancelled at step %d", step_));
    }
    if (absl::Status s = Step(); !s.ok()) return s;
    if (on_step) on_step(last_);
  }
  return absl::OkStatus();
}

}  // namespace clnerf
