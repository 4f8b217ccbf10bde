// Sparse depth: turns a capture's measured 3-D points (COLMAP's points3D, a
// transforms.json's `ply_file_path` cloud, an upload's point cloud) into
// per-view depth targets, View::depth, for DS-NeRF-style supervision
// (TrainOptions::depth_weight; Deng et al., "Depth-supervised NeRF", CVPR
// 2022).
//
// A cloud without per-view visibility is projected into every view, and a
// point is kept for a view only when nothing in the cloud lies clearly in
// front of it there: each point is splatted as a small disc into a depth
// buffer, and a point is visible when its depth is within
// `occlusion_tolerance` of the buffer's nearest depth at its pixel (the
// surface that hides a point also has points, so its splats cover it). One
// point per pixel, the nearest.
//
// Pure functions on values; thread-compatible.
#ifndef CLNERF_CORE_DATA_SPARSE_DEPTH_H_
#define CLNERF_CORE_DATA_SPARSE_DEPTH_H_

#include <vector>

#include "absl/status/status.h"
#include "core/data/scene.h"
#include "Eigen/Core"

namespace clnerf {

struct SparseDepthOptions {
  // Most depth pixels kept per view (evenly thinned beyond it, so one view
  // cannot dominate and memory stays bounded).
  int max_points_per_view = 4096;
  // Splat radius for the visibility test, as a fraction of the image's
  // longer side (at least one pixel).
  float splat_radius = 0.01f;
  // A point is visible when its depth <= (1 + tolerance) * the nearest
  // splatted depth at its pixel.
  float occlusion_tolerance = 0.05f;
  // Points closer to the camera than this fraction of the median point depth
  // of that view are dropped (points behind or at the lens).
  float min_depth_fraction = 0.02f;

  absl::Status Validate() const;
};

// Fills View::depth of every view from `points` (world space), replacing what
// was there. Views with distortion are handled; views whose image is empty
// keep an empty list. Returns the number of depth pixels attached. Non-finite
// points are ignored.
long long AttachSparseDepth(const std::vector<Eigen::Vector3f>& points, const SparseDepthOptions& options,
                            std::vector<View>* views);

// Projects a world point into `camera`: pixel coordinates (continuous, pixel
// centres at +0.5) and depth along the optical axis. False when the point is
// behind the camera or outside the image.
bool ProjectPoint(const Camera& camera, const Eigen::Vector3f& world, Eigen::Vector2f* pixel, float* depth);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_SPARSE_DEPTH_H_
