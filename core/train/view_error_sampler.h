// ViewErrorSampler: picks training views in proportion to how badly the
// model currently fits them, as instant-ngp's error map picks pixels, but per
// view. A share `error_share` of the draws goes to views in proportion to
// their running mean squared colour error; the rest stays uniform over views,
// so every view keeps being drawn and its error estimate stays current.
//
// In a continual update the views the model already renders well (replay
// labels, which θ_t starts out matching exactly) have near-zero error and the
// new scan's views a large one, so the batch's rays go where there is
// something to learn; once an old view drifts, its error and its share rise.
//
// Each view's error is an exponentially decayed mean of the squared errors of
// its rays: S_v <- decay S_v + sum of errors, C_v <- decay C_v + rays, and
// e_v = (S_v + prior) / (C_v + 1), prior = the first observed batch's mean
// error (a view not yet drawn counts as average).
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
  // Share of draws proportional to error, in [0, 1). 0 = uniform over views.
  float error_share = 0.0f;
  // Per-step decay of the error sums (about 1 / (1 - decay) steps of memory).
  float decay = 0.9f;
  absl::Status Validate() const;
};

class ViewErrorSampler {
 public:
  ViewErrorSampler(int num_views, const ViewErrorOptions& options);
  bool enabled() const { return options_.error_share > 0.0f && num_views_ > 1; }
  // A view index in [0, num_views); uniform until the first Observe().
  int Pick(std::mt19937_64* rng) const;
  // One step's rays: view[i] (< 0 or >= num_views: ignored) and its squared
  // colour error sq_err[i]. Decays the sums and rebuilds the distribution.
  void Observe(const std::vector<int>& view, const std::vector<float>& sq_err);
  // The current probability of each view (uniform before any Observe()).
  std::vector<double> Probabilities() const;
  // The current error estimate of view v (0 before any Observe()).
  double Error(int v) const;

 private:
  int num_views_;
  ViewErrorOptions options_;
  double prior_ = -1;  // < 0: nothing observed yet.
  std::vector<double> sum_, count_;
  std::vector<double> cdf_;  // Cumulative probabilities; empty = uniform.
};

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_VIEW_ERROR_SAMPLER_H_
