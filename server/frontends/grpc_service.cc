#include "server/frontends/grpc_service.h"

#include <chrono>
#include <cstring>
#include <functional>
#include <optional>
#include <thread>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "core/data/image.h"
#include "server/frontends/bearer_token.h"
#include "server/common/log_util.h"
#include "server/frontends/proto_convert.h"
#include "server/store/scan_assembler.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {

constexpr int64_t kMaxRenderChunkBytes = 1 << 20;

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
  if (!BearerTokenMatches(std::string_view(it->second.data(), it->second.size()), token_)) return grpc::Status(grpc::StatusCode::UNAUTHENTICATED, "invalid bearer token");
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::UploadScan(grpc::ServerContext* ctx, grpc::ServerReader<v1::UploadScanRequest>* reader,
                                           v1::UploadScanResponse* response) {
  if (grpc::Status a = CheckAuth(ctx); !a.ok()) return a;
  if (places_->shutting_down()) return Unavailable();
  ScanAssembler assembler(places_->options().upload_limits());
  std::shared_ptr<ModelHost> host;  // The scan's place, from its header.
  v1::UploadScanRequest msg;
  bool first = true;
  while (reader->Read(&msg)) {
    if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "upload cancelled by the client");
    absl::Status s;
    if (msg.has_header()) {
      absl::StatusOr<ScanHeaderDecl> decl =
          assembler.begun() ? absl::InvalidArgumentError("only one scan header is allowed per upload")
                            : HeaderFromProto(msg.header());
      // The place first, so an upload to an unknown place or a read-only
      // store fails before any image byte is buffered.
      if (decl.ok()) {
        absl::StatusOr<std::shared_ptr<ModelHost>> p = places_->Get(msg.header().place());
        if (!p.ok()) return ToGrpcStatus(p.status());
        host = *std::move(p);
        if (host->shutting_down()) return ToGrpcStatus(host->StoppedStatus());
        if (absl::Status h = host->WritableStatus(); !h.ok()) return ToGrpcStatus(h);
      }
      s = decl.ok() ? assembler.Begin(*std::move(decl)) : decl.status();
    } else if (msg.has_chunk()) {
      const v1::Chunk& c = msg.chunk();
      s = first ? absl::InvalidArgumentError("the first upload message must be the scan header")
                : assembler.Add(c.frame_index(), c.is_mask(), c.offset(), c.data());
    } else {
      s = absl::InvalidArgumentError("upload message has neither a header nor a chunk");
    }
    if (!s.ok()) return ToGrpcStatus(s);
    first = false;
  }
  if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "upload cancelled by the client");
  if (first) {
    // The sync API reports a message that failed to parse like the end of
    // the stream, so the two cannot be told apart here.
    return Invalid(
        "upload is empty or its first message is not a clnerf.v1.UploadScanRequest (a stream must start with the "
        "scan header; bytes that fail to parse as protobuf, or strings that are not UTF-8, end the stream)");
  }
  const std::string name = assembler.name();
  absl::StatusOr<ScanUpload> upload = assembler.Finish();
  if (!upload.ok()) {
    // Either the client stopped early or a later message failed to parse.
    return ToGrpcStatus(absl::InvalidArgumentError(absl::StrCat(
        upload.status().message(), " (the stream ended early, or a message failed to parse as protobuf)")));
  }
  absl::StatusOr<UploadAck> ack = host->AcceptScan(*upload);
  if (!ack.ok()) {
    spdlog::warn("upload '{}' rejected: {}", EscapeForLog(name), EscapeForLog(ack.status().ToString()));
    return ToGrpcStatus(ack.status());
  }
  response->set_scan_id(ack->scan_id);
  response->set_job_id(ack->job_id);
  response->set_time_step(ack->time_step);
  response->set_bytes_received(assembler.received_bytes());
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::GetJob(grpc::ServerContext*, const v1::GetJobRequest* req, v1::Job* resp) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  absl::StatusOr<JobStatus> j = host->GetJob(req->job_id());
  if (!j.ok()) return ToGrpcStatus(j.status());
  *resp = ToProto(*j);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::ListJobs(grpc::ServerContext*, const v1::ListJobsRequest* req,
                                         v1::ListJobsResponse* resp) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  constexpr int kDefaultPage = 100, kMaxPage = 1000;
  if (req->page_size() < 0) return Invalid("page_size must be >= 0");
  const size_t limit = size_t(req->page_size() == 0 ? kDefaultPage : std::min(req->page_size(), kMaxPage));
  size_t offset = 0;
  if (!req->page_token().empty() && !absl::SimpleAtoi(req->page_token(), &offset)) {
    return Invalid(absl::StrCat("page_token '", EscapeForLog(req->page_token(), 64), "' was not issued by this server"));
  }
  size_t total = 0;
  for (const JobStatus& j : host->ListJobs(offset, limit, &total)) *resp->add_jobs() = ToProto(j);
  if (offset < total && limit < total - offset) resp->set_next_page_token(absl::StrCat(offset + limit));
  resp->set_total_jobs(int(total));
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::WatchJob(grpc::ServerContext* ctx, const v1::WatchJobRequest* req,
                                         grpc::ServerWriter<v1::Job>* writer) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  uint64_t seen = 0;
  while (true) {
    if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "watch cancelled");
    // Wake up regularly to notice client cancellation and shutdown.
    absl::StatusOr<JobStatus> j =
        host->WaitJob(req->job_id(), seen, std::chrono::steady_clock::now() + std::chrono::milliseconds(500));
    if (!j.ok()) return ToGrpcStatus(j.status());
    if (j->revision > seen) {
      seen = j->revision;
      if (!writer->Write(ToProto(*j))) return grpc::Status(grpc::StatusCode::CANCELLED, "watcher went away");
      if (IsFinal(j->phase)) return grpc::Status::OK;
    }
    if (host->shutting_down()) return ToGrpcStatus(host->StoppedStatus());
  }
}

