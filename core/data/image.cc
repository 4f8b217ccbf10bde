#include "core/data/image.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>

#include "absl/strings/str_cat.h"
#include "core/data/image_codec.h"

namespace clnerf {
namespace {

// `premultiplied`: colour channels are already multiplied by alpha (OIIO's
// default for most formats; PNG/TIFF come back unassociated when asked).
absl::StatusOr<Image> FromPixels(const std::vector<float>& px, int w, int h, int nc, bool premultiplied,
                                 const Eigen::Vector3f& background, const std::string& name) {
  if (w <= 0 || h <= 0 || nc <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("image '", name, "' has no pixels"));
  }
  Image out(w, h);
  for (size_t i = 0; i < size_t(w) * h; ++i) {
    const float* p = &px[i * nc];
    float r, g, b;
    if (nc >= 3) {
      r = p[0]; g = p[1]; b = p[2];
    } else {
      r = g = b = p[0];
    }
    if (nc == 4 || nc == 2) {
      const float a = p[nc - 1];
      const float k = premultiplied ? 1.0f : a;
      r = r * k + background[0] * (1.0f - a);
      g = g * k + background[1] * (1.0f - a);
      b = b * k + background[2] * (1.0f - a);
    }
    if (!std::isfinite(r) || !std::isfinite(g) || !std::isfinite(b)) {
      return absl::InvalidArgumentError(absl::StrCat("image '", name, "' contains NaN/Inf pixels"));
    }
    out.rgb[i * 3 + 0] = r;
    out.rgb[i * 3 + 1] = g;
    out.rgb[i * 3 + 2] = b;
  }
  return out;
}

// Composites a decoded image (see FromPixels).
absl::StatusOr<Image> FromRaw(const absl::StatusOr<RawImage>& raw, const std::string& name,
                              const Eigen::Vector3f& background) {
  if (!raw.ok()) return raw.status();
  return FromPixels(raw->px, raw->width, raw->height, raw->channels, raw->premultiplied, background, name);
}

// The codec, for an image file that exists (NOT_FOUND otherwise).
absl::StatusOr<const ImageCodec*> CodecForFile(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    return absl::NotFoundError(absl::StrCat("image file not found: ", path));
  }
  return GetImageCodec();
}

}  // namespace

absl::StatusOr<Image> ReadImage(const std::string& path, const Eigen::Vector3f& background) {
  auto raw = ReadImageChannels(path);
  if (!raw.ok()) return raw.status();
  return FromRaw(raw, path, background);
}

absl::StatusOr<RawImage> ReadImageChannels(const std::string& path) {
  auto codec = CodecForFile(path);
  if (!codec.ok()) return codec.status();
  return (*codec)->ReadFile(path);
}

absl::StatusOr<ImageSize> ReadImageSize(const std::string& path) {
  auto codec = CodecForFile(path);
  if (!codec.ok()) return codec.status();
  auto header = (*codec)->ReadHeader(path);
  if (!header.ok()) return header.status();
  if (header->width <= 0 || header->height <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("image '", path, "' has an invalid size"));
  }
  return ImageSize{header->width, header->height};
}

std::string SniffImageExtension(const std::string& b) {
  auto starts = [&](const char* magic, size_t n) { return b.size() >= n && b.compare(0, n, magic, n) == 0; };
  if (starts("\x89PNG\r\n\x1a\n", 8)) return ".png";
  if (starts("\xff\xd8\xff", 3)) return ".jpg";
  if (starts("\x76\x2f\x31\x01", 4)) return ".exr";
  if (starts("II*\0", 4) || starts("MM\0*", 4)) return ".tif";
  if (starts("BM", 2)) return ".bmp";
  return "";
}

absl::StatusOr<Image> DecodeImage(const std::string& bytes, const std::string& name_hint,
                                  const Eigen::Vector3f& background) {
  if (bytes.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("image '", name_hint, "' is empty"));
  }
  std::string ext = std::filesystem::path(name_hint).extension().string();
  if (ext.empty()) ext = ".png";
  auto codec = GetImageCodec();
  if (!codec.ok()) return codec.status();
  return FromRaw((*codec)->Decode(bytes, ext, name_hint), name_hint, background);
}

namespace {
Mask MaskFromImage(const Image& img, bool nonzero_is_exclude) {
  Mask m;
  m.width = img.width;
  m.height = img.height;
  m.keep.resize(img.num_pixels());
  for (size_t i = 0; i < m.keep.size(); ++i) {
    const bool on = img.rgb[i * 3] > 0.5f;
    m.keep[i] = nonzero_is_exclude ? !on : on;
  }
  return m;
}
}  // namespace

absl::StatusOr<Mask> DecodeMask(const std::string& bytes, const std::string& name_hint,
                                bool nonzero_is_exclude) {
  auto img = DecodeImage(bytes, name_hint, Eigen::Vector3f::Zero());
  if (!img.ok()) return img.status();
  return MaskFromImage(*img, nonzero_is_exclude);
}

