// ColmapLoader: reads a COLMAP sparse reconstruction plus its images into a
// clnerf::Scene, including the CLNeRF "WAT" multi-time-step layout.
//
// The model is looked up in <dir>/sparse/0/ and then <dir>/sparse/; binary
// (cameras.bin, images.bin) is preferred over text (cameras.txt, images.txt)
// when both exist, as COLMAP does. points3D is not needed. Supported camera
// models: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV (mapped to
// fx fy cx cy k1 k2 p1 p2); others are INVALID_ARGUMENT. COLMAP's pixel
// convention (pixel centres at +0.5) matches Camera's, so cx, cy are used as
// is. Image poses are world-to-camera (qvec = w,x,y,z; tvec) in the OpenCV
// convention and are inverted to camera-to-world: R_c2w = R^T, centre = -R^T t.
//
// Images come from <dir>/images/<name>. Each distinct subfolder of images/ is
// one time step: subfolder names are sorted (natural order, so "2" < "10";
// the top level, if used, sorts first) and time_step = rank. Within each time
// step views are sorted by name (natural order) and the first and every
// `test_every`-th one go to the test split.
//
// The scene is kUnbounded with a black background and no normalisation hints
// (ComputeNormalization() centres on the cameras). The result is not
// validated; call ValidateScene() (LoadScene() does).
//
// LoadColmapScene() shares no state and is safe to call concurrently.
#ifndef CLNERF_CORE_COLMAP_LOADER_H_
#define CLNERF_CORE_COLMAP_LOADER_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/scene.h"

namespace clnerf {

struct ColmapLoadOptions {
  // Decode images. When false, only cameras are built (sizes from cameras.*).
  bool load_images = true;
  // Shrink factor >= 1 applied to images and intrinsics.
  float downscale = 1.0f;
  // Per time step, views 0, N, 2N, ... (sorted by name) are test views.
  // 0 = no test split.
  int test_every = 8;
  // Keep only the first N views of each split (0 = all).
  int max_images_per_split = 0;

  absl::Status Validate() const;
};

// Loads `dir`. NOT_FOUND when no sparse model or an image file is missing;
// INVALID_ARGUMENT for malformed or truncated model files (naming the file)
// and unsupported camera models.
absl::StatusOr<Scene> LoadColmapScene(const std::string& dir, const ColmapLoadOptions& opts = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_COLMAP_LOADER_H_
