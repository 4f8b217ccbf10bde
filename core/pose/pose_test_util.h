// Test helpers for core/pose: an exact map of a procedural place (its world
// rendered analytically, with exact depth: a perfect θ_{t-1}), a place
// whose objects change between two time steps, and a textured place filmed
// in order (a video's frames) with a run of them turned about it, as SfM
// turns a run of a scene that looks alike from opposite sides. Test code
// only.
#ifndef CLNERF_CORE_POSE_POSE_TEST_UTIL_H_
#define CLNERF_CORE_POSE_POSE_TEST_UTIL_H_

#include <cmath>
#include <string>
#include <vector>

#include "core/data/procedural_scene.h"
#include "core/pose/place_map.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace testing_util {

// The place's map rendered analytically: the procedural world at one time
// step, with exact depth (a perfect θ_{t-1}).
class ProceduralPlaceMap : public PlaceMap {
 public:
  explicit ProceduralPlaceMap(ProceduralWorld world) : world_(std::move(world)) {}
  absl::StatusOr<MapView> Render(const Camera& camera) const override {
    MapView v;
    v.camera = camera;
    v.rgb = RenderProceduralView(world_, camera, 2, 7).image;
    v.depth = RenderProceduralDistance(world_, camera);
    v.opacity.resize(v.depth.size());
    for (size_t i = 0; i < v.depth.size(); ++i) v.opacity[i] = std::isfinite(v.depth[i]) ? 1.0f : 0.0f;
    return v;
  }

 private:
  ProceduralWorld world_;
};

// Objects on a floor among pillars under a patterned sky, seen from an orbit;
// at step 1 objects are removed, added and recoloured. (The procedural room's
// bare walls and repeating planks give SIFT too little to hold on to.)
inline ProceduralSceneOptions ChangingScene(uint64_t seed) {
  ProceduralSceneOptions o;
  o.backdrop = true;
  o.seed = seed;
  o.width = 240;
  o.height = 180;
  o.num_train_views = 16;
  o.num_test_views = 2;
  o.num_time_steps = 2;
  o.change_lighting = false;
  o.change_geometry = true;  // Objects are removed, added and recoloured at step 1.
  return o;
}

struct Place {
  ProceduralSceneOptions options;
  std::vector<Camera> cameras;  // Time step 0's.
  double extent = 0;
  Scene scan;                   // Time step 1's train views (the world changed).
};

inline Place MakePlace(uint64_t seed, bool textured = false) {
  Place p;
  p.options = ChangingScene(seed);
  p.options.textured = textured;
  absl::StatusOr<Scene> all = GenerateProceduralScene(p.options);
  EXPECT_TRUE(all.ok()) << all.status();
  p.scan.kind = all->kind;
  for (const View& v : all->train) {
    if (v.camera.time_step == 0) p.cameras.push_back(v.camera);
    if (v.camera.time_step == 1) p.scan.train.push_back(v);
  }
  p.extent = PlaceExtent(p.cameras, Normalization());
  return p;
}

// A textured procedural place filmed like a phone video: `n` frames on one
// turn around it, 20 degrees up, in order.
inline std::vector<View> RenderedOrbit(uint64_t seed, int n) {
  ProceduralSceneOptions o = ChangingScene(seed);
  o.textured = true;
  o.num_train_views = 1;
  o.num_test_views = 0;
  o.width = 320;
  o.height = 240;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(o);
  EXPECT_TRUE(scene.ok()) << scene.status();
  const ProceduralWorld world = ProceduralWorldAt(o, 0);
  std::vector<View> views;
  for (int i = 0; i < n; ++i) {
    const float az = 2 * float(M_PI) * float(i) / float(n), el = 20 * float(M_PI) / 180;
    const Eigen::Vector3f pos =
        o.camera_radius * Eigen::Vector3f(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    const Eigen::Vector3f forward = (-pos).normalized();
    const Eigen::Vector3f right = forward.cross(Eigen::Vector3f::UnitZ()).normalized();
    View v;
    v.name = "frame_" + std::to_string(i);
    v.camera = scene->train[0].camera;
    v.camera.c2w << right, forward.cross(right), forward, pos;  // OpenCV: x right, y down, z forward.
    v.image = RenderProceduralView(world, v.camera, 1, seed).image;
    views.push_back(std::move(v));
  }
  return views;
}

// Turns views [first, last] by `deg` about the capture's up axis through the
// centre of its cameras: what SfM does to a run of frames of a scene that
// looks alike from opposite sides.
inline void TurnAboutTheScene(std::vector<View>* views, int first, int last, double deg) {
  Eigen::Vector3f centre = Eigen::Vector3f::Zero(), up = Eigen::Vector3f::Zero();
  for (const View& v : *views) {
    centre += v.camera.position();
    up -= v.camera.c2w.col(1);  // OpenCV: y points down.
  }
  centre /= float(views->size());  // One full turn: the place's centre.
  const Eigen::Matrix3f s = Eigen::AngleAxisf(float(deg * M_PI / 180), up.normalized()).toRotationMatrix();
  for (int i = first; i <= last; ++i) {
    Pose& c2w = (*views)[i].camera.c2w;
    c2w.leftCols<3>() = s * c2w.leftCols<3>();
    c2w.col(3) = s * (c2w.col(3) - centre) + centre;
  }
}

}  // namespace testing_util
}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_POSE_TEST_UTIL_H_
