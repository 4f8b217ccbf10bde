// The `clnerf` CLI verbs. main.cc parses flags into these argument structs
// and calls the Run* functions, which return a process exit code (0 = ok) and
// print a one-line reason on failure. Not thread-safe (CLI entry points).
#ifndef CLNERF_CLIENT_COMMANDS_H_
#define CLNERF_CLIENT_COMMANDS_H_

#include <cstdint>
#include <string>

#include "absl/status/status.h"

namespace clnerf {

// Overrides of model capacity (0 / negative = derive from the scene).
struct ModelArgs {
  int levels = 0;
  int log2_table_size = 0;
  int finest_resolution = 0;
  float steps_per_diagonal = 0;
  int occupancy_resolution = 0;
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

struct RenderArgs {
  std::string model;
  std::string out;  // A PNG path for one view, or a directory for many.
  // Either views from a dataset split...
  std::string data;
  std::string split = "test";
  int index = -1;  // -1 = all views of the split.
  // ...or an explicit camera (OpenGL/Blender c2w, row-major 4x4 or 3x4).
  std::string pose;
  int width = 100, height = 100;
  float focal = 0;  // Pixels; 0 = from camera_angle_x of 0.6911.
  int time_step = -1;
  int threads = 0;
};

struct DemoArgs {
  std::string out = "clnerf-demo";
  int iterations = 600;
  int size = 64;
  uint64_t seed = 0;
  int threads = 0;
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

// Prints "clnerf: error: <message>" to stderr and returns exit code 1.
int Fail(const absl::Status& status);

int RunTrain(const TrainArgs& args);
int RunBenchRender(const BenchRenderArgs& args);
int RunEval(const EvalArgs& args);
int RunRender(const RenderArgs& args);
int RunDemo(const DemoArgs& args);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_COMMANDS_H_
