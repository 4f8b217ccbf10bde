#include "core/continual/continual_sampler.h"

#include <algorithm>
#include <cmath>


namespace clnerf {

ContinualRaySampler::ContinualRaySampler(std::vector<SamplerView> views, const NgpModel& model,
                                         const NgpModel* frozen, float meil_new_fraction, float new_share,
                                         float depth_fraction)
    : views_(std::move(views)),
      frozen_(frozen),
      meil_new_fraction_(meil_new_fraction),
      new_share_(new_share),
      depth_fraction_(depth_fraction) {
  for (size_t v = 0; v < views_.size(); ++v) {
    model_cameras_.push_back(model.ToModelCamera(views_[v].camera));
    std::vector<uint32_t> valid;
    if (views_[v].mask != nullptr && !views_[v].mask->empty()) {
      for (uint32_t i = 0; i < views_[v].mask->keep.size(); ++i) {
        if (views_[v].mask->keep[i]) valid.push_back(i);
      }
    }
    valid_.push_back(std::move(valid));
    (views_[v].replay ? replay_views_ : new_views_).push_back(int(v));
    (views_[v].past ? past_views_ : current_views_).push_back(int(v));
    std::vector<uint32_t> dpix;
    std::vector<float> dt;
    if (views_[v].depth != nullptr && views_[v].image != nullptr && views_[v].label_pixels == nullptr) {
      SparseDepthTargets(model_cameras_.back(), model.normalization(), *views_[v].depth, &dpix, &dt);
    }
    if (!dpix.empty()) depth_views_.push_back(int(v));
    depth_pixel_.push_back(std::move(dpix));
    depth_t_.push_back(std::move(dt));
  }
}

void ContinualRaySampler::SetViewErrorSampling(const ViewErrorOptions& options) {
  error_.reset();
  if (!(options.error_share > 0.0f) || views_.empty()) return;
  std::vector<ErrorSampledView> ev;
  for (size_t v = 0; v < views_.size(); ++v) {
    const SamplerView& view = views_[v];
    ErrorSampledView e{view.camera.intrinsics.width, view.camera.intrinsics.height, nullptr};
    if (view.label_pixels != nullptr) {
      e.pixels = view.label_pixels;
    } else if (!valid_[v].empty()) {
      e.pixels = &valid_[v];
    }
    ev.push_back(e);
  }
  error_ = std::make_unique<ViewErrorSampler>(ViewErrorSampler::ForViews(ev, options));
  tiles_ = std::clamp(options.tiles, 1, 64);
}

std::vector<double> ContinualRaySampler::ViewProbabilities() const {
  std::vector<double> p(views_.size(), views_.empty() ? 0.0 : 1.0 / double(views_.size()));
  if (error_ == nullptr) return p;
  const std::vector<double> cells = error_->Probabilities();
  const size_t per_view = size_t(tiles_) * size_t(tiles_);
  for (size_t v = 0; v < views_.size(); ++v) {
    p[v] = 0;
    for (size_t t = 0; t < per_view; ++t) p[v] += cells[v * per_view + t];
  }
  return p;
}

void ContinualRaySampler::ObserveErrors(const RayBatch& batch, const std::vector<float>& sq_err) {
  if (error_ == nullptr || !error_->enabled() || last_cell_.size() != size_t(batch.size())) return;
  error_->Observe(last_cell_, sq_err);
}

void ContinualRaySampler::FillRay(int v, std::mt19937_64& r, RayBatch* out, int i, std::vector<int>* online,
                                  int64_t given_pixel, int64_t given_label) {
  const SamplerView& view = views_[v];
  const Intrinsics& in = view.camera.intrinsics;
  const std::vector<uint32_t>& valid = valid_[v];
  uint32_t pixel;
  size_t label;  // Index of the pixel's label in view.image.
  if (view.label_pixels != nullptr && given_pixel < 0) {
    label = given_label >= 0 ? size_t(given_label) : r() % view.label_pixels->size();
    pixel = (*view.label_pixels)[label];
  } else {
    pixel = given_pixel >= 0 ? uint32_t(given_pixel)
            : valid.empty()  ? uint32_t(r() % (uint64_t(in.width) * in.height))
                             : valid[r() % valid.size()];
    label = pixel;
  }
  PixelRay(model_cameras_[v], pixel, &out->origin[3 * size_t(i)], &out->dir[3 * size_t(i)]);
  out->time_step[i] = view.camera.time_step;
  out->weight[i] = view.label_weight != nullptr && label < view.label_weight->size() ? (*view.label_weight)[label] : 1.0f;
  if (view.label_depth != nullptr && label < view.label_depth->size()) out->depth[i] = (*view.label_depth)[label];
  out->robust[i] = 0;
  out->view[i] = view.replay ? -1 : v;  // Photos (new scan, buffered) have their own colour transform.
  if (view.image != nullptr) {
    const float* px = view.image->rgb.data() + label * 3;
    for (int c = 0; c < 3; ++c) out->target[3 * size_t(i) + c] = px[c];
  } else {
    online->push_back(i);
  }
}

void ContinualRaySampler::Sample(int n, std::mt19937_64* rng, RayBatch* out) {
  out->Resize(n);
  std::vector<int> online;
  const bool meil = meil_new_fraction_ > 0 && !replay_views_.empty() && !new_views_.empty();
  const bool shared = !meil && new_share_ > 0 && !past_views_.empty() && !current_views_.empty();
  const int n_new = meil ? int(std::lround(n * meil_new_fraction_)) : shared ? int(std::lround(n * new_share_)) : n;
  // MEIL-NeRF's replay weight rises from 0 to 1 with progress r.
  const float meil_weight = 0.5f * (std::cos(float(M_PI) * (1.0f + progress_)) + 1.0f);
  std::mt19937_64& r = *rng;
  // Sparse-depth rays first (new-scan views with known depths).
  const int ndepth = depth_views_.empty() ? 0 : int(std::lround(depth_fraction_ * n));
  const bool by_error = !meil && !shared && error_ != nullptr && error_->enabled();
  last_cell_.assign(by_error ? size_t(n) : 0, -1);
  for (int i = 0; i < ndepth; ++i) {
    const int v = depth_views_[r() % depth_views_.size()];
    const size_t k = r() % depth_pixel_[v].size();
    FillRay(v, r, out, i, nullptr, depth_pixel_[v][k]);
    out->depth[i] = depth_t_[v][k];
  }
  for (int i = ndepth; i < n; ++i) {
    int v;
    if (shared) {
      v = i < n_new ? current_views_[r() % current_views_.size()] : past_views_[r() % past_views_.size()];
    } else if (by_error) {
      const ViewErrorSampler::Draw d = error_->PickRay(&r);
      last_cell_[i] = d.cell;
      const SamplerView& view = views_[d.view];
      if (view.label_pixels != nullptr) {
        FillRay(d.view, r, out, i, &online, -1, d.item);
      } else {
        FillRay(d.view, r, out, i, &online, valid_[d.view].empty() ? int64_t(d.item) : int64_t(valid_[d.view][d.item]));
      }
      continue;
    } else if (!meil) {
      v = int(r() % views_.size());
    } else if (i < n_new) {
      v = new_views_[r() % new_views_.size()];
    } else {
      v = replay_views_[r() % replay_views_.size()];
    }
    FillRay(v, r, out, i, &online);
    if (meil && views_[v].replay) {
      out->robust[i] = 1;
      out->weight[i] *= meil_weight;
    }
  }
  if (online.empty() || frozen_ == nullptr) return;
  // Online generative replay: the frozen θ_{t-1} renders the replay rays,
  // each with its time step's embeddings. Rays are in this model's space;
  // both models share the normalisation.
  std::vector<float> rgb;
  RenderBatchRays(*frozen_, *out, online, &rgb);
  for (int i : online) std::copy_n(&rgb[3 * size_t(i)], 3, &out->target[3 * size_t(i)]);
}

}  // namespace clnerf
