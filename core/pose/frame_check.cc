#include "core/pose/frame_check.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "core/data/stopwatch.h"

namespace clnerf {

namespace {

// Grey values of `im` averaged over each cell of a w x h grid (area
// resampling: no aliasing of fine texture at a small size).
std::vector<float> GreyArea(const Image& im, int w, int h) {
  std::vector<double> sum(size_t(w) * h, 0.0), count(size_t(w) * h, 0.0);
  for (int y = 0; y < im.height; ++y) {
    const int ty = std::min(h - 1, int((y + 0.5) * h / im.height));
    for (int x = 0; x < im.width; ++x) {
      const int tx = std::min(w - 1, int((x + 0.5) * w / im.width));
      sum[size_t(ty) * w + tx] += Luma(im.pixel(x, y));
      count[size_t(ty) * w + tx] += 1;
    }
  }
  std::vector<float> out(sum.size());
  for (size_t i = 0; i < out.size(); ++i) out[i] = count[i] > 0 ? float(sum[i] / count[i]) : 0.f;
  return out;
}

// Separable Gaussian blur in place (edges clamped).
void Blur(std::vector<float>* v, int w, int h, float sigma) {
  if (sigma <= 0) return;
  const int r = std::max(1, int(std::ceil(2.5f * sigma)));
  std::vector<float> k(size_t(2 * r + 1));
  float total = 0;
  for (int i = -r; i <= r; ++i) total += k[size_t(i + r)] = std::exp(-0.5f * i * i / (sigma * sigma));
  for (float& x : k) x /= total;
  std::vector<float> tmp(v->size());
  for (int pass = 0; pass < 2; ++pass) {
    const std::vector<float>& src = pass == 0 ? *v : tmp;
    std::vector<float>& dst = pass == 0 ? tmp : *v;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        float s = 0;
        for (int i = -r; i <= r; ++i) {
          const int xx = pass == 0 ? std::clamp(x + i, 0, w - 1) : x;
          const int yy = pass == 1 ? std::clamp(y + i, 0, h - 1) : y;
          s += k[size_t(i + r)] * src[size_t(yy) * w + xx];
        }
        dst[size_t(y) * w + x] = s;
      }
    }
  }
}

double Correlation(const std::vector<float>& a, const std::vector<float>& b) {
  double ma = 0, mb = 0;
  for (size_t i = 0; i < a.size(); ++i) ma += a[i], mb += b[i];
  ma /= double(a.size());
  mb /= double(b.size());
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double da = a[i] - ma, db = b[i] - mb;
    sab += da * db;
    saa += da * da;
    sbb += db * db;
  }
  if (saa <= 1e-12 || sbb <= 1e-12) return 0;  // A flat image agrees with nothing.
  return sab / std::sqrt(saa * sbb);
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

absl::Status FrameCheckOptions::Validate() const {
  if (max_side < 16) return absl::InvalidArgumentError("frame check: max_side must be at least 16");
  if (!(blur_sigma >= 0)) return absl::InvalidArgumentError("frame check: blur_sigma must be >= 0");
  if (!(min_relative >= 0 && min_relative <= 1)) {
    return absl::InvalidArgumentError("frame check: min_relative must be in [0, 1]");
  }
  if (!(max_drop_correlation >= -1 && max_drop_correlation <= 1)) {
    return absl::InvalidArgumentError("frame check: max_drop_correlation must be in [-1, 1]");
  }
  if (!(max_drop_fraction >= 0 && max_drop_fraction <= 1)) {
    return absl::InvalidArgumentError("frame check: max_drop_fraction must be in [0, 1]");
  }
  return absl::OkStatus();
}

absl::StatusOr<double> FrameAgreement(const PlaceMap& map, const Image& photo, const Camera& camera,
                                      const FrameCheckOptions& options) {
  if (photo.width != camera.intrinsics.width || photo.height != camera.intrinsics.height) {
    return absl::InvalidArgumentError(absl::StrCat("frame check: the photo is ", photo.width, "x", photo.height,
                                                   ", its camera ", camera.intrinsics.width, "x",
                                                   camera.intrinsics.height));
  }
  const Camera small = CameraWithSideIn(camera, options.max_side, options.max_side);
  absl::StatusOr<MapView> view = map.Render(small);
  if (!view.ok()) return view.status();
  const int w = small.intrinsics.width, h = small.intrinsics.height;
  std::vector<float> a = GreyArea(photo, w, h), b = GreyArea(view->rgb, w, h);
  Blur(&a, w, h, options.blur_sigma);
  Blur(&b, w, h, options.blur_sigma);
  return Correlation(a, b);
}

absl::StatusOr<FrameCheckReport> CheckScanFrames(const PlaceMap& map, const Scene& scene,
                                                 const std::vector<bool>& verified,
                                                 const FrameCheckOptions& options, const std::atomic<bool>* cancel) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  const auto t0 = std::chrono::steady_clock::now();
  FrameCheckReport r;
  std::vector<double> ref, all;
  for (size_t i = 0; i < scene.train.size(); ++i) {
    if (cancel != nullptr && cancel->load()) return absl::CancelledError("frame check cancelled");
    const View& v = scene.train[i];
    absl::StatusOr<double> a = FrameAgreement(map, v.image, v.camera, options);
    if (!a.ok()) return a.status();
    r.agreement.push_back(*a);
    all.push_back(*a);
    if (i < verified.size() && verified[i]) ref.push_back(*a);
  }
  r.reference = Median(ref.empty() ? all : ref);
  const double limit = std::min(options.min_relative * r.reference, options.max_drop_correlation);
  for (size_t i = 0; i < r.agreement.size(); ++i) {
    const bool checked = i < verified.size() && verified[i];
    if (!checked && r.agreement[i] < limit) r.dropped.push_back(int(i));
  }
  if (double(r.dropped.size()) > options.max_drop_fraction * double(scene.train.size())) {
    r.capped = true;
    r.dropped.clear();
  }
  r.seconds = SecondsSince(t0);
  return r;
}

void DropCheckedFrames(const FrameCheckReport& report, Scene* scene) {
  std::vector<View> kept;
  size_t d = 0;
  for (size_t i = 0; i < scene->train.size(); ++i) {
    if (d < report.dropped.size() && report.dropped[d] == int(i)) {
      ++d;
      continue;
    }
    kept.push_back(std::move(scene->train[i]));
  }
  scene->train = std::move(kept);
}

}  // namespace clnerf
