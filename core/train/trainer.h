// Trainer: optimises a NgpModel on rays from a RaySampler with Adam, the
// cosine learning-rate schedule, MSE + opacity-entropy loss (plus, on real
// captures, the distortion loss and an occlusion penalty near the cameras),
// and periodic occupancy-grid refreshes.
//
// One training step: sample rays -> march through the occupancy grid (first
// sample jittered) -> hash-encode + density MLP on every marched sample ->
// composite sigma front to back and drop samples behind early termination ->
// colour MLP on the rest -> loss -> backward through compositing, both MLPs
// and (in a second phase, one thread per subset of levels, so no atomics) the
// hash grid -> Adam (lazy on the grid). Models with proposal sampling
// (NgpModel::uses_proposals) place each ray's samples with the proposal
// fields instead of marching, add the interlevel loss and update the proposal
// fields with dense Adam (core/field/proposal_sampler.h). With
// TrainOptions::view_colour, each photo's rays pass through that photo's
// affine colour transform before the loss (view_colour.h); the transforms
// are the trainer's own state, not part of the model. With RefineCameras,
// the rays of the named photos also carry the loss's gradient with respect to
// their origin and direction, and the photos' cameras move with it
// (camera_refiner.h).
//
// Stability: the loss, every gradient and every updated parameter are checked
// for NaN/Inf; a bad step is not applied and Step() returns INTERNAL naming
// the step that diverged, leaving the model at its last finite state.
//
// A Trainer mutates its model (and, when refining cameras, its sampler's
// cameras through RaySampler::SetCamera between batches) and is not
// thread-safe; it uses OpenMP threads internally.
#ifndef CLNERF_CORE_TRAIN_TRAINER_H_
#define CLNERF_CORE_TRAIN_TRAINER_H_

#include <atomic>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/train/adam.h"
#include "core/train/camera_refiner.h"
#include "core/train/optimizer_state.h"
#include "core/field/ngp_model.h"
#include "core/train/ray_sampler.h"