grpc::Status ClnerfServiceImpl::CancelJob(grpc::ServerContext* ctx, const v1::CancelJobRequest* req, v1::Job* resp) {
  if (grpc::Status a = CheckAuth(ctx); !a.ok()) return a;
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  absl::StatusOr<JobStatus> j = host->CancelJob(req->job_id());
  if (!j.ok()) return ToGrpcStatus(j.status());
  *resp = ToProto(*j);
  return grpc::Status::OK;
}

namespace {

// Stops a render whose client went away or whose deadline passed.
std::function<bool()> StopWhenAbandoned(grpc::ServerContext* ctx) {
  const auto deadline = ctx->deadline();
  return [ctx, deadline] { return ctx->IsCancelled() || std::chrono::system_clock::now() >= deadline; };
}

// A render stopped by StopWhenAbandoned: DEADLINE_EXCEEDED or CANCELLED.
grpc::Status AbandonedStatus(grpc::ServerContext* ctx, const absl::Status& s) {
  if (std::chrono::system_clock::now() >= ctx->deadline()) {
    return grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "the call's deadline passed; the render was stopped");
  }
  return grpc::Status(grpc::StatusCode::CANCELLED, std::string(s.message()));
}

// Unset = the latest; ModelHost::Render refuses a negative value.
std::optional<int> TimeStepOf(bool has, int value) { return has ? std::optional<int>(value) : std::nullopt; }

}  // namespace

