// NgpModel: one complete Instant-NGP radiance field with per-time-step
// embeddings: hash grid + density/colour MLPs + embedding tables + occupancy
// grid, plus the scene normalisation and rendering conventions (box size,
// background, step rule) it was trained with.
//
// A model is a value type (copyable), which is how a frozen θ_{t-1} snapshot
// is taken. It has no internal locking: concurrent const use (rendering) is
// safe; mutation (training, AddTimeStep) needs exclusive access. The serving
// layer shares published models as std::shared_ptr<const NgpModel>.
#ifndef CLNERF_CORE_FIELD_NGP_MODEL_H_
#define CLNERF_CORE_FIELD_NGP_MODEL_H_

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/field/hash_grid.h"
#include "core/field/network.h"
#include "core/field/occupancy_grid.h"
#include "core/field/proposal_field.h"
#include "core/field/ray_marcher.h"
#include "core/data/scene.h"

namespace clnerf {

// How a ray's samples are placed: by marching the occupancy grid (every
// occupied step is evaluated; right for objects, whose empty space the grid
// prunes cleanly) or by the proposal fields (a fixed few dozen samples per
// ray; right for real places, whose walls, floors and backgrounds leave thick
// occupied shells). kAuto is resolved when the model is created; it picks
// marching today (see ResolveSampler in ngp_model.cc for the measurements).
enum class SamplerKind { kAuto = 0, kOccupancy = 1, kProposal = 2 };
const char* SamplerKindName(SamplerKind kind);
absl::Status ParseSamplerKind(const std::string& name, SamplerKind* kind);

struct ModelOptions {
  HashGridOptions grid;
  NetworkOptions network;
  OccupancyGridOptions occupancy;
  MarchOptions march;
  SamplerKind sampler = SamplerKind::kAuto;
  ProposalOptions proposal;  // Used when the sampler is kProposal.
  absl::Status Validate() const;
};

// Floats of the proposal block (ModelParams::proposal) of a model built with
// `options`: 0 unless its sampler is kProposal. Checkpoint loading sizes the
// block with it before a model exists.
size_t ProposalParamCount(const ModelOptions& options);

// Trainable parameters, in three flat blocks.
struct ModelParams {
  std::vector<float> grid;  // Hash tables (HashGrid layout).
  std::vector<float> mlp;   // Both MLPs (Network layout).
  std::vector<float> emb;   // Embedding rows, one per time step.
  std::vector<float> proposal;  // Proposal fields, concatenated (empty without proposals).
};

class NgpModel {
 public:
  // Creates a randomly initialised model for `num_time_steps` steps.
  static absl::StatusOr<NgpModel> Create(const ModelOptions& options, const Normalization& norm,
                                         SceneKind kind, const Eigen::Vector3f& background,
                                         int num_time_steps, uint64_t seed);

  const ModelOptions& options() const { return options_; }
  const Normalization& normalization() const { return norm_; }
  SceneKind kind() const { return kind_; }
  const Eigen::Vector3f& background() const { return background_; }
  float bound() const { return norm_.bound; }
  const HashGrid& grid() const { return grid_; }
  const Network& network() const { return network_; }
  const OccupancyGrid& occupancy() const { return occupancy_; }
  OccupancyGrid& mutable_occupancy() { return occupancy_; }
  const ModelParams& params() const { return params_; }
  ModelParams& mutable_params() { return params_; }
  int num_time_steps() const { return num_time_steps_; }
  // True when samples are placed by the proposal fields (the sampler
  // resolved at creation; never kAuto).
  bool uses_proposals() const { return options_.sampler == SamplerKind::kProposal; }
  const ProposalField& proposal_field(int k) const { return proposal_fields_[k]; }
  size_t proposal_offset(int k) const { return k == 0 ? 0 : proposal_fields_[0].num_params(); }

  // Appends one embedding row (for a new time step) initialised from `seed`.
  void AddTimeStep(uint64_t seed);
  // Appends one embedding row that copies the last time step's row (a warm
  // start for a new scan of the same place). Needs num_time_steps() >= 1.
  void AddTimeStepCopyingLast();
  // Resets all weights, embeddings and the occupancy grid (re-init).
  void Reinitialize(uint64_t seed);

  // Bytes of the deployed model: parameters + occupancy bits + embeddings.
  // Parameter bytes plus the occupancy bitfield: the model's size.
  size_t num_bytes() const;
  // What it holds in memory: the parameters and the whole occupancy grid,
  // whose float densities (kept for the next update) usually outweigh them.
  size_t resident_bytes() const;
  size_t num_params() const;
  size_t num_proposal_params() const;
  // False if any parameter is NaN/Inf.
  bool AllFinite() const;

  // True for unbounded scenes, whose field and occupancy grid live in
  // contracted space (contraction.h): the model box is then the contracted
  // cube (-2, 2)^3 and the inner cube [-1, 1]^3 is model space unchanged.
  bool contracted() const { return kind_ == SceneKind::kUnbounded; }

  // Density sigma at n points (n x 3) of the occupancy grid's space (model
  // space, or contracted space when contracted()) for time step t (geometry
  // embedding). Parallel over points.
  void Density(const float* field_points, int n, int time_step, float* sigma) const;

  // Ray marching, dispatched on contracted(). RayInterval gives the model-space
  // interval [t0, t1] of the unit-direction ray o + t d to march (starting at
  // the near plane); false when the ray misses the box. StepAt is the step
  // length at t (used to jitter the first sample). March appends up to
  // max_count samples from t_start and returns where it stopped.
  bool RayInterval(const Eigen::Vector3f& o, const Eigen::Vector3f& d, float* t0, float* t1) const;
  float StepAt(const Eigen::Vector3f& o, const Eigen::Vector3f& d, float t) const;
  float March(const Eigen::Vector3f& o, const Eigen::Vector3f& d, float t_start, float t_end, int max_count,
              std::vector<RaySample>* out) const;

  // Occupancy refresh as in upstream: evaluates densities at jittered cell
  // positions chosen by the grid, using a random time step's geometry code.
  void UpdateOccupancy(int iteration, std::mt19937_64* rng);

  // Transforms a world-space camera into model space.
  Camera ToModelCamera(const Camera& world) const;

  // For checkpoints.
  static absl::StatusOr<NgpModel> FromParts(const ModelOptions& options, const Normalization& norm,
                                            SceneKind kind, const Eigen::Vector3f& background,
                                            int num_time_steps, ModelParams params);

 private:
  NgpModel(const ModelOptions& options, const Normalization& norm, SceneKind kind,
           const Eigen::Vector3f& background, int num_time_steps);

  ModelOptions options_;
  Normalization norm_;
  SceneKind kind_ = SceneKind::kBounded;
  Eigen::Vector3f background_ = Eigen::Vector3f::Ones();
  HashGrid grid_;
  Network network_;
  OccupancyGrid occupancy_;
  std::vector<ProposalField> proposal_fields_;
  ModelParams params_;
  int num_time_steps_ = 1;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_NGP_MODEL_H_
