#include "core/dataset.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "core/blender_loader.h"
#include "core/colmap_loader.h"
#include "core/image.h"
#include "core/llff_loader.h"
#include "core/ngp_loader.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

bool IsFile(const fs::path& p) {
  std::error_code ec;
  return fs::is_regular_file(p, ec);
}

// A transforms_train.json written by instant-ngp / nerfstudio tools carries
// "fl_x" instead of Blender's "camera_angle_x".
bool LooksLikeNgp(const fs::path& json_path) {
  std::ifstream in(json_path);
  const nlohmann::json doc = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
  return doc.is_object() && doc.contains("fl_x") && !doc.contains("camera_angle_x");
}

bool HasColmapModel(const fs::path& dir) {
  for (const fs::path& sub : {dir / "sparse" / "0", dir / "sparse"}) {
    if (IsFile(sub / "cameras.bin") || IsFile(sub / "cameras.txt")) return true;
  }
  return false;
}

}  // namespace

const char* DatasetFormatName(DatasetFormat format) {
  switch (format) {
    case DatasetFormat::kBlender:
      return "blender";
    case DatasetFormat::kInstantNgp:
      return "instant-ngp";
    case DatasetFormat::kColmap:
      return "colmap";
    case DatasetFormat::kLlff:
      return "llff";
  }
  return "unknown";
}

absl::StatusOr<DatasetFormat> DetectDatasetFormat(const std::string& dir) {
  const fs::path root(dir);
  std::error_code ec;
  if (!fs::is_directory(root, ec)) {
    return absl::NotFoundError(absl::StrCat("dataset directory not found: ", dir));
  }
  if (IsFile(root / "transforms_train.json")) {
    return LooksLikeNgp(root / "transforms_train.json") ? DatasetFormat::kInstantNgp
                                                        : DatasetFormat::kBlender;
  }
  if (IsFile(root / "transforms.json")) return DatasetFormat::kInstantNgp;
  if (HasColmapModel(root)) return DatasetFormat::kColmap;
  if (IsFile(root / "poses_bounds.npy")) return DatasetFormat::kLlff;
  return absl::NotFoundError(
      absl::StrCat("no dataset found in ", dir,
                   ": expected transforms_train.json (Blender), transforms.json (instant-ngp), "
                   "sparse/[0/]cameras.{bin,txt} (COLMAP) or poses_bounds.npy (LLFF)"));
}

absl::Status DatasetOptions::Validate() const {
  if (!(downscale >= 1.0f && downscale <= 64.0f)) {
    return absl::InvalidArgumentError(
        absl::StrCat("DatasetOptions.downscale must be in [1, 64], got ", downscale));
  }
  if (test_every < 0) return absl::InvalidArgumentError("DatasetOptions.test_every must be >= 0");
  if (max_images_per_split < 0) {
    return absl::InvalidArgumentError("DatasetOptions.max_images_per_split must be >= 0");
  }
  return absl::OkStatus();
}

absl::StatusOr<Scene> LoadScene(const std::string& dir, const DatasetOptions& opts) {
  if (absl::Status s = opts.Validate(); !s.ok()) return s;
  absl::StatusOr<DatasetFormat> format = DetectDatasetFormat(dir);
  if (!format.ok()) return format.status();
  absl::StatusOr<Scene> scene;
  switch (*format) {
    case DatasetFormat::kBlender: {
      BlenderLoadOptions o;
      o.load_images = opts.load_images;
      o.downscale = opts.downscale;
      o.max_images_per_split = opts.max_images_per_split;
      scene = LoadBlenderScene(dir, o);
      break;
    }
    case DatasetFormat::kInstantNgp: {
      NgpLoadOptions o;
      o.load_images = opts.load_images;
      o.downscale = opts.downscale;
      o.test_every = opts.test_every;
      o.max_images_per_split = opts.max_images_per_split;
      o.bounded = opts.ngp_bounded;
      scene = LoadNgpScene(dir, o);
      break;
    }
    case DatasetFormat::kColmap: {
      ColmapLoadOptions o;
      o.load_images = opts.load_images;
      o.downscale = opts.downscale;
      o.test_every = opts.test_every;
      o.max_images_per_split = opts.max_images_per_split;
      o.images_dir = opts.images_dir;
      scene = LoadColmapScene(dir, o);
      break;
    }
    case DatasetFormat::kLlff: {
      LlffLoadOptions o;
      o.load_images = opts.load_images;
      o.downscale = opts.downscale;
      o.test_every = opts.test_every;
      o.max_images_per_split = opts.max_images_per_split;
      o.images_dir = opts.images_dir;
      scene = LoadLlffScene(dir, o);
      break;
    }
  }
  if (!scene.ok()) return scene.status();
  const fs::path norm = fs::path(dir).lexically_normal();
  scene->name =
      norm.has_filename() ? norm.filename().string() : norm.parent_path().filename().string();
  if (scene->train.empty() && scene->test.empty() && scene->val.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("dataset ", dir, " has no views"));
  }
  if (absl::Status s = ValidateScene(*scene); !s.ok()) {
    return absl::InvalidArgumentError(
        absl::StrCat(dir, " (", DatasetFormatName(*format), "): ", s.message()));
  }
  return scene;
}

void DownscaleView(float factor, View* view) {
  Intrinsics& in = view->camera.intrinsics;
  if (!(factor > 1.0f) || in.width <= 0 || in.height <= 0) return;
  const int old_w = in.width, old_h = in.height;
  const int w = std::max(1, int(std::lround(old_w / factor)));
  const int h = std::max(1, int(std::lround(old_h / factor)));
  const float sx = float(w) / old_w, sy = float(h) / old_h;
  in.fx *= sx;
  in.cx *= sx;
  in.fy *= sy;
  in.cy *= sy;
  in.width = w;
  in.height = h;
  // Mismatched images/masks are left alone so ValidateScene() reports them.
  if (view->image.width == old_w && view->image.height == old_h) {
    view->image = ResizeImage(view->image, w, h);
  }
  Mask& m = view->mask;
  if (!m.empty() && m.width == old_w && m.height == old_h) {
    Image as_image(m.width, m.height);
    for (size_t i = 0; i < m.keep.size(); ++i) as_image.rgb[i * 3] = m.keep[i] ? 1.0f : 0.0f;
    const Image small = ResizeImage(as_image, w, h);
    m.width = w;
    m.height = h;
    m.keep.assign(small.num_pixels(), 0);
    for (size_t i = 0; i < m.keep.size(); ++i) m.keep[i] = small.rgb[i * 3] >= 0.5f;
  }
}

}  // namespace clnerf
