// DatasetOptions: how a dataset folder is read, shared by every loader
// (Blender, instant-ngp, COLMAP, LLFF) and by LoadScene, which detects the
// format. Fields a format does not use are ignored by its loader. A plain
// value type with a Validate(); not synchronised.
#ifndef CLNERF_CORE_DATA_DATASET_OPTIONS_H_
#define CLNERF_CORE_DATA_DATASET_OPTIONS_H_

#include <string>

#include "absl/status/status.h"

namespace clnerf {

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
  // Attach sparse-depth targets (View::depth) to the training views from the
  // capture's measured points (COLMAP points3D, a transforms.json's
  // ply_file_path) when it has any; see sparse_depth.h.
  bool sparse_depth = true;
  // Real captures without points: use the content sweep's matches
  // (content_sweep.h) as the points.
  bool sparse_depth_from_images = false;

  absl::Status Validate() const;
};

// What every loader checks first: `options` are valid and `dir` is a
// directory (NOT_FOUND otherwise).
absl::Status CheckDatasetDir(const std::string& dir, const DatasetOptions& options);

// A dataset's name (Scene::name): its folder's name, "lego" for "data/lego/"
// as for "data/lego".
std::string DatasetName(const std::string& dir);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_DATASET_OPTIONS_H_
