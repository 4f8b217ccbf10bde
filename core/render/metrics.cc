#include "core/render/metrics.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>

#include "absl/strings/str_cat.h"
#include "Eigen/Dense"

namespace clnerf {
namespace {

constexpr int kWin = kSsimWindowSize;
constexpr int kRadius = (kWin - 1) / 2;
constexpr double kSigma = 1.5;
constexpr double kC1 = (0.01 * 1.0) * (0.01 * 1.0);  // (K1 * data_range)^2
constexpr double kC2 = (0.03 * 1.0) * (0.03 * 1.0);  // (K2 * data_range)^2
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Normalised 1-D Gaussian taps at offsets -5..5 (torchmetrics `_gaussian`).
const std::array<double, kWin>& GaussianTaps() {
  static const std::array<double, kWin> taps = [] {
    std::array<double, kWin> g{};
    double sum = 0;
    for (int k = 0; k < kWin; ++k) {
      const double d = k - kRadius;
      g[k] = std::exp(-(d * d) / (2.0 * kSigma * kSigma));
      sum += g[k];
    }
    for (double& v : g) v /= sum;
    return g;
  }();
  return taps;
}

bool WellFormed(const Image& im) {
  return im.width > 0 && im.height > 0 && im.rgb.size() == im.num_pixels() * 3;
}

bool SameSize(const Image& a, const Image& b) {
  return WellFormed(a) && WellFormed(b) && a.width == b.width && a.height == b.height;
}

// Sum of the SSIM map of channel `c` over the valid region. Rows are filtered
// horizontally into a ring of kWin rows, then combined vertically.
double SsimChannelSum(const Image& a, const Image& b, int c) {
  const int w = a.width, h = a.height;
  const int ow = w - kWin + 1;
  const std::array<double, kWin>& g = GaussianTaps();

  // Per input row: the five signals x, y, x^2, y^2, xy.
  std::vector<double> in(size_t(5) * w);
  // Ring of horizontally filtered rows: slot s holds 5 arrays of ow values.
  std::vector<double> ring(size_t(kWin) * 5 * ow);
  std::vector<double> acc(size_t(5) * ow);
  double total = 0.0;

  for (int r = 0; r < h; ++r) {
    const float* pa = a.rgb.data() + size_t(r) * w * 3 + c;
    const float* pb = b.rgb.data() + size_t(r) * w * 3 + c;
    double* ix = in.data();
    double* iy = ix + w;
    double* ixx = iy + w;
    double* iyy = ixx + w;
    double* ixy = iyy + w;
    for (int j = 0; j < w; ++j) {
      const double x = pa[size_t(j) * 3], y = pb[size_t(j) * 3];
      ix[j] = x;
      iy[j] = y;
      ixx[j] = x * x;
      iyy[j] = y * y;
      ixy[j] = x * y;
    }
    double* slot = ring.data() + size_t(r % kWin) * 5 * ow;
    for (int q = 0; q < 5; ++q) {
      const double* src = in.data() + size_t(q) * w;
      double* dst = slot + size_t(q) * ow;
      for (int j = 0; j < ow; ++j) dst[j] = g[0] * src[j];
      for (int k = 1; k < kWin; ++k) {
        const double gk = g[k];
        const double* s = src + k;
        for (int j = 0; j < ow; ++j) dst[j] += gk * s[j];
      }
    }
    if (r < kWin - 1) continue;

    // Vertical pass for output row i = r - (kWin - 1), using ring rows i..r.
    const int i = r - (kWin - 1);
    for (int k = 0; k < kWin; ++k) {
      const double gk = g[k];
      const double* src = ring.data() + size_t((i + k) % kWin) * 5 * ow;
      if (k == 0) {
        for (size_t n = 0; n < acc.size(); ++n) acc[n] = gk * src[n];
      } else {
        for (size_t n = 0; n < acc.size(); ++n) acc[n] += gk * src[n];
      }
    }
    const double* mx = acc.data();
    const double* my = mx + ow;
    const double* exx = my + ow;
    const double* eyy = exx + ow;
    const double* exy = eyy + ow;
    double row_sum = 0.0;
    for (int j = 0; j < ow; ++j) {
      const double mu_x = mx[j], mu_y = my[j];
      const double mu_xx = mu_x * mu_x, mu_yy = mu_y * mu_y, mu_xy = mu_x * mu_y;
      const double s_xx = exx[j] - mu_xx;
      const double s_yy = eyy[j] - mu_yy;
      const double s_xy = exy[j] - mu_xy;
      row_sum += ((2.0 * mu_xy + kC1) * (2.0 * s_xy + kC2)) /
                 ((mu_xx + mu_yy + kC1) * (s_xx + s_yy + kC2));
    }
    total += row_sum;
  }
  return total;
}

}  // namespace

double Mse(const Image& a, const Image& b) {
  if (!SameSize(a, b)) return kNaN;
  double sum = 0.0;
  const size_t n = a.rgb.size();
  for (size_t i = 0; i < n; ++i) {
    const double d = double(a.rgb[i]) - double(b.rgb[i]);
    sum += d * d;
  }
  return sum / double(n);
}

double PsnrFromMse(double mse) {
  if (!(mse >= 0.0)) return kNaN;
  if (mse == 0.0) return std::numeric_limits<double>::infinity();
  return -10.0 * std::log10(mse);
}

double Psnr(const Image& a, const Image& b) { return PsnrFromMse(Mse(a, b)); }

double Ssim(const Image& a, const Image& b) {
  if (!SameSize(a, b) || a.width < kWin || a.height < kWin) return kNaN;
  double total = 0.0;
  for (int c = 0; c < 3; ++c) total += SsimChannelSum(a, b, c);
  const double count = 3.0 * double(a.width - kWin + 1) * double(a.height - kWin + 1);
  return total / count;
}

absl::Status CheckComparableImages(const Image& a, const Image& b) {
  for (const Image* im : {&a, &b}) {
    if (im->width <= 0 || im->height <= 0) {
      return absl::InvalidArgumentError("cannot compute metrics of an empty image");
    }
    if (im->rgb.size() != im->num_pixels() * 3) {
      return absl::InvalidArgumentError(absl::StrCat(
          "malformed image: ", im->width, "x", im->height, " with ", im->rgb.size(), " values"));
    }
  }
  if (a.width != b.width || a.height != b.height) {
    return absl::InvalidArgumentError(absl::StrCat("image sizes differ: ", a.width, "x", a.height,
                                                   " vs ", b.width, "x", b.height));
  }
  if (a.width < kWin || a.height < kWin) {
    return absl::InvalidArgumentError(absl::StrCat("SSIM needs images of at least ", kWin, "x",
                                                   kWin, " pixels, got ", a.width, "x", a.height));
  }
  return absl::OkStatus();
}

absl::StatusOr<ImageMetrics> ComputeImageMetrics(const Image& prediction, const Image& target) {
  absl::Status s = CheckComparableImages(prediction, target);
  if (!s.ok()) return s;
  return ImageMetrics{Psnr(prediction, target), Ssim(prediction, target), ColourCorrectedPsnr(prediction, target)};
}

absl::StatusOr<std::vector<ImageMetrics>> ComputeImageMetricsBatch(
    const std::vector<Image>& predictions, const std::vector<Image>& targets) {
  if (predictions.size() != targets.size()) {
    return absl::InvalidArgumentError(absl::StrCat("got ", predictions.size(),
                                                   " predictions but ", targets.size(), " targets"));
  }
  for (size_t i = 0; i < predictions.size(); ++i) {
    absl::Status s = CheckComparableImages(predictions[i], targets[i]);
    if (!s.ok()) return absl::InvalidArgumentError(absl::StrCat("image ", i, ": ", s.message()));
  }
  std::vector<ImageMetrics> out(predictions.size());
  const long n = long(predictions.size());
#pragma omp parallel for schedule(dynamic)
  for (long i = 0; i < n; ++i) {
    out[i].psnr = Psnr(predictions[i], targets[i]);
    out[i].ssim = Ssim(predictions[i], targets[i]);
    out[i].psnr_cc = ColourCorrectedPsnr(predictions[i], targets[i]);
  }
  return out;
}

ImageMetrics MeanMetrics(const std::vector<ImageMetrics>& per_image) {
  if (per_image.empty()) return ImageMetrics{kNaN, kNaN, kNaN};
  ImageMetrics mean;
  for (const ImageMetrics& m : per_image) {
    mean.psnr += m.psnr;
    mean.ssim += m.ssim;
    mean.psnr_cc += m.psnr_cc;
  }
  mean.psnr /= double(per_image.size());
  mean.ssim /= double(per_image.size());
  mean.psnr_cc /= double(per_image.size());
  return mean;
}

Image ColourCorrect(const Image& prediction, const Image& target) {
  Image out = prediction;
  if (prediction.width != target.width || prediction.height != target.height || prediction.rgb.empty() ||
      prediction.rgb.size() != target.rgb.size()) {
    return out;
  }
  const size_t n = prediction.rgb.size() / 3;
  // Normal equations of target_c ~ A_c [r g b 1].
  Eigen::Matrix4d ata = Eigen::Matrix4d::Zero();
  Eigen::Matrix<double, 4, 3> atb = Eigen::Matrix<double, 4, 3>::Zero();
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector4d x(prediction.rgb[3 * i], prediction.rgb[3 * i + 1], prediction.rgb[3 * i + 2], 1.0);
    const Eigen::RowVector3d y(target.rgb[3 * i], target.rgb[3 * i + 1], target.rgb[3 * i + 2]);
    ata.noalias() += x * x.transpose();
    atb.noalias() += x * y;
  }
  Eigen::Matrix<double, 4, 3> a;
  const Eigen::LDLT<Eigen::Matrix4d> ldlt(ata + 1e-9 * double(n) * Eigen::Matrix4d::Identity());
  a = ldlt.solve(atb);
  if (!a.allFinite()) {  // Best constant per channel.
    a.setZero();
    a.row(3) = atb.row(3) / double(n);
  }
  for (size_t i = 0; i < n; ++i) {
    const Eigen::RowVector4d x(prediction.rgb[3 * i], prediction.rgb[3 * i + 1], prediction.rgb[3 * i + 2], 1.0);
    const Eigen::RowVector3d y = x * a;
    for (int c = 0; c < 3; ++c) out.rgb[3 * i + c] = float(std::clamp(y[c], 0.0, 1.0));
  }
  return out;
}

double ColourCorrectedPsnr(const Image& prediction, const Image& target) {
  if (prediction.width != target.width || prediction.height != target.height || prediction.rgb.empty() ||
      prediction.rgb.size() != target.rgb.size()) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  return Psnr(ColourCorrect(prediction, target), target);
}

}  // namespace clnerf
