// ScanSequence: the input of continual learning, an ordered list of scans
// (time steps), each with its own training views and held-out test views.
// Three ways to get one:
//   * SplitIntoTasks: a static dataset cut into T contiguous tasks (the
//     paper's Synth-NeRF protocol: 100 training images -> 10 tasks of 10;
//     every test image goes to the task of its nearest training camera);
//   * FromTimeSteps: a scene whose views carry time steps (COLMAP WAT layout,
//     the procedural changing scene);
//   * LoadScanFolders: a directory whose sorted subfolders are the scans.
// Views keep their images; camera.time_step is the scan index. Value type.
#ifndef CLNERF_CORE_CONTINUAL_SCAN_SEQUENCE_H_
#define CLNERF_CORE_CONTINUAL_SCAN_SEQUENCE_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/dataset.h"
#include "core/data/scene.h"

namespace clnerf {

struct Scan {
  std::string name;
  std::vector<View> train;
  std::vector<View> test;
};

struct ScanSequence {
  std::string name;
  SceneKind kind = SceneKind::kBounded;
  Eigen::Vector3f background = Eigen::Vector3f::Ones();
  float aabb_scale = 0.0f;
  float world_scale_hint = 0.0f;
  Eigen::Vector3f world_offset_hint = Eigen::Vector3f::Zero();
  std::vector<Scan> scans;

  int size() const { return int(scans.size()); }
  // All scans up to and including `last` as one Scene (for normalisation,
  // capacity and the upper-bound baseline).
  Scene Union(int last) const;
  // Scan t as a Scene (the sequence's header fields + that scan's views):
  // what ContinualUpdate takes as the new scan.
  Scene ScanScene(int t) const;
};

// Cuts scene.train (in file order) into `num_tasks` contiguous tasks; test
// views (scene.test) go to the task of the nearest training camera centre.
absl::StatusOr<ScanSequence> SplitIntoTasks(const Scene& scene, int num_tasks);
// Groups views by camera.time_step (0..T-1); every step needs training views.
absl::StatusOr<ScanSequence> FromTimeSteps(const Scene& scene);
// Each sorted subfolder of `dir` is one scan, loaded with LoadScene.
absl::StatusOr<ScanSequence> LoadScanFolders(const std::string& dir, const DatasetOptions& options);
// Any of the above, chosen by what `dir` holds: a dataset whose views carry
// several time steps (COLMAP WAT) -> FromTimeSteps; a static dataset ->
// SplitIntoTasks(num_tasks); no dataset but subfolders -> LoadScanFolders.
absl::StatusOr<ScanSequence> LoadScanSequence(const std::string& dir, int num_tasks, const DatasetOptions& options);

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_SCAN_SEQUENCE_H_
