#include "core/render/metrics.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

constexpr double kC1 = 1e-4;  // (0.01 * 1)^2
constexpr double kC2 = 9e-4;  // (0.03 * 1)^2

// Small deterministic generator (independent of the standard library's
// implementation-defined distributions).
class TestRng {
 public:
  explicit TestRng(uint64_t seed) : state_(seed) {}
  double Uniform() {
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return double(z >> 11) * 0x1.0p-53;
  }

 private:
  uint64_t state_;
};

Image RandomImage(int w, int h, uint64_t seed) {
  TestRng rng(seed);
  Image im(w, h);
  for (float& v : im.rgb) v = float(rng.Uniform());
  return im;
}

// A smooth image with structure at several scales, plus mild noise.
Image SmoothImage(int w, int h, uint64_t seed) {
  TestRng rng(seed);
  Image im(w, h);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) {
        const double v = 0.45 + 0.25 * std::sin(0.31 * x + 0.7 * c) * std::cos(0.23 * y) +
                         0.1 * ((x / 6 + y / 5) % 2) + 0.05 * (rng.Uniform() - 0.5);
        im.pixel(x, y)[c] = float(v);
      }
    }
  }
  return im;
}

// Straightforward SSIM: direct 2-D window sums in double precision with the
// 2-D Gaussian normalised as a whole, evaluated at every valid position.
double ReferenceSsim(const Image& a, const Image& b) {
  constexpr int kWin = 11, kR = 5;
  constexpr double kSigma = 1.5;
  double w2[kWin][kWin];
  double wsum = 0;
  for (int u = 0; u < kWin; ++u) {
    for (int v = 0; v < kWin; ++v) {
      const double du = u - kR, dv = v - kR;
      w2[u][v] = std::exp(-(du * du + dv * dv) / (2 * kSigma * kSigma));
      wsum += w2[u][v];
    }
  }
  for (auto& row : w2) {
    for (double& v : row) v /= wsum;
  }
  double total = 0;
  long count = 0;
  for (int c = 0; c < 3; ++c) {
    for (int i = 0; i + kWin <= a.height; ++i) {
      for (int j = 0; j + kWin <= a.width; ++j) {
        double mx = 0, my = 0, exx = 0, eyy = 0, exy = 0;
        for (int u = 0; u < kWin; ++u) {
          for (int v = 0; v < kWin; ++v) {
            const double x = a.pixel(j + v, i + u)[c];
            const double y = b.pixel(j + v, i + u)[c];
            const double wt = w2[u][v];
            mx += wt * x;
            my += wt * y;
            exx += wt * x * x;
            eyy += wt * y * y;
            exy += wt * x * y;
          }
        }
        const double sxx = exx - mx * mx, syy = eyy - my * my, sxy = exy - mx * my;
        total += ((2 * mx * my + kC1) * (2 * sxy + kC2)) /
                 ((mx * mx + my * my + kC1) * (sxx + syy + kC2));
        ++count;
      }
    }
  }
  return total / double(count);
}

TEST(PsnrTest, ConstantOffsetOfOneTenthIsTwentyDb) {
  Image a(20, 17, 0.5f), b(20, 17, 0.6f);
  // 0.6f - 0.5f is 0.1 up to float rounding (2.4e-8), i.e. 20 dB to ~2e-6.
  EXPECT_NEAR(Psnr(a, b), 20.0, 1e-5);
  EXPECT_NEAR(Psnr(b, a), 20.0, 1e-5);
}

TEST(PsnrTest, ExactlyRepresentableOffset) {
  // Offset 0.25 is exact in float: MSE = 1/16, PSNR = 10 log10(16).
  Image a(8, 8, 0.25f), b(8, 8, 0.5f);
  EXPECT_DOUBLE_EQ(Mse(a, b), 1.0 / 16.0);
  EXPECT_NEAR(Psnr(a, b), 10.0 * std::log10(16.0), 1e-12);
}

TEST(PsnrTest, IdenticalImagesGiveInfinity) {
  const Image a = RandomImage(13, 9, 1);
  const double p = Psnr(a, a);
  EXPECT_TRUE(std::isinf(p));
  EXPECT_GT(p, 0);
  EXPECT_TRUE(std::isinf(PsnrFromMse(0.0)));
  EXPECT_TRUE(std::isnan(PsnrFromMse(-1.0)));
}

TEST(PsnrTest, MismatchedSizesGiveNaN) {
  EXPECT_TRUE(std::isnan(Psnr(Image(4, 4), Image(4, 5))));
  EXPECT_TRUE(std::isnan(Psnr(Image(), Image())));
}

