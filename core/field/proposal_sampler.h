// ProposalSampler: places the full field's samples along each ray with the
// model's proposal fields (mip-NeRF 360's online distillation, as nerfacto
// does it), so a ray costs a fixed few dozen full-field evaluations however
// thick or foggy the occupied space is.
//
// Per ray, in the spacing s = g(t), g(t) = t / 2 for t < 1 and 1 - 1 / (2t)
// beyond (linear near the cameras, linear in disparity far away; t in model
// units from the ray origin):
//   stage 0: samples0 intervals, stratified (jittered while training, bin
//            centres otherwise) between the ray's near point and the far
//            bound; proposal field 0 gives sigma at each interval's midpoint
//            and volume rendering gives weights;
//   stage 1: samples1 intervals resampled from stage 0's histogram (inverse
//            CDF of w^anneal + padding), evaluated by proposal field 1;
//   final:   nerf_samples intervals resampled from the last stage's histogram;
//            these are the RaySamples (t = interval midpoint, dt = width) the
//            full field evaluates.
// Training adds the interlevel loss: each proposal histogram must bound the
// full field's (stop-gradient) weights from above,
//   L = mean over rays and final intervals of max(w - w_outer, 0)^2 / (w + eps),
// where w_outer sums the proposal weights of the intervals overlapping the
// final one; it trains only the proposal fields.
//
// The sampler is immutable (it reads the model through the FieldEvaluator it
// was built with, which maps points to grid inputs); one sampler may serve
// many threads, each with its own ProposalContext.
#ifndef CLNERF_CORE_FIELD_PROPOSAL_SAMPLER_H_
#define CLNERF_CORE_FIELD_PROPOSAL_SAMPLER_H_

#include <cstdint>
#include <vector>

#include "core/field/field.h"
#include "core/field/proposal_field.h"
#include "core/field/ray_marcher.h"

namespace clnerf {

// Spacing function and its inverse (see above).
inline float ProposalSpacing(float t) { return t < 1.0f ? 0.5f * t : 1.0f - 0.5f / t; }
inline float ProposalSpacingInverse(float s) { return s < 0.5f ? 2.0f * s : 0.5f / (1.0f - s); }

// One stage's per-block state: (n + 1) edges per ray in s and t, grid inputs,
// densities and weights per interval, and the field's activations.
struct ProposalStage {
  int n = 0;
  std::vector<float> s, t;  // (n + 1) per ray.
  std::vector<float> pos;   // 3 per interval.
  std::vector<float> sigma, w;
  ProposalWorkspace ws;
};

// Per-thread state of one block of rays, kept from Place to
// InterlevelBackward.
struct ProposalContext {
  int num_rays = 0;                // Rays that met the box (hit rays).
  std::vector<int> ray_of;         // Block ray index of each hit ray.
  ProposalStage stage[2];
  int n_final = 0;
  std::vector<float> final_s;      // (n_final + 1) edges per hit ray.
  // Backward scratch.
  std::vector<float> d_w, d_sigma, diff, cum;
};

// Grid inputs and feature gradients of the proposal samples of a batch,
// stashed per field for HashGrid::BackwardLevel (levels can then be split
// over threads without atomics, as the trainer does for the main grid).
struct ProposalGridStore {
  std::vector<float> pos[2], d_feat[2];
  void Clear() {
    for (int k = 0; k < 2; ++k) {
      pos[k].clear();
      d_feat[k].clear();
    }
  }
};

class ProposalSampler {
 public:
  // The model behind `field` must use proposals (NgpModel::uses_proposals).
  explicit ProposalSampler(const FieldEvaluator& field);

  // Places the final samples of n rays (origins/dirs: 3 per ray, model
  // space, unit directions). seed = 0: deterministic bin centres (rendering);
  // otherwise stratified jitter from a stream per ray keyed by (seed,
  // ray_ids[i]) (ray_ids = nullptr: i), so a batch samples the same way on
  // any number of threads. anneal: exponent on the proposal weights before
  // resampling (1 = none). Appends to *samples; seg gets one segment per hit
  // ray (offsets into *samples, starting at samples->size() on entry) and
  // seg_ray its block ray index.
  // nerf_samples > 0 overrides the model's final sample count (rendering
  // may trade accuracy for speed; training uses the model's).
  void Place(const float* origins, const float* dirs, int n, uint64_t seed, const uint32_t* ray_ids, float anneal,
             ProposalContext* ctx, std::vector<RaySample>* samples, std::vector<int>* seg, std::vector<int>* seg_ray,
             int nerf_samples = 0) const;

  // Interlevel loss of the block's hit rays given the full field's weights
  // (n_final per hit ray, in ctx->ray_of order; zero past early termination;
  // treated as constants). Returns scale * (sum over rays and stages of the
  // per-ray sum over final intervals); accumulates scale * dL/dparams of the
  // proposal MLPs into grad (ModelParams::proposal layout) and appends each
  // stage's grid inputs and dL/dfeatures to *store.
  float InterlevelBackward(const float* nerf_w, float scale, ProposalContext* ctx, float* grad,
                           ProposalGridStore* store) const;

  // Per-ray pieces, exposed for tests.
  // Weights of one ray's intervals (no early termination).
  static void Weights(const float* sigma, const float* t_edges, int n, float* w);
  // dL/dsigma from dL/dw through Weights.
  static void WeightsBackward(const float* sigma, const float* t_edges, const float* w, const float* d_w, int n,
                              float* d_sigma);
  // Inverse-CDF resampling of m + 1 edges from n intervals (s: n + 1 edges).
  // u: m + 1 ascending values in [0, 1).
  static void Resample(const float* s, const float* w, int n, float anneal, float padding, const float* u, int m,
                       float* out);
  // Interlevel loss of one ray: final edges c (m + 1) with weights w (m),
  // proposal edges cp (n + 1) with weights wp (n). Returns the loss and adds
  // scale * dL/dwp to d_wp (n values). cum, diff: scratch.
  static float Interlevel(const float* c, const float* w, int m, const float* cp, const float* wp, int n, float scale,
                          float* d_wp, std::vector<float>* cum, std::vector<float>* diff);

 private:
  const FieldEvaluator& field_;
  const NgpModel& model_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_PROPOSAL_SAMPLER_H_
