// ViewErrorSampler: picks where training rays come from in proportion to how
// badly the model currently fits them, as instant-ngp's error map picks
// pixels. The unit is a cell: a view, or a tile of a view (ViewErrorOptions::
// tiles). A share `error_share` of the draws goes to cells in proportion to
// their running mean squared colour error; the rest follows each cell's base
// probability (uniform over views, then over pixels: the paper's sampling),
// so every cell keeps being drawn and its error estimate stays current.
//
// In a continual update the views the model already renders well (replay
// labels, which θ_t starts out matching exactly) have near-zero error and the
// new scan's views a large one, so the batch's rays go where there is
// something to learn; once an old view drifts, its error and its share rise.
//
// Each cell's error is an exponentially decayed mean of the squared errors of
// its rays: S_c <- decay S_c + sum of errors, C_c <- decay C_c + rays, and
// e_c = (S_c + prior) / (C_c + 1), prior = the first observed batch's mean
// error (a cell not yet drawn counts as average).
//
// Not thread-safe: one sampler thread calls Pick() and Observe().
#ifndef CLNERF_CORE_TRAIN_VIEW_ERROR_SAMPLER_H_
#define CLNERF_CORE_TRAIN_VIEW_ERROR_SAMPLER_H_

#include <cstdint>
#include <random>
#include <vector>

#include "absl/status/status.h"

namespace clnerf {

struct ViewErrorOptions {
  // Share of draws proportional to error, in [0, 1). 0 = off (the base
  // sampling: uniform over views, then over pixels).
  float error_share = 0.0f;
  // Per-step decay of the error sums (about 1 / (1 - decay) steps of memory).
  float decay = 0.9f;
  // Cells per view: tiles x tiles rectangles of each image (1 = whole views).
  int tiles = 1;
  absl::Status Validate() const;
};

// One image the sampler draws from: its size and, optionally, the only
// pixels that may be drawn (a mask's unmasked pixels, or the pixels a replay
// view has labels for); null = every pixel.
struct ErrorSampledView {
  int width = 0, height = 0;
  const std::vector<uint32_t>* pixels = nullptr;
};

class ViewErrorSampler {
 public:
  // Cells = options.tiles x options.tiles tiles of each view; base = uniform
  // over views, then over each view's drawable pixels.
  static ViewErrorSampler ForViews(const std::vector<ErrorSampledView>& views, const ViewErrorOptions& options);
  // A draw: its cell, view, and `item`: an index into the view's `pixels`
  // when it has them, else a pixel id.
  struct Draw {
    int cell = 0, view = 0;
    uint32_t item = 0;
  };
  Draw PickRay(std::mt19937_64* rng) const;

  // base[c] >= 0: cell c's probability without error sampling (normalised
  // here; 0 = never drawn, e.g. a tile with no pixel to draw).
  ViewErrorSampler(std::vector<double> base, const ViewErrorOptions& options);
  int num_cells() const { return int(base_.size()); }
  bool enabled() const { return options_.error_share > 0.0f && base_.size() > 1; }
  // A cell index in [0, num_cells()), drawn from Probabilities().
  int Pick(std::mt19937_64* rng) const;
  // One step's rays: cell[i] (< 0 or >= num_cells: ignored) and its squared
  // colour error sq_err[i] (NaN/Inf: ignored). Decays the sums and rebuilds
  // the distribution.
  void Observe(const std::vector<int>& cell, const std::vector<float>& sq_err);
  // The current probability of each cell (the base before any Observe()).
  std::vector<double> Probabilities() const;
  // The current error estimate of cell c (0 before any Observe()).
  double Error(int c) const;

 private:
  ViewErrorOptions options_;
  std::vector<double> base_;
  double prior_ = -1;  // < 0: nothing observed yet.
  std::vector<double> sum_, count_;
  std::vector<double> cdf_;  // Cumulative probabilities.
  // ForViews: the views and each cell's items (indices into the view's
  // pixels; empty for a view without `pixels`, whose tile is a rectangle).
  std::vector<ErrorSampledView> views_;
  std::vector<std::vector<uint32_t>> items_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_VIEW_ERROR_SAMPLER_H_
