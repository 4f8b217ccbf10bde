// FieldEvaluator: the radiance field's forward and backward pass over ray
// samples, in the spirit of tiny-cuda-nn's DifferentiableObject. It is the one
// place where a model-space sample becomes hash-grid input (contracting
// unbounded scenes, see contraction.h), features, density and colour, and the
// one backward pass from dL/dsigma and dL/drgb to the MLP, embedding and
// hash-grid gradients. Trainer::ForwardBackward, the renderer, and occupancy
// updates all go through it.
//
// Samples are grouped in segments (consecutive samples of one ray); the
// per-ray inputs (time step and view direction) are folded into per-ray
// first-layer biases once (SetRays). A forward pass is staged, because volume
// rendering decides which samples reach the colour MLP only after it has their
// densities:
//
//   SetRays -> SetSample (each sample) -> Density -> [Select] -> Colour
//   -> Backward (training only; needs Select(..., for_backward = true))
//
// All activations live in a caller-owned FieldContext, the forward "context"
// that Backward consumes. The evaluator itself is immutable after
// construction and SetLevelWeights (it holds the model by const reference
// plus the per-time-step biases), so one evaluator may serve many threads,
// each with its own FieldContext. It must not outlive the model, and the
// model's parameters must not change while it is in use (build a new
// evaluator after each update).
#ifndef CLNERF_CORE_FIELD_FIELD_H_
#define CLNERF_CORE_FIELD_FIELD_H_

#include <memory>
#include <vector>

#include "core/field/bf16_mlp.h"
#include "core/field/ngp_model.h"
#include "Eigen/Core"

namespace clnerf {

// Per-thread activations and gradients of one staged pass.
struct FieldContext {
  // Per-ray inputs (SetRays).
  int num_rays = 0;
  std::vector<int> ray_step;           // Clamped time step per ray.
  std::vector<float> ray_sh;           // kShDim x rays.
  std::vector<float> ray_colour_bias;  // Hc x rays.
  // Samples: hash-grid inputs in [0, 1]^3, features, densities.
  int num_samples = 0;
  std::vector<float> pos;    // 3 x samples.
  std::vector<float> feat;   // Dg x samples.
  std::vector<float> sigma;  // Samples.
  NetworkWorkspace ws;       // MLP activations; ws.rgb holds colours after Colour().
  // Per-segment gathers and backward scratch.
  std::vector<float> seg_geo, seg_col, seg_sh, d_h0, d_geo, d_col;
  std::vector<int> seg_step;
  std::vector<float> d_feat;  // Dg x selected samples after Backward().
};

class FieldEvaluator {
 public:
  // bf16_mlp: for inference only (the renderer's: eval, frames, replay
  // labels, bake targets), run the MLPs in bfloat16 on AMX tiles where the
  // CPU has them (bf16_mlp.h; else float, as without it). Density then
  // fills ctx->ws.h but not the hidden activations, so Select(...,
  // for_backward = true) and Backward need an evaluator built without it
  // (the trainer's); they abort on one built with it.
  explicit FieldEvaluator(const NgpModel& model, bool bf16_mlp = false);

  // Whether the MLPs run in bfloat16 tiles.
  bool bf16_mlp() const { return bf16_ != nullptr; }

  const NgpModel& model() const { return model_; }

  // Hash-grid input in [0, 1]^3 of a model-space point (contracted for
  // unbounded scenes; clamped to the grid).
  Eigen::Vector3f GridInput(const Eigen::Vector3f& p_model) const;
  // Hash-grid input of a point already in the occupancy grid's space (model
  // space, or contracted space for unbounded scenes).
  Eigen::Vector3f GridInputFromFieldSpace(const Eigen::Vector3f& q) const;

  // Per-ray inputs. dirs: 3 x nrays unit directions; steps: time step per ray
  // (nullptr = `constant_step` for all; out-of-range steps are clamped).
  void SetRays(int nrays, const float* dirs, const int* steps, int constant_step, FieldContext* ctx) const;

  // Sizes the sample arrays for m samples; then SetSample fills each one.
  void ResizeSamples(int m, FieldContext* ctx) const;
  void SetSample(int j, const Eigen::Vector3f& p_model, FieldContext* ctx) const {
    const Eigen::Vector3f g = GridInput(p_model);
    ctx->pos[3 * size_t(j)] = g.x();
    ctx->pos[3 * size_t(j) + 1] = g.y();
    ctx->pos[3 * size_t(j) + 2] = g.z();
  }

  // Encodes and runs the density MLP on the m samples; fills ctx->sigma.
  // seg: nseg + 1 sample offsets; seg_ray: the ray of each segment (nullptr =
  // segment k is ray k).
  void Density(int m, const int* seg, const int* seg_ray, int nseg, FieldContext* ctx) const;
  // Keeps samples keep[0..mk) (ascending) in the first mk columns. With
  // for_backward, everything Backward needs is kept; otherwise only what
  // Colour needs.
  void Select(const int* keep, int mk, bool for_backward, FieldContext* ctx) const;
  // Colour MLP on the first mk samples; colours land in ctx->ws.rgb (3 x mk).
  void Colour(int mk, const int* seg, const int* seg_ray, int nseg, FieldContext* ctx) const;
  // Backward from d_rgb (3 x mk) and d_sigma (mk) of the first mk samples:
  // accumulates MLP and embedding gradients into grad_mlp / grad_emb and
  // leaves dL/dfeature (Dg x mk) in ctx->d_feat, for HashGrid::BackwardLevel
  // with ctx->pos.
  void Backward(int mk, const int* seg, const int* seg_ray, int nseg, const float* d_rgb, const float* d_sigma,
                FieldContext* ctx, float* grad_mlp, float* grad_emb) const;

  // Coarse-to-fine training (TrainOptions::coarse_to_fine): one weight per
  // hash level that scales the level's features in Density and their
  // gradient in Backward (0: the level is off; its d_feat is 0). nullptr
  // (the default) = every level at 1. The array must outlive the evaluator's
  // use. DensityAt ignores it (occupancy refreshes see the whole field).
  void SetLevelWeights(const float* w) { level_weights_ = w; }

  // Density at n points in the occupancy grid's space for one time step
  // (occupancy refreshes). Parallel over points (OpenMP).
  void DensityAt(const float* field_points, int n, int time_step, float* sigma) const;

 private:
  const NgpModel& model_;
  bool contracted_;
  float bound_;
  Eigen::MatrixXf geo_bias_;  // Hd x T: geometry embedding's first-layer product per step.
  Eigen::MatrixXf app_bias_;  // Hc x T.
  const float* level_weights_ = nullptr;
  std::shared_ptr<const Bf16Mlp> bf16_;  // Null: float MLPs.
  // Multiplies each level's features of m samples (Dg x m) by its weight.
  void ScaleLevels(int m, float* feat) const;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_FIELD_H_
