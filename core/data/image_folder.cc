#include "core/data/image_folder.h"

#include <algorithm>
#include <cctype>
#include <cmath>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

bool IsDir(const fs::path& p) {
  std::error_code ec;
  return fs::is_directory(p, ec);
}

// `dir`/name, else `dir`/../name; empty when neither exists.
fs::path FindBesideOrAbove(const fs::path& dir, const std::string& name) {
  for (const fs::path& p : {dir / name, dir / ".." / name}) {
    if (IsDir(p.lexically_normal())) return p.lexically_normal();
  }
  return {};
}

}  // namespace

absl::StatusOr<ImageFolder> FindImageFolder(const fs::path& dir, const std::string& images_dir,
                                            float downscale) {
  if (!images_dir.empty()) {
    const fs::path p = (dir / images_dir).lexically_normal();  // Absolute stays absolute.
    if (!IsDir(p)) {
      return absl::NotFoundError(absl::StrCat("image folder not found: ", p.string()));
    }
    return ImageFolder{p, downscale};
  }
  const float n = std::round(downscale);
  if (n >= 2 && n == downscale) {
    const fs::path p = FindBesideOrAbove(dir, absl::StrCat("images_", int(n)));
    if (!p.empty()) return ImageFolder{p, 1.0f};
  }
  const fs::path p = FindBesideOrAbove(dir, "images");
  if (!p.empty()) return ImageFolder{p, downscale};
  // No images/: the largest of the shrunk copies that exist (images_N with the
  // smallest N), as LLFF scenes are often shared with only images_8/ or
  // images_4/. Its images are already N times smaller than the calibration.
  for (const fs::path& base : {dir, dir / ".."}) {
    int best = 0;
    std::error_code ec;
    for (const fs::directory_entry& e : fs::directory_iterator(base.lexically_normal(), ec)) {
      const std::string name = e.path().filename().string();
      int m = 0;
      if (!e.is_directory(ec) || !absl::StartsWith(name, "images_") ||
          !absl::SimpleAtoi(name.substr(7), &m) || m < 1) {
        continue;
      }
      if (best == 0 || m < best) best = m;
    }
    if (best > 0) {
      return ImageFolder{(base / absl::StrCat("images_", best)).lexically_normal(),
                         std::max(1.0f, downscale / float(best))};
    }
  }
  return ImageFolder{(dir / "images").lexically_normal(), downscale};
}

absl::StatusOr<std::vector<std::string>> ListImageFiles(const fs::path& folder) {
  if (!IsDir(folder)) {
    return absl::NotFoundError(absl::StrCat("image folder not found: ", folder.string()));
  }
  static const char* const kExtensions[] = {".png", ".jpg",  ".jpeg", ".exr",
                                            ".tif", ".tiff", ".bmp"};
  std::vector<std::string> names;
  std::error_code ec;
  for (const fs::directory_entry& e : fs::directory_iterator(folder, ec)) {
    if (!e.is_regular_file(ec)) continue;
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    if (std::find(std::begin(kExtensions), std::end(kExtensions), ext) != std::end(kExtensions)) {
      names.push_back(e.path().filename().string());
    }
  }
  if (ec) {
    return absl::NotFoundError(absl::StrCat("cannot list ", folder.string(), ": ", ec.message()));
  }
  std::sort(names.begin(), names.end());
  return names;
}

absl::Status ScaleIntrinsicsToImage(int width, int height, const std::string& what,
                                    Intrinsics* in) {
  if (width == in->width && height == in->height) return absl::OkStatus();
  if (width <= 0 || height <= 0 || in->width <= 0 || in->height <= 0) {
    return absl::InvalidArgumentError(absl::StrCat(what, ": cannot scale intrinsics for ",
                                                   in->width, "x", in->height, " to ", width, "x",
                                                   height));
  }
  const double sx = double(width) / in->width, sy = double(height) / in->height;
  const double implied_width = in->width * sy;
  if (std::abs(implied_width - width) > std::max(1.0, 0.01 * width)) {
    return absl::InvalidArgumentError(
        absl::StrCat(what, ": image is ", width, "x", height,
                     ", which does not have the aspect ratio of its calibration (", in->width, "x",
                     in->height, ")"));
  }
  in->fx = float(in->fx * sx);
  in->cx = float(in->cx * sx);
  in->fy = float(in->fy * sy);
  in->cy = float(in->cy * sy);
  in->width = width;
  in->height = height;
  return absl::OkStatus();
}

}  // namespace clnerf
