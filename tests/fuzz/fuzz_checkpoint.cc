// libFuzzer harness: DeserializeCheckpoint on arbitrary bytes. It must return
// a status (never crash, hang, overflow or read out of bounds), and whatever
// it accepts must be a finite model that renders and serialises again.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include <cstdio>
#include <cstdlib>
#include <string>

#include "core/io/checkpoint.h"
#include "core/render/renderer.h"

// With CLNERF_FUZZ_WRITE_SEED=PATH the binary writes a tiny valid checkpoint
// (2 time steps, fp16) to PATH and exits: the committed seed corpus
// (tests/fuzz/corpus/fuzz_checkpoint/) was made this way.
extern "C" int LLVMFuzzerInitialize(int*, char***) {
  const char* path = std::getenv("CLNERF_FUZZ_WRITE_SEED");
  if (path == nullptr) return 0;
  clnerf::ModelOptions o;
  o.grid.levels = 2;
  o.grid.log2_table_size = 10;
  o.grid.base_resolution = 4;
  o.grid.finest_resolution = 8;
  o.network.density_hidden = 8;
  o.network.density_hidden_layers = 1;
  o.network.colour_hidden = 8;
  o.network.colour_hidden_layers = 1;
  o.network.appearance_dim = 2;
  o.network.geometry_dim = 2;
  o.occupancy.resolution = 8;
  clnerf::Normalization norm;
  norm.scale = 0.5f;
  norm.bound = 0.5f;
  absl::StatusOr<clnerf::NgpModel> m =
      clnerf::NgpModel::Create(o, norm, clnerf::SceneKind::kBounded, Eigen::Vector3f(1, 1, 1), 2, 1);
  if (!m.ok()) {
    std::fprintf(stderr, "%s\n", m.status().ToString().c_str());
    std::exit(1);
  }
  clnerf::CheckpointOptions half;
  half.fp16_params = true;
  absl::StatusOr<size_t> n = clnerf::SaveCheckpoint(*m, path, {}, half);
  std::fprintf(stderr, "seed %s: %s\n", path, n.ok() ? std::to_string(*n).c_str() : n.status().ToString().c_str());
  std::exit(n.ok() ? 0 : 1);
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  absl::StatusOr<clnerf::LoadedCheckpoint> ck = clnerf::DeserializeCheckpoint(bytes, "fuzz");
  if (!ck.ok()) return 0;
  for (const std::vector<float>* block : {&ck->model.params().grid, &ck->model.params().mlp, &ck->model.params().emb}) {
    for (float x : *block) {
      if (!std::isfinite(x)) __builtin_trap();  // Loading must refuse non-finite parameters.
    }
  }
  // A tiny render through the accepted model.
  clnerf::Camera cam;
  cam.intrinsics = {4, 4, 4.0f, 4.0f, 2.0f, 2.0f};
  cam.c2w.col(3) = ck->model.normalization().center + Eigen::Vector3f(0, 0, -2.0f);
  clnerf::RenderOptions ro;
  ro.threads = 1;
  (void)clnerf::RenderView(ck->model, cam, ro);
  if (!clnerf::SerializeCheckpoint(ck->model, ck->extras).ok()) __builtin_trap();
  return 0;
}
