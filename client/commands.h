// The local `clnerf` CLI verbs (the engine in-process) and the benchmarks.
// Each verb has a Bind* function, which adds its subcommand and binds its
// flags onto an argument struct (registered in client/verbs.cc), and a Run*
// function, which returns a process exit code (0 = ok) and prints a one-line
// reason on failure. Not thread-safe (CLI entry points).
#ifndef CLNERF_CLIENT_COMMANDS_H_
#define CLNERF_CLIENT_COMMANDS_H_

#include <cstdint>
#include <set>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/remote_commands.h"
#include "core/bake/baker.h"
#include "core/continual/continual_protocol.h"
#include "core/continual/continual_update.h"
#include "core/continual/stability.h"
#include "core/data/dataset_options.h"
#include "core/data/procedural_scene.h"
#include "core/pose/pose_check.h"
#include "core/pose/registration.h"
#include "core/render/evaluate.h"
#include "core/train/fit.h"
#include "nlohmann/json_fwd.hpp"

namespace clnerf {

// Each verb's arguments: the verb's own flags (paths, output files) plus the
// core Options structs its flags bind to directly (client/verb_set.h), so a
// flag's default is the core default unless the verb sets its own (noted).

struct TrainArgs {
  std::string data;
  std::string out;
  std::string json;
  bool eval_after = true;  // Evaluate on the test split when done.
  bool fp16 = false;       // Save the parameters as binary16.
  // The capture's poses against its photos before training
  // (core/pose/pose_check.h): "warn" reports disputed frames, "drop" also
  // trains without them, "repair" moves them into the others' frame
  // (core/pose/run_repair.h), "off" skips the check.
  std::string pose_check = "warn";
  PoseCheckOptions check;
  DatasetOptions dataset;
  FitOptions fit;
};

struct EvalArgs {
  std::string model;
  std::string data;
  std::string split = "test";
  std::string json;
  int threads = 0;
  EvalOptions eval;
  DatasetOptions dataset;
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
  DatasetOptions dataset;  // How --data is read (its split, image folder, size).
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
  ProceduralSceneOptions scene;  // The verb's defaults: 60 train / 12 test views.
  FitOptions fit;                // The verb's default: 600 iterations.
};

struct ScansArgs {
  std::string out = "clnerf-scans";
  ProceduralSceneOptions scene;  // The verb's defaults: 3 scans, 8 test views each.
};

struct BenchRenderArgs {
  std::string model;
  std::string data;
  std::string sizes = "100,200";  // Square image sizes to time.
  int views = 20;                  // Test views per size.
  int repeats = 3;                 // Renders per view (the median is kept).
  int threads = 0;
  std::string json;
  DatasetOptions dataset;          // How --data is read.
};

// `bench scenes`: trains and evaluates each dataset as `clnerf train` does
// with its defaults, optionally with a table-size sweep around the derived
// capacity, and writes a table (JSON, CSV, markdown) and charts to `out`.
struct BenchScenesArgs {
  std::vector<std::string> dirs;
  std::string out = "bench/results/scenes";
  FitOptions fit;               // `clnerf train`'s defaults; --iters, --threads, --curve-views.
  bool capacity_sweep = false;  // Also log2 tables {derived-2 .. derived+1}, clamped to [12, 20].
  int curve_every = 0;  // PSNR-vs-time curve every N steps (0 = iterations / 10).
  int train_views = 8;  // Training views scored for the train-view PSNR.
  bool force = false;   // Re-run configurations whose results are already in `out`.
};

struct BenchContinualArgs {
  std::string method = "clnerf";  // A ContinualMethod name, or ub.
  std::string data;               // Dataset, scan-folder directory, or "procedural".
  int tasks = 0;                  // 0 = 10 for a static dataset, 5 procedural scans.
  UbBudget ub_budget = UbBudget::kTotal;
  bool paper_protocol = false;    // Every update: re-init, ub's whole budget.
  // ub's sampling: uniform over views by default (its best: the error
  // sampling the updates use measured no gain for ub).
  float ub_error_share = 0.0f;
  UpdateOptions update;           // The verb's default: 300 iterations per update.
  DatasetOptions dataset;
  int procedural_size = 64;       // Image size of the procedural scans.
  std::string json;
};

// `clnerf bench stability`: every method against every stressor.
struct BenchStabilityArgs {
  std::vector<std::string> methods = {"nt", "ewc", "er", "meil", "clnerf-noer", "clnerf", "ub"};
  std::vector<std::string> stressors;  // Empty = all.
  StabilityOptions stability;
  std::string json;
  std::string markdown;  // Also write the table here.
};

// `clnerf bench register`: a capture split into two visits; the second is
// registered into the first's model (core/pose/registration.h), in the
// place's frame and in its own.
struct BenchRegisterArgs {
  std::string data;               // Dataset folder, or "procedural".
  FitOptions fit;                 // θ_A (the verb sets 1000 iterations).
  RegistrationOptions registration;
  DatasetOptions dataset;
  double rotation_deg = 40, scale = 1.7;  // The second visit's own frame.
  uint64_t seed = 1;              // Axis and shift of that frame.
  int threads = 0;
  bool verbose = false;           // Per-frame PnP figures.
  std::string model;              // θ_A's checkpoint: loaded if it exists, else trained and saved there.
  std::string json;
};

struct BenchRescanArgs {
  std::string data;               // Dataset folder, or "procedural".
  int first_iterations = TrainOptions().iterations;  // Visit A (the place's first scan), as the server gives it.
  UpdateOptions update;           // Visit B's update (the verb sets 1000 iterations).
  RegistrationOptions registration;
  DatasetOptions dataset;
  double rotation_deg = 40, scale = 1.7;  // Visit B's own frame.
  uint64_t seed = 1;
  std::string cases = "place,own,unposed,unposed-first";
  int eval_views = 0;             // Held-out views scored (0 = all).
  // unposed-first: training seeds compared, each with its own COLMAP run and
  // its own posed baseline (one seed's held-out PSNR says little: on the
  // procedural capture, visit A with its known poses scores 23.8-28.5 dB
  // over four seeds).
  int first_seeds = 3;
  // Visit B's update is trained with this many seeds (train seed, +1, ...)
  // after one registration; the rows report their mean PSNRs.
  int update_seeds = 1;
  std::string save_renders;  // When set: visit A's held-out renders and photos are written here.
  std::string place_cache;   // Visit A's trained state: read when the file exists, else written.
  std::string posing_cache;  // COLMAP's poses of visit B: read when the file exists, else written.
  // Visit B's poses checked against its photos before registration, as the
  // update worker checks every scan: "auto" (the service's default: drop
  // the disputed frames of a scan COLMAP posed, warn otherwise), "warn",
  // "drop" (train without the disputed frames) or "off".
  std::string pose_check = "auto";
  PoseCheckOptions check;
  int threads = 0;
  std::string json;
};

// Prints "clnerf: error: <message>" to stderr and returns exit code 1.
int Fail(const absl::Status& status);
// Sets the OpenMP thread count (0 = leave the default: all cores).
void SetThreads(int threads);
// Writes `j` to `path` ("-" = stdout, "" = nowhere).
absl::Status WriteJson(const std::string& path, const nlohmann::json& j);
// An evaluation as JSON (means and per-view scores).
nlohmann::json EvalJson(const EvalResult& r);

// `bake`: a model (a file, or a service version's model.ckpt) baked into
// the asset the browser renders (core/bake/baker.h).
struct BakeArgs {
  std::string model;
  std::string out;   // Folder for manifest.json, index.bin.gz, atlas.bin.gz.
  std::string data;  // Training cameras, when the model file holds none.
  std::string json;
  int time_step = -1;
  int threads = 0;
  BakeOptions bake;
  DatasetOptions dataset;
};

// `check-poses`: a capture's poses against its own photos
// (core/pose/pose_check.h).
struct CheckPosesArgs {
  std::string data;
  std::string split = "all";
  std::string json;
  int threads = 0;
  PoseCheckOptions check;
  DatasetOptions dataset;
};
CLI::App* BindCheckPoses(CLI::App* parent, CheckPosesArgs* args);
int RunCheckPoses(const CheckPosesArgs& args);
// The report as JSON, frames named by `views` (those it was made over).
nlohmann::json PoseCheckJson(const PoseCheckReport& report, const std::vector<View>& views);
// `clnerf train`'s pose check over `scene`'s capture (args.pose_check): warns
// about disputed frames and, with "drop", trains without the disputed
// training views. Returns the report as JSON (null when off or without
// images) and the names of disputed test views; after a repair,
// `given_test` holds the test views at the poses they came with.
absl::StatusOr<nlohmann::json> CheckTrainingPoses(const TrainArgs& args, Scene* scene,
                                                  std::set<std::string>* disputed_test,
                                                  std::vector<View>* given_test);

// FitScene with a progress bar on stderr, labelled `label` (`clnerf train`
// and the verbs that train like it).
absl::StatusOr<FitResult> TrainWithProgress(const Scene& scene, const FitOptions& options,
                                            const std::string& label = "train");

// Each verb's Bind adds its subcommand under `parent` with its flags bound
// onto `args` (see client/verb_set.h); its Run runs it.
CLI::App* BindTrain(CLI::App* parent, TrainArgs* args);
CLI::App* BindEval(CLI::App* parent, EvalArgs* args);
CLI::App* BindBake(CLI::App* parent, BakeArgs* args);
CLI::App* BindRender(CLI::App* parent, RenderArgs* args);
CLI::App* BindDemo(CLI::App* parent, DemoArgs* args);
CLI::App* BindScans(CLI::App* parent, ScansArgs* args);
CLI::App* BindBenchRender(CLI::App* parent, BenchRenderArgs* args);
CLI::App* BindBenchScenes(CLI::App* parent, BenchScenesArgs* args);
CLI::App* BindBenchContinual(CLI::App* parent, BenchContinualArgs* args);
CLI::App* BindBenchStability(CLI::App* parent, BenchStabilityArgs* args);
CLI::App* BindBenchRegister(CLI::App* parent, BenchRegisterArgs* args);
CLI::App* BindBenchRescan(CLI::App* parent, BenchRescanArgs* args);

int RunTrain(const TrainArgs& args);
int RunBenchRender(const BenchRenderArgs& args);
int RunEval(const EvalArgs& args);
// RunEval's scoring of a baked asset folder (--model DIR) on `views`.
int EvalBakedAsset(const EvalArgs& args, const std::vector<View>& views);
int RunBake(const BakeArgs& args);
int RunRender(const RenderArgs& args);  // Dispatches to RunRemoteRender without --model.
int RunRemoteRender(const RenderArgs& args);
int RunDemo(const DemoArgs& args);
int RunScans(const ScansArgs& args);
int RunBenchContinual(const BenchContinualArgs& args);
int RunBenchScenes(const BenchScenesArgs& args);
int RunBenchStability(const BenchStabilityArgs& args);
int RunBenchRegister(const BenchRegisterArgs& args);
int RunBenchRescan(const BenchRescanArgs& args);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_COMMANDS_H_
