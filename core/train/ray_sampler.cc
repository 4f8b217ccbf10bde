#include "core/train/ray_sampler.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <memory>

#include "absl/strings/str_cat.h"
#include "core/render/renderer.h"

namespace clnerf {

void RayBatch::Resize(int n) {
  origin.resize(3 * size_t(n));
  dir.resize(3 * size_t(n));
  target.resize(3 * size_t(n));
  time_step.resize(n);
  weight.resize(n);
  robust.assign(n, 0);
  depth.assign(n, 0.0f);
  view.assign(n, -1);
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

long long RenderBatchRays(const NgpModel& model, const RayBatch& batch, const std::vector<int>& rays,
                          std::vector<float>* rgb) {
  rgb->resize(3 * size_t(batch.size()));
  std::vector<int> idx;
  std::vector<float> o, d, c;
  long long samples = 0;
  for (int t = 0; t < model.num_time_steps(); ++t) {
    idx.clear();
    for (int i : rays) {
      if (batch.time_step[i] == t) idx.push_back(i);
    }
    if (idx.empty()) continue;
    o.resize(3 * idx.size());
    d.resize(3 * idx.size());
    c.resize(3 * idx.size());
    for (size_t k = 0; k < idx.size(); ++k) {
      std::copy_n(&batch.origin[3 * size_t(idx[k])], 3, &o[3 * k]);
      std::copy_n(&batch.dir[3 * size_t(idx[k])], 3, &d[3 * k]);
    }
    samples += RenderRays(model, o.data(), d.data(), int(idx.size()), t, RenderOptions{}, c.data(), nullptr, nullptr);
    for (size_t k = 0; k < idx.size(); ++k) std::copy_n(&c[3 * k], 3, &(*rgb)[3 * size_t(idx[k])]);
  }
  return samples;
}

void SparseDepthTargets(const Camera& model_camera, const Normalization& norm, const std::vector<DepthPoint>& depth,
                        std::vector<uint32_t>* pixels, std::vector<float>* t) {
  const uint32_t npix = uint32_t(model_camera.intrinsics.width) * uint32_t(model_camera.intrinsics.height);
  for (const DepthPoint& d : depth) {
    if (d.pixel >= npix) continue;
    float o[3], dir[3];
    PixelRay(model_camera, d.pixel, o, dir);
    const Eigen::Vector3f x = norm.ToModel(d.world);
    const float dist = (x - Eigen::Map<const Eigen::Vector3f>(o)).dot(Eigen::Map<const Eigen::Vector3f>(dir));
    if (!(dist > 0.0f) || !std::isfinite(dist)) continue;
    pixels->push_back(d.pixel);
    t->push_back(dist);
  }
}

absl::StatusOr<std::unique_ptr<ImageRaySampler>> ImageRaySampler::Create(const std::vector<const View*>& views,
                                                                         const NgpModel& model,
                                                                         float depth_fraction) {
  if (views.empty()) return absl::InvalidArgumentError("no training views");
  if (!(depth_fraction >= 0.0f && depth_fraction <= 1.0f)) {
    return absl::InvalidArgumentError("depth_fraction must be in [0, 1]");
  }
  std::unique_ptr<ImageRaySampler> s(new ImageRaySampler());
  s->depth_fraction_ = depth_fraction;
  const Normalization& norm = model.normalization();
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
    std::vector<uint32_t> dpix;
    std::vector<float> dt;
    SparseDepthTargets(s->cameras_.back(), norm, v->depth, &dpix, &dt);
    if (!dpix.empty()) s->depth_views_.push_back(int(s->views_.size()) - 1);
    s->num_depth_pixels_ += (long long)dpix.size();
    s->depth_pixel_.push_back(std::move(dpix));
    s->depth_t_.push_back(std::move(dt));
  }
  return s;
}

void ImageRaySampler::SetViewErrorSampling(const ViewErrorOptions& options) {
  error_.reset();
  if (!(options.error_share > 0.0f) || views_.size() < 2) return;
  std::vector<ErrorSampledView> ev;
  for (size_t v = 0; v < views_.size(); ++v) {
    ev.push_back({views_[v]->image.width, views_[v]->image.height, valid_[v].empty() ? nullptr : &valid_[v]});
  }
  error_ = std::make_unique<ViewErrorSampler>(ViewErrorSampler::ForViews(ev, options));
}

void ImageRaySampler::ObserveErrors(const RayBatch& batch, const std::vector<float>& sq_err) {
  if (error_ == nullptr || last_cell_.size() != size_t(batch.size())) return;
  error_->Observe(last_cell_, sq_err);
}

void ImageRaySampler::Sample(int n, std::mt19937_64* rng, RayBatch* out) {
  out->Resize(n);
  const uint64_t base = (*rng)();
  const int nviews = int(views_.size());
  const int ndepth = depth_views_.empty() ? 0 : int(std::lround(depth_fraction_ * n));
  // Error sampling picks its views and pixels serially (one distribution).
  std::vector<ViewErrorSampler::Draw> draws;
  last_cell_.clear();
  if (error_ != nullptr && error_->enabled()) {
    last_cell_.assign(size_t(n), -1);
    draws.resize(size_t(n));
    for (int i = ndepth; i < n; ++i) {
      draws[i] = error_->PickRay(rng);
      last_cell_[i] = draws[i].cell;
    }
  }
#pragma omp parallel
  {
    std::mt19937_64 r(base + 0x9E3779B97F4A7C15ull * (omp_get_thread_num() + 1));
#pragma omp for schedule(static)
    for (int i = 0; i < n; ++i) {
      int v;
      uint32_t pixel;
      if (i < ndepth) {  // A sparse-depth pixel.
        v = depth_views_[r() % depth_views_.size()];
        const size_t k = r() % depth_pixel_[v].size();
        pixel = depth_pixel_[v][k];
        out->depth[i] = depth_t_[v][k];
      } else if (!draws.empty()) {
        v = draws[i].view;
        pixel = valid_[v].empty() ? draws[i].item : valid_[v][draws[i].item];
      } else {
        v = int(r() % uint64_t(nviews));
        const std::vector<uint32_t>& valid = valid_[v];
        pixel = valid.empty() ? uint32_t(r() % views_[v]->image.num_pixels()) : valid[r() % valid.size()];
      }
      const View& view = *views_[v];
      PixelRay(cameras_[v], pixel, &out->origin[3 * size_t(i)], &out->dir[3 * size_t(i)]);
      const float* px = view.image.rgb.data() + size_t(pixel) * 3;
      out->target[3 * size_t(i)] = px[0];
      out->target[3 * size_t(i) + 1] = px[1];
      out->target[3 * size_t(i) + 2] = px[2];
      out->time_step[i] = view.camera.time_step;
      out->weight[i] = 1.0f;
      out->view[i] = v;
    }
  }
}

}  // namespace clnerf