grpc::Status ClnerfServiceImpl::Render(grpc::ServerContext* ctx, const v1::RenderRequest* req,
                                       v1::RenderResponse* resp) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  if (host->shutting_down()) return ToGrpcStatus(host->StoppedStatus());
  absl::StatusOr<Camera> cam = CameraFromProto(req->camera(), "camera");
  if (!cam.ok()) return ToGrpcStatus(cam.status());
  absl::StatusOr<RenderResult> r =
      host->Render(*cam, TimeStepOf(req->has_time_step(), req->time_step()), req->version(), StopWhenAbandoned(ctx));
  if (absl::IsCancelled(r.status())) return AbandonedStatus(ctx, r.status());
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
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  if (req->cameras_size() == 0) return Invalid("RenderStream needs at least one camera");
  const int64_t chunk = req->max_chunk_bytes() > 0 ? std::min<int64_t>(req->max_chunk_bytes(), kMaxRenderChunkBytes)
                                                    : kMaxRenderChunkBytes;
  const std::optional<int> t = TimeStepOf(req->has_time_step(), req->time_step());
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
  if (version == 0) version = host->deployed_version();
  if (version == 0) return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, "no model is deployed yet: upload a scan first");
  const std::function<bool()> stop = StopWhenAbandoned(ctx);
  for (size_t i = 0; i < cams.size(); ++i) {
    if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "render stream cancelled");
    if (host->shutting_down()) return ToGrpcStatus(host->StoppedStatus());
    absl::StatusOr<RenderResult> r = host->Render(cams[i], t, version, stop);
    if (absl::IsCancelled(r.status())) return AbandonedStatus(ctx, r.status());
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

