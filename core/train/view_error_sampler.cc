#include "core/train/view_error_sampler.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace clnerf {

absl::Status ViewErrorOptions::Validate() const {
  if (!(error_share >= 0.0f && error_share < 1.0f)) {
    return absl::InvalidArgumentError(
        absl::StrCat("view error sampling: error_share must be in [0, 1) (0 = uniform), got ", error_share));
  }
  if (!(decay >= 0.0f && decay < 1.0f)) {
    return absl::InvalidArgumentError(absl::StrCat("view error sampling: decay must be in [0, 1), got ", decay));
  }
  return absl::OkStatus();
}

ViewErrorSampler::ViewErrorSampler(int num_views, const ViewErrorOptions& options)
    : num_views_(std::max(0, num_views)), options_(options), sum_(num_views_, 0.0), count_(num_views_, 0.0) {}

int ViewErrorSampler::Pick(std::mt19937_64* rng) const {
  if (num_views_ <= 0) return 0;
  if (cdf_.empty()) return int((*rng)() % uint64_t(num_views_));
  const double u = std::uniform_real_distribution<double>(0.0, cdf_.back())(*rng);
  const auto it = std::upper_bound(cdf_.begin(), cdf_.end(), u);
  return std::min(num_views_ - 1, int(it - cdf_.begin()));
}

double ViewErrorSampler::Error(int v) const {
  if (prior_ < 0 || v < 0 || v >= num_views_) return 0.0;
  return (sum_[v] + prior_) / (count_[v] + 1.0);
}

void ViewErrorSampler::Observe(const std::vector<int>& view, const std::vector<float>& sq_err) {
  if (!enabled()) return;
  const size_t n = std::min(view.size(), sq_err.size());
  double total = 0;
  long long rays = 0;
  for (double& s : sum_) s *= options_.decay;
  for (double& c : count_) c *= options_.decay;
  for (size_t i = 0; i < n; ++i) {
    const int v = view[i];
    const float e = sq_err[i];
    if (v < 0 || v >= num_views_ || !std::isfinite(e)) continue;
    sum_[v] += e;
    count_[v] += 1.0;
    total += e;
    ++rays;
  }
  if (prior_ < 0) {
    if (rays == 0) return;
    prior_ = total / double(rays);
  }
  std::vector<double> p = Probabilities();
  cdf_.resize(p.size());
  double acc = 0;
  for (size_t v = 0; v < p.size(); ++v) cdf_[v] = acc += p[v];
}

std::vector<double> ViewErrorSampler::Probabilities() const {
  std::vector<double> p(num_views_, num_views_ > 0 ? 1.0 / num_views_ : 0.0);
  if (prior_ < 0 || !enabled()) return p;
  double esum = 0;
  for (int v = 0; v < num_views_; ++v) esum += Error(v);
  if (!(esum > 0)) return p;
  const double a = options_.error_share;
  for (int v = 0; v < num_views_; ++v) p[v] = (1.0 - a) / num_views_ + a * Error(v) / esum;
  return p;
}

}  // namespace clnerf
