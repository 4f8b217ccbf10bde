// ServerFixture: the real gRPC server in-process on localhost:0 and a stub
// (and, with StartHttp, its HTTP front end and a client), with helpers to
// upload, watch, render and list. Test code only.
#ifndef CLNERF_SERVER_SERVER_FIXTURE_H_
#define CLNERF_SERVER_SERVER_FIXTURE_H_

#include <chrono>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "clnerf/v1/clnerf.grpc.pb.h"
#include "grpcpp/create_channel.h"
#include "gtest/gtest.h"
#include "httplib.h"
#include "server/grpc_server.h"
#include "server/testing/server_test_util.h"

namespace clnerf {
namespace testing_util {

// Streams an upload through `stub` (with a bearer token if given).
inline grpc::Status UploadVia(v1::ClnerfService::Stub* stub, const std::vector<v1::UploadScanRequest>& msgs,
                              v1::UploadScanResponse* resp, const std::string& token = "") {
  grpc::ClientContext ctx;
  if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto writer = stub->UploadScan(&ctx, resp);
  for (const auto& m : msgs) {
    if (!writer->Write(m)) break;
  }
  writer->WritesDone();
  return writer->Finish();
}

class ServerFixture : public ::testing::Test {
 protected:
  void StartServer(const ServerOptions& o) {
    auto s = GrpcServer::Start(o);
    ASSERT_TRUE(s.ok()) << s.status();
    server_ = *std::move(s);
    channel_ = grpc::CreateChannel("localhost:" + std::to_string(server_->port()), grpc::InsecureChannelCredentials());
    stub_ = v1::ClnerfService::NewStub(channel_);
  }
  // The server with its HTTP front end on 127.0.0.1:0 too, and `http_` a
  // client of it.
  void StartHttp(ServerOptions o, std::chrono::seconds read_timeout = std::chrono::seconds(60)) {
    o.http_listen = "127.0.0.1:0";
    StartServer(o);
    ASSERT_GT(server_->http_port(), 0);
    http_ = std::make_unique<httplib::Client>("127.0.0.1", server_->http_port());
    http_->set_read_timeout(read_timeout);
  }
  void StopServer() {
    if (server_) server_->Shutdown();
    server_.reset();
  }
  void TearDown() override { StopServer(); }

  grpc::Status Upload(const std::vector<v1::UploadScanRequest>& msgs, v1::UploadScanResponse* resp,
                      const std::string& token = "") {
    return UploadVia(stub_.get(), msgs, resp, token);
  }
  // Streams the job until it ends; returns its final state.
  v1::Job Watch(const std::string& job_id) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(600));
    v1::WatchJobRequest req;
    req.set_job_id(job_id);
    auto reader = stub_->WatchJob(&ctx, req);
    v1::Job job, last;
    while (reader->Read(&job)) last = job;
    EXPECT_TRUE(reader->Finish().ok());
    return last;
  }
  grpc::Status Render(const Camera& cam, int time_step, int64_t version, v1::RenderResponse* resp) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    v1::RenderRequest req;
    testing_util::FillCamera(cam, req.mutable_camera());
    if (time_step >= 0) req.set_time_step(time_step);
    req.set_version(version);
    return stub_->Render(&ctx, req, resp);
  }
  std::vector<v1::Version> Versions() {
    grpc::ClientContext ctx;
    v1::ListVersionsResponse r;
    EXPECT_TRUE(stub_->ListVersions(&ctx, v1::ListVersionsRequest(), &r).ok());
    return {r.versions().begin(), r.versions().end()};
  }
  size_t StoredScans(const std::string& store) {
    size_t n = 0;
    for (const auto& e : std::filesystem::directory_iterator(store + "/scans")) n += e.is_directory();
    return n;
  }
  // Uploads time step t of `scene` and waits for the job to finish.
  v1::Job UploadAndWait(const Scene& scene, int t) {
    v1::UploadScanResponse ack;
    grpc::Status s = Upload(UploadMessages(UploadOf(scene, t)), &ack);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return Watch(ack.job_id());
  }

  std::unique_ptr<GrpcServer> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::ClnerfService::Stub> stub_;
  std::unique_ptr<httplib::Client> http_;  // After StartHttp.
};

}  // namespace testing_util
}  // namespace clnerf

#endif  // CLNERF_SERVER_SERVER_FIXTURE_H_
