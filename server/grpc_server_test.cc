// Integration tests: the real server, in-process on localhost:0, driven
// through gRPC stubs, with tiny models so each update takes about a second.
#include "server/grpc_server.h"

#include <atomic>
#include <cstring>
#include <functional>
#include <cmath>
#include <filesystem>
#include <thread>

#include "core/io/durable_file.h"
#include "core/data/image.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "grpcpp/create_channel.h"
#include "gtest/gtest.h"
#include "server/testing/server_fixture.h"
#include "server/testing/server_test_util.h"
#include "server/store/version_store.h"

namespace clnerf {
namespace {

using testing_util::TempDir;
using testing_util::TinyScans;
using testing_util::TinyServerOptions;
using testing_util::UploadMessages;
using testing_util::UploadOf;
using testing_util::ServerFixture;


TEST_F(ServerFixture, UploadTrainPublishRenderAnyTimeStep) {
  const std::string store = TempDir("srv_basic");
  StartServer(TinyServerOptions(store));
  const Scene scene = TinyScans(2);
  const Camera cam = scene.test[0].camera;

  v1::RenderResponse r;
  EXPECT_EQ(Render(cam, -1, 0, &r).error_code(), grpc::StatusCode::FAILED_PRECONDITION);

  v1::UploadScanResponse ack;
  // Small chunks so the chunking path is exercised.
  ASSERT_TRUE(Upload(UploadMessages(UploadOf(scene, 0), 300), &ack).ok());
  EXPECT_EQ(ack.time_step(), 0);
  EXPECT_EQ(ack.scan_id(), "scan-000001");
  const v1::Job j0 = Watch(ack.job_id());
  ASSERT_EQ(j0.phase(), v1::JOB_PHASE_DONE) << j0.error();
  EXPECT_EQ(j0.version(), 1);
  EXPECT_GT(j0.metrics().at("new_psnr"), 8.0);
  EXPECT_EQ(StoredScans(store), 0u);  // Trained scans leave the inbox.

  const v1::Job j1 = UploadAndWait(scene, 1);
  ASSERT_EQ(j1.phase(), v1::JOB_PHASE_DONE) << j1.error();
  EXPECT_EQ(j1.time_step(), 1);
  EXPECT_EQ(j1.version(), 2);
  EXPECT_TRUE(j1.metrics().count("replay_buffer_psnr"));

  ASSERT_TRUE(Render(cam, -1, 0, &r).ok());
  EXPECT_EQ(r.version(), 2);
  EXPECT_EQ(r.time_step(), 1);
  auto img = DecodeImage(r.image(), "r.png");
  ASSERT_TRUE(img.ok()) << img.status();
  EXPECT_EQ(img->width, cam.intrinsics.width);
  ASSERT_TRUE(Render(cam, 0, 1, &r).ok());
  EXPECT_EQ(r.version(), 1);
  EXPECT_EQ(r.time_step(), 0);
  EXPECT_EQ(Render(cam, 5, 0, &r).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(Render(cam, -1, 42, &r).error_code(), grpc::StatusCode::NOT_FOUND);

  const auto versions = Versions();
  ASSERT_EQ(versions.size(), 2u);
  EXPECT_EQ(versions[1].parent(), 1);
  EXPECT_TRUE(versions[1].deployed());
  EXPECT_EQ(versions[1].time_steps(), 2);

  // RenderStream: two frames, small chunks, reassembled.
  grpc::ClientContext ctx;
  v1::RenderStreamRequest sreq;
  testing_util::FillCamera(cam, sreq.add_cameras());
  testing_util::FillCamera(scene.test[1].camera, sreq.add_cameras());
  sreq.set_max_chunk_bytes(500);
  sreq.set_format(v1::IMAGE_FORMAT_FLOAT32);
  auto reader = stub_->RenderStream(&ctx, sreq);
  std::map<int, std::string> frames;
  v1::RenderChunk c;
  while (reader->Read(&c)) {
    EXPECT_EQ(c.offset(), int64_t(frames[c.frame_index()].size()));
    frames[c.frame_index()] += c.data();
  }
  ASSERT_TRUE(reader->Finish().ok());
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(frames[0].size(), size_t(cam.intrinsics.width * cam.intrinsics.height * 3 * 4));
}

// A scan's point cloud reaches training: the first scan and a continual
// update both train with sparse-depth rays and deploy.
TEST_F(ServerFixture, UploadedPointCloudsBecomeDepthSupervision) {
  const std::string store = TempDir("srv_points_e2e");
  StartServer(TinyServerOptions(store));
  const Scene scene = TinyScans(2);
  for (int t = 0; t < 2; ++t) {
    ScanUpload up = UploadOf(scene, t);
    for (const View& v : scene.train) {
      if (v.camera.time_step != t) continue;
      Eigen::Vector3f o, d;
      v.camera.Ray(0.5f * v.camera.intrinsics.width, 0.5f * v.camera.intrinsics.height, &o, &d);
      up.points.push_back(o + d.dot(-o) * d);  // The point of the view axis nearest the object's centre.
    }
    v1::UploadScanResponse ack;
    ASSERT_TRUE(Upload(UploadMessages(up), &ack).ok());
    const v1::Job j = Watch(ack.job_id());
    ASSERT_EQ(j.phase(), v1::JOB_PHASE_DONE) << j.error();
    ASSERT_TRUE(j.metrics().count("depth_pixels")) << "scan " << t;
    EXPECT_GT(j.metrics().at("depth_pixels"), 0.0);
  }
}

TEST_F(ServerFixture, RendersDuringAnUpdateNeverFailAndSeeMonotonicVersions) {
  const std::string store = TempDir("srv_concurrent");
  StartServer(TinyServerOptions(store));
  const Scene scene = TinyScans(2);
  ASSERT_EQ(UploadAndWait(scene, 0).phase(), v1::JOB_PHASE_DONE);
  v1::UploadScanResponse ack;
  ASSERT_TRUE(Upload(UploadMessages(UploadOf(scene, 1)), &ack).ok());
  std::atomic<bool> done{false};
  std::atomic<int> failures{0}, renders{0}, saw_new{0};
  std::vector<std::thread> clients;
  for (int c = 0; c < 3; ++c) {
    clients.emplace_back([&, c] {
      int64_t last = 0;
      int after_done = 0;
      while (after_done < 2) {
        if (done) ++after_done;
        v1::RenderResponse r;
        grpc::Status s = Render(scene.test[c].camera, 0, 0, &r);
        if (!s.ok()) {
          failures++;
          ADD_FAILURE() << s.error_message();
          continue;
        }
        if (r.version() < last) failures++;
        last = r.version();
        if (r.version() == 2) saw_new++;
        renders++;
      }
    });
  }
  const v1::Job j = Watch(ack.job_id());
  done = true;
  for (auto& t : clients) t.join();
  ASSERT_EQ(j.phase(), v1::JOB_PHASE_DONE) << j.error();
  EXPECT_EQ(failures.load(), 0);
  EXPECT_GT(renders.load(), 6);
  EXPECT_GT(saw_new.load(), 0);  // Every client rendered twice after the swap.
}

TEST_F(ServerFixture, RollbackRedeploysAnOlderVersion) {
  const std::string store = TempDir("srv_rollback");
  StartServer(TinyServerOptions(store));
  const Scene scene = TinyScans(2);
  ASSERT_EQ(UploadAndWait(scene, 0).phase(), v1::JOB_PHASE_DONE);
  ASSERT_EQ(UploadAndWait(scene, 1).phase(), v1::JOB_PHASE_DONE);
  grpc::ClientContext ctx;
  v1::SetDeployedVersionRequest req;
  req.set_version(1);
  v1::Version v;
  ASSERT_TRUE(stub_->SetDeployedVersion(&ctx, req, &v).ok());
  EXPECT_TRUE(v.deployed());
  v1::RenderResponse r;
  ASSERT_TRUE(Render(scene.test[0].camera, -1, 0, &r).ok());
  EXPECT_EQ(r.version(), 1);
  EXPECT_EQ(r.time_step(), 0);
  grpc::ClientContext ctx2;
  req.set_version(9);
  EXPECT_EQ(stub_->SetDeployedVersion(&ctx2, req, &v).error_code(), grpc::StatusCode::NOT_FOUND);
  // The rollback survives a restart, and the next scan trains on version 1.
  StopServer();
  StartServer(TinyServerOptions(store));
  ASSERT_TRUE(Render(scene.test[0].camera, -1, 0, &r).ok());
  EXPECT_EQ(r.version(), 1);
  const v1::Job j = UploadAndWait(scene, 1);
  ASSERT_EQ(j.phase(), v1::JOB_PHASE_DONE);
  EXPECT_EQ(j.version(), 3);
  EXPECT_EQ(j.time_step(), 1);
  EXPECT_EQ(Versions().back().parent(), 1);
}

// One optimiser across the sequence in the service: with carry_optimizer
// the place keeps the newest version's Adam state (one optimizer.bin beside
// the versions, not one per version) and the next update resumes it, across
// a restart; an older version has none (a rollback starts fresh); a corrupt
// state only costs the resume (the update starts a fresh optimiser and still
// publishes).
TEST_F(ServerFixture, CarriedOptimizerTravelsWithItsVersionAcrossARestart) {
  const std::string store = TempDir("srv_optimizer");
  ServerOptions o = TinyServerOptions(store);
  o.update.carry_optimizer = true;
  const uint64_t iters = uint64_t(o.update.train.iterations);
  StartServer(o);
  const Scene scene = TinyScans(3);
  ASSERT_EQ(UploadAndWait(scene, 0).phase(), v1::JOB_PHASE_DONE);
  auto versions = VersionStore::Open(store, /*clean_temps=*/false);
  ASSERT_TRUE(versions.ok()) << versions.status();
  auto opt = (*versions)->LoadOptimizer(1);
  ASSERT_TRUE(opt.ok()) << opt.status();
  ASSERT_NE(*opt, nullptr);
  EXPECT_EQ((*opt)->step, iters);
  StopServer();
  StartServer(o);
  ASSERT_EQ(UploadAndWait(scene, 1).phase(), v1::JOB_PHASE_DONE);
  opt = (*versions)->LoadOptimizer(2);
  ASSERT_TRUE(opt.ok() && *opt != nullptr) << opt.status();
  EXPECT_EQ((*opt)->step, 2 * iters);  // Resumed from version 1's.
  opt = (*versions)->LoadOptimizer(1);  // Replaced: only the newest version's is kept.
  ASSERT_TRUE(opt.ok()) << opt.status();
  EXPECT_EQ(*opt, nullptr);
  EXPECT_FALSE(std::filesystem::exists(store + "/versions/000002/optimizer.bin"));
  // Corrupt the place's state: the next update starts fresh and publishes.
  ASSERT_TRUE(AtomicWriteFile(store + "/optimizer.bin", "garbage").ok());
  EXPECT_EQ((*versions)->LoadOptimizer(2).status().code(), absl::StatusCode::kDataLoss);
  ASSERT_EQ(UploadAndWait(scene, 2).phase(), v1::JOB_PHASE_DONE);
  opt = (*versions)->LoadOptimizer(3);
  ASSERT_TRUE(opt.ok() && *opt != nullptr) << opt.status();
  EXPECT_EQ((*opt)->step, iters);
}

TEST_F(ServerFixture, KeepVersionsPrunesTheOldest) {
  const std::string store = TempDir("srv_prune");
  ServerOptions o = TinyServerOptions(store);
  o.keep_versions = 2;
  StartServer(o);
  const Scene scene = TinyScans(3);
  for (int t = 0; t < 3; ++t) ASSERT_EQ(UploadAndWait(scene, t).phase(), v1::JOB_PHASE_DONE);
  auto versions = Versions();
  ASSERT_EQ(versions.size(), 2u);
  EXPECT_EQ(versions[0].version(), 2);
  EXPECT_EQ(versions[1].version(), 3);
  v1::RenderResponse r;
  EXPECT_EQ(Render(scene.test[0].camera, -1, 1, &r).error_code(), grpc::StatusCode::NOT_FOUND);
  // Roll back to version 2 and train once more: version 4 (parent 2) is
  // deployed and the oldest, 2, goes.
  grpc::ClientContext ctx;
  v1::SetDeployedVersionRequest req;
  req.set_version(2);
  v1::Version v;
  ASSERT_TRUE(stub_->SetDeployedVersion(&ctx, req, &v).ok());
  ASSERT_EQ(UploadAndWait(scene, 2).phase(), v1::JOB_PHASE_DONE);
  versions = Versions();
  ASSERT_EQ(versions.size(), 2u);
  EXPECT_EQ(versions[0].version(), 3);
  EXPECT_EQ(versions[1].version(), 4);
  EXPECT_EQ(versions[1].parent(), 2);
  EXPECT_TRUE(versions[1].deployed());
  EXPECT_FALSE(std::filesystem::exists(store + "/versions/000002"));
  EXPECT_EQ(Render(scene.test[0].camera, -1, 2, &r).error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(ServerFixture, RestartMidTrainingLosesNoScan) {
  const std::string store = TempDir("srv_restart");
  StartServer(TinyServerOptions(store, 100000));  // Would take hours.
  const Scene scene = TinyScans(1);
  v1::UploadScanResponse ack;
  ASSERT_TRUE(Upload(UploadMessages(UploadOf(scene, 0)), &ack).ok());
  // Wait until it is training.
  for (int i = 0; i < 600; ++i) {
    grpc::ClientContext ctx;
    v1::GetJobRequest req;
    req.set_job_id(ack.job_id());
    v1::Job j;
    ASSERT_TRUE(stub_->GetJob(&ctx, req, &j).ok());
    if (j.phase() == v1::JOB_PHASE_TRAINING && j.iteration() > 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  StopServer();
  EXPECT_EQ(StoredScans(store), 1u);
  StartServer(TinyServerOptions(store));
  const v1::Job j = Watch(ack.job_id());  // Same job id after the restart.
  ASSERT_EQ(j.phase(), v1::JOB_PHASE_DONE) << j.error();
  EXPECT_EQ(j.version(), 1);
  EXPECT_EQ(StoredScans(store), 0u);
  const auto versions = Versions();
  ASSERT_EQ(versions.size(), 1u);
  EXPECT_EQ(versions[0].scan_id(), ack.scan_id());
}

TEST_F(ServerFixture, BadInputGetsItsStatusAndChangesNothing) {
  const std::string store = TempDir("srv_bad");
  ServerOptions o = TinyServerOptions(store);
  o.max_queue = 1;
  StartServer(o);
  const Scene scene = TinyScans(1);
  ASSERT_EQ(UploadAndWait(scene, 0).phase(), v1::JOB_PHASE_DONE);
  const std::string manifest_before = *ReadFileToString(store + "/manifest.json");
  const auto good = UploadMessages(UploadOf(scene, 0));
  struct Case {
    const char* name;
    std::vector<v1::UploadScanRequest> msgs;
    grpc::StatusCode want;
  };
  std::vector<Case> cases;
  {
    auto m = good;  // Corrupt image bytes (same length, garbage).
    std::string& d = *m[1].mutable_chunk()->mutable_data();
    for (size_t i = 20; i < d.size(); ++i) d[i] = char(i * 7);
    cases.push_back({"corrupt image", m, grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    auto m = good;
    m[0].mutable_header()->mutable_frames(0)->mutable_camera()->set_pose(3, std::nanf(""));
    cases.push_back({"NaN pose", m, grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    auto m = good;
    auto* pose = m[0].mutable_header()->mutable_frames(1)->mutable_camera()->mutable_pose();
    for (int k : {0, 1, 2}) pose->Set(k, pose->Get(k) * 2.0f);  // Non-rigid.
    cases.push_back({"non-rigid pose", m, grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    auto m = good;
    m[0].mutable_header()->mutable_frames(0)->mutable_camera()->mutable_intrinsics()->set_width(30);
    cases.push_back({"size mismatch", m, grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    auto m = good;
    m.erase(m.begin() + 3);  // A missing chunk.
    cases.push_back({"missing chunk", m, grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    auto m = good;
    m.resize(m.size() / 2);  // Truncated upload.
    cases.push_back({"truncated upload", m, grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    std::vector<v1::UploadScanRequest> m(good.begin() + 1, good.end());
    cases.push_back({"no header", m, grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    auto m = good;
    m.push_back(m[1]);  // Bytes beyond the declared size.
    m.back().mutable_chunk()->set_offset(m[1].chunk().data().size());
    cases.push_back({"extra bytes", m, grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    cases.push_back({"empty upload", {}, grpc::StatusCode::INVALID_ARGUMENT});
  }
  for (const Case& c : cases) {
    v1::UploadScanResponse ack;
    grpc::Status s = Upload(c.msgs, &ack);
    EXPECT_EQ(s.error_code(), c.want) << c.name << ": " << s.error_message();
    EXPECT_FALSE(s.error_message().empty()) << c.name;
  }
  EXPECT_EQ(StoredScans(store), 0u);
  EXPECT_EQ(Versions().size(), 1u);
  EXPECT_EQ(*ReadFileToString(store + "/manifest.json"), manifest_before);

  grpc::ClientContext ctx;
  v1::GetJobRequest jr;
  jr.set_job_id("job-999999");
  v1::Job job;
  EXPECT_EQ(stub_->GetJob(&ctx, jr, &job).error_code(), grpc::StatusCode::NOT_FOUND);
  v1::RenderResponse r;
  Camera bad = scene.test[0].camera;
  bad.intrinsics.width = 0;
  EXPECT_EQ(Render(bad, -1, 0, &r).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
}

TEST_F(ServerFixture, FullQueueIsResourceExhaustedAndCancelWorks) {
  const std::string store = TempDir("srv_queue");
  ServerOptions o = TinyServerOptions(store, 100000);
  o.max_queue = 1;
  StartServer(o);
  const Scene scene = TinyScans(1);
  const auto msgs = UploadMessages(UploadOf(scene, 0));
  v1::UploadScanResponse a, b, c;
  ASSERT_TRUE(Upload(msgs, &a).ok());  // Starts training (long).
  for (int i = 0; i < 200 && server_->host().Info().running_job.empty(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ASSERT_TRUE(Upload(msgs, &b).ok());  // Waits in the queue.
  EXPECT_EQ(b.time_step(), 1);
  EXPECT_EQ(Upload(msgs, &c).error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_EQ(StoredScans(store), 2u);
  for (const std::string& id : {b.job_id(), a.job_id()}) {
    grpc::ClientContext ctx;
    v1::CancelJobRequest req;
    req.set_job_id(id);
    v1::Job j;
    ASSERT_TRUE(stub_->CancelJob(&ctx, req, &j).ok());
  }
  EXPECT_EQ(Watch(a.job_id()).phase(), v1::JOB_PHASE_CANCELLED);
  EXPECT_EQ(Watch(b.job_id()).phase(), v1::JOB_PHASE_CANCELLED);
  EXPECT_EQ(StoredScans(store), 0u);
  EXPECT_TRUE(Versions().empty());
}

TEST_F(ServerFixture, DeploymentGateRefusesAndKeepsThePreviousVersion) {
  const std::string store = TempDir("srv_gate");
  StartServer(TinyServerOptions(store));
  const Scene scene = TinyScans(2);
  ASSERT_EQ(UploadAndWait(scene, 0).phase(), v1::JOB_PHASE_DONE);
  StopServer();
  ServerOptions strict = TinyServerOptions(store);
  strict.gate.min_new_psnr = 60.0f;  // No 30-iteration model clears this.
  StartServer(strict);
  const v1::Job j = UploadAndWait(scene, 1);
  EXPECT_EQ(j.phase(), v1::JOB_PHASE_FAILED);
  EXPECT_NE(j.error().find("deployment gate"), std::string::npos) << j.error();
  EXPECT_TRUE(j.metrics().count("new_psnr"));
  v1::RenderResponse r;
  ASSERT_TRUE(Render(scene.test[0].camera, -1, 0, &r).ok());
  EXPECT_EQ(r.version(), 1);
  EXPECT_EQ(Versions().size(), 1u);
}

// The stability matrix's stressors through the real service (see
// core/continual/stability.h): each stressed scan's job ends DONE or FAILED with a
// reason; a FAILED job leaves the deployed version as it was; renders of
// every time step stay finite; every stored version loads with finite
// parameters. A diverging update (learning rate 1e30) must be refused, and a
// single NaN gradient must not stop an update.
TEST_F(ServerFixture, StressedScansNeverDeployANonFiniteModel) {
  const std::string store = TempDir("srv_stress");
  StartServer(TinyServerOptions(store));
  const Scene scene = TinyScans(2);
  ASSERT_EQ(UploadAndWait(scene, 0).phase(), v1::JOB_PHASE_DONE);
  enum class Expect { kEither, kDone, kFailed };
  struct Case {
    const char* name;
    std::function<void(ServerOptions*)> options;
    std::function<void(ScanUpload*)> scan;
    Expect expect;
  };
  auto none_o = [](ServerOptions*) {};
  auto none_s = [](ScanUpload*) {};
  const std::vector<Case> cases = {
      {"lr_1e30", [](ServerOptions* o) { o->update.train.learning_rate = 1e30f; }, none_s, Expect::kFailed},
      {"lr_x10", [](ServerOptions* o) { o->update.train.learning_rate *= 10; }, none_s, Expect::kEither},
      {"iters_x5", [](ServerOptions* o) { o->update.train.iterations *= 5; }, none_s, Expect::kEither},
      {"nan_gradient", [](ServerOptions* o) { o->update.train.inject_nan_gradient_at_step = 15; }, none_s,
       Expect::kDone},
      {"blank_scan", none_o,
       [](ScanUpload* u) {
         Image grey(24, 24);
         for (float& x : grey.rgb) x = 0.5f;
         for (ScanFrame& f : u->frames) f.image = *EncodePng(grey);
       },
       Expect::kEither},
      {"single_view", none_o,
       [](ScanUpload* u) {
         std::vector<ScanFrame> keep;
         bool have_train = false;
         for (ScanFrame& f : u->frames) {
           if (f.test || !have_train) keep.push_back(f);
           have_train |= !f.test;
         }
         u->frames = keep;
       },
       Expect::kEither},
      {"far_cameras", none_o,
       [](ScanUpload* u) {
         for (ScanFrame& f : u->frames) f.camera.c2w.col(3) *= 5.0f;
       },
       Expect::kEither},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    StopServer();
    ServerOptions o = TinyServerOptions(store);
    c.options(&o);
    StartServer(o);
    const int64_t before = server_->host().deployed_version();
    ScanUpload up = UploadOf(scene, 1);
    c.scan(&up);
    v1::UploadScanResponse ack;
    ASSERT_TRUE(Upload(UploadMessages(up), &ack).ok());
    const v1::Job j = Watch(ack.job_id());
    ASSERT_TRUE(j.phase() == v1::JOB_PHASE_DONE || j.phase() == v1::JOB_PHASE_FAILED) << j.phase();
    if (c.expect == Expect::kDone) {
      EXPECT_EQ(j.phase(), v1::JOB_PHASE_DONE) << j.error();
    }
    if (c.expect == Expect::kFailed) {
      EXPECT_EQ(j.phase(), v1::JOB_PHASE_FAILED);
    }
    const int64_t after = server_->host().deployed_version();
    if (j.phase() == v1::JOB_PHASE_FAILED) {
      EXPECT_FALSE(j.error().empty());
      EXPECT_EQ(after, before);
    } else {
      EXPECT_EQ(after, before + 1);
    }
    // Every time step of the deployed model renders finite pixels.
    absl::StatusOr<VersionInfo> info = server_->host().GetVersion(after);
    ASSERT_TRUE(info.ok()) << info.status();
    for (int t = 0; t < info->time_steps; ++t) {
      grpc::ClientContext ctx;
      v1::RenderRequest req;
      testing_util::FillCamera(scene.test[0].camera, req.mutable_camera());
      req.set_time_step(t);
      req.set_format(v1::IMAGE_FORMAT_FLOAT32);
      v1::RenderResponse r;
      ASSERT_TRUE(stub_->Render(&ctx, req, &r).ok());
      ASSERT_EQ(r.image().size(), size_t(r.width()) * r.height() * 3 * sizeof(float));
      std::vector<float> px(r.image().size() / sizeof(float));
      std::memcpy(px.data(), r.image().data(), r.image().size());
      for (float x : px) ASSERT_TRUE(std::isfinite(x));
    }
  }
  StopServer();
  absl::StatusOr<std::unique_ptr<VersionStore>> vs = VersionStore::Open(store);
  ASSERT_TRUE(vs.ok()) << vs.status();
  absl::StatusOr<std::vector<VersionInfo>> all = (*vs)->List();
  ASSERT_TRUE(all.ok());
  EXPECT_GE(all->size(), 2u);  // The first scan plus at least nan_gradient's.
  for (const VersionInfo& v : *all) {
    absl::StatusOr<LoadedVersion> lv = (*vs)->Load(v.version);
    ASSERT_TRUE(lv.ok()) << lv.status();
    EXPECT_TRUE(lv->model.AllFinite()) << v.version;
  }
}

TEST_F(ServerFixture, TokenGuardsMutatingCallsOnly) {
  const std::string store = TempDir("srv_auth");
  ServerOptions o = TinyServerOptions(store);
  o.token = "s3cret";
  StartServer(o);
  const Scene scene = TinyScans(1);
  const auto msgs = UploadMessages(UploadOf(scene, 0));
  v1::UploadScanResponse ack;
  EXPECT_EQ(Upload(msgs, &ack).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(Upload(msgs, &ack, "wrong").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  grpc::ClientContext ctx;
  v1::SetDeployedVersionRequest req;
  req.set_version(1);
  v1::Version v;
  EXPECT_EQ(stub_->SetDeployedVersion(&ctx, req, &v).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(StoredScans(store), 0u);
  ASSERT_TRUE(Upload(msgs, &ack, "s3cret").ok());
  EXPECT_EQ(Watch(ack.job_id()).phase(), v1::JOB_PHASE_DONE);  // Reads are open.
  grpc::ClientContext ictx;
  v1::ServerInfo info;
  ASSERT_TRUE(stub_->GetServerInfo(&ictx, v1::GetServerInfoRequest(), &info).ok());
  EXPECT_TRUE(info.auth_required());
  EXPECT_EQ(info.deployed_version(), 1);
}

TEST_F(ServerFixture, HealthServiceAnswers) {
  StartServer(TinyServerOptions(TempDir("srv_health")));
  auto health = grpc::health::v1::Health::NewStub(channel_);
  for (const char* service : {"", "clnerf.v1.ClnerfService"}) {
    grpc::ClientContext ctx;
    grpc::health::v1::HealthCheckRequest req;
    req.set_service(service);
    grpc::health::v1::HealthCheckResponse resp;
    ASSERT_TRUE(health->Check(&ctx, req, &resp).ok()) << service;
    EXPECT_EQ(resp.status(), grpc::health::v1::HealthCheckResponse::SERVING);
  }
  grpc::ClientContext ctx;
  grpc::health::v1::HealthCheckRequest req;
  req.set_service("no.such.Service");
  grpc::health::v1::HealthCheckResponse resp;
  EXPECT_EQ(health->Check(&ctx, req, &resp).error_code(), grpc::StatusCode::NOT_FOUND);
  // After shutdown starts, uploads are refused.
  server_->host().Shutdown();
  v1::UploadScanResponse ack;
  EXPECT_EQ(Upload(UploadMessages(UploadOf(TinyScans(1), 0)), &ack).error_code(), grpc::StatusCode::UNAVAILABLE);
}

}  // namespace
}  // namespace clnerf
