// Image: a dense float RGB image with an optional per-pixel mask, and the
// functions that read and write it (through OpenImageIO, loaded on first use:
// core/data/image_codec.h).
//
// Pixel values are stored interleaved (r, g, b) in row-major order, in [0, 1],
// in the image's own encoding (sRGB PNG/JPEG values are not linearised, as in
// NeRF practice). Alpha images are composited onto a caller-chosen background
// when read. An Image is a value type; concurrent reads are safe, concurrent
// writes to the same Image are not.
#ifndef CLNERF_CORE_DATA_IMAGE_H_
#define CLNERF_CORE_DATA_IMAGE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "Eigen/Core"
#include "core/data/image_codec.h"

namespace clnerf {

struct Image {
  int width = 0;
  int height = 0;
  std::vector<float> rgb;  // width * height * 3, row-major, interleaved.

  Image() = default;
  Image(int w, int h, float fill = 0.0f) : width(w), height(h), rgb(size_t(w) * h * 3, fill) {}
  bool empty() const { return width == 0 || height == 0; }
  size_t num_pixels() const { return size_t(width) * height; }
  float* pixel(int x, int y) { return rgb.data() + (size_t(y) * width + x) * 3; }
  const float* pixel(int x, int y) const { return rgb.data() + (size_t(y) * width + x) * 3; }
};

// Grey value (Rec. 601 luma) of one RGB pixel.
inline float Luma(const float* rgb) { return 0.299f * rgb[0] + 0.587f * rgb[1] + 0.114f * rgb[2]; }

// Per-pixel training mask: 1 = use the pixel, 0 = exclude it (transient).
struct Mask {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> keep;
  bool empty() const { return keep.empty(); }
};

// Reads an image file (PNG, JPEG, EXR, ...). RGBA is composited onto
// `background`; greyscale is replicated into RGB. Errors: NOT_FOUND if the file
// is missing, INVALID_ARGUMENT if it cannot be decoded.
absl::StatusOr<Image> ReadImage(const std::string& path,
                                const Eigen::Vector3f& background = Eigen::Vector3f::Ones());

// An image file's channels as stored (alpha straight and not composited,
// grey not replicated). Errors as ReadImage().
absl::StatusOr<RawImage> ReadImageChannels(const std::string& path);

// The width and height of an image file, from its header only (no pixels are
// decoded). Errors as ReadImage().
struct ImageSize {
  int width = 0;
  int height = 0;
};
absl::StatusOr<ImageSize> ReadImageSize(const std::string& path);

// Decodes an image held in memory (e.g. uploaded bytes).
absl::StatusOr<Image> DecodeImage(const std::string& bytes, const std::string& name_hint,
                                  const Eigen::Vector3f& background = Eigen::Vector3f::Ones());

// The file extension (".png", ".jpg", ".exr", ".tif", ".bmp") that matches the
// magic bytes of an encoded image, or "" if the format is not recognised.
std::string SniffImageExtension(const std::string& bytes);
// Decodes a mask held in memory (same convention as ReadMask).
absl::StatusOr<Mask> DecodeMask(const std::string& bytes, const std::string& name_hint,
                                bool nonzero_is_exclude);
// Encodes an image as an 8-bit RGB PNG in memory (values clamped, rounded).
absl::StatusOr<std::string> EncodePng(const Image& image);
// Encodes an image as a baseline 8-bit RGB JPEG in memory; `quality` 1..100.
absl::StatusOr<std::string> EncodeJpeg(const Image& image, int quality = 85);
// Encodes a mask as an 8-bit greyscale PNG: 255 = keep, 0 = exclude.
absl::StatusOr<std::string> EncodeMaskPng(const Mask& mask);
// Reads a mask image; any channel > 0.5 of the first channel means "keep"
// unless `nonzero_is_exclude` (instant-ngp "dynamic_mask" convention) is set.
absl::StatusOr<Mask> ReadMask(const std::string& path, bool nonzero_is_exclude);

// Writes an 8-bit image (format from the extension, e.g. .png). Values are
// clamped to [0, 1] and rounded.
absl::Status WriteImage(const std::string& path, const Image& image);

// Writes an RGBA 8-bit PNG with the given alpha channel (same size as image).
absl::Status WriteImageRGBA(const std::string& path, const Image& image,
                            const std::vector<float>& alpha);

// Bilinear resize (used for downscaled training and tests).
Image ResizeImage(const Image& image, int width, int height);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_IMAGE_H_