namespace clnerf {

// Elastic weight consolidation: adds lambda/2 * sum F_i (theta_i - anchor_i)^2
// to the loss. `fisher` and `anchor` have the layout of ModelParams; embedding
// rows beyond the anchor's (new time steps) are not penalised.
struct EwcPenalty {
  float lambda = 1e5f;
  ModelParams fisher;
  ModelParams anchor;
};

// How the learning rate moves. s = this run's step, S = the Adam steps
// before this run (TrainOptions::resume's, else 0), n = iterations,
// tau = lr_timescale (0: n):
//   kCosine             a cosine from lr to lr * lr_final_ratio over this run:
//                       a fresh schedule per run.
//   kInverseSqrt        lr * sqrt(tau / (tau + S + s)): one schedule over
//                       every run of a sequence that needs no horizon (the
//                       service never knows how many scans will come).
//   kInverseSqrtCosine  this run's cosine, peaking at kInverseSqrt's value at
//                       the run's start (each update still anneals before it
//                       is deployed; later updates start lower).
enum class LrSchedule { kCosine, kInverseSqrt, kInverseSqrtCosine };
absl::StatusOr<LrSchedule> ParseLrSchedule(const std::string& name);
const char* LrScheduleName(LrSchedule s);

struct TrainOptions {
  int iterations = 2000;          // Training steps.
  int batch_rays = 4096;          // Rays in the first batch.
  int target_samples = 1 << 17;   // Adapt rays so a batch marches ~this many samples (0 = fixed).
  int max_batch_rays = 1 << 15;   // Upper bound for the adaptive batch.
  float learning_rate = 1e-2f;    // Initial learning rate (all blocks).
  float lr_final_ratio = 1.0f / 30.0f;  // Cosine decay to lr * ratio.
  float opacity_reg = 1e-3f;      // Weight of mean(-o log o).
  // Weight of the distortion loss (mip-NeRF 360) on each ray's weights, in
  // ray distance normalised by the box size (contracted distance for
  // unbounded scenes). < 0 = auto: kAutoDistortion for unbounded scenes, 0 for
  // bounded ones.
  float distortion_reg = -1.0f;
  static constexpr float kAutoDistortion = 1e-2f;
  // > 0: the distortion weight rises linearly from 0 over this fraction of
  // `iterations` (early training's blobs are then not pulled into thin
  // layers before the views agree on where the surfaces are). 0: constant.
  float distortion_warmup = 0.0f;
  // Occlusion penalty near the cameras (FreeNeRF): adds weight * sigma * dt
  // for every composited sample closer than `near_density_distance` (model
  // units) to its ray's origin. A region just in front of one camera is seen
  // by almost no other camera, so on real captures with large textureless
  // surfaces the field can explain each view with a "billboard" there; this
  // makes that solution cost more than the true surface. < 0 = auto:
  // kAutoNearDensity for unbounded scenes, 0 for bounded ones.
  float near_density_reg = -1.0f;
  float near_density_distance = 0.2f;
  // > 0: the weight fades linearly to 0 over this fraction of `iterations`
  // (the penalty steers early training away from billboards; once the
  // surfaces exist it is no longer needed). 0: constant.
  float near_density_fade = 0.0f;
  static constexpr float kAutoNearDensity = 1e-2f;
  // Unbounded (real) scenes: composite each training ray onto a random
  // background colour (instant-ngp's trick), so the field cannot explain
  // dark pixels with transparency and must become opaque; this is what lets
  // rays terminate early. Rendering still uses the model's background.
  bool random_background = false;
  // Proposal models (NgpModel::uses_proposals): weight of the interlevel
  // loss, and how many steps the proposal weights are annealed over before
  // resampling (w^a with a rising from 0 to 1 as nerfacto does; < 0 = auto:
  // a quarter of `iterations`, at most 1000).
  float interlevel_weight = 1.0f;
  int proposal_anneal_iterations = -1;
  // Sparse-depth supervision (rays with RayBatch::depth > 0, from a
  // capture's points, sparse_depth.h, or distilled from a replay label,
  // ReplayLabelOptions::depth_min_opacity): weight of SparseDepthLoss
  // (volume_rendering.h), times the ray's RayBatch::weight and averaged over
  // the batch as the colour loss is, and
  // its Gaussian's width in model units (scaled by the depth beyond 1).
  // depth-nerfacto uses 1e-3 and a variance of 0.01 (width 0.1); 1e-2 won on
  // flower_4 (+1.1 dB over three seeds; 1e-3: -0.5) and beer_2 (+0.3 dB)
  // (docs/sparse_depth.md). Without depth rays neither matters.
  float depth_weight = 1e-2f;
  float depth_sigma = 0.1f;
  // Per-view colour transforms (view_colour.h): each photo the sampler
  // names (RayBatch::view) gets an affine colour transform of the composited
  // colour, trained with the rest at `view_colour_lr_scale` times the
  // learning rate and held near the identity by a prior of weight
  // `view_colour_prior`. Views without one (test views, replay) use the
  // identity. Absorbs exposure / white-balance changes between a phone
  // video's frames.
  bool view_colour = false;
  float view_colour_prior = 1e-2f;
  float view_colour_lr_scale = 0.1f;
  // Normalised weight decay on the hash grid (Zip-NeRF): adds
  // grid_decay * sum over levels of mean(feature^2) of the level to the
  // loss, so features that few rays constrain shrink towards 0 instead of
  // keeping arbitrary values (speckle in rarely seen regions). Zip-NeRF
  // uses 0.1. In training it reaches, as the grid's lazy Adam does, only the
  // entries the batch touched (a step's cost stays with its rays); the
  // gradient check (ComputeLossAndGradients) takes every entry. 0 = off.
  // Default 0.01: over lego_100, fox_8, flower_4, beer_2 and a procedural
  // room it gave +0.50, +0.42, +1.38, -0.02 and -0.20 dB with 7-25 % less
  // speckle on all five, where 0.1 lost 2.4-2.7 dB on beer_2 and the room
  // (docs/clean_fields.md, session 71).
  float grid_decay = 0.01f;
  // Coarse-to-fine hash levels (BARF, Neuralangelo): training starts with a
  // quarter of the levels (at least one) and switches the finer ones on, one
  // after another, each fading in over one level's share, until this
  // fraction of `iterations` has passed; a level that is off contributes no
  // feature and gets no gradient, so fine levels only add detail once the
  // coarse ones hold the geometry. Meant for a model trained from scratch
  // (an update of a trained model would lose its fine levels for a while).
  // 0 = off (every level from the start); at most 1.
  float coarse_to_fine = 0.0f;
  LrSchedule lr_schedule = LrSchedule::kCosine;
  int lr_timescale = 0;           // tau of the inverse-sqrt schedules (0 = iterations).
  AdamOptions adam;
  // Continue this optimiser (not owned): its moments and step count (the
  // bias correction and the schedule's S). It must be CompatibleWith the
  // model's parameters (an incompatible one is ignored with a warning);
  // embedding rows added since start with zero moments.
  const OptimizerState* resume = nullptr;
  uint64_t seed = 0;
  int threads = 0;                // OpenMP threads; 0 = all cores.
  const EwcPenalty* ewc = nullptr;  // Optional EWC regulariser (not owned).
  // Stability: a batch whose loss or gradient is NaN/Inf is skipped (nothing
  // is applied, the iteration is spent, a warning is logged) as long as the
  // parameters themselves are finite; the step fails with INTERNAL
  // ("training diverged") once more than this many batches in a row were
  // bad, or at once when a parameter is non-finite. 0: fail on the first.
  int max_bad_batches = 3;
  // Fault injection (tests and `clnerf bench stability`): poisons one
  // gradient entry of this 1-based step with NaN. 0 = off.
  int inject_nan_gradient_at_step = 0;
  absl::Status Validate() const;
  // The distortion loss's weight at training step `step` of a scene that is
  // (un)bounded: distortion_reg resolved (< 0: auto), times the warm-up's
  // ramp.
  float DistortionWeightAt(int step, bool contracted) const;
  // The occlusion penalty's weight at step `step`: near_density_reg
  // resolved (< 0: auto), times the fade (near_density_fade).
  float NearDensityWeightAt(int step, bool contracted) const;
};

struct StepStats {
  int step = 0;           // 1-based index of the step just taken.
  float loss = 0;         // Total loss of the batch.
  float mse = 0;          // Colour MSE of the batch.
  float psnr = 0;         // -10 log10(mse).
  int rays = 0;
  long long samples = 0;  // Network-evaluated samples (marched).
  long long samples_composited = 0;  // After early termination.
  double seconds = 0;     // Wall time of the step.
};

class Trainer {
 public:
  // The model and sampler must outlive the trainer.
  Trainer(NgpModel* model, RaySampler* sampler, const TrainOptions& options);
  ~Trainer();

