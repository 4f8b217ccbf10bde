// Cameras given on the command line for renders: a nerfstudio camera path
// (camera_path.json, as written by the nerfstudio viewer's render panel) and
// a single --pose matrix. Both use the OpenGL / Blender / nerfstudio pose
// convention (x right, y up, camera looks along -z); the results are core
// Cameras, whose poses are OpenCV internally.
//
// nerfstudio camera_path.json (what is read):
//   "render_width", "render_height": image size in pixels (when the width is
//       missing it is render_height * the first camera's "aspect");
//   "camera_type": absent or "perspective" (other projections are refused);
//   "camera_path": [{"camera_to_world": 16 numbers, row-major 4x4 (nested
//       4x4 / 3x4 arrays are accepted too), "fov": vertical field of view in
//       degrees, "aspect": width / height (unused, like nerfstudio)}].
// As in nerfstudio's render script, fx = fy = (height / 2) / tan(fov / 2) and
// the principal point is the image centre. Keyframes, "fps", "seconds" and
// "render_time" are ignored. Poses are taken as-is in the server's world
// frame. Pure functions; thread-safe.
#ifndef CLNERF_CLIENT_CAMERA_PATH_H_
#define CLNERF_CLIENT_CAMERA_PATH_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"

namespace clnerf {

// Parses camera_path.json text. INVALID_ARGUMENT names the first bad entry.
absl::StatusOr<std::vector<Camera>> ParseNerfstudioCameraPath(const std::string& json_text);
// Reads and parses a camera_path.json file (NOT_FOUND if it is missing).
absl::StatusOr<std::vector<Camera>> LoadNerfstudioCameraPath(const std::string& path);

// A camera from 12 or 16 numbers (row-major 3x4 / 4x4 camera-to-world,
// OpenGL convention; separated by spaces and/or commas) and a size. `focal`
// is in pixels; 0 = the NeRF-synthetic field of view (camera_angle_x 0.6911).
absl::StatusOr<Camera> ParsePoseCamera(const std::string& numbers, int width, int height, float focal);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_CAMERA_PATH_H_
