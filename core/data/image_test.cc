#include "core/data/image.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(ImageCodecTest, PngRoundTripsTo8BitPrecision) {
  Image img(7, 5);
  for (size_t i = 0; i < img.rgb.size(); ++i) img.rgb[i] = float((i * 37) % 256) / 255.0f;
  auto png = EncodePng(img);
  ASSERT_TRUE(png.ok()) << png.status();
  ASSERT_GT(png->size(), 8u);
  EXPECT_EQ(png->substr(1, 3), "PNG");
  auto back = DecodeImage(*png, "x.png");
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_EQ(back->width, 7);
  ASSERT_EQ(back->height, 5);
  for (size_t i = 0; i < img.rgb.size(); ++i) EXPECT_NEAR(back->rgb[i], img.rgb[i], 0.5f / 255.0f);
}

TEST(ImageCodecTest, JpegRoundTripsCloseAndQualityTradesSize) {
  // A smooth gradient: JPEG keeps it within a few levels at quality 95.
  Image img(32, 24);
  for (int y = 0; y < img.height; ++y) {
    for (int x = 0; x < img.width; ++x) {
      float* p = &img.rgb[(size_t(y) * img.width + x) * 3];
      p[0] = x / 31.0f;
      p[1] = y / 23.0f;
      p[2] = 0.5f;
    }
  }
  auto hi = EncodeJpeg(img, 95);
  auto lo = EncodeJpeg(img, 10);
  ASSERT_TRUE(hi.ok()) << hi.status();
  ASSERT_TRUE(lo.ok()) << lo.status();
  EXPECT_EQ(SniffImageExtension(*hi), ".jpg");
  EXPECT_LT(lo->size(), hi->size());
  auto back = DecodeImage(*hi, "x.jpg");
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_EQ(back->width, 32);
  ASSERT_EQ(back->height, 24);
  double err = 0;
  for (size_t i = 0; i < img.rgb.size(); ++i) err = std::max(err, double(std::fabs(back->rgb[i] - img.rgb[i])));
  EXPECT_LT(err, 12.0 / 255.0);
  EXPECT_EQ(EncodeJpeg(img, 0).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeJpeg(img, 101).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeJpeg(Image(), 80).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(ImageCodecTest, MaskRoundTripsAndHonoursTheConvention) {
  Mask m;
  m.width = 4;
  m.height = 3;
  m.keep = {1, 0, 1, 1, 0, 0, 1, 0, 1, 1, 1, 0};
  auto png = EncodeMaskPng(m);
  ASSERT_TRUE(png.ok()) << png.status();
  auto keep = DecodeMask(*png, "m.png", /*nonzero_is_exclude=*/false);
  ASSERT_TRUE(keep.ok()) << keep.status();
  EXPECT_EQ(keep->keep, m.keep);
  auto excl = DecodeMask(*png, "m.png", /*nonzero_is_exclude=*/true);
  ASSERT_TRUE(excl.ok());
  for (size_t i = 0; i < m.keep.size(); ++i) EXPECT_EQ(excl->keep[i], !m.keep[i]);
}

TEST(ImageCodecTest, SniffsFormatsFromMagicBytes) {
  auto png = EncodePng(Image(2, 2, 0.5f));
  ASSERT_TRUE(png.ok());
  EXPECT_EQ(SniffImageExtension(*png), ".png");
  EXPECT_EQ(SniffImageExtension(std::string("\xff\xd8\xff\xe0rest", 8)), ".jpg");
  EXPECT_EQ(SniffImageExtension("hello world"), "");
  EXPECT_EQ(SniffImageExtension(""), "");
}

TEST(ImageCodecTest, CorruptBytesAreInvalidArgument) {
  auto bad = DecodeImage(std::string("\x89PNG\r\n\x1a\nnot really a png", 25), "bad.png");
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(DecodeImage("", "empty.png").status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodePng(Image()).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(ImageFileTest, SizeComesFromTheHeader) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("clnerf_image_size_" + std::to_string(getpid()));
  fs::create_directories(dir);
  ASSERT_TRUE(WriteImage((dir / "a.png").string(), Image(7, 5, 0.25f)).ok());
  std::ofstream(dir / "bad.png") << "not a png";
  absl::StatusOr<ImageSize> size = ReadImageSize((dir / "a.png").string());
  const absl::Status missing = ReadImageSize((dir / "b.png").string()).status();
  const absl::Status bad = ReadImageSize((dir / "bad.png").string()).status();
  fs::remove_all(dir);
  ASSERT_TRUE(size.ok()) << size.status();
  EXPECT_EQ(size->width, 7);
  EXPECT_EQ(size->height, 5);
  EXPECT_EQ(missing.code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(bad.code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace clnerf
