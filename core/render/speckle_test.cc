#include "core/render/speckle.h"

#include <cmath>
#include <random>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

// A textured photo: stripes and a checker at a few scales.
Image Textured(int w, int h) {
  Image im(w, h);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float v = 0.5f + 0.2f * std::sin(0.7f * x) * std::cos(0.3f * y) + 0.15f * (((x / 6) + (y / 6)) % 2);
      float* p = im.pixel(x, y);
      p[0] = v;
      p[1] = 0.8f * v;
      p[2] = 1.0f - v;
    }
  }
  return im;
}

Image PlusNoise(const Image& im, float amplitude, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-amplitude, amplitude);
  Image out = im;
  for (size_t i = 0; i < out.num_pixels(); ++i) {
    const float n = u(rng);  // Grey noise: the same on every channel.
    for (int c = 0; c < 3; ++c) out.rgb[3 * i + c] += n;
  }
  return out;
}

Image Box3(const Image& im) {
  Image out = im;
  for (int y = 1; y + 1 < im.height; ++y) {
    for (int x = 1; x + 1 < im.width; ++x) {
      for (int c = 0; c < 3; ++c) {
        float s = 0;
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dx = -1; dx <= 1; ++dx) s += im.pixel(x + dx, y + dy)[c];
        }
        out.pixel(x, y)[c] = s / 9.0f;
      }
    }
  }
  return out;
}

TEST(SpeckleTest, IdenticalImagesScoreZero) {
  const Image a = Textured(64, 48);
  absl::StatusOr<DetailScore> s = ScoreDetail(a, a);
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_EQ(s->speckle, 0.0);
  EXPECT_EQ(s->blur, 0.0);
}

// On a flat photo, grey noise of amplitude a is high-passed to an RMS of
// a / sqrt(3) * sqrt(8 / 9) = 0.544 a: that is its speckle.
TEST(SpeckleTest, NoiseOnAFlatPhotoIsSpeckleOfItsHighPassedRms) {
  const Image flat(96, 80, 0.5f);
  for (const float a : {0.05f, 0.2f}) {
    absl::StatusOr<DetailScore> s = ScoreDetail(PlusNoise(flat, a, 7), flat);
    ASSERT_TRUE(s.ok()) << s.status();
    EXPECT_NEAR(s->speckle, 0.544 * a, 0.06 * a) << a;
    EXPECT_EQ(s->blur, 0.0);
  }
}

// Noise is speckle, blur is blur, and a render one pixel off (a pose error)
// is neither, much: the measures tell the three apart where PSNR cannot.
TEST(SpeckleTest, TellsNoiseFromBlurFromAShift) {
  const Image photo = Textured(96, 80);
  Image shifted = photo;
  for (int y = 0; y < photo.height; ++y) {
    for (int x = 1; x < photo.width; ++x) {
      for (int c = 0; c < 3; ++c) shifted.pixel(x, y)[c] = photo.pixel(x - 1, y)[c];
    }
  }
  absl::StatusOr<DetailScore> noisy = ScoreDetail(PlusNoise(photo, 0.1f, 3), photo);
  absl::StatusOr<DetailScore> blurred = ScoreDetail(Box3(photo), photo);
  absl::StatusOr<DetailScore> moved = ScoreDetail(shifted, photo);
  ASSERT_TRUE(noisy.ok() && blurred.ok() && moved.ok());
  EXPECT_GT(noisy->speckle, 5 * noisy->blur);
  EXPECT_GT(blurred->blur, 5 * blurred->speckle);
  EXPECT_LT(moved->speckle, 0.25 * noisy->speckle);
  EXPECT_LT(moved->blur, 0.25 * blurred->blur);
  // More noise, more speckle.
  absl::StatusOr<DetailScore> noisier = ScoreDetail(PlusNoise(photo, 0.2f, 3), photo);
  ASSERT_TRUE(noisier.ok());
  EXPECT_GT(noisier->speckle, 1.5 * noisy->speckle);
}

TEST(SpeckleTest, BadSizesAreRefused) {
  EXPECT_TRUE(absl::IsInvalidArgument(ScoreDetail(Image(20, 20), Image(21, 20)).status()));
  EXPECT_TRUE(absl::IsInvalidArgument(ScoreDetail(Image(8, 20), Image(8, 20)).status()));
  Image broken(20, 20);
  broken.rgb.pop_back();
  EXPECT_TRUE(absl::IsInvalidArgument(ScoreDetail(broken, Image(20, 20)).status()));
}

}  // namespace
}  // namespace clnerf
