// ImageFolder: where a COLMAP- or LLFF-style dataset keeps its images, and how
// intrinsics calibrated for one image size follow the images actually read.
//
// These layouts ship full-size images in images/ and, often, copies shrunk by
// 2, 4, 8 in images_2/, images_4/, images_8/ (LLFF, mip-NeRF 360), while the
// calibration (COLMAP cameras, LLFF's h w f) stays that of the originals. Some
// captures also keep the model in a subfolder (e.g. <scene>/source/sparse/0)
// with the images beside it (<scene>/images). FindImageFolder() picks the
// folder; ScaleIntrinsicsToImage() rescales intrinsics to a decoded image.
// Pure functions; thread-safe.
#ifndef CLNERF_CORE_DATA_IMAGE_FOLDER_H_
#define CLNERF_CORE_DATA_IMAGE_FOLDER_H_

#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/camera.h"

namespace clnerf {

struct ImageFolder {
  std::filesystem::path path;  // The folder images are read from (may not exist).
  // What is left of the requested downscale once the folder's own factor is
  // accounted for (1 when images_N was picked for a downscale of N).
  float residual_downscale = 1.0f;
};

// Resolves the image folder of the dataset in `dir`.
//  * `images_dir` non-empty: that folder (absolute, or relative to `dir`);
//    NOT_FOUND when it does not exist. The whole `downscale` still applies.
//  * otherwise, when `downscale` is an integer N >= 2 and images_N exists in
//    `dir` or in `dir`/.., that folder, with a residual downscale of 1;
//  * otherwise images/ in `dir`, else in `dir`/.., with the whole `downscale`;
//  * otherwise (no images/ at all) the images_M with the smallest M in `dir`,
//    else in `dir`/.., with a residual downscale of max(1, downscale / M): a
//    capture shared with only images_8/ loads without --images-dir;
//  * otherwise `dir`/images, which does not exist.
absl::StatusOr<ImageFolder> FindImageFolder(const std::filesystem::path& dir,
                                            const std::string& images_dir, float downscale);

// The image files (.png, .jpg, .jpeg, .exr, .tif, .tiff, .bmp, any case)
// directly in `folder`, sorted by name (byte order, as LLFF's loader sorts).
// NOT_FOUND when `folder` does not exist.
absl::StatusOr<std::vector<std::string>> ListImageFiles(const std::filesystem::path& folder);

// Rescales intrinsics calibrated for in->width x in->height to an image of
// `width` x `height`: sx = width / in->width, sy = height / in->height; fx and
// cx scale by sx, fy and cy by sy (pixel centres at +0.5 on both sides, so the
// continuous coordinates scale exactly); distortion is in normalised
// coordinates and does not change. INVALID_ARGUMENT when the aspect ratios
// disagree (the width implied by sy is off by more than 1% and more than one
// pixel: a wrong or rotated image), the message naming `what`.
absl::Status ScaleIntrinsicsToImage(int width, int height, const std::string& what, Intrinsics* in);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_IMAGE_FOLDER_H_