  // One iteration. A bad batch (NaN/Inf loss or gradient) is skipped up to
  // options.max_bad_batches times in a row; beyond that, or when the
  // parameters are non-finite, INTERNAL ("training diverged at step N: ...")
  // and the model keeps its last finite parameters.
  absl::Status Step();
  // Runs until `options.iterations` steps were taken, `cancel` becomes true
  // (CANCELLED) or a step fails. `on_step` is called after every step.
  absl::Status Run(const std::function<void(const StepStats&)>& on_step,
                   const std::atomic<bool>* cancel = nullptr);

  // The optimiser's state now (moments of the model's blocks and the Adam
  // steps taken including the resumed ones), to resume a later run.
  OptimizerState ExportOptimizerState() const;

  const StepStats& last() const { return last_; }
  int step() const { return step_; }
  // Coarse-to-fine (TrainOptions::coarse_to_fine): the hash levels' weights
  // in the last forward pass; empty when every level was fully on.
  const std::vector<float>& level_weights() const { return level_weights_; }
  float CurrentLearningRate() const;
  double total_seconds() const { return total_seconds_; }
  long long total_samples() const { return total_samples_; }
  long long total_rays() const { return total_rays_; }
  // Batches skipped because their loss or gradient was NaN/Inf.
  int skipped_batches() const { return skipped_batches_; }
  // Samples that reached the colour MLP and the backward pass.
  long long total_composited() const { return total_composited_; }

