// `clnerf bench places`: one server holding many places (bench/places.sh runs
// it against servers on stores of 1, 10 and 50 places):
//   --seed N       makes sure places bench-000 .. bench-(N-1) exist, each with
//                  a deployed model of a small procedural 100x100 scene;
//   (measure)      on the server's places: the server's resident memory
//                  (--server-pid), each place's first render and whether its
//                  model had to load (cold) or was in memory (warm), then warm
//                  100x100 renders round robin over every place, and, with
//                  --upload-served, the time from an upload's acknowledgement
//                  to its version being served.
// Prints one human line and writes JSON.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/commands.h"
#include "client/remote_client.h"
#include "client/remote_commands.h"
#include "client/percentile.h"
#include "client/remote_format.h"
#include "client/scan_upload.h"
#include "client/verb_set.h"
#include "core/continual/scan_sequence.h"
#include "core/data/procedural_scene.h"
#include "nlohmann/json.hpp"
#include "proto/wire/wire.h"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

constexpr const char* kPlacesBenchVerb = "bench places";
using Clock = std::chrono::steady_clock;

absl::Status RpcError(const std::string& what, const grpc::Status& s) {
  return absl::UnavailableError(absl::StrCat(what, ": ", StatusCodeName(s.error_code()), ": ", s.error_message()));
}

// The server's resident set (kB in /proc/PID/status), in bytes; 0 if unknown.
int64_t ResidentBytes(int pid) {
  if (pid <= 0) return 0;
  std::ifstream f(absl::StrCat("/proc/", pid, "/status"));
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::atoll(line.c_str() + 6) * 1024;
  }
  return 0;
}

absl::StatusOr<std::vector<clnerf::v1::Place>> ListPlaces(RemoteClient& c) {
  clnerf::v1::ListPlacesResponse r;
  auto ctx = c.Context(kUnaryTimeoutSeconds);
  grpc::Status s = c.service().ListPlaces(ctx.get(), clnerf::v1::ListPlacesRequest(), &r);
  if (!s.ok()) return RpcError("list places", s);
  return std::vector<clnerf::v1::Place>(r.places().begin(), r.places().end());
}

// Uploads `scan` to `place`; returns the job id and the acknowledgement time.
absl::StatusOr<std::pair<std::string, Clock::time_point>> UploadTo(RemoteClient& c, const std::string& place,
                                                                   const Scene& scan, const std::string& name) {
  absl::StatusOr<EncodedScan> enc = EncodeScan(name, scan.kind, scan.train, scan.test);
  if (!enc.ok()) return enc.status();
  enc->header.mutable_header()->set_pose_frame("place");  // Procedural scans share one frame.
  enc->header.mutable_header()->set_place(place);
  SendResult r = SendScan(c, *enc, nullptr);
  if (!r.status.ok()) return RpcError(absl::StrCat("upload to ", place), r.status);
  return std::make_pair(r.response.job_id(), Clock::now());
}

