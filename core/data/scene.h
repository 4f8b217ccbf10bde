// Scene: the in-memory dataset type that every loader produces and the
// trainer, evaluator and continual update consume. A scene holds views
// (image + optional mask + camera with time step) split into train/val/test,
// plus what the loader knows about the scene's extent.
//
// Normalisation maps world coordinates into the model's box [-bound, bound]^3
// as x_model = rotation (x_world - center) * scale. It is computed once, by
// ComputeNormalization(), and stored with the model, so renders in world
// coordinates stay valid for the model's lifetime. Scenes are value types with
// no internal synchronisation.
#ifndef CLNERF_CORE_DATA_SCENE_H_
#define CLNERF_CORE_DATA_SCENE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "Eigen/Core"

namespace clnerf {

// A pixel of a view whose ray meets a known world point (a sparse 3-D point
// the view sees): the target of sparse-depth supervision (sparse_depth.h).
struct DepthPoint {
  uint32_t pixel = 0;  // y * width + x.
  Eigen::Vector3f world = Eigen::Vector3f::Zero();
};

struct View {
  std::string name;  // File stem or path relative to the dataset root.
  Camera camera;
  Image image;       // May be empty for camera-only views (replay memory).
  Mask mask;         // Optional; empty means "use every pixel".
  // Pixels with a known depth (AttachSparseDepth); empty for most captures.
  std::vector<DepthPoint> depth;
};

// Shrinks `view` by `factor` (>= 1), as the loaders do. The new size is
// round(size / factor) (at least 1); intrinsics are rescaled to it
// (Intrinsics::Scaled), and the image and mask, when present, are
// resampled. A factor of 1 is a no-op.
void DownscaleView(float factor, View* view);

// What kind of content the scene has; drives the box size, the step-size rule
// and the background colour.
enum class SceneKind {
  kBounded,    // Synthetic object scenes: box [-0.5, 0.5]^3, constant steps, white bg.
  kUnbounded,  // Real captures: contracted space, exponential steps, black bg.
};

struct Normalization {
  Eigen::Vector3f center = Eigen::Vector3f::Zero();
  float scale = 1.0f;   // world -> model multiplier.
  float bound = 0.5f;   // model box half-size s: content lives in [-s, s]^3.
  // World -> model axes (a proper rotation; rows are the model's x, y, z in
  // world coordinates). Identity for bounded scenes; for unbounded ones the
  // capture's own frame (up = the cameras' mean up), so the axis-aligned
  // contraction cube sits the same way whatever frame the files used.
  Eigen::Matrix3f rotation = Eigen::Matrix3f::Identity();
  Eigen::Vector3f ToModel(const Eigen::Vector3f& w) const { return rotation * (w - center) * scale; }
  Eigen::Vector3f ToWorld(const Eigen::Vector3f& m) const { return rotation.transpose() * m / scale + center; }
};

struct Scene {
  std::string name;
  SceneKind kind = SceneKind::kBounded;
  Eigen::Vector3f background = Eigen::Vector3f::Ones();
  std::vector<View> train;
  std::vector<View> val;
  std::vector<View> test;
  // Loader hints for ComputeNormalization (0 / unset when unknown).
  float aabb_scale = 0.0f;        // instant-ngp `aabb_scale`.
  float world_scale_hint = 0.0f;  // e.g. Blender: 1/3, instant-ngp: 0.33.
  Eigen::Vector3f world_offset_hint = Eigen::Vector3f::Zero();
  // World-space points on the scene's content (COLMAP's sparse points, or
  // points on each camera's axis at LLFF's near bound and at the geometric
  // mean of its bounds); empty when the loader has none. ComputeNormalization
  // places and sizes the model's box from points estimated from the images
  // (so every format of a capture gives one box) and falls back to these
  // when the images match nothing.
  std::vector<Eigen::Vector3f> content_points;
  // Measured world points on the content, for sparse-depth supervision:
  // COLMAP's points3D, a transforms.json's `ply_file_path` cloud, or an
  // upload's point cloud. Unlike content_points, never synthetic.
  std::vector<Eigen::Vector3f> sparse_points;

  int num_time_steps() const;  // 1 + max time step over all views (0 if none).
};

// Normalisation rules:
//  * kBounded:   bound 0.5; center/scale from the hints when given, else the
//                cameras' look-at centre and a scale putting the mean camera
//                distance at 4/3 (Blender's 4.0 units after scaling by 1/3).
//  * kUnbounded: contracted space (contraction.h), bound 2. center = the
//                cameras' look-at point when their axes converge, else the
//                median content point, else the mean camera position; scale
//                puts every camera and the median content point inside the
//                inner cube [-1, 1]^3 (10 % margin). Content points are the
//                loader's (COLMAP's sparse points, LLFF's bounds); when it has
//                none and the views have images they are estimated from the
//                images (content_sweep.h), so a transforms.json or an upload
//                of a forward-facing capture or a walkthrough is placed as its
//                COLMAP model would be. Loader hints (instant-ngp
//                scale/offset/aabb_scale) are not used, so an upload through
//                the service, which carries no hints, normalises the same way.
//                rotation: z = the cameras' mean up vector; about it, the
//                turn that fits the cameras in the tightest L-inf box around
//                the centre (searched in half-degree steps from the main
//                horizontal axis of the camera positions), so one capture in
//                any file format (COLMAP's arbitrary frame, colmap2nerf's
//                z-up one) gets the same box; identity when the cameras give
//                no up.
Normalization ComputeNormalization(const Scene& scene);

// Checks every view: valid camera, image size matches intrinsics, mask size
// matches the image. Returns INVALID_ARGUMENT naming the first bad view.
absl::Status ValidateScene(const Scene& scene);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_SCENE_H_
