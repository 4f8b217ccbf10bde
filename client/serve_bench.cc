// `clnerf bench serve`: measures a running clnerf server from the outside
// (bench/serve.sh starts one on a fresh store):
//   * upload throughput (MB/s) and the time from the end of an upload to the
//     new version being served, for real scans (lego_100 tasks by default);
//   * render latency p50/p99 at several image sizes and client counts, idle
//     and while an update trains, and every failure.
// Prints one human line and writes JSON.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <thread>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "proto/wire/wire.h"
#include "client/commands.h"
#include "client/verb_set.h"
#include "client/remote_client.h"
#include "client/remote_commands.h"
#include "client/percentile.h"
#include "client/remote_format.h"
#include "client/scan_upload.h"
#include "core/io/checkpoint.h"
#include "core/data/dataset.h"
#include "core/render/renderer.h"
#include "core/data/procedural_scene.h"
#include "core/continual/scan_sequence.h"
#include "nlohmann/json.hpp"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

constexpr const char* kServeBenchVerb = "bench serve";
using Clock = std::chrono::steady_clock;

struct Latency {
  int size = 0, clients = 0, requests = 0, failures = 0;
  double p50_ms = 0, p99_ms = 0, mean_ms = 0, max_ms = 0;
  bool update_running_throughout = false;
  std::string first_error;
};

Camera Resized(Camera c, int size) {
  c.intrinsics = c.intrinsics.Scaled(size, size);
  return c;
}

Latency MeasureRenders(RemoteClient& client, const std::vector<Camera>& cams, int size, int clients, int per_client) {
  Latency out;
  out.size = size;
  out.clients = clients;
  std::vector<std::vector<double>> ms(clients);
  std::atomic<int> failures{0};
  std::mutex err_mu;
  std::vector<std::thread> threads;
  for (int c = 0; c < clients; ++c) {
    threads.emplace_back([&, c] {
      for (int i = 0; i < per_client; ++i) {
        clnerf::v1::RenderRequest req;
        *req.mutable_camera() = CameraToProto(Resized(cams[size_t(c * per_client + i) % cams.size()], size));
        clnerf::v1::RenderResponse resp;
        auto ctx = client.Context(kRenderTimeoutSeconds);
        const auto t0 = Clock::now();
        grpc::Status s = client.service().Render(ctx.get(), req, &resp);
        const double dt = Ms(Clock::now() - t0);
        if (!s.ok()) {
          failures++;
          std::lock_guard<std::mutex> lock(err_mu);
          if (out.first_error.empty()) out.first_error = StatusCodeName(s.error_code()) + (": " + s.error_message());
          continue;
        }
        ms[c].push_back(dt);
      }
    });
  }
  for (auto& t : threads) t.join();
  std::vector<double> all;
  for (const auto& v : ms) all.insert(all.end(), v.begin(), v.end());
  out.requests = clients * per_client;
  out.failures = failures.load();
  out.p50_ms = Percentile(all, 0.5);
  out.p99_ms = Percentile(all, 0.99);
  out.max_ms = all.empty() ? 0 : *std::max_element(all.begin(), all.end());
  double sum = 0;
  for (double v : all) sum += v;
  out.mean_ms = all.empty() ? 0 : sum / all.size();
  return out;
}

absl::StatusOr<clnerf::v1::Job> GetJob(RemoteClient& client, const std::string& id) {
  clnerf::v1::GetJobRequest req;
  req.set_job_id(id);
  clnerf::v1::Job job;
  auto ctx = client.Context(kUnaryTimeoutSeconds);
  grpc::Status s = client.service().GetJob(ctx.get(), req, &job);
  if (!s.ok()) return absl::UnavailableError(StatusCodeName(s.error_code()) + (": " + s.error_message()));
  return job;
}

