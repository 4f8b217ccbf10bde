#include "core/render/evaluate.h"

#include <chrono>
#include <filesystem>

#include "absl/strings/str_format.h"
#include "core/render/metrics.h"
#include "core/render/speckle.h"

namespace clnerf {

absl::Status EvalOptions::Validate() const {
  if (max_views < 0) return absl::InvalidArgumentError("eval: max_views must be >= 0");
  return render.Validate();
}

double ConstantColourPsnr(const std::vector<View>& train, const std::vector<View>& test) {
  double mean[3] = {0, 0, 0}, n = 0;
  for (const View& v : train) {
    for (size_t i = 0; i < v.image.num_pixels(); ++i)
      for (int c = 0; c < 3; ++c) mean[c] += v.image.rgb[3 * i + c];
    n += double(v.image.num_pixels());
  }
  double mse = 0, count = 0;
  for (const View& v : test) {
    for (size_t i = 0; i < v.image.num_pixels(); ++i)
      for (int c = 0; c < 3; ++c) {
        const double e = v.image.rgb[3 * i + c] - mean[c] / n;
        mse += e * e;
        count += 1;
      }
  }
  return PsnrFromMse(mse / count);
}

absl::StatusOr<EvalResult> EvaluateViews(const NgpModel& model, const std::vector<View>& views,
                                         const EvalOptions& options) {
  return EvaluateWith(
      [&](const View& v) {
        RenderOptions ro = options.render;
        ro.time_step = std::min(v.camera.time_step, model.num_time_steps() - 1);
        return RenderView(model, v.camera, ro);
      },
      views, options);
}

absl::StatusOr<EvalResult> EvaluateWith(const ViewRenderer& render, const std::vector<View>& views,
                                        const EvalOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (views.empty()) return absl::InvalidArgumentError("no views to evaluate");
  std::vector<size_t> pick;
  if (options.max_views > 0 && size_t(options.max_views) < views.size()) {
    for (int i = 0; i < options.max_views; ++i) pick.push_back(size_t(i) * views.size() / options.max_views);
  } else {
    for (size_t i = 0; i < views.size(); ++i) pick.push_back(i);
  }
  if (!options.save_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(options.save_dir, ec);
    if (ec) return absl::InternalError(absl::StrFormat("cannot create '%s': %s", options.save_dir, ec.message()));
  }
  EvalResult result;
  for (size_t k : pick) {
    const View& v = views[k];
    if (v.image.empty()) return absl::InvalidArgumentError(absl::StrFormat("view '%s' has no image", v.name));
    const auto t0 = std::chrono::steady_clock::now();
    absl::StatusOr<RenderedView> r = render(v);
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!r.ok()) return r.status();
    absl::StatusOr<ImageMetrics> m = ComputeImageMetrics(r->rgb, v.image);
    if (!m.ok()) return m.status();
    absl::StatusOr<DetailScore> detail = ScoreDetail(r->rgb, v.image);
    if (!detail.ok()) return detail.status();
    result.views.push_back(
        {v.name, v.camera.time_step, m->psnr, m->ssim, secs, m->psnr_cc, detail->speckle, detail->blur});
    if (!options.save_dir.empty()) {
      // "r_0" and "r_0.png" both become 0000_r_0.png (not r_0.png.png).
      const std::string stem = std::filesystem::path(v.name).stem().string();
      const std::string base = absl::StrFormat("%s/%04d_%s", options.save_dir, int(k), stem);
      if (absl::Status s = WriteImage(base + ".png", r->rgb); !s.ok()) return s;
      // The photo it is scored against, beside it (as the metrics see it:
      // RGBA photos composited on the background).
      if (absl::Status s = WriteImage(base + ".photo.png", v.image); !s.ok()) return s;
    }
  }
  for (const ViewScore& s : result.views) {
    result.psnr += s.psnr;
    result.ssim += s.ssim;
    result.psnr_cc += s.psnr_cc;
    result.speckle += s.speckle;
    result.blur += s.blur;
    result.mean_render_seconds += s.render_seconds;
  }
  const double n = double(result.views.size());
  result.psnr /= n;
  result.ssim /= n;
  result.psnr_cc /= n;
  result.speckle /= n;
  result.blur /= n;
  result.mean_render_seconds /= n;
  return result;
}

}  // namespace clnerf
