#include "core/data/image_codec.h"

#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>

#include "absl/strings/str_cat.h"

namespace clnerf {
namespace {

constexpr const char* kModuleName = "libclnerf_oiio.so";

}  // namespace

std::vector<std::string> ImageCodecCandidates() {
  if (const char* env = std::getenv("CLNERF_IMAGE_CODEC"); env != nullptr && *env != '\0') {
    return {env};
  }
  std::vector<std::string> out;
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    out.push_back((exe.parent_path() / kModuleName).string());
    out.push_back((exe.parent_path() / ".." / "lib" / "clnerf" / kModuleName).lexically_normal().string());
  }
#ifdef CLNERF_IMAGE_CODEC_BUILD_PATH
  out.push_back(CLNERF_IMAGE_CODEC_BUILD_PATH);
#endif
  return out;
}

absl::StatusOr<const ImageCodec*> LoadImageCodec(const std::vector<std::string>& candidates) {
  using Entry = const ImageCodec* (*)();
  std::string tried;
  for (const std::string& path : candidates) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
      absl::StrAppend(&tried, "\n  ", path, ": not found");
      continue;
    }
    // Never closed: the codec lives as long as the process.
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
      absl::StrAppend(&tried, "\n  ", path, ": ", dlerror());
      continue;
    }
    auto entry = reinterpret_cast<Entry>(dlsym(handle, kImageCodecEntryName));
    const ImageCodec* codec = entry != nullptr ? entry() : nullptr;
    if (codec == nullptr) {
      absl::StrAppend(&tried, "\n  ", path, ": no entry point ", kImageCodecEntryName);
      continue;
    }
    return codec;
  }
  return absl::UnavailableError(absl::StrCat(
      "cannot load the image codec module (", kModuleName,
      ", OpenImageIO); set CLNERF_IMAGE_CODEC to its path. Tried:", tried));
}

absl::StatusOr<const ImageCodec*> GetImageCodec() {
  static const auto* codec = new absl::StatusOr<const ImageCodec*>(LoadImageCodec(ImageCodecCandidates()));
  return *codec;
}

}  // namespace clnerf
