// ContinualRaySampler: training rays for a continual update, drawn from
// views of three kinds: the new scan (ground truth), buffered past images
// (experience replay, ground truth) and generative-replay views whose labels
// are θ_{t-1}'s renders. Uniform mode picks a view uniformly over all of them
// (CLNeRF); MEIL mode draws a fixed fraction of rays from new views and the
// rest from replay views, with a Charbonnier loss whose weight rises with
// training progress. Generative-replay labels come either from a float cache
// rendered once (offline) or from the frozen model per batch (online).
//
// Views and images are referenced, not copied: they must outlive the sampler.
// Sample() is called by one thread at a time (it parallelises internally).
#ifndef CLNERF_CORE_CONTINUAL_CONTINUAL_SAMPLER_H_
#define CLNERF_CORE_CONTINUAL_CONTINUAL_SAMPLER_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "core/field/ngp_model.h"
#include "core/train/ray_sampler.h"
#include "core/train/view_error_sampler.h"

namespace clnerf {

struct SamplerView {
  Camera camera;                 // World space.
  const Image* image = nullptr;  // GT or cached replay label; null = online replay.
  const Mask* mask = nullptr;
  bool replay = false;           // Generative replay (label from θ_{t-1}).
  bool past = false;             // From an earlier scan (buffered image or replay).
  // Sparse-depth targets (the new scan's View::depth; may be null).
  const std::vector<DepthPoint>* depth = nullptr;
  // Labels for a subset of the view's pixels only (replay_labels.h): label k
  // (image->rgb[3k..3k+2]) is pixel (*label_pixels)[k]; rays are drawn from
  // these pixels. Null = `image` covers every pixel.
  const std::vector<uint32_t>* label_pixels = nullptr;
  // Loss weight per label (replay_weights.h), indexed as the labels are;
  // null = 1.
  const std::vector<float>* label_weight = nullptr;
  // Depth-distillation target per label (ReplayLabelView::target_depth),
  // indexed as the labels are, copied to RayBatch::depth; null = none.
  const std::vector<float>* label_depth = nullptr;
};

class ContinualRaySampler : public RaySampler {
 public:
  // `model` defines model space; `frozen` renders online replay labels (may
  // be null if no view needs it). meil_new_fraction <= 0 means uniform.
  // Uniform mode with new_share > 0: that fraction of each batch comes from
  // the new scan's views (uniform among them), the rest uniformly from past
  // views; new_share <= 0 is uniform over all views (the paper).
  // When views carry sparse depth, `depth_fraction` of each batch is drawn
  // from their depth pixels first (as ImageRaySampler does).
  ContinualRaySampler(std::vector<SamplerView> views, const NgpModel& model, const NgpModel* frozen,
                      float meil_new_fraction, float new_share = 0.0f, float depth_fraction = 0.0f);
  void Sample(int n, std::mt19937_64* rng, RayBatch* out) override;
  std::vector<Camera> Cameras() const override { return model_cameras_; }
  void SetCamera(int view, const Camera& model_camera) override { model_cameras_.at(size_t(view)) = model_camera; }
  // RayBatch::view indexes `views` (photos only; replay rays carry -1).
  int NumPhotoViews() const override { return int(views_.size()); }
  // Pixels with a sparse-depth target over all views.
  long long num_depth_pixels() const {
    long long n = 0;
    for (const auto& p : depth_pixel_) n += (long long)p.size();
    return n;
  }
  void SetProgress(float progress) override { progress_ = progress; }
  // Uniform mode: draw views (or tiles of views, options.tiles) partly in
  // proportion to their current error (view_error_sampler.h) instead of
  // uniformly. Off until called with error_share > 0.
  void SetViewErrorSampling(const ViewErrorOptions& options);
  void ObserveErrors(const RayBatch& batch, const std::vector<float>& sq_err) override;
  // Each view's current probability of being drawn (summed over its tiles).
  std::vector<double> ViewProbabilities() const;

 private:
  // pixel < 0: a random unmasked pixel (or label, for label views); label
  // >= 0: that label of a label view.
  void FillRay(int view, std::mt19937_64& r, RayBatch* out, int i, std::vector<int>* online, int64_t pixel = -1,
               int64_t label = -1);

  std::vector<SamplerView> views_;
  std::vector<Camera> model_cameras_;
  std::vector<std::vector<uint32_t>> valid_;
  std::vector<int> new_views_, replay_views_;  // By `replay` (MEIL).
  std::vector<int> current_views_, past_views_;  // By `past` (new_share).
  const NgpModel* frozen_;
  float meil_new_fraction_;
  float new_share_;
  float progress_ = 0;
  float depth_fraction_ = 0;
  // Error sampling (null = off); cells are tiles_ x tiles_ tiles of each view.
  std::unique_ptr<ViewErrorSampler> error_;
  int tiles_ = 1;
  std::vector<int> last_cell_;  // The cell of each ray of the last batch (-1: none).
  std::vector<int> depth_views_;
  std::vector<std::vector<uint32_t>> depth_pixel_;
  std::vector<std::vector<float>> depth_t_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_CONTINUAL_SAMPLER_H_
