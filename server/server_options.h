// ServerOptions: every setting of clnerf-server, with its default, in one
// commented struct. main() fills it from flags and an optional JSON config
// file (keys are the field names below; nested "update", "gate"); nothing
// else parses flags. Validate() reports the first bad setting.
//
// How the cores are shared: one update worker trains with `train_threads`
// OpenMP threads; at most `render_concurrency` renders run at once, each with
// `render_threads` threads, and further render requests wait (up to
// `render_wait_seconds`, then RESOURCE_EXHAUSTED). Training runs at nice
// `train_nice`, so a render preempts it rather than sharing the cores
// evenly with it.
//
// A plain value type; not synchronised.
#ifndef CLNERF_SERVER_SERVER_OPTIONS_H_
#define CLNERF_SERVER_SERVER_OPTIONS_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/continual/continual_update.h"
#include "core/bake/baker.h"
#include "core/continual/deployment_gate.h"
#include "core/pose/pose_check.h"
#include "core/pose/registration.h"
#include "core/pose/sfm.h"
#include "server/store/scan_assembler.h"

namespace clnerf {

struct ServerOptions {
  std::string listen = "0.0.0.0:50051";  // host:port; port 0 picks a free one.
  // The web viewer and its JSON API over HTTP (http_server.h): host:port,
  // port 0 picks a free one; "" (default) = off. The token applies to its
  // mutating routes too.
  std::string http_listen;
  // Names the HTTP front end answers to besides IP addresses and localhost
  // (the Host header; guards against DNS rebinding, http_origin_guard.h),
  // e.g. "nerf.example.org"; "*" = any name.
  std::vector<std::string> http_allowed_hosts;
  // The HTTP port's limits on a request's head (request line + headers;
  // frontends/http_connection_guard.h): its bytes (beyond: 431) and the time
  // from connecting to its end (beyond: 408).
  int http_max_head_bytes = 32 * 1024;
  double http_head_timeout_seconds = 10;
  std::string store_dir = "clnerf-store";
  std::string token;     // Bearer token for mutating calls ("" = no auth).
  std::string tls_cert;  // PEM certificate chain; with tls_key enables TLS.
  std::string tls_key;

  int max_queue = 8;                    // Scans waiting for training; more -> RESOURCE_EXHAUSTED.
  int render_concurrency = 2;           // Renders running at once.
  // OpenMP threads per render; 0 = adaptive: the cores divided by the big
  // renders running at that moment (at least 1; small ones, which last
  // milliseconds, do not count), so a lone render uses every core and
  // concurrent ones share them.
  int render_threads = 0;
  // Renders of at most this many pixels skip the render-slot queue: they take
  // milliseconds and little memory, so they never wait behind a big one.
  int64_t small_render_pixels = 128 * 128;
  double render_wait_seconds = 30;      // Longest wait for a render slot.
  int train_threads = 2;                // OpenMP threads of the update worker.
  // Updates training at once across all places (each uses train_threads);
  // the others wait their turn, oldest first, round robin among places.
  int max_concurrent_trainings = 1;
  // Nice value (0-19) of the update worker and its training threads: renders
  // get the cores first and training the cycles they leave. 0 = same
  // priority as renders. Measured on fox_8 in the viewer (bench/viewer.sh):
  // see docs/service.md "The web viewer".
  int train_nice = 10;
  int grpc_threads = 16;                // Upper bound on gRPC's sync-server threads.
  int max_message_bytes = 4 << 20;      // Per gRPC message (upload chunks are <= 1 MiB).
  int64_t max_scan_bytes = int64_t(1) << 30;  // Encoded image + mask bytes of one scan.
  int max_frames = 4000;                // Frames (train + test) per scan.
  int64_t max_render_pixels = 4096 * 4096;  // Largest render request (absolute cap).
  // Pixels that the running renders may hold together: one request may ask
  // for at most render_pixel_budget / render_concurrency pixels (and
  // max_render_pixels), so memory stays bounded however the slots are used.
  // Default: 2 slots of 2048 x 2048 (about 180 MB of render scratch each).
  int64_t render_pixel_budget = int64_t(2) * 2048 * 2048;
  // Poison scans: a scan whose training was interrupted (crash, kill, hang
  // ended by a restart) this many times is parked, not retried.
  int max_scan_attempts = 3;
  double store_retry_seconds = 5;       // After a store write error, how often to re-check it.
  // Bytes of loaded models (every place's, every version's) kept in memory;
  // beyond it the least recently used are evicted and reload on their next
  // use (model_registry.h). A model a render or a training holds is never
  // evicted under it, so the resident bytes can exceed the budget by those.
  // 0 = auto: half the machine's physical memory.
  int64_t model_memory_budget = 0;
  // Bytes of baked-asset files (GET /api/asset) kept in memory across places,
  // least recently used evicted first: many viewers of one version cost one
  // read of each file. 0 = none (every request reads the file).
  int64_t asset_memory_budget = int64_t(64) << 20;
  int keep_versions = 0;                // Versions kept on disk (oldest pruned, never the deployed one); 0 = all.
  double shutdown_grace_seconds = 20;   // In-flight RPCs get this long on shutdown.

