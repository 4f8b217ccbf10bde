#include "core/render/speckle.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "absl/strings/str_format.h"

namespace clnerf {

namespace {

// Box filter of odd size k over a w x h plane, 'valid' region only: the
// result is (w - k + 1) x (h - k + 1). Separable, in double.
std::vector<double> BoxValid(const std::vector<double>& in, int w, int h, int k, int* ow, int* oh) {
  const int w1 = w - k + 1, h1 = h - k + 1;
  std::vector<double> rows(size_t(w1) * h);
  for (int y = 0; y < h; ++y) {
    double s = 0;
    for (int x = 0; x < k; ++x) s += in[size_t(y) * w + x];
    for (int x = 0; x < w1; ++x) {
      rows[size_t(y) * w1 + x] = s;
      if (x + k < w) s += in[size_t(y) * w + x + k] - in[size_t(y) * w + x];
    }
  }
  std::vector<double> out(size_t(w1) * h1);
  const double inv = 1.0 / double(k * k);
  for (int x = 0; x < w1; ++x) {
    double s = 0;
    for (int y = 0; y < k; ++y) s += rows[size_t(y) * w1 + x];
    for (int y = 0; y < h1; ++y) {
      out[size_t(y) * w1 + x] = s * inv;
      if (y + k < h) s += rows[size_t(y + k) * w1 + x] - rows[size_t(y) * w1 + x];
    }
  }
  *ow = w1;
  *oh = h1;
  return out;
}

// Local RMS of the image's 3x3 high-pass (see the header), on the region
// where both windows fit.
std::vector<double> LocalDetail(const Image& im, int* ow, int* oh) {
  const int w = im.width, h = im.height;
  std::vector<double> g(size_t(w) * h);
  for (size_t i = 0; i < g.size(); ++i) g[i] = Luma(&im.rgb[3 * i]);
  int bw = 0, bh = 0;
  const std::vector<double> blur = BoxValid(g, w, h, kSpeckleHighPass, &bw, &bh);
  const int r = kSpeckleHighPass / 2;
  std::vector<double> hp2(blur.size());
  for (int y = 0; y < bh; ++y) {
    for (int x = 0; x < bw; ++x) {
      const double d = g[size_t(y + r) * w + x + r] - blur[size_t(y) * bw + x];
      hp2[size_t(y) * bw + x] = d * d;
    }
  }
  std::vector<double> e = BoxValid(hp2, bw, bh, kSpeckleWindow, ow, oh);
  for (double& v : e) v = std::sqrt(std::max(v, 0.0));
  return e;
}

}  // namespace

absl::StatusOr<DetailScore> ScoreDetail(const Image& render, const Image& photo) {
  const int need = kSpeckleHighPass + kSpeckleWindow - 1;
  if (render.width != photo.width || render.height != photo.height) {
    return absl::InvalidArgumentError(absl::StrFormat("render is %dx%d, photo %dx%d", render.width, render.height,
                                                      photo.width, photo.height));
  }
  if (render.width < need || render.height < need ||
      render.rgb.size() != size_t(render.width) * render.height * 3 || photo.rgb.size() != render.rgb.size()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("images must be well formed and at least %dx%d for the detail score", need, need));
  }
  int w = 0, h = 0;
  const std::vector<double> er = LocalDetail(render, &w, &h);
  const std::vector<double> ep = LocalDetail(photo, &w, &h);
  DetailScore s;
  for (size_t i = 0; i < er.size(); ++i) {
    s.speckle += std::max(0.0, er[i] - ep[i]);
    s.blur += std::max(0.0, ep[i] - er[i]);
  }
  s.speckle /= double(er.size());
  s.blur /= double(er.size());
  return s;
}

}  // namespace clnerf