  // Loss and gradients of one fixed batch without updating anything (used by
  // gradient checks). Gradients are returned in the same layout as params.
  struct Gradients {
    std::vector<float> grid, mlp, emb, proposal, view_colour;
    // With ray_gradients: dL/d(origin) and dL/d(direction) of every ray,
    // 3 per ray, model space (camera_refiner.h's inputs). Without it, empty
    // unless a refiner is active (then filled for its photos' rays only).
    std::vector<float> ray_origin, ray_dir;
  };
  // The per-view colour transforms (12 per photo; empty when
  // options.view_colour is off or the sampler names no photos).
  const std::vector<float>& view_colours() const { return view_colour_; }
  std::vector<float>* mutable_view_colours() { return &view_colour_; }
  float ComputeLossAndGradients(const RayBatch& batch, const std::vector<float>& jitter, Gradients* grads,
                                bool ray_gradients = false);

  // From the next step on, learns pose corrections of the sampler's views
  // with refine[v] != 0 (camera_refiner.h; v indexes RaySampler::Cameras()
  // and RayBatch::view), and moves the sampler's cameras with them.
  // INVALID_ARGUMENT for bad options.
  absl::Status RefineCameras(const CameraRefineOptions& options, std::vector<uint8_t> refine);
  // Null unless RefineCameras was called.
  const CameraRefiner* camera_refiner() const { return refiner_.get(); }

 private:
  struct ThreadScratch;
  // ray_bg: 3 per ray, or nullptr for the model's background.
  float ForwardBackward(const RayBatch& batch, const float* jitter, const float* ray_bg, bool compute_grid_touch);
  // The exponent on proposal weights before resampling at the current step.
  float ProposalAnneal() const;
  // TrainOptions::coarse_to_fine: each hash level's weight at this step
  // (into level_weights_); false when every level is fully on.
  bool LevelWeights();
  // Adds the EWC penalty's gradient (marking grid entries touched) and
  // returns its loss.
  float ApplyEwc(bool track_touched);
  // TrainOptions::grid_decay's loss and gradient: over the touched entries
  // (training), or over every entry (gradient checks).
  float ApplyGridDecay(bool touched_only);
  // Zeroes the gradients and touched flags of one level's touched entries.
  void ClearLevelGradients(int level);
  // Marks the batch's rays that need origin/direction gradients (ray_wants_)
  // and sizes their buffers; false when none does.
  bool WantRayGradients(const RayBatch& batch);
  // The camera refiner's step on the last batch's ray gradients.
  void StepCameras(const RayBatch& batch, float lr);

  NgpModel* model_;
  RaySampler* sampler_;
  TrainOptions options_;
  Adam adam_;
  std::mt19937_64 rng_;
  int step_ = 0;
  uint64_t adam_base_ = 0;        // Adam steps before this run (resumed).
  int consecutive_bad_ = 0, skipped_batches_ = 0;
  int batch_rays_;
  double mean_samples_per_ray_ = 0;
  double mean_used_per_ray_ = 0;  // Composited samples per ray (sizes the first march wave).
  StepStats last_;
  double total_seconds_ = 0;
  long long total_samples_ = 0;
  long long total_rays_ = 0;
  long long total_composited_ = 0;
  int threads_ = 1;

  // Gradient buffers.
  std::vector<float> grad_grid_;
  std::vector<float> level_weights_;  // Per hash level (coarse_to_fine).
  std::vector<uint8_t> touched_;
  std::vector<std::vector<uint32_t>> touched_lists_;  // Per level.
  std::vector<float> grad_mlp_, grad_emb_;
  std::vector<float> grad_prop_;  // Proposal fields (dense).
  std::vector<float> view_colour_, grad_view_colour_;  // Per-view colour transforms.
  uint64_t batch_seed_ = 1;       // Proposal placement stream of the current batch (non-zero).
  std::vector<std::unique_ptr<ThreadScratch>> scratch_;
  // Camera refinement (null = off) and the per-ray gradients it consumes.
  std::unique_ptr<CameraRefiner> refiner_;
  int camera_steps_ = 0;
  bool all_ray_gradients_ = false;  // ComputeLossAndGradients(..., ray_gradients = true).
  std::vector<uint8_t> ray_wants_;
  std::vector<float> ray_grad_origin_, ray_grad_dir_;
  // Batch statistics from the last ForwardBackward.
  double batch_mse_ = 0;
  std::vector<float> ray_sq_err_;  // Per ray of the last batch: mean squared colour error.
  long long batch_samples_ = 0, batch_composited_ = 0;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_TRAINER_H_
