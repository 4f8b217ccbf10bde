// Replicas end to end (issue 22): three real clnerf-server processes on
// 127.0.0.1:0 over one store directory, coordinated by a real etcd on
// loopback (etcd_test_util.h), with tiny procedural scenes trained in small
// batches (as TinyServerOptions), two-second leases and 0.2 s polls:
//   * an upload through one replica is served by all three within the bound;
//   * kill -9 of the replica that is training: another finishes the scan,
//     versions stay contiguous and no scan is trained twice;
//   * SIGSTOP of the trainer past its lease: another takes the place over and
//     publishes; after SIGCONT the stopped one's publish is refused (fenced,
//     counted in its /metrics) and the store is unchanged by it;
//   * six places under a memory budget for two: every render on every
//     replica succeeds, evictions are counted, /metrics is Prometheus text.
// Skipped only where no etcd binary is installed (CI installs it).
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/testing/etcd_test_util.h"
#include "server/testing/prometheus_text_test_util.h"
#include "server/testing/server_fixture.h"
#include "server/testing/server_process_test_util.h"
// After the project headers: httplib.h's system headers clash with Eigen's otherwise.
#include "httplib.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using testing_util::LocalEtcd;
using testing_util::ServerProcess;

constexpr int kLeaseTtl = 2;
constexpr double kPoll = 0.2;
// A replica serves a version deployed elsewhere within one poll plus one
// model load; asserted with generous slack for a loaded 2-core machine.
constexpr double kServeBoundSeconds = 10;

double Since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

class ReplicasTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (LocalEtcd::Find().empty()) GTEST_SKIP() << "no etcd binary (Debian etcd-server; scripts/install-deps.sh)";
    root_ = testing_util::TempDir("replicas");
    ASSERT_EQ(etcd_.Start(root_ + "/etcd"), "");
    store_ = root_ + "/store";
    std::ofstream(root_ + "/config.json")
        << R"({"batch_rays": 512, "target_samples": 8192, "bake": {"resolution": 64, "visibility_rays": 4096, "fit_rays": 2048},)"
        << R"( "gate": {"min_new_psnr": 8, "min_replay_consistency_psnr": 10, "max_replay_drop_db": 10}})";
    scene_ = testing_util::TinyScans(3);
  }

  std::unique_ptr<ServerProcess> Start(const std::string& name, int iters, const std::string& extra = "") {
    const std::string args = absl::StrFormat(
        "--store %s --listen 127.0.0.1:0 --http 127.0.0.1:0 --iters %d --first-scan-iters 0 --config %s/config.json --etcd %s "
        "--etcd-prefix /test --lease-ttl %d --replica-poll %g --train-threads 1 --render-threads 1 --train-nice 0 %s",
        store_, iters, root_, etcd_.endpoint(), kLeaseTtl, kPoll, extra);
    auto p = std::make_unique<ServerProcess>("", args, absl::StrCat(root_, "/", name, ".log"), 300);
    EXPECT_GT(p->port(), 0) << name << " did not start; see " << root_ << "/" << name << ".log";
    EXPECT_GT(p->http_port(), 0);
    return p;
  }
  void StartThree(int iters, const std::string& extra = "") {
    for (const char* n : {"A", "B", "C"}) replicas_.push_back(Start(n, iters, extra));
  }

  v1::UploadScanResponse Upload(ServerProcess& r, int t, const std::string& place = "") {
    std::vector<v1::UploadScanRequest> msgs = testing_util::UploadMessages(testing_util::UploadOf(scene_, t));
    msgs[0].mutable_header()->set_place(place);
    v1::UploadScanResponse ack;
    const grpc::Status s = testing_util::UploadVia(r.Stub().get(), msgs, &ack);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return ack;
  }

  // The version a replica serves for `place` (-1: the render failed).
  int64_t Served(ServerProcess& r, const std::string& place = "", std::string* error = nullptr) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    v1::RenderRequest req;
    Camera cam = scene_.test[0].camera;
    cam.intrinsics = cam.intrinsics.Scaled(8, 8);
    testing_util::FillCamera(cam, req.mutable_camera());
    req.set_place(place);
    v1::RenderResponse resp;
    const grpc::Status s = r.Stub()->Render(&ctx, req, &resp);
    if (!s.ok() && error != nullptr) *error = s.error_message();
    return s.ok() ? resp.version() : -1;
  }

  // Seconds until every running replica serves `version` of `place`; -1 on timeout.
  double WaitAllServe(int64_t version, double timeout_s, const std::string& place = "") {
    const auto t0 = Clock::now();
    while (Since(t0) < timeout_s) {
      bool all = true;
      for (auto& r : replicas_) {
        if (r->running() && Served(*r, place) != version) all = false;
      }
      if (all) return Since(t0);
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return -1;
  }

  v1::Job Job(ServerProcess& r, const std::string& id, const std::string& place = "") {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    v1::GetJobRequest req;
    req.set_job_id(id);
    req.set_place(place);
    v1::Job job;
    (void)r.Stub()->GetJob(&ctx, req, &job);
    return job;
  }

  // Waits until any running replica reports the job in `phase`; that replica's index or -1.
  int WaitPhase(const std::string& id, v1::JobPhase phase, double timeout_s, const std::string& place = "") {
    const auto t0 = Clock::now();
    while (Since(t0) < timeout_s) {
      for (size_t i = 0; i < replicas_.size(); ++i) {
        if (replicas_[i]->running() && Job(*replicas_[i], id, place).phase() == phase) return int(i);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return -1;
  }

  // versions/ of the default place: version numbers, and any other entries.
  std::vector<int64_t> VersionsOnDisk(std::vector<std::string>* others = nullptr) {
    std::vector<int64_t> v;
    for (const auto& e : fs::directory_iterator(store_ + "/versions")) {
      const std::string n = e.path().filename().string();
      int64_t x;
      if (absl::SimpleAtoi(n, &x)) {
        v.push_back(x);
      } else if (others != nullptr) {
        others->push_back(n);
      }
    }
    std::sort(v.begin(), v.end());
    return v;
  }

  // Every file under versions/ with its size.
  std::set<std::string> VersionFiles() {
    std::set<std::string> out;
    for (const auto& e : fs::recursive_directory_iterator(store_ + "/versions")) {
      out.insert(e.path().string() + (e.is_regular_file() ? ":" + std::to_string(e.file_size()) : "/"));
    }
    return out;
  }

  std::map<std::string, double> Metrics(ServerProcess& r, std::string* error) {
    httplib::Client c("127.0.0.1", r.http_port());
    c.set_read_timeout(10, 0);
    std::map<std::string, double> samples;
    auto res = c.Get("/metrics");
    if (!res || res->status != 200) {
      *error = "GET /metrics failed";
      return samples;
    }
    *error = testing_util::ParsePrometheusText(res->body, &samples);
    return samples;
  }

  LocalEtcd etcd_;
  std::string root_, store_;
  Scene scene_;
  std::vector<std::unique_ptr<ServerProcess>> replicas_;
};

TEST_F(ReplicasTest, AnUploadToOneIsServedByAllAndAKilledTrainerIsReplaced) {
  StartThree(/*iters=*/60);
  ASSERT_EQ(replicas_.size(), 3u);
  const v1::UploadScanResponse ack0 = Upload(*replicas_[0], 0);
  ASSERT_GE(WaitPhase(ack0.job_id(), v1::JOB_PHASE_DONE, 120), 0) << "scan 0 was never trained";
  const double served = WaitAllServe(1, 60);
  ASSERT_GE(served, 0) << "not every replica serves version 1";
  EXPECT_LE(served, kServeBoundSeconds);
  // Every replica knows the job, whichever trained it (within a poll of serving it).
  for (size_t i = 0; i < replicas_.size(); ++i) {
    v1::Job job;
    for (const auto t0 = Clock::now(); Since(t0) < 5 && job.version() != 1;) {
      job = Job(*replicas_[i], ack0.job_id());
      if (job.version() != 1) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    EXPECT_EQ(job.version(), 1) << "replica " << "ABC"[i] << ": phase " << v1::JobPhase_Name(job.phase()) << ", error '"
                                << job.error() << "'";
  }

  // Scan 1 through B; kill -9 whichever replica trains it, mid-update.
  const v1::UploadScanResponse ack1 = Upload(*replicas_[1], 1);
  const int trainer = WaitPhase(ack1.job_id(), v1::JOB_PHASE_TRAINING, 60);
  ASSERT_GE(trainer, 0) << "no replica started training scan 1";
  replicas_[trainer]->Signal(SIGKILL);
  replicas_[trainer]->Wait();
  const int finisher = WaitPhase(ack1.job_id(), v1::JOB_PHASE_DONE, 120);
  ASSERT_GE(finisher, 0) << "no surviving replica finished scan 1";
  ASSERT_NE(finisher, trainer);
  EXPECT_GE(WaitAllServe(2, 60), 0);
  std::vector<std::string> others;
  EXPECT_EQ(VersionsOnDisk(&others), (std::vector<int64_t>{1, 2})) << "versions must stay contiguous";
  // No scan in two versions; version 2 holds scan 1.
  std::set<std::string> scans;
  for (int64_t v : {1, 2}) {
    std::ifstream f(absl::StrFormat("%s/versions/%06d/version.json", store_, v));
    const nlohmann::json j = nlohmann::json::parse(f);
    EXPECT_TRUE(scans.insert(j.at("scan_id").get<std::string>()).second) << "a scan was trained twice";
    if (v == 2) {
      EXPECT_EQ(j.at("scan_id"), ack1.scan_id());
    }
  }
}

TEST_F(ReplicasTest, AStoppedTrainersLatePublishIsFencedAndChangesNothing) {
  StartThree(/*iters=*/60);
  const v1::UploadScanResponse ack = Upload(*replicas_[0], 0);
  const int stopped = WaitPhase(ack.job_id(), v1::JOB_PHASE_TRAINING, 60);
  ASSERT_GE(stopped, 0) << "no replica started training";
  replicas_[stopped]->Signal(SIGSTOP);
  // Past the lease: another replica takes the place over and publishes.
  const int other = WaitPhase(ack.job_id(), v1::JOB_PHASE_DONE, 120);
  ASSERT_GE(other, 0) << "no other replica took over the stopped trainer's scan";
  ASSERT_NE(other, stopped);
  std::vector<std::string> leftovers;
  ASSERT_EQ(VersionsOnDisk(&leftovers), (std::vector<int64_t>{1}));
  const std::set<std::string> before = VersionFiles();

  replicas_[stopped]->Signal(SIGCONT);
  // It finishes its (now stale) update; its publish must be refused.
  std::string error;
  double fenced = 0;
  for (const auto t0 = Clock::now(); Since(t0) < 120 && fenced < 1;) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    fenced = Metrics(*replicas_[stopped], &error)["clnerf_fenced_commits_total"];
  }
  EXPECT_GE(fenced, 1) << "the stopped replica's publish was not refused (or never tried)";
  EXPECT_EQ(error, "");
  // It learns the outcome like any replica, and the store is as the new owner left it.
  EXPECT_GE(WaitAllServe(1, 60), 0);
  int64_t v = 0;
  for (const auto t0 = Clock::now(); Since(t0) < 30 && v != 1;) {
    v = Job(*replicas_[stopped], ack.job_id()).version();
    if (v != 1) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  EXPECT_EQ(v, 1);
  EXPECT_EQ(VersionFiles(), before) << "the fenced publish changed the store";
  EXPECT_EQ(VersionsOnDisk(), (std::vector<int64_t>{1}));
}

TEST_F(ReplicasTest, SixPlacesUnderABudgetForTwoEveryRenderSucceeds) {
  StartThree(/*iters=*/30);
  const std::vector<std::string> places = {"p0", "p1", "p2", "p3", "p4", "p5"};
  std::vector<v1::UploadScanResponse> acks;
  for (size_t i = 0; i < places.size(); ++i) {
    ServerProcess& r = *replicas_[i % 3];
    grpc::ClientContext ctx;
    v1::CreatePlaceRequest req;
    req.set_name(places[i]);
    v1::Place p;
    ASSERT_TRUE(r.Stub()->CreatePlace(&ctx, req, &p).ok());
    acks.push_back(Upload(*replicas_[(i + 1) % 3], 0, places[i]));  // Through another replica.
  }
  for (size_t i = 0; i < places.size(); ++i) {
    ASSERT_GE(WaitPhase(acks[i].job_id(), v1::JOB_PHASE_DONE, 180, places[i]), 0) << places[i];
  }
  int64_t model_bytes = 0;
  {
    grpc::ClientContext ctx;
    v1::ListPlacesResponse list;
    ASSERT_TRUE(replicas_[2]->Stub()->ListPlaces(&ctx, v1::ListPlacesRequest(), &list).ok());
    EXPECT_EQ(list.places_size(), 7);  // default + six, created through different replicas.
    for (const v1::Place& p : list.places()) model_bytes = std::max(model_bytes, p.memory_bytes());
  }
  ASSERT_GT(model_bytes, 0);
  for (auto& r : replicas_) r->Signal(SIGTERM);
  for (auto& r : replicas_) r->Wait();
  replicas_.clear();
  // Room for two models (what a loaded one holds: parameters, occupancy grid, cameras).
  StartThree(30, absl::StrCat("--model-memory-budget ", model_bytes * 5 / 2));
  for (int round = 0; round < 2; ++round) {
    for (const std::string& place : places) {
      for (auto& r : replicas_) {
        std::string why;
        EXPECT_EQ(Served(*r, place, &why), 1) << place << ": " << why;
      }
    }
  }
  for (auto& r : replicas_) {
    std::string error;
    std::map<std::string, double> m = Metrics(*r, &error);
    EXPECT_EQ(error, "");
    EXPECT_GE(m["clnerf_model_evictions_total"], 4) << "round robin over 6 places with room for 2 must evict";
    EXPECT_LE(m["clnerf_model_bytes"], double(model_bytes * 5 / 2));
  }
}

}  // namespace
}  // namespace clnerf
