// `clnerf scans`: writes the procedural changing scene as one Blender-format
// folder per scan (scan_000, scan_001, ...), ready for `clnerf upload`. Each
// scan changes the lighting and the geometry, like a room rescanned days
// apart. This is the embedded default data of the service demo.
#include <cstdio>

#include "absl/strings/str_format.h"
#include "client/commands.h"
#include "core/data/procedural_scene.h"
#include "spdlog/spdlog.h"

namespace clnerf {

int RunScans(const ScansArgs& a) {
  ProceduralSceneOptions po;
  po.seed = a.seed;
  po.width = po.height = a.size;
  po.num_train_views = a.train_views;
  po.num_test_views = a.test_views;
  po.num_time_steps = a.scans;
  po.thin_structures = a.thin;
  spdlog::info("generating {} scans of the procedural changing scene ({} train / {} test views each, {}x{})", a.scans,
               po.num_train_views, po.num_test_views, a.size, a.size);
  absl::StatusOr<ProceduralDataset> data = GenerateProceduralDataset(po);
  if (!data.ok()) return Fail(data.status());
  if (absl::Status s = WriteScanFolders(*data, a.out); !s.ok()) return Fail(s);
  for (int t = 0; t < a.scans; ++t) std::printf("%s/scan_%03d\n", a.out.c_str(), t);
  return 0;
}

}  // namespace clnerf
