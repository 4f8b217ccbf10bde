// `clnerf scans`: writes the procedural changing scene as one Blender-format
// folder per scan (scan_000, scan_001, ...), ready for `clnerf upload`. Each
// scan changes the lighting and the geometry, like a room rescanned days
// apart. This is the embedded default data of the service demo.
#include <cstdio>

#include "absl/strings/str_format.h"
#include "client/commands.h"
#include "client/core_flags.h"
#include "client/verb_set.h"
#include "core/data/procedural_scene.h"
#include "spdlog/spdlog.h"

namespace clnerf {

CLI::App* BindScans(CLI::App* parent, ScansArgs* a) {
  CLI::App* c =
      parent->add_subcommand("scans", "Write scans of the procedural changing scene (one folder per scan, for upload)");
  ProceduralSceneOptions& po = a->scene;
  po.num_time_steps = 3;
  po.num_test_views = 8;
  c->add_option("--out", a->out, "Output directory")->capture_default_str();
  c->add_option("--scans", po.num_time_steps, "Number of scans (time steps)")->capture_default_str();
  BindSquareSizeFlag(c, &po);
  c->add_option("--train-views", po.num_train_views, "Training views per scan")->capture_default_str();
  c->add_option("--test-views", po.num_test_views, "Held-out views per scan")->capture_default_str();
  c->add_option("--seed", po.seed, "Random seed")->capture_default_str();
  c->add_flag("--thin", po.thin_structures, "Add thin rods (about a pixel wide) to the scene");
  return c;
}

int RunScans(const ScansArgs& a) {
  const ProceduralSceneOptions& po = a.scene;
  spdlog::info("generating {} scans of the procedural changing scene ({} train / {} test views each, {}x{})",
               po.num_time_steps, po.num_train_views, po.num_test_views, po.width, po.height);
  absl::StatusOr<ProceduralDataset> data = GenerateProceduralDataset(po);
  if (!data.ok()) return Fail(data.status());
  if (absl::Status s = WriteScanFolders(*data, a.out); !s.ok()) return Fail(s);
  for (int t = 0; t < po.num_time_steps; ++t) std::printf("%s/scan_%03d\n", a.out.c_str(), t);
  return 0;
}

}  // namespace clnerf
