// The `clnerf` CLI verbs. main.cc parses flags into these argument structs
// and calls the Run* functions, which return a process exit code (0 = ok) and
// print a one-line reason on failure. Not thread-safe (CLI entry points).
#ifndef CLNERF_CLIENT_COMMANDS_H_
#define CLNERF_CLIENT_COMMANDS_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/remote_commands.h"
#include "nlohmann/json_fwd.hpp"

namespace clnerf {

struct FitOptions;  // core/train/fit.h
struct FitResult;   // core/train/fit.h
struct Scene;       // core/data/scene.h

// Overrides of model capacity (0 / negative = derive from the scene).
struct ModelArgs {
  int levels = 0;
  int log2_table_size = 0;
  int finest_resolution = 0;
  float steps_per_diagonal = 0;
  int occupancy_resolution = 0;
  float cone_angle = -1;           // < 0: derived.
  float near = -1;                 // < 0: derived (model units from the camera).
  float occupancy_threshold = -1;  // < 0: derived (0.01 / min step).
  float distortion = -1;           // < 0: auto (TrainOptions::distortion_reg).
  float near_density = -1;         // < 0: auto (TrainOptions::near_density_reg).
  float near_density_distance = -1;  // < 0: TrainOptions' default.
  float near_density_fade = -1;      // < 0: TrainOptions' default.
  bool random_background = false;
  bool no_embed = false;
};

struct TrainArgs {
  std::string data;
  std::string out;
  int iterations = 2000;
  uint64_t seed = 0;
  int threads = 0;
  float downscale = 1.0f;
  float learning_rate = 1e-2f;
  int target_samples = 1 << 17;
  int curve_every = 0;
  int curve_views = 8;
  std::string json;
  bool eval_after = true;  // Evaluate on the test split when done.
  bool fp16 = false;       // Save the parameters as binary16.
  ModelArgs model;
};

struct EvalArgs {
  std::string model;
  std::string data;
  std::string split = "test";
  std::string json;
  std::string save_dir;
  int max_views = 0;
  int threads = 0;
  float downscale = 1.0f;
};

// `render` renders locally with --model, else on the server (`remote`).
struct RenderArgs {
  std::string model;  // Empty: remote mode.
  std::string out;  // A PNG path for one view, or a directory for many.
  // Either views from a dataset split (--data / --views-from)...
  std::string data;
  std::string split = "test";
  int index = -1;  // -1 = all views of the split.
  // ...or an explicit camera (OpenGL/Blender c2w, row-major 4x4 or 3x4)...
  std::string pose;
  int width = 100, height = 100;
  float focal = 0;  // Pixels; 0 = from camera_angle_x of 0.6911.
  // ...or a nerfstudio camera_path.json.
  std::string camera_path;
  int time_step = -1;
  int threads = 0;
  // Remote mode only.
  int64_t version = 0;  // 0 = the deployed version.
  RemoteOptions remote;
};

struct DemoArgs {
  std::string out = "clnerf-demo";
  int iterations = 600;
  int size = 64;
  uint64_t seed = 0;
  int threads = 0;
  bool thin = false;      // Thin rods (ProceduralSceneOptions::thin_structures).
  bool backdrop = false;  // Unbounded scene (ProceduralSceneOptions::backdrop).
};

struct ScansArgs {
  std::string out = "clnerf-scans";
  int scans = 3;
  int size = 64;
  int train_views = 50;
  int test_views = 8;
  uint64_t seed = 0;
  bool thin = false;  // Thin rods (ProceduralSceneOptions::thin_structures).
};

struct BenchRenderArgs {
  std::string model;
  std::string data;
  std::string sizes = "100,200";  // Square image sizes to time.
  int views = 20;                  // Test views per size.
  int repeats = 3;                 // Renders per view (the median is kept).
  int threads = 0;
  std::string json;
};

// `bench scenes`: trains and evaluates each dataset as `clnerf train` does
// with its defaults, optionally with a table-size sweep around the derived
// capacity, and writes a table (JSON, CSV, markdown) and charts to `out`.
struct BenchScenesArgs {
  std::vector<std::string> dirs;
  std::string out = "bench/results/scenes";
  int iterations = TrainArgs{}.iterations;  // `clnerf train`'s default.
  bool capacity_sweep = false;  // Also log2 tables {derived-2 .. derived+1}, clamped to [12, 20].
  int threads = 0;
  int curve_every = 0;  // PSNR-vs-time curve every N steps (0 = iterations / 10).
  int curve_views = 8;  // Held-out views per curve point.
  int train_views = 8;  // Training views scored for the train-view PSNR.
  bool force = false;   // Re-run configurations whose results are already in `out`.
};

struct BenchContinualArgs {
  std::string method = "clnerf";  // nt|ewc|er|meil|clnerf|clnerf-noer|ub
  std::string data;               // Dataset, scan-folder directory, or "procedural".
  int tasks = 0;                  // 0 = 10 for a static dataset, 5 procedural scans.
  int iterations = 300;           // Training steps per update.
  std::string ub_budget = "total";  // ub: total (tasks x iterations) | per-step (iterations).
  std::string init = "warm";      // reinit|warm
  std::string replay = "offline"; // offline|online
  int buffer = 10;                // K real images (clnerf, er).
  bool prioritized = false;       // Keep the K lowest-PSNR images instead of a reservoir.
  bool no_embed = false;
  float ewc_lambda = 1e5f;
  float warm_lr_scale = 1.0f;     // Learning-rate factor for warm-started updates.
  float new_share = 0.0f;         // Fraction of rays from the new scan (0 = uniform).
  bool copy_embedding = false;    // New time step's embeddings start as the last step's.
  float downscale = 1.0f;
  int procedural_size = 64;       // Image size of the procedural scans.
  uint64_t seed = 0;
  int threads = 0;
  std::string json;
};

// `clnerf bench stability`: every method against every stressor.
struct BenchStabilityArgs {
  std::vector<std::string> methods = {"nt", "ewc", "er", "meil", "clnerf-noer", "clnerf", "ub"};
  std::vector<std::string> stressors;  // Empty = all.
  int scans = 3;
  int size = 32;
  int iterations = 100;
  int batch_samples = 1 << 15;
  uint64_t seed = 0;
  int threads = 0;
  std::string json;
  std::string markdown;  // Also write the table here.
};

// Prints "clnerf: error: <message>" to stderr and returns exit code 1.
int Fail(const absl::Status& status);
// Sets the OpenMP thread count (0 = leave the default: all cores).
void SetThreads(int threads);
// Writes `j` to `path` ("-" = stdout, "" = nowhere).
absl::Status WriteJson(const std::string& path, const nlohmann::json& j);

// `clnerf train`'s pieces, shared by the verbs that train like it: the
// FitOptions its flags give, and FitScene with a progress bar (on stderr,
// labelled `label`) after applying the explicit capacity overrides.
FitOptions MakeFitOptions(const TrainArgs& args);
absl::StatusOr<FitResult> TrainWithProgress(const Scene& scene, FitOptions fo, const ModelArgs& overrides,
                                            const std::string& label = "train");

int RunTrain(const TrainArgs& args);
int RunBenchRender(const BenchRenderArgs& args);
int RunEval(const EvalArgs& args);
int RunRender(const RenderArgs& args);  // Dispatches to RunRemoteRender without --model.
int RunRemoteRender(const RenderArgs& args);
int RunDemo(const DemoArgs& args);
int RunScans(const ScansArgs& args);
int RunBenchContinual(const BenchContinualArgs& args);
int RunBenchScenes(const BenchScenesArgs& args);
int RunBenchStability(const BenchStabilityArgs& args);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_COMMANDS_H_
