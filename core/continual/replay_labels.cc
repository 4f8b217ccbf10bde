#include "core/continual/replay_labels.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>

#include "absl/strings/str_format.h"
#include "core/render/renderer.h"
#include "core/train/ray_sampler.h"

namespace clnerf {

absl::Status ReplayLabelOptions::Validate() const {
  if (!(labels_per_draw >= 0) || !std::isfinite(labels_per_draw)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("replay labels: labels_per_draw must be >= 0 (0 = every pixel), got %g", labels_per_draw));
  }
  if (probe_rays < 1) return absl::InvalidArgumentError("replay labels: probe_rays must be >= 1");
  if (!(depth_min_opacity >= 0 && depth_min_opacity <= 1)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "replay labels: depth_min_opacity must be in [0, 1] (0 = no depth distillation), got %g", depth_min_opacity));
  }
  return absl::OkStatus();
}

long long SetDistillationDepths(float min_opacity, ReplayLabelView* view) {
  view->target_depth.clear();
  const size_t n = view->depth.size();
  if (min_opacity <= 0 || n == 0 || view->opacity.size() != n) return 0;
  view->target_depth.assign(n, 0.0f);
  long long targets = 0;
  for (size_t k = 0; k < n; ++k) {
    const float a = view->opacity[k], d = view->depth[k];
    if (a >= min_opacity && d > 0 && std::isfinite(d)) {
      view->target_depth[k] = d / a;
      ++targets;
    }
  }
  return targets;
}

namespace {

uint64_t NumPixels(const Camera& c) { return uint64_t(c.intrinsics.width) * uint64_t(c.intrinsics.height); }

}  // namespace

bool RenderLabelPixels(const NgpModel& model, const Camera& world, const std::vector<uint32_t>& pixels,
                       const RenderOptions& ro, float* rgb, long long* samples, float* opacity, float* depth) {
  const Camera cam = model.ToModelCamera(world);
  std::vector<float> o(3 * pixels.size()), d(3 * pixels.size());
  for (size_t k = 0; k < pixels.size(); ++k) PixelRay(cam, pixels[k], &o[3 * k], &d[3 * k]);
  const long long s = RenderRays(model, o.data(), d.data(), int(pixels.size()), world.time_step, ro, rgb, opacity,
                                 depth);
  if (s < 0) return false;
  if (samples != nullptr) *samples += s;
  return true;
}

double ProbeSamplesPerRay(const NgpModel& model, const std::vector<Camera>& cameras, int probe_rays, uint64_t seed) {
  if (cameras.empty() || probe_rays < 1) return 0;
  std::mt19937_64 rng(seed);
  // Rays per camera, at least one camera's worth of spread.
  std::vector<std::vector<uint32_t>> pixels(cameras.size());
  for (int i = 0; i < probe_rays; ++i) {
    const size_t v = rng() % cameras.size();
    const uint64_t n = NumPixels(cameras[v]);
    if (n > 0) pixels[v].push_back(uint32_t(rng() % n));
  }
  long long samples = 0, rays = 0;
  std::vector<float> rgb;
  for (size_t v = 0; v < cameras.size(); ++v) {
    if (pixels[v].empty()) continue;
    rgb.resize(3 * pixels[v].size());
    if (RenderLabelPixels(model, cameras[v], pixels[v], RenderOptions{}, rgb.data(), &samples)) rays += pixels[v].size();
  }
  return rays > 0 ? double(samples) / double(rays) : 0.0;
}

long long LabelsPerView(double expected_draws, int num_views, const ReplayLabelOptions& options) {
  constexpr long long kAll = std::numeric_limits<long long>::max();
  if (options.labels_per_draw <= 0 || !(expected_draws > 0) || num_views < 1) return kAll;
  const double per_view = std::ceil(double(options.labels_per_draw) * expected_draws / double(num_views));
  return per_view >= 9e18 ? kAll : std::max(1LL, (long long)per_view);
}

absl::StatusOr<std::vector<ReplayLabelView>> RenderReplayLabels(
    const NgpModel& model, const std::vector<Camera>& cameras, long long labels_per_view, uint64_t seed,
    const std::atomic<bool>* cancel, const std::function<void(int, int)>& progress, ReplayLabelReport* report) {
  ReplayLabelReport rep;
  std::vector<ReplayLabelView> out;
  out.reserve(cameras.size());
  RenderOptions ro;
  if (cancel != nullptr) ro.should_stop = [cancel] { return cancel->load(std::memory_order_relaxed); };
  std::mt19937_64 rng(seed);
  std::vector<uint32_t> all;
  for (size_t v = 0; v < cameras.size(); ++v) {
    if (cancel != nullptr && cancel->load()) return absl::CancelledError("update cancelled while preparing replay");
    const Camera& cam = cameras[v];
    const uint64_t n = NumPixels(cam);
    rep.view_pixels += (long long)n;
    ReplayLabelView lv;
    if (labels_per_view <= 0 || uint64_t(labels_per_view) >= n) {
      // The whole view, as one image render.
      RenderOptions whole = ro;
      whole.time_step = cam.time_step;
      absl::StatusOr<RenderedView> r = RenderView(model, cam, whole);
      if (absl::IsCancelled(r.status())) return absl::CancelledError("update cancelled while preparing replay");
      if (!r.ok()) return r.status();
      lv.rgb = std::move(r->rgb);
      lv.opacity = std::move(r->opacity);
      lv.depth = std::move(r->depth);
      for (float& z : lv.depth) z *= model.normalization().scale;  // World to model units.
      rep.labels += (long long)n;
    } else {
      // A partial Fisher-Yates shuffle picks the subset; sorted, the rays
      // render in scanline order (coherent hash-grid reads).
      all.resize(n);
      std::iota(all.begin(), all.end(), 0u);
      for (long long k = 0; k < labels_per_view; ++k) {
        const uint64_t j = uint64_t(k) + rng() % (n - uint64_t(k));
        std::swap(all[k], all[j]);
      }
      lv.pixels.assign(all.begin(), all.begin() + labels_per_view);
      std::sort(lv.pixels.begin(), lv.pixels.end());
      lv.rgb = Image(int(lv.pixels.size()), 1);
      lv.opacity.resize(lv.pixels.size());
      lv.depth.resize(lv.pixels.size());
      if (!RenderLabelPixels(model, cam, lv.pixels, ro, lv.rgb.rgb.data(), nullptr, lv.opacity.data(), lv.depth.data())) {
        return absl::CancelledError("update cancelled while preparing replay");
      }
      rep.labels += labels_per_view;
    }
    rep.bytes += (lv.rgb.rgb.size() + lv.depth.size() + lv.opacity.size()) * sizeof(float) +
                 lv.pixels.size() * sizeof(uint32_t);
    out.push_back(std::move(lv));
    if (progress) progress(int(v + 1), int(cameras.size()));
  }
  if (report != nullptr) *report = rep;
  return out;
}

}  // namespace clnerf
