// OptimizerState: Adam's state for a model, carried from one training run to
// the next so that a continual sequence is one optimisation instead of a
// fresh start per update (UNIKD's finding: resetting the optimiser and the
// learning-rate schedule at every step costs accuracy).
//
// It holds the first and second moments of the model's parameter blocks
// (hash grid, MLPs, embeddings, proposal fields: the layout of ModelParams)
// and the number of Adam steps taken, which drives the bias correction and a
// horizon-free learning-rate schedule (TrainOptions::lr_schedule). A model
// that grew since (a new time step appends an embedding row) resumes with
// zero moments for the new entries; any other size mismatch is refused.
// The per-photo colour transforms are not carried: they belong to one run's
// photos.
//
// Serialized form (little-endian): magic "CLOS", uint32 version, uint64
// step, uint32 block count, then per block uint64 n, n float32 m, n float32
// v. Exact: a round trip reproduces every bit.
//
// A value type without locking.
#ifndef CLNERF_CORE_TRAIN_OPTIMIZER_STATE_H_
#define CLNERF_CORE_TRAIN_OPTIMIZER_STATE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/field/ngp_model.h"

namespace clnerf {

struct OptimizerState {
  // Block order: 0 grid, 1 mlp, 2 emb, 3 proposal (ModelParams).
  static constexpr int kBlocks = 4;
  uint64_t step = 0;  // Adam steps taken so far.
  std::vector<float> m[kBlocks], v[kBlocks];

  size_t bytes() const;
  // OK if it can resume training `params`: every block the same size, except
  // the embeddings, which may have grown by whole rows.
  absl::Status CompatibleWith(const ModelParams& params) const;

  std::string Serialize() const;
  // DATA_LOSS on truncated or inconsistent bytes, FAILED_PRECONDITION on an
  // unknown format version.
  static absl::StatusOr<OptimizerState> Deserialize(const std::string& bytes);
};

bool operator==(const OptimizerState& a, const OptimizerState& b);

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_OPTIMIZER_STATE_H_
