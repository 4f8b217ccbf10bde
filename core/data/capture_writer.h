// CaptureWriter: stores one single-scan real capture (a kUnbounded Scene,
// e.g. a procedural forward-facing rig or room walkthrough) in the file
// formats users bring, the inverse of the loaders:
//
//   kNgp:    transforms.json (instant-ngp / colmap2nerf style: fl_x, fl_y,
//            cx, cy, w, h, aabb_scale 16, OpenGL camera-to-world frames) and
//            images/NNNN.png;
//   kColmap: sparse/0/cameras.txt (one PINHOLE camera per view),
//            sparse/0/images.txt (world-to-camera quaternion and translation)
//            and images/NNNN.png; sparse/0/points3D.txt (positions, no
//            tracks) when the scene has sparse_points, which the other
//            formats then carry too (kNgp: points.ply named by
//            `ply_file_path`; kLlff: the bounds come from them);
//   kLlff:   poses_bounds.npy (N x 17 float64: the 3x5 [down, right, back |
//            centre | h w f] matrix and near/far bounds per view) and
//            images/NNNN.png. The bounds are the 0.1 and 99.9 percentiles of
//            the depths of the content points (EstimateContentPoints) in
//            front of each camera, as LLFF's imgs2poses takes them from
//            COLMAP's points.
//
// Views are written train then test, in that order and with consecutive
// names, so every loader sees the same sequence (its own split rule, e.g.
// every 8th view for test, then applies to all formats alike). So the same
// capture can be loaded from each format and compared: the cross-format
// tests and the format ablation of issue 19 use it.
//
// Thread-safety: a pure function (it writes only under `dir`).
#ifndef CLNERF_CORE_DATA_CAPTURE_WRITER_H_
#define CLNERF_CORE_DATA_CAPTURE_WRITER_H_

#include <string>

#include "absl/status/status.h"
#include "core/data/scene.h"

namespace clnerf {

enum class CaptureFormat { kNgp, kColmap, kLlff };

// "ngp", "colmap" or "llff".
const char* CaptureFormatName(CaptureFormat format);

// Writes `scene` (train and test views; every view needs an image; LLFF
// needs fx == fy and the principal point at the image centre) under `dir`,
// created if needed. INVALID_ARGUMENT for a scene the format cannot hold,
// INTERNAL for I/O failures.
absl::Status WriteCapture(const Scene& scene, CaptureFormat format, const std::string& dir);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_CAPTURE_WRITER_H_
