// PlaceMap: what registration localises new photos against. A place keeps no
// old images, only its model θ_{t-1} and the cameras of every earlier scan;
// the map renders colour and depth at any camera in the place's frame, and
// those renders stand in for the photos a structure-from-motion map would
// hold.
//
// ModelPlaceMap renders an NgpModel at one of its time steps. Other maps
// (tests render a procedural world analytically) implement the same call.
// Thread-safety: Render is const and may be called from several threads when
// the implementation allows (ModelPlaceMap does: the model is const).
#ifndef CLNERF_CORE_POSE_PLACE_MAP_H_
#define CLNERF_CORE_POSE_PLACE_MAP_H_

#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/field/ngp_model.h"
#include "core/render/renderer.h"

namespace clnerf {

// A rendered view of the place: colour, and per pixel the distance along the
// pixel's unit ray to the surface (world units) with the opacity that
// supports it (1 = a solid surface; depth is meaningless where it is low).
struct MapView {
  Camera camera;
  Image rgb;
  std::vector<float> depth;
  std::vector<float> opacity;
};

class PlaceMap {
 public:
  virtual ~PlaceMap() = default;
  virtual absl::StatusOr<MapView> Render(const Camera& camera) const = 0;
};

class ModelPlaceMap : public PlaceMap {
 public:
  // `model` must outlive the map. `options.time_step` picks the embeddings
  // (-1: the latest). Depth is the median one (RenderOptions::median_depth).
  ModelPlaceMap(const NgpModel& model, RenderOptions options) : model_(model), options_(WithMedianDepth(options)) {}
  absl::StatusOr<MapView> Render(const Camera& camera) const override;

 private:
  static RenderOptions WithMedianDepth(RenderOptions o) {
    o.median_depth = true;
    return o;
  }
  const NgpModel& model_;
  const RenderOptions options_;
};

// Up to `max_views` of `cameras` spread over the place (farthest-point
// sampling on centre and viewing direction, seeded by the first camera), so
// the renders cover what the cameras saw. Returns indices into `cameras`.
std::vector<int> SpreadCameras(const std::vector<Camera>& cameras, int max_views);

// The same camera with its long side brought into [min_side, max_side]
// (scaled up when smaller: a model renders any size, and small photos give
// SIFT too few keypoints).
Camera CameraWithSideIn(const Camera& camera, int min_side, int max_side);

// The place's size in world units: the diagonal of the box around the
// cameras' centres, or, when the cameras barely move (a forward-facing rig),
// the size of the model's inner box (2 / normalization scale), whichever is
// larger. Registration measures its tolerances and errors in this unit.
double PlaceExtent(const std::vector<Camera>& cameras, const Normalization& norm);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_PLACE_MAP_H_
