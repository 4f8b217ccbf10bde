#include "core/continual/replay_weights.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "core/data/sparse_depth.h"
#include "core/render/renderer.h"
#include "core/train/ray_sampler.h"

namespace clnerf {

absl::Status ReplayWeightOptions::Validate() const {
  if (!(seen_weight >= 0.0f && seen_weight <= 1.0f)) {
    return absl::InvalidArgumentError(absl::StrCat("replay weights: seen_weight must be in [0, 1], got ", seen_weight));
  }
  if (!(colour_tolerance > 0.0f && colour_tolerance <= 1.0f)) {
    return absl::InvalidArgumentError("replay weights: colour_tolerance must be in (0, 1]");
  }
  if (!(depth_tolerance >= 0.0f && depth_tolerance <= 1.0f)) {
    return absl::InvalidArgumentError("replay weights: depth_tolerance must be in [0, 1]");
  }
  if (!(min_opacity > 0.0f && min_opacity <= 1.0f)) {
    return absl::InvalidArgumentError("replay weights: min_opacity must be in (0, 1]");
  }
  if (depth_map_max_side < 4 || depth_map_max_side > 4096) {
    return absl::InvalidArgumentError("replay weights: depth_map_max_side must be in [4, 4096]");
  }
  return absl::OkStatus();
}

bool SeenByNewView(const Eigen::Vector3f& x, const float* rgb, const View& view, const Camera& cam,
                   const NewViewDepth& dm, const ReplayWeightOptions& options, float* photo_rgb) {
  Eigen::Vector2f p;
  float z;
  if (!ProjectPoint(cam, x, &p, &z)) return false;
  const int w = cam.intrinsics.width, h = cam.intrinsics.height;
  const int px = std::min(w - 1, int(p.x())), py = std::min(h - 1, int(p.y()));
  const size_t pixel = size_t(py) * size_t(w) + size_t(px);
  if (!view.mask.empty() && !view.mask.keep[pixel]) return false;
  // Occlusion: θ_{t-1}'s depth along the new camera's ray through x.
  const Intrinsics& si = dm.small.intrinsics;
  const int sx = std::min(si.width - 1, int(p.x() * float(si.width) / float(w)));
  const int sy = std::min(si.height - 1, int(p.y() * float(si.height) / float(h)));
  const float visible = dm.depth[size_t(sy) * size_t(si.width) + size_t(sx)];
  const float dist = (x - cam.position()).norm();
  if (!(dist <= visible * (1.0f + options.depth_tolerance))) return false;
  // Photo-consistency: the surface still looks as θ_{t-1} remembers it.
  const float* c = view.image.rgb.data() + 3 * pixel;
  const float diff = (std::abs(c[0] - rgb[0]) + std::abs(c[1] - rgb[1]) + std::abs(c[2] - rgb[2])) / 3.0f;
  if (!(diff <= options.colour_tolerance)) return false;
  if (photo_rgb != nullptr) std::copy_n(c, 3, photo_rgb);
  return true;
}

absl::Status WeightReplayLabels(const NgpModel& prev, const std::vector<Camera>& cameras,
                                const std::vector<View>& new_views, const ReplayWeightOptions& options,
                                const std::atomic<bool>* cancel, std::vector<ReplayLabelView>* labels,
                                ReplayWeightReport* report) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (labels->size() != cameras.size()) {
    return absl::InvalidArgumentError(absl::StrCat("replay weights: ", labels->size(), " label views for ",
                                                   cameras.size(), " cameras"));
  }
  const auto t0 = std::chrono::steady_clock::now();
  ReplayWeightReport rep;
  if ((options.seen_weight >= 1.0f && !options.seen_label_from_photo) || new_views.empty() ||
      prev.num_time_steps() < 1) {
    if (report != nullptr) *report = rep;
    return absl::OkStatus();
  }
  // θ_{t-1}'s depth maps of the new views' photos, at its newest time step.
  std::vector<const View*> photos;
  std::vector<Camera> new_cams;
  std::vector<NewViewDepth> maps;
  for (const View& v : new_views) {
    if (v.image.empty()) continue;
    const Camera cam = prev.ToModelCamera(v.camera);
    const int w = cam.intrinsics.width, h = cam.intrinsics.height;
    const float f = std::min(1.0f, float(options.depth_map_max_side) / float(std::max(w, h)));
    const int sw = std::max(1, int(std::lround(float(w) * f))), sh = std::max(1, int(std::lround(float(h) * f)));
    NewViewDepth dm;
    dm.small = cam;
    dm.small.intrinsics = cam.intrinsics.Scaled(sw, sh);
    dm.depth.resize(size_t(sw) * size_t(sh));
    std::vector<float> o(3 * dm.depth.size()), d(3 * dm.depth.size()), rgb(3 * dm.depth.size());
    for (uint32_t k = 0; k < uint32_t(dm.depth.size()); ++k) PixelRay(dm.small, k, &o[3 * k], &d[3 * k]);
    RenderOptions ro;
    if (cancel != nullptr) ro.should_stop = [cancel] { return cancel->load(std::memory_order_relaxed); };
    if (RenderRays(prev, o.data(), d.data(), int(dm.depth.size()), prev.num_time_steps() - 1, ro, rgb.data(), nullptr,
                   dm.depth.data()) < 0) {
      return absl::CancelledError("update cancelled while weighting replay");
    }
    photos.push_back(&v);
    new_cams.push_back(cam);
    maps.push_back(std::move(dm));
  }
  for (size_t v = 0; v < cameras.size(); ++v) {
    if (cancel != nullptr && cancel->load()) return absl::CancelledError("update cancelled while weighting replay");
    ReplayLabelView& lv = (*labels)[v];
    const size_t n = lv.pixels.empty() ? lv.rgb.num_pixels() : lv.pixels.size();
    if (lv.depth.size() != n || lv.opacity.size() != n) {
      return absl::InvalidArgumentError("replay weights: the labels carry no depth and opacity");
    }
    const Camera cam = prev.ToModelCamera(cameras[v]);
    std::vector<char> seen(n, 0);
    long long nseen = 0;
#pragma omp parallel for schedule(static) reduction(+ : nseen)
    for (long long k = 0; k < (long long)n; ++k) {
      if (!(lv.opacity[k] >= options.min_opacity) || !(lv.depth[k] > 0.0f)) continue;
      float o[3], d[3];
      PixelRay(cam, lv.pixels.empty() ? uint32_t(k) : lv.pixels[k], o, d);
      const Eigen::Vector3f x = Eigen::Map<const Eigen::Vector3f>(o) + lv.depth[k] * Eigen::Map<const Eigen::Vector3f>(d);
      float* rgb = lv.rgb.rgb.data() + 3 * k;
      float photo[3];
      for (size_t j = 0; j < photos.size(); ++j) {
        if (SeenByNewView(x, rgb, *photos[j], new_cams[j], maps[j], options, photo)) {
          if (options.seen_label_from_photo) std::copy_n(photo, 3, rgb);
          seen[k] = 1;
          ++nseen;
          break;
        }
      }
    }
    rep.labels += (long long)n;
    rep.seen += nseen;
    if (options.seen_weight > 0.0f) {
      lv.weight.assign(n, 1.0f);
      for (size_t k = 0; k < n; ++k) {
        if (seen[k]) lv.weight[k] = options.seen_weight;
      }
      continue;
    }
    // Weight 0: seen labels leave the view (a whole view becomes a list of
    // its unseen pixels); a view left with none has rgb empty.
    if (nseen == 0) continue;
    ReplayLabelView kept;
    kept.rgb = Image(int(n - size_t(nseen)), n == size_t(nseen) ? 0 : 1);
    size_t m = 0;
    for (size_t k = 0; k < n; ++k) {
      if (seen[k]) continue;
      kept.pixels.push_back(lv.pixels.empty() ? uint32_t(k) : lv.pixels[k]);
      std::copy_n(&lv.rgb.rgb[3 * k], 3, &kept.rgb.rgb[3 * m]);
      kept.depth.push_back(lv.depth[k]);
      kept.opacity.push_back(lv.opacity[k]);
      ++m;
    }
    lv = std::move(kept);
  }
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (report != nullptr) *report = rep;
  return absl::OkStatus();
}

}  // namespace clnerf