TEST(SsimTest, IdenticalImagesGiveOne) {
  const Image a = RandomImage(32, 24, 2);
  EXPECT_NEAR(Ssim(a, a), 1.0, 1e-12);
  const Image s = SmoothImage(40, 40, 3);
  EXPECT_NEAR(Ssim(s, s), 1.0, 1e-12);
}

TEST(SsimTest, IsSymmetric) {
  const Image a = SmoothImage(33, 27, 4);
  const Image b = RandomImage(33, 27, 5);
  EXPECT_NEAR(Ssim(a, b), Ssim(b, a), 1e-14);
}

TEST(SsimTest, ConstantImagesGiveLuminanceTerm) {
  // Zero variance and covariance: the contrast-structure term is C2/C2 = 1 and
  // SSIM reduces to (2 c1 c2 + C1) / (c1^2 + c2^2 + C1).
  const float c1f = 0.3f, c2f = 0.7f;
  Image a(15, 12, c1f), b(15, 12, c2f);
  const double c1 = c1f, c2 = c2f;
  const double expected = (2 * c1 * c2 + kC1) / (c1 * c1 + c2 * c2 + kC1);
  EXPECT_NEAR(Ssim(a, b), expected, 1e-12);
  EXPECT_NEAR(expected, 0.724185, 1e-6);  // Worked by hand: 0.4201 / 0.5801.
}

TEST(SsimTest, ConstantOffsetMatchesDirectReference) {
  const Image a = SmoothImage(37, 29, 6);
  Image b = a;
  for (float& v : b.rgb) v += 0.1f;
  const double ref = ReferenceSsim(a, b);
  EXPECT_NEAR(Ssim(a, b), ref, 1e-5);
  EXPECT_LT(ref, 1.0);
  EXPECT_GT(ref, 0.5);
}

TEST(SsimTest, RandomNoiseMatchesDirectReference) {
  const Image a = RandomImage(24, 31, 7);
  const Image b = RandomImage(24, 31, 8);
  EXPECT_NEAR(Ssim(a, b), ReferenceSsim(a, b), 1e-5);

  // A noisy copy of a smooth image: a mid-range SSIM.
  const Image s = SmoothImage(30, 30, 9);
  Image n = s;
  TestRng rng(10);
  for (float& v : n.rgb) v += float(0.2 * (rng.Uniform() - 0.5));
  const double ref = ReferenceSsim(s, n);
  EXPECT_NEAR(Ssim(s, n), ref, 1e-5);
  EXPECT_GT(ref, 0.1);
  EXPECT_LT(ref, 0.95);
}

// Golden values computed independently (pure Python, float32-rounded inputs,
// TF/torchmetrics formula) for an analytic 16x13 pattern.
TEST(SsimTest, GoldenValueFromIndependentComputation) {
  Image a(16, 13), b(16, 13);
  for (int y = 0; y < 13; ++y) {
    for (int x = 0; x < 16; ++x) {
      for (int c = 0; c < 3; ++c) {
        a.pixel(x, y)[c] = float(((3 * y + 7 * x + 2 * c) % 11) / 10.0);
        b.pixel(x, y)[c] =
            float(0.8 * double(a.pixel(x, y)[c]) + 0.1 * (((x * y + c) % 3) / 2.0));
      }
    }
  }
  EXPECT_NEAR(Ssim(a, b), 0.9587523509281313, 1e-9);
  EXPECT_NEAR(Psnr(a, b), 20.853382155285026, 1e-9);
}

TEST(SsimTest, TooSmallOrMismatchedGivesNaN) {
  EXPECT_TRUE(std::isnan(Ssim(Image(10, 20), Image(10, 20))));
  EXPECT_TRUE(std::isnan(Ssim(Image(20, 20), Image(20, 21))));
  EXPECT_FALSE(std::isnan(Ssim(Image(11, 11, 0.5f), Image(11, 11, 0.5f))));
}

TEST(MetricsTest, CheckedVariantsReportErrors) {
  EXPECT_EQ(ComputeImageMetrics(Image(16, 16), Image(16, 17)).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ComputeImageMetrics(Image(), Image()).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ComputeImageMetrics(Image(8, 8), Image(8, 8)).status().code(),
            absl::StatusCode::kInvalidArgument);
  Image malformed(16, 16);
  malformed.rgb.pop_back();
  EXPECT_FALSE(CheckComparableImages(malformed, Image(16, 16)).ok());

  auto m = ComputeImageMetrics(Image(16, 16, 0.5f), Image(16, 16, 0.6f));
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_NEAR(m->psnr, 20.0, 1e-5);
}

