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
  if (tiles < 1 || tiles > 64) {
    return absl::InvalidArgumentError(absl::StrCat("view error sampling: tiles must be in [1, 64], got ", tiles));
  }
  return absl::OkStatus();
}

ViewErrorSampler::ViewErrorSampler(std::vector<double> base, const ViewErrorOptions& options)
    : options_(options), base_(std::move(base)), sum_(base_.size(), 0.0), count_(base_.size(), 0.0) {
  double total = 0;
  for (double& b : base_) total += b = std::isfinite(b) && b > 0 ? b : 0.0;
  for (double& b : base_) b = total > 0 ? b / total : 1.0 / double(base_.size());
  cdf_.resize(base_.size());
  double acc = 0;
  for (size_t c = 0; c < base_.size(); ++c) cdf_[c] = acc += base_[c];
}

ViewErrorSampler ViewErrorSampler::ForViews(const std::vector<ErrorSampledView>& views,
                                            const ViewErrorOptions& options) {
  const int tiles = std::clamp(options.tiles, 1, 64), per_view = tiles * tiles;
  std::vector<std::vector<uint32_t>> items(views.size() * size_t(per_view));
  std::vector<double> base(items.size(), 0.0);
  for (size_t v = 0; v < views.size(); ++v) {
    const ErrorSampledView& view = views[v];
    const int w = std::max(1, view.width), h = std::max(1, view.height);
    const size_t first = v * size_t(per_view);
    double total = 0;
    if (view.pixels != nullptr) {
      for (uint32_t k = 0; k < view.pixels->size(); ++k) {
        const uint32_t p = (*view.pixels)[k];
        const int x = int(p % uint32_t(w)), y = std::min(h - 1, int(p / uint32_t(w)));
        items[first + size_t(y * tiles / h) * size_t(tiles) + size_t(x * tiles / w)].push_back(k);
      }
      for (int t = 0; t < per_view; ++t) total += base[first + t] = double(items[first + t].size());
    } else {
      for (int t = 0; t < per_view; ++t) {
        const int tx = t % tiles, ty = t / tiles;
        total += base[first + t] =
            double((tx + 1) * w / tiles - tx * w / tiles) * double((ty + 1) * h / tiles - ty * h / tiles);
      }
    }
    for (int t = 0; t < per_view && total > 0; ++t) base[first + t] /= total;
  }
  ViewErrorOptions o = options;
  o.tiles = tiles;
  ViewErrorSampler s(std::move(base), o);
  s.views_ = views;
  s.items_ = std::move(items);
  return s;
}

ViewErrorSampler::Draw ViewErrorSampler::PickRay(std::mt19937_64* rng) const {
  Draw d;
  d.cell = Pick(rng);
  if (views_.empty()) return d;
  const int tiles = options_.tiles, per_view = tiles * tiles;
  d.view = d.cell / per_view;
  const ErrorSampledView& view = views_[d.view];
  const std::vector<uint32_t>& items = items_[d.cell];
  if (view.pixels != nullptr) {
    d.item = items.empty() ? 0u : items[(*rng)() % items.size()];
    return d;
  }
  const int w = std::max(1, view.width), h = std::max(1, view.height);
  const int t = d.cell % per_view, tx = t % tiles, ty = t / tiles;
  const int x0 = tx * w / tiles, x1 = (tx + 1) * w / tiles, y0 = ty * h / tiles, y1 = (ty + 1) * h / tiles;
  const int x = x0 + int((*rng)() % uint64_t(std::max(1, x1 - x0)));
  const int y = y0 + int((*rng)() % uint64_t(std::max(1, y1 - y0)));
  d.item = uint32_t(y) * uint32_t(w) + uint32_t(x);
  return d;
}

int ViewErrorSampler::Pick(std::mt19937_64* rng) const {
  if (cdf_.empty()) return 0;
  const double u = std::uniform_real_distribution<double>(0.0, cdf_.back())(*rng);
  int c = int(std::upper_bound(cdf_.begin(), cdf_.end(), u) - cdf_.begin());
  c = std::min(c, num_cells() - 1);
  while (c > 0 && base_[c] == 0.0) --c;  // Never a cell that cannot be drawn (u at a boundary).
  return c;
}

double ViewErrorSampler::Error(int c) const {
  if (prior_ < 0 || c < 0 || c >= num_cells()) return 0.0;
  return (sum_[c] + prior_) / (count_[c] + 1.0);
}

void ViewErrorSampler::Observe(const std::vector<int>& cell, const std::vector<float>& sq_err) {
  if (!enabled()) return;
  const size_t n = std::min(cell.size(), sq_err.size());
  double total = 0;
  long long rays = 0;
  for (double& s : sum_) s *= options_.decay;
  for (double& c : count_) c *= options_.decay;
  for (size_t i = 0; i < n; ++i) {
    const int c = cell[i];
    const float e = sq_err[i];
    if (c < 0 || c >= num_cells() || base_[c] == 0.0 || !std::isfinite(e)) continue;
    sum_[c] += e;
    count_[c] += 1.0;
    total += e;
    ++rays;
  }
  if (prior_ < 0) {
    if (rays == 0) return;
    prior_ = total / double(rays);
  }
  const std::vector<double> p = Probabilities();
  double acc = 0;
  for (size_t c = 0; c < p.size(); ++c) cdf_[c] = acc += p[c];
}

std::vector<double> ViewErrorSampler::Probabilities() const {
  if (prior_ < 0 || !enabled()) return base_;
  double esum = 0;
  for (int c = 0; c < num_cells(); ++c) esum += base_[c] > 0 ? Error(c) : 0.0;
  if (!(esum > 0)) return base_;
  const double a = options_.error_share;
  std::vector<double> p(base_.size());
  for (int c = 0; c < num_cells(); ++c) p[c] = base_[c] > 0 ? (1.0 - a) * base_[c] + a * Error(c) / esum : 0.0;
  return p;
}

}  // namespace clnerf
