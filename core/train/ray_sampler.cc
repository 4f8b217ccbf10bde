#include "core/train/ray_sampler.h"

#include <omp.h>

#include <memory>

#include "absl/strings/str_cat.h"

namespace clnerf {

void RayBatch::Resize(int n) {
  origin.resize(3 * size_t(n));
  dir.resize(3 * size_t(n));
  target.resize(3 * size_t(n));
  time_step.resize(n);
  weight.resize(n);
  robust.assign(n, 0);
}

void PixelRay(const Camera& cam, uint32_t pixel, float* origin, float* dir) {
  const int w = cam.intrinsics.width;
  const int x = int(pixel % uint32_t(w)), y = int(pixel / uint32_t(w));
  Eigen::Vector3f o, d;
  cam.Ray(x + 0.5f, y + 0.5f, &o, &d);
  for (int c = 0; c < 3; ++c) {
    origin[c] = o[c];
    dir[c] = d[c];
  }
}

absl::StatusOr<std::unique_ptr<ImageRaySampler>> ImageRaySampler::Create(const std::vector<const View*>& views,
                                                                         const NgpModel& model) {
  if (views.empty()) return absl::InvalidArgumentError("no training views");
  std::unique_ptr<ImageRaySampler> s(new ImageRaySampler());
  for (const View* v : views) {
    if (v->image.empty()) return absl::InvalidArgumentError(absl::StrCat("view '", v->name, "' has no image"));
    s->views_.push_back(v);
    s->cameras_.push_back(model.ToModelCamera(v->camera));
    std::vector<uint32_t> valid;
    if (!v->mask.empty()) {
      for (uint32_t i = 0; i < v->mask.keep.size(); ++i) {
        if (v->mask.keep[i]) valid.push_back(i);
      }
      if (valid.empty()) return absl::InvalidArgumentError(absl::StrCat("view '", v->name, "' is fully masked"));
    }
    s->valid_.push_back(std::move(valid));
  }
  return s;
}

void ImageRaySampler::Sample(int n, std::mt19937_64* rng, RayBatch* out) {
  out->Resize(n);
  const uint64_t base = (*rng)();
  const int nviews = int(views_.size());
#pragma omp parallel
  {
    std::mt19937_64 r(base + 0x9E3779B97F4A7C15ull * (omp_get_thread_num() + 1));
#pragma omp for schedule(static)
    for (int i = 0; i < n; ++i) {
      const int v = int(r() % uint64_t(nviews));
      const View& view = *views_[v];
      const std::vector<uint32_t>& valid = valid_[v];
      const uint32_t pixel = valid.empty() ? uint32_t(r() % view.image.num_pixels())
                                           : valid[r() % valid.size()];
      PixelRay(cameras_[v], pixel, &out->origin[3 * size_t(i)], &out->dir[3 * size_t(i)]);
      const float* px = view.image.rgb.data() + size_t(pixel) * 3;
      out->target[3 * size_t(i)] = px[0];
      out->target[3 * size_t(i) + 1] = px[1];
      out->target[3 * size_t(i) + 2] = px[2];
      out->time_step[i] = view.camera.time_step;
      out->weight[i] = 1.0f;
    }
  }
}

}  // namespace clnerf
