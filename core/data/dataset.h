// Dataset: the single entry point that turns a directory on disk into a
// clnerf::Scene. DetectDatasetFormat() looks at which files the directory
// holds and LoadScene() dispatches to the matching loader (blender_loader.h,
// ngp_loader.h, colmap_loader.h, llff_loader.h), then checks the result with
// ValidateScene().
//
// Detection order (first match wins):
//   1. transforms_train.json -> kBlender (or kInstantNgp when that file carries
//      any key a NeRF-synthetic file never has: fl_x/fl_y, cx/cy, w/h,
//      distortion, camera_model, aabb_scale, scale/offset or ply_file_path,
//      at the top level or in its first frame; "camera_angle_x", which
//      colmap2nerf-style tools also write, decides nothing),
//   2. transforms.json       -> kInstantNgp,
//   3. sparse/0/ or sparse/ with cameras.{bin,txt} -> kColmap (preferred
//      over LLFF when both are present, as in LLFF's and mip-NeRF 360's
//      releases: the model carries distortion and sparse points),
//   4. poses_bounds.npy                  -> kLlff.
//
// Each loader's header states the convention its files use (Blender and
// instant-ngp: OpenGL camera-to-world; COLMAP: OpenCV world-to-camera; LLFF:
// down-right-back camera-to-world); each converts once, on load, to
// camera-to-world poses in the OpenCV convention. Loaders never throw; errors are absl::Status values (NOT_FOUND for missing files or
// directories, INVALID_ARGUMENT for malformed content). All functions here are
// thread-compatible: they share no state, so concurrent calls on different
// scenes are safe.
#ifndef CLNERF_CORE_DATA_DATASET_H_
#define CLNERF_CORE_DATA_DATASET_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/dataset_options.h"
#include "core/data/scene.h"

namespace clnerf {

enum class DatasetFormat {
  kBlender,     // NeRF-synthetic: transforms_{train,val,test}.json.
  kInstantNgp,  // instant-ngp / nerfstudio: transforms.json.
  kColmap,      // COLMAP sparse model + images/ (or images_N/).
  kLlff,        // LLFF poses_bounds.npy + images/ (or images_N/).
};

// "blender", "instant-ngp", "colmap" or "llff".
const char* DatasetFormatName(DatasetFormat format);

// NOT_FOUND when `dir` does not exist or holds none of the known layouts.
absl::StatusOr<DatasetFormat> DetectDatasetFormat(const std::string& dir);

// Detects the format, loads the scene with the matching loader and validates
// it. Scene::name is the directory's base name.
absl::StatusOr<Scene> LoadScene(const std::string& dir, const DatasetOptions& opts = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_DATASET_H_
