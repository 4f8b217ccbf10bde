// DeploymentGate: the checks a freshly trained θ_t must pass before the
// server publishes it. This is where "stability where methods fail" meets the
// product: a diverged or forgetful update is refused with a reason and
// θ_{t-1} stays deployed.
//
// Checks, in order (the first failure is reported, metrics are filled as far
// as they were computed):
//  1. every parameter of θ_t is finite;
//  2. PSNR on the new scan's held-out test frames (or, without any, on an
//     evenly spaced subset of its training frames) >= min_new_psnr, and, when
//     the place's own quality is known (the same PSNR of the version it
//     updates), at most max_new_psnr_drop_db below it;
//  3. on the real images buffered from earlier scans, θ_t's PSNR is at most
//     max_replay_drop_db below θ_{t-1}'s, counting θ_{t-1}'s only up to
//     what the place generalises to (replay_memorised_margin_db);
//  4. on other past views (cameras only), θ_t's render matches θ_{t-1}'s to
//     at least min_replay_consistency_psnr.
//
// The server runs it before every publish; `clnerf bench stability` runs it
// after every update to decide what would have been deployed.
//
// Thread-safety: a pure function of const inputs.
#ifndef CLNERF_CORE_CONTINUAL_DEPLOYMENT_GATE_H_
#define CLNERF_CORE_CONTINUAL_DEPLOYMENT_GATE_H_

#include <map>
#include <string>

#include "absl/status/status.h"
#include "core/field/ngp_model.h"
#include "core/continual/replay_memory.h"
#include "core/data/scene.h"

namespace clnerf {

// Thresholds of the gate (defaults suit the server's updates; the server's
// config file can override each).
struct GateOptions {
  // Minimum PSNR (dB) of θ_t on the new scan's held-out test frames (on up to
  // `validation_views` of its training frames when the upload has none).
  float min_new_psnr = 15.0f;
  // Relative to the place: the largest drop (dB) of that PSNR below the
  // previous version's (a scan trained in the wrong frame scores far below
  // what the place reached: 20.2 against 28.0 dB on a room; the fixed floor
  // alone let it through). 0 = off.
  float max_new_psnr_drop_db = 5.0f;
  // Past views: the largest PSNR drop (dB) of θ_t against θ_{t-1} allowed on
  // the buffered real images of earlier scans.
  float max_replay_drop_db = 2.0f;
  // A buffered image is one θ_{t-1} trained on: what it scores there above
  // the place's held-out quality (place_psnr) is memorised pixels, not
  // quality, and any further training shakes it loose. A tiny 32 x 32 place
  // trained 2000 steps scored 45.4 dB on its buffered images and 24.5 on
  // held-out views; a 120-step update then scored 27.1 on the buffered
  // images and was refused. So θ_{t-1}'s buffered PSNR counts only up to
  // place_psnr + this margin. < 0 = no cap (or when place_psnr is unknown).
  float replay_memorised_margin_db = 2.0f;
  // Past views without a real image: minimum PSNR of θ_t against θ_{t-1}'s
  // own render (generative-replay consistency).
  float min_replay_consistency_psnr = 18.0f;
  // Views rendered per check (evenly spaced), to bound validation time.
  int validation_views = 8;
  absl::Status Validate() const;
};

// Check 3 alone: OK, or FAILED_PRECONDITION with the reason, for θ_{t-1}'s
// (`before`) and θ_t's (`after`) PSNR on the buffered images; `place_psnr`
// as for RunDeploymentGate (0 = unknown).
absl::Status CheckReplayDrop(double before, double after, double place_psnr, const GateOptions& options);

struct GateReport {
  absl::Status status;  // OK = publish; FAILED_PRECONDITION with the reason otherwise.
  std::map<std::string, double> metrics;
};

// `scan` holds the new scan (time steps already assigned). `prev` and
// `prev_memory` are null for the first version. `place_psnr`: the previous
// version's PSNR on its own new scan, measured the same way (held-out, or
// training frames); 0 = unknown.
GateReport RunDeploymentGate(const NgpModel& next, const Scene& scan, const NgpModel* prev,
                             const ReplayMemory* prev_memory, const GateOptions& options, int threads,
                             double place_psnr = 0);

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_DEPLOYMENT_GATE_H_
