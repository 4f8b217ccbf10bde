// Dataset: the single entry point that turns a directory on disk into a
// clnerf::Scene. DetectDatasetFormat() looks at which files the directory
// holds and LoadScene() dispatches to the matching loader (blender_loader.h,
// ngp_loader.h, colmap_loader.h, llff_loader.h), then checks the result with
// ValidateScene().
//
// Detection order (first match wins):
//   1. transforms_train.json -> kBlender (or kInstantNgp when that file carries
//      instant-ngp intrinsics, i.e. "fl_x" and no "camera_angle_x"),
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
#ifndef CLNERF_CORE_DATASET_H_
#define CLNERF_CORE_DATASET_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/scene.h"

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

struct DatasetOptions {
  // Decode images (and masks). When false only cameras are loaded; image
  // sizes still come from the metadata or from the image headers.
  bool load_images = true;
  // Integer-ish factor >= 1 by which images are shrunk; intrinsics follow.
  // COLMAP and LLFF read images_N/ for an integer N when it exists.
  float downscale = 1.0f;
  // COLMAP and LLFF only: the image folder, absolute or relative to the
  // dataset directory; "" = automatic (images_N/ or images/, beside the model
  // or one level up). See colmap_loader.h.
  std::string images_dir = "";
  // instant-ngp (without an explicit split), COLMAP and LLFF: every `test_every`-th
  // view, starting with the first, goes to the test split. 0 = no test split.
  int test_every = 8;
  // Keep at most this many views per split (0 = all). Useful for quick runs.
  int max_images_per_split = 0;
  // instant-ngp only: treat the scene as a bounded object scene (kBounded,
  // white background) instead of an unbounded capture.
  bool ngp_bounded = false;

  absl::Status Validate() const;
};

// Detects the format, loads the scene with the matching loader and validates
// it. Scene::name is the directory's base name.
absl::StatusOr<Scene> LoadScene(const std::string& dir, const DatasetOptions& opts = {});

// Shared by the loaders: shrinks `view` by `factor` (>= 1). The new size is
// round(size / factor) (at least 1); intrinsics are rescaled to it, and the
// image and mask, when present, are resampled. A factor of 1 is a no-op.
void DownscaleView(float factor, View* view);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATASET_H_
