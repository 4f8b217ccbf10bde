// ImageCodec: the one small interface behind which OpenImageIO decodes and
// encodes image files and in-memory images for core/data/image.h.
//
// OpenImageIO is loaded on first use, from a module of its own
// (libclnerf_oiio.so, built from core/data/oiio/), rather than linked into
// every binary: Debian's OpenImageIO pulls in ~260 shared libraries, and
// loading them cost every process start ~0.4 s of CPU (`clnerf --help`, the
// server, each test process) whether or not it touched an image. A process
// that never reads or writes an image never loads them.
//
// Where the module is looked for, first match wins:
//   1. $CLNERF_IMAGE_CODEC (a path; when set, nothing else is tried);
//   2. beside the executable, then ../lib/clnerf/ from it (an installed or
//      container layout: /usr/local/bin + /usr/local/lib/clnerf);
//   3. the build tree's own copy (its absolute path is compiled in).
//
// Thread safety: GetImageCodec() is safe to call from any thread (the module
// is loaded once); the codec it returns is stateless and its methods may be
// called concurrently.
#ifndef CLNERF_CORE_DATA_IMAGE_CODEC_H_
#define CLNERF_CORE_DATA_IMAGE_CODEC_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace clnerf {

// Decoded channels of an image as stored: 1 (grey), 2 (grey + alpha),
// 3 (RGB) or 4 (RGBA), interleaved, row-major, float in the file's range.
struct RawImage {
  int width = 0;
  int height = 0;
  int channels = 0;
  // Colour channels already multiplied by alpha (formats that store
  // associated alpha); PNG and TIFF come back straight.
  bool premultiplied = false;
  std::vector<float> px;  // width * height * channels; empty for a header read
};

class ImageCodec {
 public:
  virtual ~ImageCodec() = default;
  // Decodes an image file (format from its contents and extension).
  // Errors: INVALID_ARGUMENT when it cannot be opened or decoded.
  virtual absl::StatusOr<RawImage> ReadFile(const std::string& path) const = 0;
  // Width, height and channels from the file's header; `px` stays empty.
  virtual absl::StatusOr<RawImage> ReadHeader(const std::string& path) const = 0;
  // Decodes encoded bytes; `ext` (".png", ".jpg", ...) names the format and
  // `name` is used in errors.
  virtual absl::StatusOr<RawImage> Decode(const std::string& bytes, const std::string& ext,
                                          const std::string& name) const = 0;
  // Writes 8-bit interleaved pixels (`nc` channels; 4 = straight RGBA) to a
  // file whose extension names the format.
  virtual absl::Status WriteFile(const std::string& path, int w, int h, int nc,
                                 const uint8_t* px) const = 0;
  // Encodes 8-bit pixels in memory as `ext` ("png", "jpg"); `quality`
  // (1..100) is used by JPEG, 0 = the writer's default.
  virtual absl::StatusOr<std::string> Encode(const std::string& ext, int w, int h, int nc,
                                             const uint8_t* px, int quality) const = 0;
};

// The process's codec, loading the module on the first call. Errors:
// UNAVAILABLE (with every path tried and why) when the module cannot be
// loaded; the same error is returned on every later call.
absl::StatusOr<const ImageCodec*> GetImageCodec();

// Where GetImageCodec() looks, in order (see above).
std::vector<std::string> ImageCodecCandidates();
// Loads the module from the first of `candidates` that holds it, without
// caching (GetImageCodec() calls this once). Errors: UNAVAILABLE naming each
// path and why it failed (missing, not loadable, no entry point).
absl::StatusOr<const ImageCodec*> LoadImageCodec(const std::vector<std::string>& candidates);

// The module's entry point (extern "C", versioned with the interface), and
// its name for dlsym.
#define CLNERF_IMAGE_CODEC_ENTRY clnerf_image_codec_v1
inline constexpr char kImageCodecEntryName[] = "clnerf_image_codec_v1";

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_IMAGE_CODEC_H_
