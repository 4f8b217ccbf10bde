#include "client/camera_path.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "nlohmann/json.hpp"

namespace clnerf {
namespace {

constexpr float kPi = 3.14159265358979f;
// Poses from viewers are float32-rounded; allow a little slack on rigidity.
constexpr float kRigidTolerance = 1e-2f;

// 12 or 16 row-major numbers -> OpenCV camera-to-world.
absl::StatusOr<Pose> PoseFromNumbers(const std::vector<float>& v, const std::string& what) {
  if (v.size() != 12 && v.size() != 16) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: need 12 or 16 numbers, got %d", what, int(v.size())));
  }
  for (float x : v) {
    if (!std::isfinite(x)) return absl::InvalidArgumentError(absl::StrFormat("%s: non-finite number", what));
  }
  if (v.size() == 16 && (std::abs(v[12]) > 1e-4f || std::abs(v[13]) > 1e-4f || std::abs(v[14]) > 1e-4f ||
                         std::abs(v[15] - 1) > 1e-4f)) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: bottom row must be 0 0 0 1", what));
  }
  Pose p;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) p(r, c) = v[r * 4 + c];
  return ConvertPose(p, PoseConvention::kOpenGL);
}

// Flattens a number array, or an array of row arrays, into `out`.
bool Flatten(const nlohmann::json& j, std::vector<float>* out) {
  if (!j.is_array()) return false;
  for (const nlohmann::json& e : j) {
    if (e.is_number()) out->push_back(e.get<float>());
    else if (e.is_array()) {
      for (const nlohmann::json& x : e) {
        if (!x.is_number()) return false;
        out->push_back(x.get<float>());
      }
    } else {
      return false;
    }
  }
  return true;
}

Camera MakeCamera(const Pose& c2w, int width, int height, float fx, float fy) {
  Camera cam;
  cam.c2w = c2w;
  cam.intrinsics.width = width;
  cam.intrinsics.height = height;
  cam.intrinsics.fx = fx;
  cam.intrinsics.fy = fy;
  cam.intrinsics.cx = 0.5f * width;
  cam.intrinsics.cy = 0.5f * height;
  return cam;
}

}  // namespace

absl::StatusOr<std::vector<Camera>> ParseNerfstudioCameraPath(const std::string& text) {
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) return absl::InvalidArgumentError("camera path: not a JSON object");
  if (j.contains("camera_type") && j["camera_type"] != "perspective") {
    return absl::InvalidArgumentError(
        absl::StrFormat("camera path: camera_type %s is not supported (only perspective)", j["camera_type"].dump()));
  }
  if (!j.contains("camera_path") || !j["camera_path"].is_array() || j["camera_path"].empty()) {
    return absl::InvalidArgumentError("camera path: \"camera_path\" must be a non-empty array");
  }
  const nlohmann::json& path = j["camera_path"];
  if (!j.contains("render_height") || !j["render_height"].is_number()) {
    return absl::InvalidArgumentError("camera path: \"render_height\" is missing");
  }
  const int height = int(std::lround(j["render_height"].get<double>()));
  int width = 0;
  if (j.contains("render_width") && j["render_width"].is_number()) {
    width = int(std::lround(j["render_width"].get<double>()));
  } else if (path[0].is_object() && path[0].contains("aspect") && path[0]["aspect"].is_number()) {
    width = int(std::lround(height * path[0]["aspect"].get<double>()));
  }
  if (width <= 0 || height <= 0) {
    return absl::InvalidArgumentError(absl::StrFormat("camera path: bad image size %dx%d", width, height));
  }
  std::vector<Camera> cams;
  for (size_t i = 0; i < path.size(); ++i) {
    const nlohmann::json& c = path[i];
    const std::string what = absl::StrFormat("camera path entry %d", int(i));
    std::vector<float> m;
    if (!c.is_object() || !c.contains("camera_to_world") || !Flatten(c["camera_to_world"], &m)) {
      return absl::InvalidArgumentError(what + ": \"camera_to_world\" must be an array of numbers");
    }
    absl::StatusOr<Pose> pose = PoseFromNumbers(m, what);
    if (!pose.ok()) return pose.status();
    if (!c.contains("fov") || !c["fov"].is_number()) return absl::InvalidArgumentError(what + ": \"fov\" is missing");
    const double fov = c["fov"].get<double>();
    if (!(fov > 0 && fov < 180)) {
      return absl::InvalidArgumentError(absl::StrFormat("%s: fov %g is not in (0, 180) degrees", what, fov));
    }
    const float f = float(0.5 * height / std::tan(0.5 * fov * kPi / 180.0));
    Camera cam = MakeCamera(*pose, width, height, f, f);
    if (absl::Status s = ValidateCamera(cam, kRigidTolerance); !s.ok()) {
      return absl::InvalidArgumentError(absl::StrFormat("%s: %s", what, s.message()));
    }
    cams.push_back(cam);
  }
  return cams;
}

absl::StatusOr<std::vector<Camera>> LoadNerfstudioCameraPath(const std::string& path) {
  std::ifstream f(path);
  if (!f) return absl::NotFoundError(absl::StrFormat("cannot read camera path '%s'", path));
  std::stringstream ss;
  ss << f.rdbuf();
  absl::StatusOr<std::vector<Camera>> cams = ParseNerfstudioCameraPath(ss.str());
  if (!cams.ok()) return absl::Status(cams.status().code(), absl::StrFormat("%s: %s", path, cams.status().message()));
  return cams;
}

absl::StatusOr<Camera> ParsePoseCamera(const std::string& numbers, int width, int height, float focal) {
  std::vector<float> v;
  for (absl::string_view tok : absl::StrSplit(numbers, absl::ByAnyChar(", \t\n"), absl::SkipEmpty())) {
    float x;
    if (!absl::SimpleAtof(tok, &x)) {
      return absl::InvalidArgumentError(absl::StrFormat("--pose: '%s' is not a number", std::string(tok)));
    }
    v.push_back(x);
  }
  absl::StatusOr<Pose> pose = PoseFromNumbers(v, "--pose");
  if (!pose.ok()) return pose.status();
  if (width <= 0 || height <= 0) {
    return absl::InvalidArgumentError(absl::StrFormat("bad image size %dx%d", width, height));
  }
  const float f = focal > 0 ? focal : 0.5f * width / std::tan(0.5f * 0.6911112f);
  Camera cam = MakeCamera(*pose, width, height, f, f);
  if (absl::Status s = ValidateCamera(cam, kRigidTolerance); !s.ok()) {
    return absl::InvalidArgumentError(absl::StrFormat("--pose: %s", s.message()));
  }
  return cam;
}

}  // namespace clnerf