  // Replicas (coordinator.h): several servers over one shared store, each
  // started with the same etcd. "" (default) = a single server with local
  // locks and no etcd.
  std::string etcd;                    // etcd's client address, HOST:PORT.
  std::string etcd_prefix = "/clnerf"; // Keys of this deployment in etcd.
  // A replica that stops renewing (dead, paused, cut off) loses its places'
  // training leases after this long; another then trains their scans.
  int64_t lease_ttl_seconds = 10;
  // How often a replica looks for scans uploaded through others, and for
  // versions they deployed (which it then loads and serves): the bound on
  // how stale a replica's view is, plus one model load.
  double replica_poll_seconds = 1;

  UpdateOptions update = DefaultUpdateOptions();
  // A place's first scan has no earlier model to start from: it trains this
  // many iterations (by default what `clnerf train` gives a capture) instead
  // of update.train.iterations, so the place starts converged (fox_8, one
  // half as the first scan: 23.08 dB held out at 300 steps, 28.87 at 2000;
  // after a 300-step second visit 25.45 and 28.93; docs/registration.md).
  // 0 = the same as every update.
  int first_scan_iterations = TrainOptions().iterations;
  GateOptions gate;  // The deployment gate (core/continual/deployment_gate.h).
  // Registration of every later scan into its place's frame before it
  // trains (core/pose/registration.h); config object "registration".
  RegistrationOptions registration;
  // Posing of unposed scans (photos, a video's frames) with structure from
  // motion before they register or train (core/pose/sfm.h); config object
  // "posing". The workspace is set per job (under the store), so it stays
  // empty here.
  SfmOptions posing;
  std::string colmap_binary = "colmap";  // Looked up on PATH.
  // Every scan's poses (uploaded, or COLMAP's) are checked against its own
  // photos before it registers or trains (core/pose/pose_check.h): frames
  // turned against the rest are logged and recorded with the version
  // (metrics pose_check_*). "auto" (default) drops them from scans the
  // service posed itself (COLMAP's mirrored frames: two answers for an
  // unposed visit of beer_2's first run, 26.23 -> 27.83 dB and, over three
  // update seeds, 21.5-21.9 -> 24.3-25.2 dB) and warns on poses a user
  // uploaded; "warn" only reports them; "drop" also trains and gates
  // without them; "off" skips the check. Config object "pose_check":
  // action, min_inliers, max_disagreement_deg, sequence_neighbours,
  // min_chance_ratio, pose_px, min_explained_fraction, estimator.
  std::string pose_check_action = "auto";
  PoseCheckOptions pose_check;
  // Baking (issue 41; core/bake/baker.h, docs/baking.md): each new
  // version's latest time step is baked into the asset the browser renders
  // itself, after the gate and before the publish (job phase BAKING), so a
  // version is viewable the moment it is deployed; other time steps are
  // baked on their first request (GET /api/asset) and kept beside the
  // version. A failed bake never stops a publish. Config object "bake":
  // on_publish, resolution, min_block_weight, visibility_rays,
  // in_between_views, fit_rays,
  // fit_max_entries, fit_max_model_samples, density_fit_rays (0 = off),
  // max_asset_bytes, max_object_asset_bytes.
  bool bake_on_publish = true;
  BakeOptions bake;

  // CLNeRF with warm start, offline replay, 300 iterations per update
  // (a lego_100 task in ~35 s on 2 cores; see docs/benchmarks.md).
  static UpdateOptions DefaultUpdateOptions();
  absl::Status Validate() const;
  // The limits ScanAssembler checks for each upload.
  UploadLimits upload_limits() const;
};

// model_memory_budget with "auto" (0) resolved.
int64_t ResolvedModelMemoryBudget(const ServerOptions& options);

// Applies a JSON config (an object whose keys are field names above; unknown
// keys are errors so typos do not pass silently) on top of `options`.
absl::Status ApplyConfigJson(const std::string& json_text, ServerOptions* options);
absl::Status ApplyConfigFile(const std::string& path, ServerOptions* options);

}  // namespace clnerf

#endif  // CLNERF_SERVER_SERVER_OPTIONS_H_
