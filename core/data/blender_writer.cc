#include "core/data/blender_writer.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

// Blender's NeRF-synthetic files carry this (unused) per-frame rotation.
constexpr double kBlenderFrameRotation = 0.012566370614359171;

// --- Blender writer helpers ----------------------------------------------------

absl::Status CheckSplit(const std::vector<View>& views, const std::vector<std::vector<float>>* alpha,
                        const char* split) {
  if (alpha != nullptr && alpha->size() != views.size()) {
    return absl::InvalidArgumentError(absl::StrCat("alpha for split '", split, "' has ",
                                                   alpha->size(), " entries for ", views.size(),
                                                   " views"));
  }
  for (size_t i = 0; i < views.size(); ++i) {
    const View& v = views[i];
    const Intrinsics& in = v.camera.intrinsics;
    const Intrinsics& first = views[0].camera.intrinsics;
    const std::string where = absl::StrCat("view ", i, " ('", v.name, "') of split '", split, "'");
    absl::Status s = ValidateCamera(v.camera);
    if (!s.ok()) return absl::InvalidArgumentError(absl::StrCat(where, ": ", s.message()));
    if (v.image.empty() || v.image.width != in.width || v.image.height != in.height ||
        v.image.rgb.size() != v.image.num_pixels() * 3) {
      return absl::InvalidArgumentError(
          absl::StrCat(where, ": missing image or image size does not match the camera"));
    }
    if (in.width != first.width || in.height != first.height || in.fx != first.fx) {
      return absl::InvalidArgumentError(absl::StrCat(
          where, ": the Blender format needs one camera model per split (size and focal differ)"));
    }
    if (in.has_distortion() || std::abs(in.fx - in.fy) > 1e-4f * in.fx ||
        std::abs(in.cx - 0.5f * in.width) > 1e-3f || std::abs(in.cy - 0.5f * in.height) > 1e-3f) {
      return absl::InvalidArgumentError(absl::StrCat(
          where, ": the Blender format needs square pixels, a centred principal point and no "
                 "distortion"));
    }
    if (alpha != nullptr && (*alpha)[i].size() != v.image.num_pixels()) {
      return absl::InvalidArgumentError(absl::StrCat(where, ": alpha size does not match image"));
    }
  }
  return absl::OkStatus();
}

absl::Status WriteJson(const std::string& path, const nlohmann::json& j) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) return absl::InternalError(absl::StrCat("cannot open '", path, "' for writing"));
  f << j.dump(4) << "\n";
  f.close();
  if (!f) return absl::InternalError(absl::StrCat("cannot write '", path, "'"));
  return absl::OkStatus();
}

// Writes <dir>/transforms_<json_split>.json for `views`; images are written
// to <dir>/<image_split>/r_<i>.png when `write_images`.
absl::Status WriteSplit(const std::vector<View>& views,
                        const std::vector<std::vector<float>>* alpha,
                        const Eigen::Vector3f& background, const std::string& dir,
                        const std::string& json_split, const std::string& image_split,
                        bool write_images, double fallback_angle_x) {
  nlohmann::json j;
  double angle_x = fallback_angle_x;  // For empty splits.
  if (!views.empty()) {
    const Intrinsics& in = views[0].camera.intrinsics;
    angle_x = 2.0 * std::atan(0.5 * double(in.width) / double(in.fx));
  }
  j["camera_angle_x"] = angle_x;
  j["frames"] = nlohmann::json::array();
  for (size_t i = 0; i < views.size(); ++i) {
    const View& v = views[i];
    const std::string stem = absl::StrCat("r_", i);
    const Pose gl = ExportPose(v.camera.c2w, PoseConvention::kOpenGL);
    nlohmann::json m = nlohmann::json::array();
    for (int r = 0; r < 4; ++r) {
      nlohmann::json row = nlohmann::json::array();
      for (int c = 0; c < 4; ++c) {
        row.push_back(r < 3 ? double(gl(r, c)) : (c == 3 ? 1.0 : 0.0));
      }
      m.push_back(row);
    }
    nlohmann::json frame;
    frame["file_path"] = absl::StrCat("./", image_split, "/", stem);
    frame["rotation"] = kBlenderFrameRotation;
    frame["time_step"] = v.camera.time_step;
    frame["transform_matrix"] = m;
    j["frames"].push_back(std::move(frame));

    if (!write_images) continue;
    // Un-composite so that rgb * a + background * (1 - a) gives the image back.
    const Image& im = v.image;
    Image straight(im.width, im.height);
    std::vector<float> a(im.num_pixels(), 1.0f);
    if (alpha != nullptr) a = (*alpha)[i];
    for (size_t p = 0; p < im.num_pixels(); ++p) {
      const float ap = std::clamp(a[p], 0.0f, 1.0f);
      a[p] = ap;
      for (int c = 0; c < 3; ++c) {
        const float comp = im.rgb[p * 3 + c];
        straight.rgb[p * 3 + c] =
            ap > 0.0f ? std::clamp((comp - (1.0f - ap) * background[c]) / ap, 0.0f, 1.0f) : 0.0f;
      }
    }
    const std::string path = (fs::path(dir) / image_split / (stem + ".png")).string();
    absl::Status s = WriteImageRGBA(path, straight, a);
    if (!s.ok()) return s;
  }
  return WriteJson((fs::path(dir) / ("transforms_" + json_split + ".json")).string(),
                   j);
}

}  // namespace

