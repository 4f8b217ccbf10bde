#include "core/continual/replay_confidence.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>

#include "absl/strings/str_cat.h"

namespace clnerf {

absl::Status ReplayConfidenceOptions::Validate() const {
  if (!(agreement_tolerance >= 0.0f && agreement_tolerance <= 1.0f)) {
    return absl::InvalidArgumentError(
        absl::StrCat("replay confidence: agreement_tolerance must be in [0, 1] (0 = off), got ", agreement_tolerance));
  }
  if (!(transmittance_weight >= 0.0f && transmittance_weight <= 1.0f)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "replay confidence: transmittance_weight must be in [0, 1] (0 = off), got ", transmittance_weight));
  }
  return absl::OkStatus();
}

float ConfidenceFactor(float disagreement, float opacity, const ReplayConfidenceOptions& options) {
  float f = 1.0f;
  if (options.agreement_tolerance > 0.0f && disagreement >= 0.0f) {
    const float r = disagreement / options.agreement_tolerance;
    f /= 1.0f + r * r;
  }
  if (options.transmittance_weight > 0.0f && std::isfinite(opacity)) {
    const float a = std::clamp(opacity, 0.0f, 1.0f);
    f *= 1.0f - options.transmittance_weight * 4.0f * a * (1.0f - a);
  }
  return f;
}

absl::Status ApplyReplayConfidence(const NgpModel* older, const std::vector<Camera>& cameras,
                                   const ReplayConfidenceOptions& options, const std::atomic<bool>* cancel,
                                   std::vector<ReplayLabelView>* labels, ReplayConfidenceReport* report) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (labels->size() != cameras.size()) {
    return absl::InvalidArgumentError(absl::StrCat("replay confidence: ", labels->size(), " label views for ",
                                                   cameras.size(), " cameras"));
  }
  const auto t0 = std::chrono::steady_clock::now();
  ReplayConfidenceReport rep;
  if (!options.enabled()) {
    if (report != nullptr) *report = rep;
    return absl::OkStatus();
  }
  RenderOptions ro;
  if (cancel != nullptr) ro.should_stop = [cancel] { return cancel->load(std::memory_order_relaxed); };
  double factor_sum = 0;
  std::vector<uint32_t> all;
  std::vector<float> older_rgb;
  for (size_t v = 0; v < cameras.size(); ++v) {
    if (cancel != nullptr && cancel->load()) return absl::CancelledError("update cancelled while weighting replay");
    ReplayLabelView& lv = (*labels)[v];
    const size_t n = lv.pixels.empty() ? lv.rgb.num_pixels() : lv.pixels.size();
    if (n == 0) continue;
    if (lv.opacity.size() != n) return absl::InvalidArgumentError("replay confidence: the labels carry no opacity");
    // θ_{t-2}'s render of the same pixels, when it knows their time step.
    const bool compare = options.agreement_tolerance > 0.0f && older != nullptr && cameras[v].time_step >= 0 &&
                         cameras[v].time_step < older->num_time_steps();
    if (compare) {
      const std::vector<uint32_t>* pixels = &lv.pixels;
      if (lv.pixels.empty()) {
        all.resize(n);
        std::iota(all.begin(), all.end(), 0u);
        pixels = &all;
      }
      older_rgb.resize(3 * n);
      if (!RenderLabelPixels(*older, cameras[v], *pixels, ro, older_rgb.data(), nullptr)) {
        return absl::CancelledError("update cancelled while weighting replay");
      }
      rep.compared += (long long)n;
    }
    if (lv.weight.empty()) lv.weight.assign(n, 1.0f);
    for (size_t k = 0; k < n; ++k) {
      float d = -1.0f;
      if (compare) {
        const float* a = lv.rgb.rgb.data() + 3 * k;
        const float* b = older_rgb.data() + 3 * k;
        d = (std::abs(a[0] - b[0]) + std::abs(a[1] - b[1]) + std::abs(a[2] - b[2])) / 3.0f;
      }
      const float f = ConfidenceFactor(d, lv.opacity[k], options);
      lv.weight[k] *= f;
      factor_sum += f;
    }
    rep.labels += (long long)n;
  }
  rep.mean_factor = rep.labels > 0 ? factor_sum / double(rep.labels) : 1.0;
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (report != nullptr) *report = rep;
  return absl::OkStatus();
}

}  // namespace clnerf