// Waits for the job, then for a render of `place` that reports its version.
absl::StatusOr<int64_t> WaitServed(RemoteClient& c, const std::string& place, const std::string& job_id,
                                   const Camera& cam) {
  clnerf::v1::Job job;
  while (true) {
    clnerf::v1::GetJobRequest req;
    req.set_job_id(job_id);
    req.set_place(place);
    auto ctx = c.Context(kUnaryTimeoutSeconds);
    grpc::Status s = c.service().GetJob(ctx.get(), req, &job);
    if (!s.ok()) return RpcError("get job", s);
    if (IsTerminal(job.phase())) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  if (job.phase() != clnerf::v1::JOB_PHASE_DONE) {
    return absl::AbortedError(absl::StrCat("job ", job_id, " of ", place, " ended ", PhaseName(job.phase()), ": ",
                                           job.error()));
  }
  while (true) {
    clnerf::v1::RenderRequest req;
    Camera small = cam;
    small.intrinsics = small.intrinsics.Scaled(8, 8);
    *req.mutable_camera() = CameraToProto(small);
    req.set_place(place);
    clnerf::v1::RenderResponse resp;
    auto ctx = c.Context(kUnaryTimeoutSeconds);
    if (c.service().Render(ctx.get(), req, &resp).ok() && resp.version() >= job.version()) return job.version();
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

absl::StatusOr<double> RenderMs(RemoteClient& c, const std::string& place, const Camera& cam) {
  clnerf::v1::RenderRequest req;
  *req.mutable_camera() = CameraToProto(cam);
  req.set_place(place);
  clnerf::v1::RenderResponse resp;
  auto ctx = c.Context(kRenderTimeoutSeconds);
  const auto t0 = Clock::now();
  grpc::Status s = c.service().Render(ctx.get(), req, &resp);
  const double ms = Ms(Clock::now() - t0);
  if (!s.ok()) return RpcError(absl::StrCat("render ", place), s);
  return ms;
}

std::string PlaceName(int i) { return absl::StrFormat("bench-%03d", i); }

}  // namespace

CLI::App* BindBenchPlaces(CLI::App* parent, BenchPlacesArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "places", "Many places on one server: memory, cold and warm renders, upload-to-served time");
  c->add_option("--seed", a->seed, "Create places bench-000.. with a model each, up to this many, then stop")
      ->capture_default_str();
  c->add_option("--renders", a->renders, "Warm 100x100 renders, round robin over the places")->capture_default_str();
  c->add_option("--server-pid", a->server_pid, "The server's process id (for its resident memory)");
  c->add_flag("--upload-served", a->upload_served,
              "Also upload a second scan to bench-000 and time acknowledgement -> served");
  c->add_option("--label", a->label, "A name for this run in the output")->capture_default_str();
  c->add_option("--json-out", a->json, "Write JSON here ('-' = stdout)");
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunBenchPlaces(const BenchPlacesArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote(kPlacesBenchVerb, client.status());
  RemoteClient& c = **client;
  // The scene: procedural, 100x100, two time steps (seed with the first,
  // time the upload of the second).
  ProceduralSceneOptions po;
  po.num_time_steps = 2;
  po.width = po.height = 100;
  po.num_train_views = 10;
  po.num_test_views = 8;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  if (!scene.ok()) return FailRemote(kPlacesBenchVerb, scene.status());
  absl::StatusOr<ScanSequence> seq = FromTimeSteps(*scene);
  if (!seq.ok()) return FailRemote(kPlacesBenchVerb, seq.status());
  const Scene scan0 = seq->ScanScene(0), scan1 = seq->ScanScene(1);
  std::vector<Camera> cams;
  for (const View& v : scan0.test) cams.push_back(v.camera);

  nlohmann::json j;
  j["label"] = a.label;
  if (a.seed > 0) {
    absl::StatusOr<std::vector<clnerf::v1::Place>> have = ListPlaces(c);
    if (!have.ok()) return FailRemote(kPlacesBenchVerb, have.status());
    std::map<std::string, int64_t> deployed;
    for (const auto& p : *have) deployed[p.name()] = p.deployed_version();
    const auto t0 = Clock::now();
    int made = 0;
    for (int i = 0; i < a.seed; ++i) {
      const std::string name = PlaceName(i);
      if (deployed.count(name) && deployed[name] > 0) continue;
      if (!deployed.count(name)) {
        clnerf::v1::CreatePlaceRequest req;
        req.set_name(name);
        clnerf::v1::Place p;
        auto ctx = c.Context(kUnaryTimeoutSeconds);
        grpc::Status s = c.service().CreatePlace(ctx.get(), req, &p);
        if (!s.ok()) return FailRemote(kPlacesBenchVerb, RpcError("create " + name, s));
      }
      absl::StatusOr<std::pair<std::string, Clock::time_point>> up = UploadTo(c, name, scan0, "bench-seed");
      if (!up.ok()) return FailRemote(kPlacesBenchVerb, up.status());
      absl::StatusOr<int64_t> v = WaitServed(c, name, up->first, cams[0]);
      if (!v.ok()) return FailRemote(kPlacesBenchVerb, v.status());
      ++made;
      spdlog::info("seeded {} ({}/{})", name, i + 1, a.seed);
    }
    j["seeded"] = made;
    j["seed_seconds"] = std::chrono::duration<double>(Clock::now() - t0).count();
    std::printf("bench places --seed %d: %d place(s) made in %.1f s\n", a.seed, made,
                j["seed_seconds"].get<double>());
    if (!a.json.empty()) {
      if (absl::Status s = WriteJson(a.json, j); !s.ok()) return FailRemote(kPlacesBenchVerb, s);
    }
    return 0;
  }

  absl::StatusOr<std::vector<clnerf::v1::Place>> places = ListPlaces(c);
  if (!places.ok()) return FailRemote(kPlacesBenchVerb, places.status());
  std::vector<std::string> names;
  int loaded_before = 0;
  std::map<std::string, bool> was_loaded;
  for (const auto& p : *places) {
    if (p.deployed_version() <= 0) continue;
    names.push_back(p.name());
    was_loaded[p.name()] = p.loaded();
    loaded_before += p.loaded() ? 1 : 0;
  }
  if (names.empty()) return FailRemote(kPlacesBenchVerb, absl::FailedPreconditionError("no place has a model: run --seed first"));
  const int64_t rss_before = ResidentBytes(a.server_pid);

  // First render of each place: cold if its model was not in memory.
  std::vector<double> cold, first_warm;
  for (size_t i = 0; i < names.size(); ++i) {
    absl::StatusOr<double> ms = RenderMs(c, names[i], cams[i % cams.size()]);
    if (!ms.ok()) return FailRemote(kPlacesBenchVerb, ms.status());
    (was_loaded[names[i]] ? first_warm : cold).push_back(*ms);
  }
  // Warm renders: round robin; a render is warm if every model stays in
  // memory (with a budget below the places' total, these are loads too:
  // reported as such by the loaded counts below).
  std::vector<double> warm;
  int failures = 0;
  std::string first_error;
  for (int r = 0; r < a.renders; ++r) {
    const std::string& name = names[size_t(r) % names.size()];
    absl::StatusOr<double> ms = RenderMs(c, name, cams[size_t(r) % cams.size()]);
    if (!ms.ok()) {
      ++failures;
      if (first_error.empty()) first_error = std::string(ms.status().message());
      continue;
    }
    warm.push_back(*ms);
  }
  absl::StatusOr<std::vector<clnerf::v1::Place>> after = ListPlaces(c);
  if (!after.ok()) return FailRemote(kPlacesBenchVerb, after.status());
  int loaded_after = 0;
  int64_t model_bytes_loaded = 0;  // As counted against the memory budget.
  for (const auto& p : *after) {
    if (!p.loaded()) continue;
    ++loaded_after;
    model_bytes_loaded += p.memory_bytes();
  }
  const int64_t rss = ResidentBytes(a.server_pid);

  j["places"] = names.size();
  j["loaded_before"] = loaded_before;
  j["loaded_after"] = loaded_after;
  int64_t per_place = 0, params_per_place = 0;
  for (const auto& p : *after) {
    per_place = std::max(per_place, p.memory_bytes());
    params_per_place = std::max(params_per_place, p.model_bytes());
  }
  j["model_bytes_per_place"] = per_place;  // In memory (parameters + occupancy grid).
  j["model_param_bytes_per_place"] = params_per_place;
  j["model_bytes_loaded"] = model_bytes_loaded;
  j["rss_before_bytes"] = rss_before;
  j["rss_bytes"] = rss;
  j["cold_renders"] = cold.size();
  j["cold_p50_ms"] = Percentile(cold, 0.5);
  j["cold_max_ms"] = cold.empty() ? 0 : *std::max_element(cold.begin(), cold.end());
  j["first_render_warm_p50_ms"] = Percentile(first_warm, 0.5);
  j["warm_renders"] = warm.size();
  j["warm_p50_ms"] = Percentile(warm, 0.5);
  j["warm_p99_ms"] = Percentile(warm, 0.99);
  j["failures"] = failures;
  j["first_error"] = first_error;
  double served_s = 0;
  if (a.upload_served) {
    absl::StatusOr<std::pair<std::string, Clock::time_point>> up = UploadTo(c, names[0], scan1, "bench-scan-1");
    if (!up.ok()) return FailRemote(kPlacesBenchVerb, up.status());
    absl::StatusOr<int64_t> v = WaitServed(c, names[0], up->first, cams[0]);
    if (!v.ok()) return FailRemote(kPlacesBenchVerb, v.status());
    served_s = std::chrono::duration<double>(Clock::now() - up->second).count();
    j["upload_to_served_seconds"] = served_s;
    j["upload_version"] = *v;
  }
  std::printf(
      "bench places [%s]: %zu place(s), %d/%d loaded before/after, server RSS %.1f MB (model bytes loaded %.1f MB) | "
      "cold first render p50 %.0f ms max %.0f ms (%zu cold) | warm 100x100 p50 %.1f ms p99 %.1f ms (%zu renders, %d "
      "failures)%s\n",
      a.label.c_str(), names.size(), loaded_before, loaded_after, rss / 1e6, model_bytes_loaded / 1e6,
      Percentile(cold, 0.5), j["cold_max_ms"].get<double>(), cold.size(), Percentile(warm, 0.5),
      Percentile(warm, 0.99), warm.size(), failures,
      a.upload_served ? absl::StrFormat(" | upload ack -> served %.1f s", served_s).c_str() : "");
  if (!a.json.empty()) {
    if (absl::Status s = WriteJson(a.json, j); !s.ok()) return FailRemote(kPlacesBenchVerb, s);
  }
  return failures == 0 ? 0 : 1;
}

}  // namespace clnerf
