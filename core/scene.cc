#include "core/scene.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "Eigen/Dense"

namespace clnerf {

int Scene::num_time_steps() const {
  int n = 0;
  for (const auto* split : {&train, &val, &test}) {
    for (const View& v : *split) n = std::max(n, v.camera.time_step + 1);
  }
  return n;
}

namespace {

// Least-squares point closest to all camera optical axes (the look-at point).
Eigen::Vector3f LookAtCenter(const std::vector<View>& views) {
  Eigen::Matrix3f a = Eigen::Matrix3f::Zero();
  Eigen::Vector3f b = Eigen::Vector3f::Zero();
  for (const View& v : views) {
    const Eigen::Vector3f d = v.camera.c2w.col(2).normalized();
    const Eigen::Vector3f o = v.camera.c2w.col(3);
    const Eigen::Matrix3f p = Eigen::Matrix3f::Identity() - d * d.transpose();
    a += p;
    b += p * o;
  }
  if (std::abs(a.determinant()) < 1e-6f) {
    Eigen::Vector3f mean = Eigen::Vector3f::Zero();
    for (const View& v : views) mean += v.camera.c2w.col(3);
    return views.empty() ? mean : Eigen::Vector3f(mean / float(views.size()));
  }
  return a.ldlt().solve(b);
}

}  // namespace

Normalization ComputeNormalization(const Scene& scene) {
  Normalization n;
  const std::vector<View>& views = scene.train.empty() ? scene.test : scene.train;
  if (scene.kind == SceneKind::kBounded) {
    n.bound = 0.5f;
    if (scene.world_scale_hint > 0) {
      n.center = scene.world_offset_hint;
      n.scale = scene.world_scale_hint;
    } else {
      n.center = LookAtCenter(views);
      float mean_dist = 0;
      for (const View& v : views) mean_dist += (v.camera.position() - n.center).norm();
      mean_dist = views.empty() ? 1.0f : mean_dist / views.size();
      n.scale = mean_dist > 0 ? (4.0f / 3.0f) / mean_dist : 1.0f;
    }
    return n;
  }
  // Unbounded / real captures.
  if (scene.world_scale_hint > 0) {
    n.center = scene.world_offset_hint;
    n.scale = scene.world_scale_hint;
  } else {
    Eigen::Vector3f mean = Eigen::Vector3f::Zero();
    for (const View& v : views) mean += v.camera.position();
    n.center = views.empty() ? mean : Eigen::Vector3f(mean / float(views.size()));
    float min_dist = 1e30f;
    for (const View& v : views) min_dist = std::min(min_dist, (v.camera.position() - n.center).norm());
    n.scale = (min_dist > 1e-6f && min_dist < 1e29f) ? 1.0f / min_dist : 1.0f;
  }
  n.bound = scene.aabb_scale > 0 ? std::max(0.5f, 0.5f * scene.aabb_scale) : 8.0f;
  return n;
}

absl::Status ValidateScene(const Scene& scene) {
  for (const auto* split : {&scene.train, &scene.val, &scene.test}) {
    for (const View& v : *split) {
      absl::Status s = ValidateCamera(v.camera);
      if (!s.ok()) return absl::InvalidArgumentError(absl::StrCat("view '", v.name, "': ", s.message()));
      const Intrinsics& in = v.camera.intrinsics;
      if (!v.image.empty() && (v.image.width != in.width || v.image.height != in.height)) {
        return absl::InvalidArgumentError(absl::StrCat(
            "view '", v.name, "': image is ", v.image.width, "x", v.image.height,
            " but the camera says ", in.width, "x", in.height));
      }
      for (float x : v.image.rgb) {
        if (!std::isfinite(x)) {
          return absl::InvalidArgumentError(absl::StrCat("view '", v.name, "': image has non-finite pixel values"));
        }
      }
      if (!v.mask.empty() && (v.mask.width != in.width || v.mask.height != in.height)) {
        return absl::InvalidArgumentError(absl::StrCat("view '", v.name, "': mask size mismatch"));
      }
    }
  }
  return absl::OkStatus();
}

}  // namespace clnerf
