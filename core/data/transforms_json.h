// Helpers shared by the two `transforms*.json` loaders (Blender synthetic and
// instant-ngp/nerfstudio): reading a JSON document, a frame's pose and time
// step, and resolving a frame's image path. Pure functions; thread-safe.
#ifndef CLNERF_CORE_DATA_TRANSFORMS_JSON_H_
#define CLNERF_CORE_DATA_TRANSFORMS_JSON_H_

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/camera.h"

namespace clnerf {

// Prefixes a status message with `ctx` (e.g. "transforms.json frame 3").
absl::Status Annotate(const absl::Status& s, const std::string& ctx);
// NOT_FOUND if the file cannot be opened, INVALID_ARGUMENT if malformed.
absl::StatusOr<nlohmann::json> ReadJson(const std::filesystem::path& path);
// A frame's 3x4 or 4x4 row-major "transform_matrix" (last row ignored), as stored.
absl::StatusOr<Pose> ParsePose(const nlohmann::json& frame, const std::string& ctx);
// A frame's optional non-negative integer "time_step" (default 0).
absl::StatusOr<int> ParseTimeStep(const nlohmann::json& frame, const std::string& ctx);
// `file_path` relative to `dir`; ".png" is appended when the bare path does
// not exist but the .png does.
std::filesystem::path ResolveImagePath(const std::filesystem::path& dir, const std::string& file_path);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_TRANSFORMS_JSON_H_
