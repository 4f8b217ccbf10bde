// Stability matrix: "test stability where methods fail". One cell runs a
// continual method (nt, ewc, er, meil, clnerf, clnerf-noer) or the upper
// bound (ub) through a small procedural changing scene under one stressor,
// the way the server would run it: every update's result goes through the
// deployment gate (core/continual/deployment_gate.h); an update that fails (e.g.
// INTERNAL "training diverged") or is refused by the gate leaves θ_{t-1}
// deployed, and the next scan continues from it.
//
// The stressor hits the last update of the sequence (the "stressed update");
// earlier updates run with the defaults, so there is a deployed θ_{t-1} to
// protect. Stressors:
//   none          the control;
//   iters_x5      5x the iterations;
//   lr_x3, lr_x10 the learning rate times 3 and 10;
//   chain_20      20 scans, each warm-started from the last;
//   blank_scan    a scan of near-constant grey images (lens cap on);
//   single_view   a scan with one training view;
//   far_cameras   a scan whose cameras sit 5x farther out than before, far
//                 outside the scene box the first scan set;
//   nan_gradient  a NaN injected into one gradient halfway through;
//   stale_memory  θ_{t-1} paired with the replay memory of the version
//                 before it (not applicable to ub, which has none).
// Each cell records whether the stressed update was deployed, why not, the
// final PSNR of whatever is deployed, and two invariants that must hold in
// every cell: no deployed model has a non-finite parameter, and θ_{t-1}
// (parameters and replay memory) is bit-identical after every update,
// successful or not.
//
// Thread-safety: RunStabilityCell is reentrant (no shared state); it uses
// options.threads OpenMP threads.
#ifndef CLNERF_CORE_CONTINUAL_STABILITY_H_
#define CLNERF_CORE_CONTINUAL_STABILITY_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/field/capacity.h"
#include "core/continual/deployment_gate.h"

namespace clnerf {

enum class Stressor {
  kNone,
  kItersX5,
  kLrX3,
  kLrX10,
  kChain20,
  kBlankScan,
  kSingleView,
  kFarCameras,
  kNanGradient,
  kStaleMemory,
};

const std::vector<Stressor>& AllStressors();
const char* StressorName(Stressor s);
absl::StatusOr<Stressor> ParseStressor(const std::string& name);

struct StabilityOptions {
  int scans = 3;            // Scans of the procedural sequence (chain_20: chain_scans).
  int chain_scans = 20;     // Scans for chain_20.
  int image_size = 32;      // Square images of the procedural scans.
  int train_views = 12;     // Per scan.
  int test_views = 4;       // Per scan.
  int iterations = 100;     // Per update (ub: scans x this, as `bench continual`).
  int buffer = 10;          // K for clnerf / er.
  int batch_samples = 1 << 15;  // TrainOptions::target_samples (rays adapt); small scans need few.
  uint64_t seed = 0;
  int threads = 0;          // 0 = all cores.
  GateOptions gate;         // The server's defaults.
  ModelOptions model;       // Base model options (capacity is derived from the scans as usual).
  CapacityOptions capacity;
  absl::Status Validate() const;
};

struct StabilityCell {
  std::string method;
  Stressor stressor = Stressor::kNone;
  bool applicable = true;     // false: the stressor means nothing for this method (ub + stale_memory).
  int updates = 0;            // Updates attempted (ub: 1).
  int failed = 0;             // Updates that returned an error (no model).
  int refused = 0;            // Updates whose model the gate refused.
  bool stressed_deployed = false;  // The stressed update's model was deployed.
  std::string reason;         // Why the stressed update was not deployed (or the first failure of a chain).
  int skipped_batches = 0;    // Training batches skipped as NaN/Inf (see TrainOptions::max_bad_batches).
  bool has_model = false;     // Something is deployed at the end.
  double psnr = 0;            // Mean test PSNR of the deployed model over the scans it holds.
  // The stressed update's own model when the gate refused it: its mean test
  // PSNR over the scans it would have held (what the gate kept from users).
  double refused_psnr = 0;
  int scored_scans = 0;
  bool deployed_always_finite = true;   // Invariant.
  bool previous_always_intact = true;   // Invariant: θ_{t-1} and M_{t-1} bit-identical after each update.
  double seconds = 0;
  // "31.20", "diverged -> refused", "refused by gate (18.20)", "n/a";
  // chains with refusals add " (k refused)".
  std::string Summary() const;
};

// method: nt | ewc | er | meil | clnerf | clnerf-noer | ub.
absl::StatusOr<StabilityCell> RunStabilityCell(const std::string& method, Stressor stressor,
                                               const StabilityOptions& options);

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_STABILITY_H_