grpc::Status ClnerfServiceImpl::ListCameras(grpc::ServerContext*, const v1::ListCamerasRequest* req,
                                            v1::ListCamerasResponse* resp) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  if (req->has_time_step() && req->time_step() < 0) return Invalid("time_step must be >= 0");
  absl::StatusOr<CameraList> list = (*place)->Cameras(req->version());
  if (!list.ok()) return ToGrpcStatus(list.status());
  if (req->has_time_step() && req->time_step() >= list->time_steps) {
    return ToGrpcStatus(absl::NotFoundError(absl::StrCat("version ", list->version, " has ", list->time_steps,
                                                         " time steps; there is no time step ", req->time_step())));
  }
  resp->set_version(list->version);
  resp->set_time_steps(list->time_steps);
  for (size_t k = 0; k < list->cameras.size(); ++k) {
    const Camera& c = list->cameras[k];
    if (req->has_time_step() && c.time_step != req->time_step()) continue;
    v1::TrainedCamera* out = resp->add_cameras();
    out->set_time_step(c.time_step);
    out->set_index(list->index[k]);
    out->set_name(list->names[k]);
    *out->mutable_camera() = CameraToProto(c);
  }
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::Localize(grpc::ServerContext* ctx, const v1::LocalizeRequest* req,
                                         v1::LocalizeResponse* resp) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  if (req->photos_size() == 0) return Invalid("Localize needs at least one photo");
  if (req->photos_size() > kMaxLocalizePhotos) {
    return Invalid(absl::StrCat("Localize takes at most ", kMaxLocalizePhotos, " photos per request, not ",
                                req->photos_size()));
  }
  std::vector<PhotoQuery> photos;
  for (int i = 0; i < req->photos_size(); ++i) {
    absl::StatusOr<PhotoQuery> q = PhotoFromProto(req->photos(i), i);
    if (!q.ok()) return ToGrpcStatus(q.status());
    photos.push_back(*std::move(q));
  }
  absl::StatusOr<LocalizeResult> r = (*place)->Localize(req->version(), photos, StopWhenAbandoned(ctx));
  if (absl::IsCancelled(r.status())) return AbandonedStatus(ctx, r.status());
  if (!r.ok()) return ToGrpcStatus(r.status());
  *resp = ToProto(*r);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::ListVersions(grpc::ServerContext*, const v1::ListVersionsRequest* req,
                                             v1::ListVersionsResponse* resp) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  absl::StatusOr<std::vector<VersionInfo>> all = host->ListVersions();
  if (!all.ok()) return ToGrpcStatus(all.status());
  const int64_t deployed = host->deployed_version();
  for (const VersionInfo& v : *all) *resp->add_versions() = ToProto(v, deployed);
  resp->set_deployed_version(deployed);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::GetVersion(grpc::ServerContext*, const v1::GetVersionRequest* req, v1::Version* resp) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  const int64_t v = req->version() == 0 ? host->deployed_version() : req->version();
  if (v == 0) return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, "no model is deployed yet");
  absl::StatusOr<VersionInfo> info = host->GetVersion(v);
  if (!info.ok()) return ToGrpcStatus(info.status());
  *resp = ToProto(*info, host->deployed_version());
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::SetDeployedVersion(grpc::ServerContext* ctx, const v1::SetDeployedVersionRequest* req,
                                                   v1::Version* resp) {
  if (grpc::Status a = CheckAuth(ctx); !a.ok()) return a;
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  absl::StatusOr<VersionInfo> info = host->SetDeployedVersion(req->version());
  if (!info.ok()) return ToGrpcStatus(info.status());
  *resp = ToProto(*info, host->deployed_version());
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::GetServerInfo(grpc::ServerContext*, const v1::GetServerInfoRequest* req,
                                              v1::ServerInfo* resp) {
  absl::StatusOr<std::shared_ptr<ModelHost>> place = places_->Get(req->place());
  if (!place.ok()) return ToGrpcStatus(place.status());
  ModelHost* const host = place->get();
  const HostInfo h = host->Info();
  const ServerOptions& o = host->options();
  resp->set_server_version("clnerf-server 0.1.0");
  resp->set_deployed_version(h.deployed_version);
  resp->set_time_steps(h.time_steps);
  resp->set_queued_jobs(h.queued_jobs);
  resp->set_running_job(h.running_job);
  // Adaptive (0): a lone render may use every core.
  resp->set_render_threads(o.render_threads > 0 ? o.render_threads * o.render_concurrency
                                                : int(std::max(1u, std::thread::hardware_concurrency())));
  resp->set_train_threads(o.train_threads);
  resp->set_max_queue(o.max_queue);
  resp->set_method(ContinualMethodName(o.update.method));
  resp->set_iterations_per_update(o.update.train.iterations);
  resp->set_auth_required(!token_.empty());
  resp->set_uptime_seconds(int64_t(h.uptime_seconds));
  resp->set_model_bytes(h.model_bytes);
  resp->set_replay_cameras(h.replay_cameras);
  resp->set_store_error(h.store_error);
  return grpc::Status::OK;
}

namespace {

v1::Place PlaceProto(const std::string& name, const ModelHost& host) {
  const HostInfo h = host.Info();
  v1::Place p;
  p.set_name(name);
  p.set_deployed_version(h.deployed_version);
  p.set_time_steps(h.time_steps);
  p.set_queued_jobs(h.queued_jobs);
  p.set_running_job(h.running_job);
  p.set_loaded(h.loaded);
  p.set_model_bytes(h.model_bytes);
  p.set_memory_bytes(h.memory_bytes);
  p.set_store_error(h.store_error);
  return p;
}

}  // namespace

grpc::Status ClnerfServiceImpl::ListPlaces(grpc::ServerContext*, const v1::ListPlacesRequest*,
                                           v1::ListPlacesResponse* resp) {
  for (const std::string& name : places_->Names()) {
    absl::StatusOr<std::shared_ptr<ModelHost>> host = places_->Get(name);
    if (!host.ok()) continue;  // Deleted meanwhile.
    *resp->add_places() = PlaceProto(name, **host);
  }
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::CreatePlace(grpc::ServerContext* ctx, const v1::CreatePlaceRequest* req,
                                            v1::Place* resp) {
  if (grpc::Status a = CheckAuth(ctx); !a.ok()) return a;
  absl::StatusOr<std::shared_ptr<ModelHost>> host = places_->Create(req->name());
  if (!host.ok()) return ToGrpcStatus(host.status());
  *resp = PlaceProto(req->name(), **host);
  return grpc::Status::OK;
}

grpc::Status ClnerfServiceImpl::DeletePlace(grpc::ServerContext* ctx, const v1::DeletePlaceRequest* req,
                                            v1::DeletePlaceResponse* resp) {
  if (grpc::Status a = CheckAuth(ctx); !a.ok()) return a;
  if (absl::Status s = places_->Delete(req->name()); !s.ok()) return ToGrpcStatus(s);
  resp->set_name(req->name());
  return grpc::Status::OK;
}

}  // namespace clnerf
