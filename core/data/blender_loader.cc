#include "core/data/blender_loader.h"

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>
#include <vector>

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "core/data/dataset.h"
#include "core/data/image.h"
#include "core/data/transforms_json.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

absl::Status LoadSplit(const fs::path& dir, const std::string& file_name,
                       const DatasetOptions& opts, std::vector<View>* out) {
  const fs::path json_path = dir / file_name;
  absl::StatusOr<json> doc = ReadJson(json_path);
  if (!doc.ok()) return doc.status();
  const std::string file = json_path.string();
  try {
    if (!doc->is_object() || !(*doc)["camera_angle_x"].is_number()) {
      return absl::InvalidArgumentError(
          absl::StrCat(file, ": missing or non-numeric field 'camera_angle_x'"));
    }
    const double angle_x = (*doc)["camera_angle_x"].get<double>();
    if (!(angle_x > 0 && angle_x < std::numbers::pi)) {
      return absl::InvalidArgumentError(
          absl::StrCat(file, ": field 'camera_angle_x' must be in (0, pi), got ", angle_x));
    }
    if (!(*doc)["frames"].is_array()) {
      return absl::InvalidArgumentError(
          absl::StrCat(file, ": missing or non-array field 'frames'"));
    }
    const json& frames = (*doc)["frames"];
    size_t n = frames.size();
    if (opts.max_images_per_split > 0) n = std::min(n, size_t(opts.max_images_per_split));
    // Size used when images are not loaded: "w"/"h", else the first image's.
    int split_w = doc->value("w", 0), split_h = doc->value("h", 0);
    for (size_t i = 0; i < n; ++i) {
      const json& f = frames[i];
      const std::string ctx = absl::StrCat(file, ": frame ", i);
      if (!f.is_object() || !f.contains("file_path") || !f["file_path"].is_string()) {
        return absl::InvalidArgumentError(absl::StrCat(ctx, ": missing string field 'file_path'"));
      }
      const fs::path image_path = ResolveImagePath(dir, f["file_path"].get<std::string>());
      View view;
      view.name = image_path.lexically_relative(dir).lexically_normal().generic_string();
      absl::StatusOr<Pose> pose = ParsePose(f, ctx);
      if (!pose.ok()) return pose.status();
      view.camera.c2w = ConvertPose(*pose, PoseConvention::kOpenGL);
      absl::StatusOr<int> t = ParseTimeStep(f, ctx);
      if (!t.ok()) return t.status();
      view.camera.time_step = *t;

      int w = split_w, h = split_h;
      if (opts.load_images || w <= 0 || h <= 0) {
        absl::StatusOr<Image> image = ReadImage(image_path.string(), Eigen::Vector3f::Ones());
        if (!image.ok()) return Annotate(image.status(), ctx);
        w = split_w = image->width;
        h = split_h = image->height;
        if (opts.load_images) view.image = *std::move(image);
      }
      Intrinsics& in = view.camera.intrinsics;
      in.width = w;
      in.height = h;
      in.fx = in.fy = float(0.5 * w / std::tan(0.5 * angle_x));
      in.cx = 0.5f * w;
      in.cy = 0.5f * h;

      if (opts.load_images && f.contains("mask_path")) {
        if (!f["mask_path"].is_string()) {
          return absl::InvalidArgumentError(
              absl::StrCat(ctx, ": field 'mask_path' must be a string"));
        }
        absl::StatusOr<Mask> mask =
            ReadMask((dir / f["mask_path"].get<std::string>()).string(), false);
        if (!mask.ok()) return Annotate(mask.status(), ctx);
        view.mask = *std::move(mask);
      }
      DownscaleView(opts.downscale, &view);
      out->push_back(std::move(view));
    }
  } catch (const json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(file, ": ", e.what()));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<Scene> LoadBlenderScene(const std::string& dir, const DatasetOptions& opts) {
  if (absl::Status s = CheckDatasetDir(dir, opts); !s.ok()) return s;
  const fs::path root(dir);
  Scene scene;
  scene.name = DatasetName(dir);
  scene.kind = SceneKind::kBounded;
  scene.background = Eigen::Vector3f::Ones();
  scene.world_scale_hint = 1.0f / 3.0f;
  scene.world_offset_hint = Eigen::Vector3f::Zero();

  bool any = false;
  std::error_code ec;
  const std::pair<const char*, std::vector<View>*> splits[] = {
      {"train", &scene.train}, {"val", &scene.val}, {"test", &scene.test}};
  for (const auto& [split, views] : splits) {
    const std::string file_name = absl::StrCat("transforms_", split, ".json");
    if (!fs::exists(root / file_name, ec)) continue;
    any = true;
    if (absl::Status s = LoadSplit(root, file_name, opts, views); !s.ok()) return s;
  }
  if (!any) {
    return absl::NotFoundError(
        absl::StrCat("no transforms_{train,val,test}.json in ", dir, " (not a Blender dataset)"));
  }
  return scene;
}

}  // namespace clnerf