TEST(MetricsTest, BatchAndMean) {
  std::vector<Image> preds, gts;
  for (int i = 0; i < 6; ++i) {
    gts.push_back(SmoothImage(20, 18, 100 + i));
    preds.push_back(gts.back());
    for (float& v : preds.back().rgb) v += 0.05f * float(i + 1);
  }
  auto per = ComputeImageMetricsBatch(preds, gts);
  ASSERT_TRUE(per.ok()) << per.status();
  ASSERT_EQ(per->size(), 6u);
  double psnr_sum = 0, ssim_sum = 0;
  for (int i = 0; i < 6; ++i) {
    EXPECT_DOUBLE_EQ((*per)[i].psnr, Psnr(preds[i], gts[i]));
    EXPECT_DOUBLE_EQ((*per)[i].ssim, Ssim(preds[i], gts[i]));
    psnr_sum += (*per)[i].psnr;
    ssim_sum += (*per)[i].ssim;
  }
  const ImageMetrics mean = MeanMetrics(*per);
  EXPECT_NEAR(mean.psnr, psnr_sum / 6, 1e-12);  // Mean of per-image PSNRs.
  EXPECT_NEAR(mean.ssim, ssim_sum / 6, 1e-12);

  EXPECT_TRUE(std::isnan(MeanMetrics({}).psnr));
  EXPECT_FALSE(ComputeImageMetricsBatch(preds, {}).ok());
  std::vector<Image> bad = gts;
  bad[3] = Image(5, 5);
  auto err = ComputeImageMetricsBatch(preds, bad);
  ASSERT_FALSE(err.ok());
  EXPECT_NE(err.status().message().find("image 3"), std::string::npos);
}

}  // namespace
}  // namespace clnerf

namespace clnerf {
namespace {

Image NoiseImage(int w, int h, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.1f, 0.9f);
  Image im(w, h);
  for (float& v : im.rgb) v = u(rng);
  return im;
}

TEST(ColourCorrectedPsnrTest, UndoesAnExposureAndWhiteBalanceChange) {
  const Image truth = NoiseImage(24, 20, 3);
  // The prediction is the truth under a different exposure and white
  // balance (an affine map per pixel, inside [0, 1]).
  Image pred = truth;
  for (size_t i = 0; i < pred.rgb.size() / 3; ++i) {
    const float r = truth.rgb[3 * i], g = truth.rgb[3 * i + 1], b = truth.rgb[3 * i + 2];
    pred.rgb[3 * i] = 0.8f * r + 0.05f;
    pred.rgb[3 * i + 1] = 0.7f * g + 0.1f * r + 0.02f;
    pred.rgb[3 * i + 2] = 0.9f * b - 0.05f * g + 0.08f;
  }
  const double raw = Psnr(pred, truth);
  const double cc = ColourCorrectedPsnr(pred, truth);
  EXPECT_LT(raw, 30.0);
  EXPECT_GT(cc, 60.0);  // Exactly affine: only float rounding is left.
  // A prediction wrong in content is not rescued.
  const Image other = NoiseImage(24, 20, 4);
  EXPECT_LT(ColourCorrectedPsnr(other, truth), raw);
  EXPECT_GE(ColourCorrectedPsnr(other, truth), Psnr(other, truth) - 1e-6);
  // A constant prediction gets the best constant per channel: the truth's mean.
  const Image flat(24, 20, 0.5f);
  Image mean(24, 20);
  double m[3] = {0, 0, 0};
  for (size_t i = 0; i < truth.rgb.size(); ++i) m[i % 3] += truth.rgb[i];
  for (size_t i = 0; i < mean.rgb.size(); ++i) mean.rgb[i] = float(m[i % 3] / (truth.rgb.size() / 3));
  EXPECT_NEAR(ColourCorrectedPsnr(flat, truth), Psnr(mean, truth), 1e-3);
  // Mismatched sizes: NaN, as Psnr.
  EXPECT_TRUE(std::isnan(ColourCorrectedPsnr(NoiseImage(8, 8, 1), truth)));
  // The checked metrics carry it.
  absl::StatusOr<ImageMetrics> im = ComputeImageMetrics(pred, truth);
  ASSERT_TRUE(im.ok());
  EXPECT_NEAR(im->psnr_cc, cc, 1e-9);
}

}  // namespace
}  // namespace clnerf
