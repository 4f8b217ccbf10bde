// ColmapLoader: reads a COLMAP sparse reconstruction plus its images into a
// clnerf::Scene, including the CLNeRF "WAT" multi-time-step layout.
//
// Convention: COLMAP poses are world-to-camera in the OpenCV convention
// (x right, y down, looking along +z): qvec = (w, x, y, z) and tvec give
// x_cam = R x_world + t. They are inverted once, here, to camera-to-world
// (R_c2w = R^T, centre = -R^T t) and need no axis change.
//
// The model is looked up in <dir>/sparse/0/ and then <dir>/sparse/; binary
// (cameras.bin, images.bin) is preferred over text (cameras.txt, images.txt)
// when both exist, as COLMAP does. points3D.{bin,txt} in the same folder is
// optional: when present its points (world xyz) become Scene::content_points.
// Supported camera models: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL,
// OPENCV (mapped to fx fy cx cy k1 k2 p1 p2); others are INVALID_ARGUMENT.
// COLMAP's pixel convention (pixel centres at +0.5) matches Camera's, so cx,
// cy are used as is.
//
// Images: <folder>/<name>, the folder chosen by FindImageFolder()
// (image_folder.h): `images_dir` when given; else images_N for an integer
// downscale N when that folder exists (LLFF / mip-NeRF 360 ship images_2, _4,
// _8); else images/. Each is looked up in <dir> and then in <dir>/.., so a
// model kept in <scene>/source/sparse/0 finds <scene>/images. COLMAP's
// intrinsics are for the images it was run on; they are always rescaled to
// the size of the image actually read (its header only when load_images is
// false; the camera's own size when that file is missing then).
//
// Each distinct subfolder in the image names is one time step: subfolder
// names are sorted (natural order, so "2" < "10"; the top level, if used,
// sorts first) and time_step = rank. Within each time step views are sorted by
// name (natural order) and the first and every `test_every`-th one go to the
// test split.
//
// The scene is kUnbounded with a black background and no normalisation hints
// (ComputeNormalization() centres on the cameras). The result is not
// validated; call ValidateScene() (LoadScene() does).
//
// LoadColmapScene() shares no state and is safe to call concurrently.
#ifndef CLNERF_CORE_DATA_COLMAP_LOADER_H_
#define CLNERF_CORE_DATA_COLMAP_LOADER_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/dataset_options.h"
#include "core/data/scene.h"

namespace clnerf {


// Loads `dir`. NOT_FOUND when no sparse model, the explicit image folder or
// (with load_images) an image file is missing; INVALID_ARGUMENT for malformed
// or truncated model files (naming the file), unsupported camera models, and
// images whose aspect ratio does not match their camera.
absl::StatusOr<Scene> LoadColmapScene(const std::string& dir, const DatasetOptions& opts = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_COLMAP_LOADER_H_