absl::StatusOr<Mask> ReadMask(const std::string& path, bool nonzero_is_exclude) {
  auto img = ReadImage(path, Eigen::Vector3f::Zero());
  if (!img.ok()) return img.status();
  return MaskFromImage(*img, nonzero_is_exclude);
}


namespace {
absl::Status WriteU8(const std::string& path, int w, int h, int nc, const std::vector<uint8_t>& px) {
  std::error_code ec;
  auto parent = std::filesystem::path(path).parent_path();
  if (!parent.empty()) std::filesystem::create_directories(parent, ec);
  auto codec = GetImageCodec();
  if (!codec.ok()) return codec.status();
  return (*codec)->WriteFile(path, w, h, nc, px.data());
}
uint8_t ToU8(float v) { return uint8_t(std::lround(std::clamp(v, 0.0f, 1.0f) * 255.0f)); }

// Encodes 8-bit pixels in memory through the codec's writer for `ext` ("png",
// "jpg"); `quality` (1..100) is passed on for JPEG.
absl::StatusOr<std::string> EncodeU8(const char* ext, int w, int h, int nc, const std::vector<uint8_t>& px,
                                     int quality = 0) {
  if (w <= 0 || h <= 0) return absl::InvalidArgumentError("cannot encode an empty image");
  auto codec = GetImageCodec();
  if (!codec.ok()) return codec.status();
  return (*codec)->Encode(ext, w, h, nc, px.data(), quality);
}

absl::StatusOr<std::string> EncodeU8Png(int w, int h, int nc, const std::vector<uint8_t>& px) {
  return EncodeU8("png", w, h, nc, px);
}
}  // namespace

absl::StatusOr<std::string> EncodePng(const Image& image) {
  std::vector<uint8_t> px(image.rgb.size());
  for (size_t i = 0; i < px.size(); ++i) px[i] = ToU8(image.rgb[i]);
  return EncodeU8Png(image.width, image.height, 3, px);
}

absl::StatusOr<std::string> EncodeJpeg(const Image& image, int quality) {
  if (quality < 1 || quality > 100) {
    return absl::InvalidArgumentError(absl::StrCat("JPEG quality ", quality, " is outside 1..100"));
  }
  std::vector<uint8_t> px(image.rgb.size());
  for (size_t i = 0; i < px.size(); ++i) px[i] = ToU8(image.rgb[i]);
  return EncodeU8("jpg", image.width, image.height, 3, px, quality);
}

absl::StatusOr<std::string> EncodeMaskPng(const Mask& mask) {
  std::vector<uint8_t> px(mask.keep.size());
  for (size_t i = 0; i < px.size(); ++i) px[i] = mask.keep[i] ? 255 : 0;
  return EncodeU8Png(mask.width, mask.height, 1, px);
}

absl::Status WriteImage(const std::string& path, const Image& image) {
  std::vector<uint8_t> px(image.rgb.size());
  for (size_t i = 0; i < px.size(); ++i) px[i] = ToU8(image.rgb[i]);
  return WriteU8(path, image.width, image.height, 3, px);
}

absl::Status WriteImageRGBA(const std::string& path, const Image& image,
                            const std::vector<float>& alpha) {
  if (alpha.size() != image.num_pixels()) {
    return absl::InvalidArgumentError("alpha size does not match image");
  }
  std::vector<uint8_t> px(image.num_pixels() * 4);
  for (size_t i = 0; i < image.num_pixels(); ++i) {
    for (int c = 0; c < 3; ++c) px[i * 4 + c] = ToU8(image.rgb[i * 3 + c]);
    px[i * 4 + 3] = ToU8(alpha[i]);
  }
  return WriteU8(path, image.width, image.height, 4, px);
}

Image ResizeImage(const Image& image, int width, int height) {
  Image out(width, height);
  const float sx = float(image.width) / width, sy = float(image.height) / height;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const float fx = std::clamp((x + 0.5f) * sx - 0.5f, 0.0f, float(image.width - 1));
      const float fy = std::clamp((y + 0.5f) * sy - 0.5f, 0.0f, float(image.height - 1));
      const int x0 = int(fx), y0 = int(fy);
      const int x1 = std::min(x0 + 1, image.width - 1), y1 = std::min(y0 + 1, image.height - 1);
      const float ax = fx - x0, ay = fy - y0;
      for (int c = 0; c < 3; ++c) {
        const float v = (1 - ay) * ((1 - ax) * image.pixel(x0, y0)[c] + ax * image.pixel(x1, y0)[c]) +
                        ay * ((1 - ax) * image.pixel(x0, y1)[c] + ax * image.pixel(x1, y1)[c]);
        out.pixel(x, y)[c] = v;
      }
    }
  }
  return out;
}

}  // namespace clnerf
