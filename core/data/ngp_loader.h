// NgpLoader: reads an instant-ngp / nerfstudio dataset (transforms.json) into
// a clnerf::Scene.
//
// Intrinsics keys "fl_x fl_y cx cy w h k1 k2 p1 p2" (and "camera_angle_x" /
// "camera_angle_y" as a fallback for the focal lengths) are read globally and
// may be overridden per frame. Missing fl_y = fl_x; missing cx, cy = W/2, H/2;
// missing w, h = the image's size. Non-zero "k3"/"k4" or a fisheye
// "camera_model" are rejected (INVALID_ARGUMENT) rather than silently ignored.
// "transform_matrix" is an OpenGL camera-to-world pose, converted to OpenCV.
// Per frame, optional: "time_step" (integer >= 0), "mask_path" (non-zero =
// keep), and instant-ngp's "dynamic_mask_<stem>.png" next to the image
// (non-zero = exclude); when both masks exist a pixel is kept only if both
// keep it.
//
// Splits, in order of precedence: transforms_train.json (with optional
// transforms_val.json / transforms_test.json, each a full instant-ngp file,
// transforms.json then being ignored; frames keep their file order); a
// per-frame "split" key ("train", "val", "test"; frames without one train);
// otherwise frames are sorted by file_path and every `test_every`-th one,
// starting with the first, is a test view.
//
// Normalisation hints: aabb_scale from the file (default 1);
// world_scale_hint = the file's "scale" (default 0.33, instant-ngp's default).
// instant-ngp maps x_ngp = x_world * scale + offset into its [0,1]^3 box
// (offset defaults to 0.5); our model box is centred at 0, so the world point
// that lands on the box centre is (0.5 - offset) / scale, which is what
// world_offset_hint holds: 0 unless the file gives "offset".
// Kind kUnbounded with a black background unless DatasetOptions::bounded
// (then kBounded with a white background, RGBA composited on it).
// The result is not validated; call ValidateScene() (LoadScene() does).
//
// LoadNgpScene() shares no state and is safe to call concurrently.
#ifndef CLNERF_CORE_DATA_NGP_LOADER_H_
#define CLNERF_CORE_DATA_NGP_LOADER_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/dataset_options.h"
#include "core/data/scene.h"

namespace clnerf {


// Loads `dir` (which holds transforms.json or transforms_train.json). Missing
// json or image files are NOT_FOUND; malformed json or fields are
// INVALID_ARGUMENT naming the file, the frame and the field.
absl::StatusOr<Scene> LoadNgpScene(const std::string& dir, const DatasetOptions& opts = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_NGP_LOADER_H_
