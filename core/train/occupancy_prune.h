// OccupancyPrune: after training, drops occupancy cells whose density is too
// low to change any training pixel, so rendering marches fewer samples.
//
// Training keeps a cell occupied while its density EMA exceeds a low bar
// (OccupancyGrid), and on captures with bare walls much of the box ends up
// occupied by faint haze: beer_2 had 67% of its cells occupied and 240-320
// samples per ray. Pruning probes each occupied cell's density (the maximum
// over a few jittered points and over every time step's geometry code), then
// tries thresholds from a ladder, lowest first, and keeps the highest whose
// PSNR on a fixed set of training pixels stays within `max_psnr_drop` of the
// unpruned model. Only the occupancy bits change; the field does not.
//
// Not thread-safe with respect to the model (it mutates its occupancy grid);
// uses OpenMP threads internally.
#ifndef CLNERF_CORE_TRAIN_OCCUPANCY_PRUNE_H_
#define CLNERF_CORE_TRAIN_OCCUPANCY_PRUNE_H_

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/scene.h"
#include "core/field/ngp_model.h"

namespace clnerf {

struct PruneOptions {
  int probes_per_cell = 4;        // Jittered density probes per occupied cell.
  int calibration_rays = 8192;    // Training pixels the PSNR is checked on.
  float max_psnr_drop = 0.05f;    // dB allowed on those pixels.
  // Candidate thresholds, as fractions of the grid's own threshold (which is
  // 0.01 / min_step: a fraction k is an opacity of ~0.01 k per finest step),
  // tried in increasing order.
  std::vector<float> ladder = {0.001f, 0.002f, 0.005f, 0.01f, 0.02f, 0.05f, 0.1f};
  uint64_t seed = 1;
  absl::Status Validate() const;
};

struct PruneReport {
  size_t cells_before = 0, cells_after = 0;  // Occupied cells.
  float threshold = 0;                       // Density threshold applied (0 = nothing pruned).
  double psnr_before = 0, psnr_after = 0;    // On the calibration pixels.
  double samples_before = 0, samples_after = 0;  // Per calibration ray.
};

// Prunes `model`'s occupancy grid using training `views` (with images) as
// calibration. Proposal models have no grid to prune: returned unchanged
// with an empty report. INVALID_ARGUMENT for bad options or no usable view.
absl::StatusOr<PruneReport> PruneOccupancy(NgpModel* model, const std::vector<const View*>& views,
                                           const PruneOptions& options);

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_OCCUPANCY_PRUNE_H_
