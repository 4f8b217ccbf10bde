// LlffLoader: reads an LLFF dataset (poses_bounds.npy plus an image folder,
// as LLFF's imgs2poses.py writes it and as the LLFF and mip-NeRF 360 scenes
// ship) into a clnerf::Scene.
//
// poses_bounds.npy is an (N, 17) float64 or float32 array (npy_reader.h), one
// row per image in sorted file-name order. Each row is a row-major 3x5 matrix
// [R | t | (h, w, f)] followed by the near and far depth bounds.
//
// Convention: R's columns are the camera's axes in LLFF's "down, right,
// backwards" order and t its centre, camera-to-world. They are converted once,
// here, to this project's OpenCV camera-to-world (x right, y down, looking
// along +z): [right, down, forward] = [col1, col0, -col2], centre t. (This is
// what COLMAP's model gives: LLFF only permuted its axes.)
//
// Intrinsics: h, w, f describe the full-size images. They are rescaled to the
// images actually read (sx = width / w, sy = height / h): fx = f sx,
// fy = f sy, cx = width / 2, cy = height / 2; no distortion. Images are the
// sorted image files of the folder FindImageFolder() (image_folder.h) picks:
// `images_dir` when given, else images_N for an integer downscale N when it
// exists, else images/, each looked up in <dir> and then <dir>/... Their
// count must match N. When load_images is false only the image headers are
// read for their size.
//
// Split: views are taken in that order and the first and every `test_every`-th
// one go to the test split. The scene is kUnbounded with a black background
// and no normalisation hints. Scene::content_points holds, per camera, the
// points on its optical axis at depth `near` and at depth sqrt(near * far)
// (the geometric mean of the bounds, which stays on the content when `far`
// reaches a distant background); they only place the model box. The result
// is not validated; call ValidateScene() (LoadScene() does).
//
// LoadLlffScene() shares no state and is safe to call concurrently.
#ifndef CLNERF_CORE_DATA_LLFF_LOADER_H_
#define CLNERF_CORE_DATA_LLFF_LOADER_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/dataset_options.h"
#include "core/data/scene.h"

namespace clnerf {


// Loads `dir` (which holds poses_bounds.npy). NOT_FOUND when the directory,
// poses_bounds.npy, the image folder or an image is missing; INVALID_ARGUMENT
// naming the file for a malformed .npy (dtype, order, shape), a count of
// images that does not match its rows, non-positive h, w, f or bounds, and
// images whose aspect ratio does not match h, w.
absl::StatusOr<Scene> LoadLlffScene(const std::string& dir, const DatasetOptions& opts = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_LLFF_LOADER_H_
