// ContentSweep: where a capture's content lies, estimated from its posed
// images alone by plane-sweep stereo. Used to place and size the model box
// (ComputeNormalization) when the files carry no points: a transforms.json
// written by colmap2nerf or ns-process-data, or a scan uploaded to the
// service, holds the same cameras and images as the COLMAP model it came
// from, but not its sparse points. Without some idea of depth a
// forward-facing capture or a walkthrough (camera axes that do not meet)
// would be centred on its cameras and its content pushed into the contracted
// shell, so the same capture gave different models in different formats.
//
// Method: images are shrunk to at most `max_side` pixels (box filter, grey).
// For up to `max_references` reference views, evenly spaced through the list,
// up to `neighbours` other views looking the same way (optical axes within
// `max_axis_angle_deg`) are picked at quantiles of their baseline. Depth
// planes are uniform in inverse depth between `near_over_extent` and
// `far_over_extent` times the cameras' extent (the largest distance between
// two camera centres), so the sweep has no absolute scale and a similarity
// transform of the cameras moves the points with it. Each neighbour is warped
// onto each plane and compared with the reference by zero-mean normalised
// cross-correlation over (2 `patch_radius` + 1)^2 windows, averaged over the
// neighbours that see the pixel. A pixel yields a point when its patch has
// texture, its best plane scores at least `min_score`, beats the plane
// average by `min_margin` and is not at either end of the range. White walls
// give no points; their edges, furniture and floor seams do.
//
// Pure functions of their arguments, single-threaded and deterministic for a
// given build; safe to call concurrently.
#ifndef CLNERF_CORE_DATA_CONTENT_SWEEP_H_
#define CLNERF_CORE_DATA_CONTENT_SWEEP_H_

#include <vector>

#include "absl/status/status.h"
#include "core/data/scene.h"
#include "Eigen/Core"

namespace clnerf {

struct ContentSweepOptions {
  // Longer image side after shrinking, pixels. Depth only places the box, so
  // a coarse image is enough, and the sweep stays well under a second.
  int max_side = 96;
  // Reference views (evenly spaced through the views given).
  int max_references = 8;
  // Views matched against each reference.
  int neighbours = 4;
  // Neighbours look within this angle of the reference's optical axis.
  float max_axis_angle_deg = 35.0f;
  // Depth planes, uniform in inverse depth. Measured (procedural forward
  // rig, 96 px): 160 planes from 0.03 extents were ~28 px of disparity apart
  // at the widest baseline and matched nothing; 256 from 0.1 extents match
  // on flower_4, beer_2, the procedural forward rig and room in < 1 s.
  int num_depths = 256;
  // The swept range, in multiples of the camera extent.
  float near_over_extent = 0.1f;
  float far_over_extent = 100.0f;
  // ZNCC window half-size, pixels of the shrunk image.
  int patch_radius = 2;
  // Grey-level standard deviation a reference patch needs (0..1 images).
  float min_texture = 0.02f;
  // Best mean ZNCC a pixel needs, and its lead over the mean over planes.
  float min_score = 0.7f;
  float min_margin = 0.25f;

  absl::Status Validate() const;
};

// World points on the content of `views` (which need images). Empty when
// fewer than two views have images, the cameras all sit at one point, no two
// look the same way, or nothing matched.
std::vector<Eigen::Vector3f> EstimateContentPoints(const std::vector<View>& views,
                                                   const ContentSweepOptions& options = {});

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_CONTENT_SWEEP_H_
