#include "server/grpc_service.h"

#include <chrono>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "core/image.h"
#include "server/proto_convert.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {

constexpr int64_t kMaxChunkBytes = 1 << 20;

grpc::Status Invalid(const std::string& msg) { return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, msg); }

grpc::Status Unavailable() { return grpc::Status(grpc::StatusCode::UNAVAILABLE, "server is shutting down"); }

// Encodes a render in the requested format.
absl::StatusOr<std::string> EncodeRender(const Image& img, v1::ImageFormat format) {
  if (format == v1::IMAGE_FORMAT_FLOAT32) {
    std::string out(img.rgb.size() * sizeof(float), '\0');
    std::memcpy(out.data(), img.rgb.data(), out.size());
    return out;
  }
  if (format != v1::IMAGE_FORMAT_PNG && format != v1::IMAGE_FORMAT_UNSPECIFIED) {
    return absl::InvalidArgumentError(absl::StrCat("unknown image format ", int(format)));
  }
  return EncodePng(img);
}

v1::ImageFormat Resolved(v1::ImageFormat f) { return f == v1::IMAGE_FORMAT_UNSPECIFIED ? v1::IMAGE_FORMAT_PNG : f; }

}  // namespace

grpc::Status ClnerfServiceImpl::CheckAuth(const grpc::ServerContext* ctx) const {
  if (token_.empty()) return grpc::Status::OK;
  const auto& md = ctx->client_metadata();
  auto it = md.find("authorization");
  if (it == md.end()) {
    return grpc::Status(grpc::StatusCode::UNAUTHENTICATED, "this call needs 'authorization: Bearer <token>'");
  }
  const std::string got(it->second.data(), it->second.size());
  const std::string want = "Bearer " + token_;
  // Constant-time comparison.
  unsigned diff = got.size() ^ want.size();
  for (size_t i = 0; i < want.size(); ++i) diff |= unsigned(i < got.size() ? got[i] : 0) ^ unsigned(want[i]);
  if (diff != 0) return grpc::Status(grpc::StatusCode::UNAUTHENTICATED, "invalid bearer token");
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::UploadScan(grpc::ServerContext* ctx, grpc::ServerReader<v1::UploadScanRequest>* reader,
                                           v1::UploadScanResponse* response) {
  if (grpc::Status a = CheckAuth(ctx); !a.ok()) return a;
  if (host_->shutting_down()) return Unavailable();
  const ServerOptions& opt = host_->options();
  v1::UploadScanRequest msg;
  if (!reader->Read(&msg)) return Invalid("upload is empty: the first message must be the scan header");
  if (!msg.has_header()) return Invalid("the first upload message must be the scan header");
  const v1::ScanHeader header = msg.header();
  const int n = header.frames_size() + header.test_frames_size();
  if (n > opt.max_frames) {
    return Invalid(absl::StrCat("scan has ", n, " frames; the limit is ", opt.max_frames));
  }
  absl::StatusOr<ScanUpload> upload = ScanFromHeader(header);
  if (!upload.ok()) return ToGrpcStatus(upload.status());
  std::vector<int64_t> want_image(n), want_mask(n);
  int64_t total = 0;
  for (int i = 0; i < n; ++i) {
    const v1::Frame& f = i < header.frames_size() ? header.frames(i) : header.test_frames(i - header.frames_size());
    want_image[i] = f.image_bytes();
    want_mask[i] = f.mask_bytes();
    total += f.image_bytes() + f.mask_bytes();
  }
  if (total > opt.max_scan_bytes) {
    return Invalid(absl::StrCat("scan declares ", total, " bytes; the limit is ", opt.max_scan_bytes));
  }
  int64_t received = 0;
  while (reader->Read(&msg)) {
    if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "upload cancelled by the client");
    if (!msg.has_chunk()) return Invalid("only one scan header is allowed per upload");
    const v1::Chunk& c = msg.chunk();
    if (c.frame_index() < 0 || c.frame_index() >= n) {
      return Invalid(absl::StrCat("chunk for frame ", c.frame_index(), " but the scan has ", n, " frames"));
    }
    if (int64_t(c.data().size()) > kMaxChunkBytes) {
      return Invalid(absl::StrCat("chunk of ", c.data().size(), " bytes exceeds 1 MiB"));
    }
    ScanFrame& f = upload->frames[c.frame_index()];
    std::string& dst = c.is_mask() ? f.mask : f.image;
    const int64_t want = c.is_mask() ? want_mask[c.frame_index()] : want_image[c.frame_index()];
    if (c.offset() != int64_t(dst.size())) {
      return Invalid(absl::StrCat("frame ", c.frame_index(), c.is_mask() ? " mask" : " image", ": chunk at offset ",
                                  c.offset(), " but ", dst.size(), " bytes were received (missing or reordered chunk)"));
    }
    if (int64_t(dst.size() + c.data().size()) > want) {
      return Invalid(absl::StrCat("frame ", c.frame_index(), c.is_mask() ? " mask" : " image", ": more bytes than the ",
                                  want, " declared"));
    }
    if (dst.empty() && want > 0) dst.reserve(size_t(want));
    dst.append(c.data());
    received += int64_t(c.data().size());
  }
  if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "upload cancelled by the client");
  for (int i = 0; i < n; ++i) {
    const ScanFrame& f = upload->frames[i];
    if (int64_t(f.image.size()) != want_image[i] || int64_t(f.mask.size()) != want_mask[i]) {
      return Invalid(absl::StrCat("upload is truncated: frame ", i, " ('", f.name, "') has ", f.image.size(), " of ",
                                  want_image[i], " image bytes and ", f.mask.size(), " of ", want_mask[i],
                                  " mask bytes"));
    }
  }
  absl::StatusOr<UploadAck> ack = host_->AcceptScan(*upload);
  if (!ack.ok()) {
    spdlog::warn("upload '{}' rejected: {}", header.name(), ack.status().ToString());
    return ToGrpcStatus(ack.status());
  }
  response->set_scan_id(ack->scan_id);
  response->set_job_id(ack->job_id);
  response->set_time_step(ack->time_step);
  response->set_bytes_received(received);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::GetJob(grpc::ServerContext*, const v1::GetJobRequest* req, v1::Job* resp) {
  absl::StatusOr<JobStatus> j = host_->GetJob(req->job_id());
  if (!j.ok()) return ToGrpcStatus(j.status());
  *resp = ToProto(*j);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::ListJobs(grpc::ServerContext*, const v1::ListJobsRequest*, v1::ListJobsResponse* resp) {
  for (const JobStatus& j : host_->ListJobs()) *resp->add_jobs() = ToProto(j);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::WatchJob(grpc::ServerContext* ctx, const v1::WatchJobRequest* req,
                                         grpc::ServerWriter<v1::Job>* writer) {
  uint64_t seen = 0;
  while (true) {
    if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "watch cancelled");
    // Wake up regularly to notice client cancellation and shutdown.
    absl::StatusOr<JobStatus> j =
        host_->WaitJob(req->job_id(), seen, std::chrono::steady_clock::now() + std::chrono::milliseconds(500));
    if (!j.ok()) return ToGrpcStatus(j.status());
    if (j->revision > seen) {
      seen = j->revision;
      if (!writer->Write(ToProto(*j))) return grpc::Status(grpc::StatusCode::CANCELLED, "watcher went away");
      if (IsFinal(j->phase)) return grpc::Status::OK;
    }
    if (host_->shutting_down()) return Unavailable();
  }
}

grpc::Status ClnerfServiceImpl::CancelJob(grpc::ServerContext* ctx, const v1::CancelJobRequest* req, v1::Job* resp) {
  if (grpc::Status a = CheckAuth(ctx); !a.ok()) return a;
  absl::StatusOr<JobStatus> j = host_->CancelJob(req->job_id());
  if (!j.ok()) return ToGrpcStatus(j.status());
  *resp = ToProto(*j);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::Render(grpc::ServerContext*, const v1::RenderRequest* req, v1::RenderResponse* resp) {
  if (host_->shutting_down()) return Unavailable();
  absl::StatusOr<Camera> cam = CameraFromProto(req->camera(), "camera");
  if (!cam.ok()) return ToGrpcStatus(cam.status());
  std::optional<int> t;
  if (req->has_time_step() && req->time_step() >= 0) t = req->time_step();
  absl::StatusOr<RenderResult> r = host_->Render(*cam, t, req->version());
  if (!r.ok()) return ToGrpcStatus(r.status());
  absl::StatusOr<std::string> bytes = EncodeRender(r->image, req->format());
  if (!bytes.ok()) return ToGrpcStatus(bytes.status());
  resp->set_version(r->version);
  resp->set_time_step(r->time_step);
  resp->set_width(r->image.width);
  resp->set_height(r->image.height);
  resp->set_format(Resolved(req->format()));
  resp->set_image(*std::move(bytes));
  resp->set_render_seconds(r->seconds);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::RenderStream(grpc::ServerContext* ctx, const v1::RenderStreamRequest* req,
                                             grpc::ServerWriter<v1::RenderChunk>* writer) {
  if (req->cameras_size() == 0) return Invalid("RenderStream needs at least one camera");
  const int64_t chunk = req->max_chunk_bytes() > 0 ? std::min<int64_t>(req->max_chunk_bytes(), kMaxChunkBytes) : kMaxChunkBytes;
  // Check every camera before rendering anything.
  std::vector<Camera> cams;
  for (int i = 0; i < req->cameras_size(); ++i) {
    absl::StatusOr<Camera> cam = CameraFromProto(req->cameras(i), absl::StrCat("camera ", i));
    if (!cam.ok()) return ToGrpcStatus(cam.status());
    cams.push_back(*cam);
  }
  // Pin the version for the whole stream: "deployed" means the one deployed
  // when the stream started.
  int64_t version = req->version();
  if (version == 0) version = host_->deployed_version();
  if (version == 0) return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, "no model is deployed yet: upload a scan first");
  for (size_t i = 0; i < cams.size(); ++i) {
    if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "render stream cancelled");
    if (host_->shutting_down()) return Unavailable();
    std::optional<int> t;
    if (req->has_time_step() && req->time_step() >= 0) t = req->time_step();
    absl::StatusOr<RenderResult> r = host_->Render(cams[i], t, version);
    if (!r.ok()) return ToGrpcStatus(r.status());
    absl::StatusOr<std::string> bytes = EncodeRender(r->image, req->format());
    if (!bytes.ok()) return ToGrpcStatus(bytes.status());
    const int64_t total = int64_t(bytes->size());
    for (int64_t off = 0; off < total; off += chunk) {
      v1::RenderChunk c;
      c.set_frame_index(int(i));
      c.set_version(r->version);
      c.set_time_step(r->time_step);
      c.set_width(r->image.width);
      c.set_height(r->image.height);
      c.set_format(Resolved(req->format()));
      c.set_offset(off);
      c.set_total_bytes(total);
      c.set_data(bytes->substr(size_t(off), size_t(std::min(chunk, total - off))));
      if (!writer->Write(c)) return grpc::Status(grpc::StatusCode::CANCELLED, "client went away");
    }
  }
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::ListVersions(grpc::ServerContext*, const v1::ListVersionsRequest*,
                                             v1::ListVersionsResponse* resp) {
  absl::StatusOr<std::vector<VersionInfo>> all = host_->ListVersions();
  if (!all.ok()) return ToGrpcStatus(all.status());
  const int64_t deployed = host_->deployed_version();
  for (const VersionInfo& v : *all) *resp->add_versions() = ToProto(v, deployed);
  resp->set_deployed_version(deployed);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::GetVersion(grpc::ServerContext*, const v1::GetVersionRequest* req, v1::Version* resp) {
  const int64_t v = req->version() == 0 ? host_->deployed_version() : req->version();
  if (v == 0) return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, "no model is deployed yet");
  absl::StatusOr<VersionInfo> info = host_->GetVersion(v);
  if (!info.ok()) return ToGrpcStatus(info.status());
  *resp = ToProto(*info, host_->deployed_version());
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::SetDeployedVersion(grpc::ServerContext* ctx, const v1::SetDeployedVersionRequest* req,
                                                   v1::Version* resp) {
  if (grpc::Status a = CheckAuth(ctx); !a.ok()) return a;
  absl::StatusOr<VersionInfo> info = host_->SetDeployedVersion(req->version());
  if (!info.ok()) return ToGrpcStatus(info.status());
  *resp = ToProto(*info, host_->deployed_version());
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::GetServerInfo(grpc::ServerContext*, const v1::GetServerInfoRequest*,
                                              v1::ServerInfo* resp) {
  const HostInfo h = host_->Info();
  const ServerOptions& o = host_->options();
  resp->set_server_version("clnerf-server 0.1.0");
  resp->set_deployed_version(h.deployed_version);
  resp->set_time_steps(h.time_steps);
  resp->set_queued_jobs(h.queued_jobs);
  resp->set_running_job(h.running_job);
  resp->set_render_threads(o.render_threads * o.render_concurrency);
  resp->set_train_threads(o.train_threads);
  resp->set_max_queue(o.max_queue);
  resp->set_method(ContinualMethodName(o.update.method));
  resp->set_iterations_per_update(o.update.train.iterations);
  resp->set_auth_required(!token_.empty());
  resp->set_uptime_seconds(int64_t(h.uptime_seconds));
  resp->set_model_bytes(h.model_bytes);
  resp->set_replay_cameras(h.replay_cameras);
  return grpc::Status::OK;
}

}  // namespace clnerf