// Polls until the job leaves the given phases (or ends).
absl::StatusOr<clnerf::v1::Job> WaitWhile(RemoteClient& client, const std::string& id,
                                          std::initializer_list<clnerf::v1::JobPhase> phases) {
  while (true) {
    absl::StatusOr<clnerf::v1::Job> j = GetJob(client, id);
    if (!j.ok()) return j;
    if (IsTerminal(j->phase()) || std::find(phases.begin(), phases.end(), j->phase()) == phases.end()) return j;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

struct UploadFigures {
  int64_t bytes = 0;
  double upload_seconds = 0, mb_per_s = 0;
  double upload_end_to_served_seconds = 0;
  int64_t version = 0;
  std::string job_id;
  Clock::time_point acked;
};

absl::StatusOr<UploadFigures> Upload(RemoteClient& client, const Scene& scan, const std::string& name) {
  absl::StatusOr<EncodedScan> enc = EncodeScan(name, scan.kind, scan.train, scan.test);
  if (!enc.ok()) return enc.status();
  enc->header.mutable_header()->set_pose_frame("place");  // Procedural scans share one frame.
  SendResult r = SendScan(client, *enc, nullptr);
  if (!r.status.ok()) {
    return absl::UnavailableError(absl::StrCat("upload: ", StatusCodeName(r.status.error_code()), ": ",
                                               r.status.error_message()));
  }
  UploadFigures f;
  f.acked = Clock::now();
  f.bytes = r.bytes_sent;
  f.upload_seconds = r.seconds;
  f.mb_per_s = r.seconds > 0 ? r.bytes_sent / 1e6 / r.seconds : 0;
  f.job_id = r.response.job_id();
  return f;
}

// Waits for the upload's job and for a render that reports its version.
absl::Status WaitServed(RemoteClient& client, const Camera& cam, UploadFigures* f) {
  absl::StatusOr<clnerf::v1::Job> j = WaitWhile(
      client, f->job_id,
      {clnerf::v1::JOB_PHASE_QUEUED, clnerf::v1::JOB_PHASE_PREPARING_REPLAY, clnerf::v1::JOB_PHASE_TRAINING,
       clnerf::v1::JOB_PHASE_VALIDATING, clnerf::v1::JOB_PHASE_PUBLISHING});
  if (!j.ok()) return j.status();
  if (j->phase() != clnerf::v1::JOB_PHASE_DONE) {
    return absl::AbortedError(absl::StrCat("job ", f->job_id, " ended ", PhaseName(j->phase()), ": ", j->error()));
  }
  while (true) {
    clnerf::v1::RenderRequest req;
    *req.mutable_camera() = CameraToProto(Resized(cam, 8));
    clnerf::v1::RenderResponse resp;
    auto ctx = client.Context(kUnaryTimeoutSeconds);
    grpc::Status s = client.service().Render(ctx.get(), req, &resp);
    if (s.ok() && resp.version() >= j->version()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  f->upload_end_to_served_seconds = std::chrono::duration<double>(Clock::now() - f->acked).count();
  f->version = j->version();
  return absl::OkStatus();
}

nlohmann::json ToJson(const Latency& l) {
  return {{"size", l.size},     {"clients", l.clients}, {"requests", l.requests}, {"failures", l.failures},
          {"p50_ms", l.p50_ms}, {"p99_ms", l.p99_ms},   {"mean_ms", l.mean_ms},   {"max_ms", l.max_ms},
          {"update_running_throughout", l.update_running_throughout}, {"first_error", l.first_error}};
}

nlohmann::json ToJson(const UploadFigures& f) {
  return {{"bytes", f.bytes}, {"upload_seconds", f.upload_seconds}, {"mb_per_s", f.mb_per_s},
          {"upload_end_to_served_seconds", f.upload_end_to_served_seconds}, {"version", f.version},
          {"job_id", f.job_id}};
}

// The same renders in-process (the deployed version read from the server's
// store, all cores): the reference for the service's overhead.
absl::StatusOr<double> InProcessP50(const std::string& store, int64_t version, const std::vector<Camera>& cams,
                                    int size, int renders) {
  const std::string path = absl::StrFormat("%s/versions/%06d/model.ckpt", store, version);
  absl::StatusOr<LoadedCheckpoint> ck = LoadCheckpoint(path);
  if (!ck.ok()) return ck.status();
  std::vector<double> ms;
  for (int i = 0; i < renders; ++i) {
    const auto t0 = Clock::now();
    absl::StatusOr<RenderedView> r = RenderView(ck->model, Resized(cams[size_t(i) % cams.size()], size), RenderOptions{});
    if (!r.ok()) return r.status();
    ms.push_back(Ms(Clock::now() - t0));
  }
  return Percentile(ms, 0.5);
}

absl::StatusOr<std::vector<int>> ParseInts(const std::string& csv) {
  std::vector<int> out;
  for (absl::string_view p : absl::StrSplit(csv, ',', absl::SkipEmpty())) {
    int v;
    if (!absl::SimpleAtoi(p, &v) || v <= 0) return absl::InvalidArgumentError(absl::StrCat("bad number '", p, "'"));
    out.push_back(v);
  }
  return out;
}

}  // namespace

CLI::App* BindBenchServe(CLI::App* parent, BenchServeArgs* a) {
  CLI::App* c = parent->add_subcommand("serve", "Render latency (idle / during an update), upload throughput and "
                                                "upload-to-served time against a running server");
  c->add_option("--data", a->data, "Dataset cut into tasks (scans 0 and 1 are uploaded) or 'procedural'")
      ->capture_default_str();
  c->add_option("--tasks", a->tasks, "Tasks to cut a static dataset into")->capture_default_str();
  c->add_option("--sizes", a->sizes, "Comma-separated square render sizes")->capture_default_str();
  c->add_option("--clients", a->clients, "Comma-separated concurrent client counts")->capture_default_str();
  c->add_option("--renders", a->renders_per_client, "Requests per client per configuration")->capture_default_str();
  c->add_option("--store", a->store,
                "The server's store directory: also time the same renders in-process (the 100x100 target)");
  c->add_option("--json-out", a->json, "Write JSON here ('-' = stdout)");
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunBenchServe(const BenchServeArgs& a) {
  absl::StatusOr<std::vector<int>> sizes = ParseInts(a.sizes);
  if (!sizes.ok()) return FailRemote(kServeBenchVerb, sizes.status());
  absl::StatusOr<std::vector<int>> clients = ParseInts(a.clients);
  if (!clients.ok()) return FailRemote(kServeBenchVerb, clients.status());
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote(kServeBenchVerb, client.status());

  absl::StatusOr<ScanSequence> seq;
  if (a.data == "procedural") {
    ProceduralSceneOptions po;
    po.num_time_steps = 2;
    po.width = po.height = 100;
    po.num_train_views = 10;
    po.num_test_views = 20;
    absl::StatusOr<Scene> s = GenerateProceduralScene(po);
    if (!s.ok()) return FailRemote(kServeBenchVerb, s.status());
    seq = FromTimeSteps(*s);
  } else {
    seq = LoadScanSequence(a.data, a.tasks, DatasetOptions{});
  }
  if (!seq.ok()) return FailRemote(kServeBenchVerb, seq.status());
  if (seq->size() < 2) return FailRemote(kServeBenchVerb, absl::InvalidArgumentError("need at least 2 scans"));
  const Scene scan0 = seq->ScanScene(0), scan1 = seq->ScanScene(1);
  std::vector<Camera> cams;
  for (const View& v : scan0.test) cams.push_back(v.camera);
  if (cams.empty()) for (const View& v : scan0.train) cams.push_back(v.camera);

  nlohmann::json j;
  j["data"] = a.data;
  // 1. First scan: upload throughput and upload -> served.
  spdlog::info("uploading scan 0 ({} train + {} test views) and waiting for it to be served", scan0.train.size(),
               scan0.test.size());
  absl::StatusOr<UploadFigures> up0 = Upload(**client, scan0, "bench-scan-0");
  if (!up0.ok()) return FailRemote(kServeBenchVerb, up0.status());
  if (absl::Status s = WaitServed(**client, cams[0], &*up0); !s.ok()) return FailRemote(kServeBenchVerb, s);
  spdlog::info("scan 0: {:.2f} MB/s upload, served {:.1f} s after the upload ended", up0->mb_per_s,
               up0->upload_end_to_served_seconds);

  // 2. Idle latencies.
  std::vector<Latency> idle, busy;
  for (int size : *sizes) {
    for (int c : *clients) {
      idle.push_back(MeasureRenders(**client, cams, size, c, a.renders_per_client));
      spdlog::info("idle   {}px x {} clients: p50 {:.1f} ms p99 {:.1f} ms ({} failures)", size, c, idle.back().p50_ms,
                   idle.back().p99_ms, idle.back().failures);
    }
  }
  // 2b. Targets on the idle figures (issue 11): a lone 32x32 render p50 <=
  // 10 ms; a lone 100x100 render p50 <= 1.5x the in-process time; with 4
  // clients, p99 <= 4x p50.
  nlohmann::json targets = nlohmann::json::array();
  std::string target_line;
  {
    int64_t deployed = 0;
    {
      clnerf::v1::ServerInfo info;
      auto ctx = (*client)->Context(kUnaryTimeoutSeconds);
      if ((*client)->service().GetServerInfo(ctx.get(), clnerf::v1::GetServerInfoRequest(), &info).ok()) {
        deployed = info.deployed_version();
      }
    }
    for (const Latency& l : idle) {
      nlohmann::json t = {{"size", l.size}, {"clients", l.clients}, {"p50_ms", l.p50_ms}, {"p99_ms", l.p99_ms}};
      if (l.clients == 1 && l.size <= 32) {
        t["target"] = "p50 <= 10 ms";
        t["met"] = l.p50_ms <= 10.0;
        target_line += absl::StrFormat(" %dpx p50 %.1f ms (<= 10: %s);", l.size, l.p50_ms, l.p50_ms <= 10 ? "met" : "NOT met");
      }
      if (l.clients == 1 && l.size == 100 && !a.store.empty() && deployed > 0) {
        absl::StatusOr<double> ref = InProcessP50(a.store, deployed, cams, l.size, std::max(6, a.renders_per_client));
        if (ref.ok()) {
          const double ratio = l.p50_ms / std::max(1e-9, *ref);
          t["inprocess_p50_ms"] = *ref;
          t["ratio_to_inprocess"] = ratio;
          t["target"] = "p50 <= 1.5x in-process";
          t["met"] = ratio <= 1.5;
          target_line += absl::StrFormat(" %dpx p50 %.1f ms vs %.1f ms in-process = %.2fx (<= 1.5: %s);", l.size,
                                         l.p50_ms, *ref, ratio, ratio <= 1.5 ? "met" : "NOT met");
        } else {
          spdlog::warn("in-process reference not measured: {}", ref.status().ToString());
        }
      }
      if (l.clients >= 4) {
        const double spread = l.p50_ms > 0 ? l.p99_ms / l.p50_ms : 0;
        t["p99_over_p50"] = spread;
        t["target"] = "p99 <= 4x p50";
        t["met"] = spread <= 4.0;
        target_line += absl::StrFormat(" %dpx x%d p99/p50 %.2f (<= 4: %s);", l.size, l.clients, spread,
                                       spread <= 4 ? "met" : "NOT met");
      }
      if (t.contains("target")) targets.push_back(t);
    }
  }
  j["idle_targets"] = targets;

  // 3. The same while the second scan trains.
  absl::StatusOr<UploadFigures> up1 = Upload(**client, scan1, "bench-scan-1");
  if (!up1.ok()) return FailRemote(kServeBenchVerb, up1.status());
  absl::StatusOr<clnerf::v1::Job> jt =
      WaitWhile(**client, up1->job_id, {clnerf::v1::JOB_PHASE_QUEUED, clnerf::v1::JOB_PHASE_PREPARING_REPLAY});
  if (!jt.ok()) return FailRemote(kServeBenchVerb, jt.status());
  for (int size : *sizes) {
    for (int c : *clients) {
      Latency l = MeasureRenders(**client, cams, size, c, a.renders_per_client);
      absl::StatusOr<clnerf::v1::Job> now = GetJob(**client, up1->job_id);
      l.update_running_throughout = now.ok() && now->phase() == clnerf::v1::JOB_PHASE_TRAINING;
      busy.push_back(l);
      spdlog::info("update {}px x {} clients: p50 {:.1f} ms p99 {:.1f} ms ({} failures, training throughout: {})",
                   size, c, l.p50_ms, l.p99_ms, l.failures, l.update_running_throughout);
    }
  }
  if (absl::Status s = WaitServed(**client, cams[0], &*up1); !s.ok()) return FailRemote(kServeBenchVerb, s);

  // 4. Throughput on a bigger upload: every view of every scan as one scan;
  // its job is cancelled right after the acknowledgement.
  const Scene all = seq->Union(seq->size() - 1);
  absl::StatusOr<UploadFigures> big = Upload(**client, all, "bench-throughput");
  if (!big.ok()) return FailRemote(kServeBenchVerb, big.status());
  {
    clnerf::v1::CancelJobRequest req;
    req.set_job_id(big->job_id);
    clnerf::v1::Job job;
    auto ctx = (*client)->Context(kUnaryTimeoutSeconds);
    grpc::Status s = (*client)->service().CancelJob(ctx.get(), req, &job);
    if (!s.ok()) spdlog::warn("cancel {}: {}", big->job_id, s.error_message());
  }
  spdlog::info("throughput upload: {} views, {:.2f} MB in {:.2f} s = {:.2f} MB/s (validated and fsync'd before the ack)",
               all.train.size() + all.test.size(), big->bytes / 1e6, big->upload_seconds, big->mb_per_s);

  int failures = 0;
  double worst_ratio = 0;
  bool all_during = true;
  nlohmann::json lat = nlohmann::json::array();
  for (size_t i = 0; i < idle.size(); ++i) {
    failures += idle[i].failures + busy[i].failures;
    const double ratio = idle[i].p99_ms > 0 ? busy[i].p99_ms / idle[i].p99_ms : 0;
    worst_ratio = std::max(worst_ratio, ratio);
    all_during = all_during && busy[i].update_running_throughout;
    lat.push_back({{"idle", ToJson(idle[i])}, {"during_update", ToJson(busy[i])}, {"p99_ratio", ratio}});
  }
  j["latency"] = lat;
  j["uploads"] = {ToJson(*up0), ToJson(*up1)};
  j["throughput_upload"] = ToJson(*big);
  j["upload_mb_per_s"] = big->mb_per_s;
  j["failures"] = failures;
  j["worst_p99_ratio"] = worst_ratio;
  j["target_p99_ratio"] = 3.0;
  j["all_measured_during_training"] = all_during;
  j["target_met"] = failures == 0 && worst_ratio <= 3.0;

  std::string cells;
  for (size_t i = 0; i < idle.size(); ++i) {
    cells += absl::StrFormat(" %dpx x%d: %.0f/%.0f ms idle, %.0f/%.0f ms training;", idle[i].size, idle[i].clients,
                             idle[i].p50_ms, idle[i].p99_ms, busy[i].p50_ms, busy[i].p99_ms);
  }
  std::printf("bench serve (%s): render p50/p99%s worst p99 ratio %.2f (target <= 3), %d failures | idle targets:%s | "
              "upload %.2f MB/s (%.1f MB) | upload end -> served %.1f s (scan 0), %.1f s (scan 1)\n",
              a.data.c_str(), cells.c_str(), worst_ratio, failures, target_line.c_str(), big->mb_per_s, big->bytes / 1e6,
              up0->upload_end_to_served_seconds,
              up1->upload_end_to_served_seconds);
  if (!a.json.empty()) {
    if (absl::Status s = WriteJson(a.json, j); !s.ok()) return FailRemote(kServeBenchVerb, s);
  }
  return 0;
}

}  // namespace clnerf
