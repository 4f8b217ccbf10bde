// The remote `clnerf` verbs: they talk to a clnerf server (clnerf.v1 over
// gRPC) instead of running the engine in-process. Each verb's Bind* function
// binds its flags onto its argument struct; each Run* function returns a process exit code and,
// on failure, prints one line "clnerf <verb>: <CODE>: <message>" to stderr.
// Results go to stdout (a human line or table, or JSON with --json); logs and
// progress bars go to stderr. Not thread-safe (CLI entry points).
//
// Exit codes: 0 ok; 1 an RPC, I/O or argument error; 2 the watched job
// FAILED; 3 the watched job was CANCELLED.
#ifndef CLNERF_CLIENT_REMOTE_COMMANDS_H_
#define CLNERF_CLIENT_REMOTE_COMMANDS_H_

#include <cstdint>
#include <string>

namespace CLI {
class App;
}  // namespace CLI

namespace clnerf {

// Flags shared by every remote verb (see remote_client.h for their meaning).
struct RemoteOptions {
  std::string server;           // HOST:PORT; DefaultServer() when not given.
  std::string token;            // Bearer token; empty = none.
  double timeout_seconds = -1;  // Per-RPC deadline; < 0 = the verb's default.
  std::string tls_ca;           // PEM root certificate file; empty = plaintext.
  bool json = false;            // Machine-readable output on stdout.
  std::string place;            // The place meant; "" = "default" ($CLNERF_PLACE).
};

// $CLNERF_SERVER, else "localhost:50051".
std::string DefaultServer();
// $CLNERF_TOKEN, else "".
std::string DefaultToken();

inline constexpr int kExitJobFailed = 2;
inline constexpr int kExitJobCancelled = 3;

struct UploadArgs {
  RemoteOptions remote;
  std::string dir;                  // Any dataset LoadScene() reads.
  std::string name;                 // Scan name; default: the folder's name.
  std::string test_split = "test";  // test|val|none (test falls back to val).
  bool watch = false;               // Then follow the job like `watch`.
  // own: the poses are in the capture's own frame (registered into the
  // place's by the server); place: already in the place's frame.
  std::string pose_frame = "own";
  // Unposed uploads (the server poses them): `dir` a folder of photos only,
  // a video file, or any dataset with --unposed (its poses are not sent).
  bool unposed = false;
  bool sequential = false;  // Photos in capture order (always for a video).
  int video_frames = 60;    // Frames kept from a video (sharpest per window).
  int video_max_side = 640; // Longer side of the kept frames.
};

struct JobArgs {  // watch, cancel.
  RemoteOptions remote;
  std::string job_id;
};

struct ListArgs {  // jobs, versions, info.
  RemoteOptions remote;
};

struct CamerasArgs {
  RemoteOptions remote;
  int64_t version = 0;  // 0 = deployed.
  int time_step = -1;   // -1 = every time step.
};

struct LocalizeArgs {
  RemoteOptions remote;
  int64_t version = 0;              // 0 = deployed.
  std::vector<std::string> photos;  // Image files (or folders of them).
  // Optional pinhole intrinsics for every photo (0 = guessed by the server).
  float fx = 0, fy = 0, cx = -1, cy = -1;
};

struct RollbackArgs {
  RemoteOptions remote;
  int64_t version = 0;
};

struct PlacesArgs {
  RemoteOptions remote;
  std::string action = "list";  // list | create | delete.
  std::string name;
  bool yes = false;             // delete: confirmed.
};

struct BenchServeArgs {
  RemoteOptions remote;
  std::string data = "../shared/data/lego_100";  // Dataset cut into tasks, or "procedural".
  int tasks = 10;                  // Tasks for a static dataset (scans 0 and 1 are used).
  std::string sizes = "32,100,200";  // Square render sizes.
  std::string clients = "1,4";       // Concurrent clients.
  std::string store;                 // The server's store (optional): in-process reference renders.
  int renders_per_client = 6;      // Requests per client per configuration.
  std::string json;
};

struct BenchPlacesArgs {
  RemoteOptions remote;
  int seed = 0;               // > 0: create and train places up to this many, then stop.
  int renders = 200;          // Warm renders, round robin over the places.
  int server_pid = 0;         // For the server's resident memory (0 = not measured).
  bool upload_served = false; // Also time an upload's acknowledgement -> served.
  std::string label;
  std::string json;
};

// Each verb's Bind adds its subcommand under `parent` with its flags bound
// onto `args` (see client/verb_set.h); its Run runs it.
CLI::App* BindUpload(CLI::App* parent, UploadArgs* args);
CLI::App* BindBenchServe(CLI::App* parent, BenchServeArgs* args);
CLI::App* BindBenchPlaces(CLI::App* parent, BenchPlacesArgs* args);
CLI::App* BindWatch(CLI::App* parent, JobArgs* args);
CLI::App* BindJobs(CLI::App* parent, ListArgs* args);
CLI::App* BindCancel(CLI::App* parent, JobArgs* args);
CLI::App* BindVersions(CLI::App* parent, ListArgs* args);
CLI::App* BindRollback(CLI::App* parent, RollbackArgs* args);
CLI::App* BindInfo(CLI::App* parent, ListArgs* args);
CLI::App* BindPlaces(CLI::App* parent, PlacesArgs* args);
CLI::App* BindCameras(CLI::App* parent, CamerasArgs* args);
CLI::App* BindLocalize(CLI::App* parent, LocalizeArgs* args);

int RunUpload(const UploadArgs& args);
int RunBenchServe(const BenchServeArgs& args);
int RunBenchPlaces(const BenchPlacesArgs& args);
int RunWatch(const JobArgs& args);
int RunJobs(const ListArgs& args);
int RunCancel(const JobArgs& args);
int RunVersions(const ListArgs& args);
int RunRollback(const RollbackArgs& args);
int RunInfo(const ListArgs& args);
int RunPlaces(const PlacesArgs& args);
int RunCameras(const CamerasArgs& args);
int RunLocalize(const LocalizeArgs& args);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_REMOTE_COMMANDS_H_