absl::Status WriteBlenderDataset(const Scene& scene, const std::string& dir,
                                 const ViewAlphas* alpha) {
  const struct {
    const std::vector<View>* views;
    const std::vector<std::vector<float>>* alpha;
    const char* name;
  } splits[] = {{&scene.train, alpha ? &alpha->train : nullptr, "train"},
                {&scene.val, alpha ? &alpha->val : nullptr, "val"},
                {&scene.test, alpha ? &alpha->test : nullptr, "test"}};
  for (const auto& sp : splits) {
    absl::Status s = CheckSplit(*sp.views, sp.alpha, sp.name);
    if (!s.ok()) return s;
  }
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create '", dir, "': ", ec.message()));
  double fallback_angle_x = 0.6911112;
  for (const auto& sp : splits) {
    if (sp.views->empty()) continue;
    const Intrinsics& in = sp.views->front().camera.intrinsics;
    fallback_angle_x = 2.0 * std::atan(0.5 * double(in.width) / double(in.fx));
    break;
  }
  for (const auto& sp : splits) {
    absl::Status s;
    if (std::string(sp.name) == "val" && scene.val.empty()) {
      // Blender loaders expect a val split; reuse the test frames and images.
      s = WriteSplit(scene.test, nullptr, scene.background, dir, "val", "test",
                     /*write_images=*/false, fallback_angle_x);
    } else {
      s = WriteSplit(*sp.views, sp.alpha, scene.background, dir, sp.name, sp.name,
                     /*write_images=*/true, fallback_angle_x);
    }
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}


absl::Status WriteScanFolders(const Scene& scene, const std::string& dir,
                              const ViewAlphas* alpha) {
  if (alpha != nullptr &&
      (alpha->train.size() != scene.train.size() || alpha->val.size() != scene.val.size() ||
       alpha->test.size() != scene.test.size())) {
    return absl::InvalidArgumentError("alpha does not match the scene's splits");
  }
  const int steps = scene.num_time_steps();
  if (steps == 0) return absl::InvalidArgumentError("scene has no views");
  for (int t = 0; t < steps; ++t) {
    Scene sub;
    sub.name = scene.name;
    sub.kind = scene.kind;
    sub.background = scene.background;
    ViewAlphas sub_alpha;
    const std::vector<View>* src[] = {&scene.train, &scene.val, &scene.test};
    std::vector<View>* dst[] = {&sub.train, &sub.val, &sub.test};
    const std::vector<std::vector<float>>* asrc[] = {
        alpha ? &alpha->train : nullptr, alpha ? &alpha->val : nullptr,
        alpha ? &alpha->test : nullptr};
    std::vector<std::vector<float>>* adst[] = {&sub_alpha.train, &sub_alpha.val, &sub_alpha.test};
    for (int k = 0; k < 3; ++k) {
      for (size_t i = 0; i < src[k]->size(); ++i) {
        if ((*src[k])[i].camera.time_step != t) continue;
        dst[k]->push_back((*src[k])[i]);
        if (asrc[k] != nullptr) adst[k]->push_back((*asrc[k])[i]);
      }
    }
    if (sub.train.empty()) {
      return absl::InvalidArgumentError(absl::StrCat("time step ", t, " has no train views"));
    }
    const std::string folder =
        (fs::path(dir) / absl::StrFormat("scan_%03d", t)).string();
    absl::Status s = WriteBlenderDataset(sub, folder, alpha ? &sub_alpha : nullptr);
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}


}  // namespace clnerf
