// Test helpers for core/pose: an exact map of a procedural place (its world
// rendered analytically, with exact depth: a perfect θ_{t-1}) and a place
// whose objects change between two time steps. Test code only.
#ifndef CLNERF_CORE_POSE_POSE_TEST_UTIL_H_
#define CLNERF_CORE_POSE_POSE_TEST_UTIL_H_

#include <cmath>
#include <vector>

#include "core/data/procedural_scene.h"
#include "core/pose/place_map.h"
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

}  // namespace testing_util
}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_POSE_TEST_UTIL_H_
