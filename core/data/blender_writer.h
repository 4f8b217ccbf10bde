// BlenderWriter: stores any Scene in the NeRF-synthetic ("Blender") format,
// the inverse of core/data/blender_loader.h: one dataset folder, or one folder per
// time step (the "directory of scan folders" input of continual learning).
// Used by the procedural scene generator, the demos and the tests.
//
// Thread-safety: pure functions (they write only under `dir`).
#ifndef CLNERF_CORE_DATA_BLENDER_WRITER_H_
#define CLNERF_CORE_DATA_BLENDER_WRITER_H_

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "core/data/scene.h"

namespace clnerf {

// Per-view alpha channels parallel to scene.train / val / test (each inner
// vector has width * height entries).
struct ViewAlphas {
  std::vector<std::vector<float>> train, val, test;
};

// Writes `scene` in the NeRF-synthetic (Blender) format under `dir` (created
// if needed): transforms_{train,val,test}.json with "camera_angle_x" and
// frames {"file_path": "./<split>/r_<i>", "rotation", "time_step",
// "transform_matrix" (4x4, OpenGL convention via ExportPose)}, and RGBA PNGs
// <dir>/<split>/r_<i>.png. If scene.val is empty, transforms_val.json lists
// the test frames (pointing at the test images). PNG colours are straight
// (unassociated) alpha, un-composited from scene.background with `alpha`, so
// compositing the PNG again reproduces the image to 8-bit precision; without
// `alpha`, alpha = 1. Empty splits get a json with no frames. All views of a
// split must share one pinhole camera model (same size, fx == fy, centred
// principal point, no distortion) and have images; otherwise INVALID_ARGUMENT.
// I/O failures give INTERNAL. Existing files in `dir` are overwritten. The
// format has no scene kind: a backdrop (kUnbounded) scene written here loads
// back as a bounded object scene.
absl::Status WriteBlenderDataset(const Scene& scene, const std::string& dir,
                                 const ViewAlphas* alpha = nullptr);

// Writes one Blender-format folder per time step, <dir>/scan_000,
// <dir>/scan_001, ..., each holding the views with that time step (indices
// restart at 0 per folder; frames keep their original "time_step"). This is
// the "directory of scan folders" input of continual learning. Every time
// step in [0, scene.num_time_steps()) must have at least one train view.
absl::Status WriteScanFolders(const Scene& scene, const std::string& dir,
                              const ViewAlphas* alpha = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_BLENDER_WRITER_H_
