#include "core/data/dataset.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "core/data/blender_loader.h"
#include "core/data/colmap_loader.h"
#include "core/data/content_sweep.h"
#include "core/data/image.h"
#include "core/data/llff_loader.h"
#include "core/data/ngp_loader.h"
#include "core/data/sparse_depth.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

bool IsFile(const fs::path& p) {
  std::error_code ec;
  return fs::is_regular_file(p, ec);
}

// A transforms_train.json written by instant-ngp / nerfstudio tools (their
// colmap2nerf, ns-process-data and the like) carries calibration or scene keys
// that a NeRF-synthetic (Blender) file never has: pixel focal lengths,
// principal point, image size, distortion, aabb_scale, a point cloud. Such
// tools often write Blender's "camera_angle_x" as well, so its presence says
// nothing. Blender = none of these keys, at the top level or in the first frame.
bool LooksLikeNgp(const fs::path& json_path) {
  std::ifstream in(json_path);
  const nlohmann::json doc = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
  if (!doc.is_object()) return false;
  static const char* const kNgpKeys[] = {"fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2",
                                         "camera_model", "aabb_scale", "scale", "offset", "ply_file_path"};
  const auto has_ngp_key = [](const nlohmann::json& obj) {
    if (!obj.is_object()) return false;
    for (const char* key : kNgpKeys) {
      if (obj.contains(key)) return true;
    }
    return false;
  };
  if (has_ngp_key(doc)) return true;
  const auto frames = doc.find("frames");
  return frames != doc.end() && frames->is_array() && !frames->empty() && has_ngp_key(frames->front());
}

// A COLMAP model under sparse/0 or sparse: cameras at least (`complete`:
// with the images file beside them, in the same form).
bool HasColmapModel(const fs::path& dir, bool complete = false) {
  for (const fs::path& sub : {dir / "sparse" / "0", dir / "sparse"}) {
    for (const char* ext : {".bin", ".txt"}) {
      if (IsFile(sub / (std::string("cameras") + ext)) && (!complete || IsFile(sub / (std::string("images") + ext)))) {
        return true;
      }
    }
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
  // A complete COLMAP model first; an LLFF folder whose sparse/0 keeps only
  // cameras and points (no images.bin) loads from poses_bounds.npy; a
  // broken model without it goes to the COLMAP loader, which names what is
  // missing.
  if (HasColmapModel(root, /*complete=*/true)) return DatasetFormat::kColmap;
  if (IsFile(root / "poses_bounds.npy")) return DatasetFormat::kLlff;
  if (HasColmapModel(root)) return DatasetFormat::kColmap;
  return absl::NotFoundError(
      absl::StrCat("no dataset found in ", dir,
                   ": expected transforms_train.json (Blender), transforms.json (instant-ngp), "
                   "sparse/[0/]cameras.{bin,txt} (COLMAP) or poses_bounds.npy (LLFF)"));
}


absl::StatusOr<Scene> LoadScene(const std::string& dir, const DatasetOptions& opts) {
  if (absl::Status s = opts.Validate(); !s.ok()) return s;
  absl::StatusOr<DatasetFormat> format = DetectDatasetFormat(dir);
  if (!format.ok()) return format.status();
  absl::StatusOr<Scene> scene;
  switch (*format) {
    case DatasetFormat::kBlender: scene = LoadBlenderScene(dir, opts); break;
    case DatasetFormat::kInstantNgp: scene = LoadNgpScene(dir, opts); break;
    case DatasetFormat::kColmap: scene = LoadColmapScene(dir, opts); break;
    case DatasetFormat::kLlff: scene = LoadLlffScene(dir, opts); break;
  }
  if (!scene.ok()) return scene.status();
  scene->name = DatasetName(dir);
  if (scene->train.empty() && scene->test.empty() && scene->val.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("dataset ", dir, " has no views"));
  }
  if (absl::Status s = ValidateScene(*scene); !s.ok()) {
    return absl::InvalidArgumentError(
        absl::StrCat(dir, " (", DatasetFormatName(*format), "): ", s.message()));
  }
  if (opts.sparse_depth && opts.load_images && scene->sparse_points.empty() && opts.sparse_depth_from_images &&
      scene->kind == SceneKind::kUnbounded) {
    // No measured points: the plane sweep's matches stand in for them.
    scene->sparse_points = EstimateContentPoints(scene->train);
  }
  if (opts.sparse_depth && opts.load_images && !scene->sparse_points.empty()) {
    AttachSparseDepth(scene->sparse_points, SparseDepthOptions(), &scene->train);
  }
  return scene;
}


}  // namespace clnerf
