// BlenderLoader: reads a NeRF-synthetic ("Blender") dataset directory, i.e.
// transforms_train.json, transforms_val.json and transforms_test.json next to
// the rendered images, into a clnerf::Scene.
//
// Each split file holds a global "camera_angle_x" (horizontal field of view)
// and "frames", each with a "file_path" relative to the dataset directory
// (".png" is appended when the path has no extension and the bare path does
// not exist) and a 4x4 (or 3x4) "transform_matrix": an OpenGL camera-to-world
// pose, converted here to the internal OpenCV convention. Optional per-frame
// fields: "time_step" (integer >= 0, default 0) and "mask_path" (a keep-mask,
// non-zero = use the pixel). Intrinsics: fx = fy = 0.5 * W / tan(0.5 *
// camera_angle_x), cx = W / 2, cy = H / 2, with W x H the image size (or the
// file's optional "w"/"h"). RGBA images are composited on white.
//
// The scene is kBounded with a white background and the NeRF-synthetic
// normalisation hints: world_scale_hint = 1/3 and world_offset_hint = 0, so
// the [-1.5, 1.5]^3 object box maps onto the model box [-0.5, 0.5]^3.
// The result is not validated; call ValidateScene() (LoadScene() does).
//
// LoadBlenderScene() shares no state and is safe to call concurrently.
#ifndef CLNERF_CORE_DATA_BLENDER_LOADER_H_
#define CLNERF_CORE_DATA_BLENDER_LOADER_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/dataset_options.h"
#include "core/data/scene.h"

namespace clnerf {


// Loads `dir`. At least one of the three split files must exist (NOT_FOUND
// otherwise); missing image files are NOT_FOUND, malformed json or fields are
// INVALID_ARGUMENT naming the file and the field.
absl::StatusOr<Scene> LoadBlenderScene(const std::string& dir, const DatasetOptions& opts = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_BLENDER_LOADER_H_
