#include "server/frontends/http_api.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <string>
#include <string_view>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "core/data/image.h"
#include "httplib.h"
#include "nlohmann/json.hpp"
#include "proto/wire/wire.h"
#include "server/frontends/bearer_token.h"
#include "server/frontends/http_render_request.h"
#include "server/frontends/http_scan_upload.h"
#include "server/common/log_util.h"
#include "spdlog/spdlog.h"

namespace clnerf {

using json = nlohmann::json;

int HttpStatusFor(absl::StatusCode code) {
  switch (code) {
    case absl::StatusCode::kOk: return 200;
    case absl::StatusCode::kInvalidArgument:
    case absl::StatusCode::kOutOfRange: return 400;
    case absl::StatusCode::kUnauthenticated: return 401;
    case absl::StatusCode::kPermissionDenied: return 403;
    case absl::StatusCode::kNotFound: return 404;
    case absl::StatusCode::kAlreadyExists:
    case absl::StatusCode::kAborted:
    case absl::StatusCode::kFailedPrecondition: return 409;
    case absl::StatusCode::kResourceExhausted: return 429;
    // nginx's "client closed request": the client (or a newer request of
    // its view) no longer wants the answer.
    case absl::StatusCode::kCancelled: return 499;
    case absl::StatusCode::kUnimplemented: return 501;
    case absl::StatusCode::kUnavailable: return 503;
    case absl::StatusCode::kDeadlineExceeded: return 504;
    default: return 500;
  }
}

namespace {

// The place a request names with ?place= ("" or absent = default).
absl::StatusOr<std::shared_ptr<ModelHost>> PlaceOf(const Places& places, const httplib::Request& req) {
  return places.Get(req.has_param("place") ? req.get_param_value("place") : "");
}

void SendJson(httplib::Response& res, const json& body, int status = 200) {
  res.status = status;
  res.set_header("Cache-Control", "no-store");
  res.set_content(body.dump(-1, ' ', false, json::error_handler_t::replace), "application/json");
}

void SendError(httplib::Response& res, const absl::Status& s) {
  spdlog::debug("http answer {}: {}", HttpStatusFor(s.code()), EscapeForLog(std::string(s.message()), 256));
  SendJson(res,
           json{{"error", std::string(s.message())},
                {"code", StatusCodeName(static_cast<grpc::StatusCode>(s.code()))}},
           HttpStatusFor(s.code()));
}

json Vec(const Eigen::Vector3f& v) { return json::array({v.x(), v.y(), v.z()}); }

// A camera as the viewer uses it: eye, a target on its axis at the focus
// distance, its own up, its vertical field of view; plus the raw pose.
json CameraJson(const Camera& c, const SceneSummary& s) {
  const Eigen::Vector3f eye = c.position();
  const Eigen::Vector3f fwd = c.c2w.col(2).normalized();
  float d = (s.focus - eye).dot(fwd);
  if (!(d > 0.05f * s.radius)) d = s.radius;
  json pose = json::array();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 4; ++j) pose.push_back(c.c2w(i, j));
  }
  const Intrinsics& in = c.intrinsics;
  return json{{"time_step", c.time_step},
              {"eye", Vec(eye)},
              {"target", Vec(eye + fwd * d)},
              {"up", Vec(-c.c2w.col(1))},
              {"fov", 2 * std::atan(0.5 * in.height / in.fy) * 180 / M_PI},
              {"width", in.width},
              {"height", in.height},
              {"c2w", pose}};
}

json VersionJson(const VersionInfo& v, int64_t deployed) {
  return json{{"version", v.version},         {"parent", v.parent},
              {"time_steps", v.time_steps},   {"size_bytes", v.size_bytes},
              {"model_bytes", v.model_bytes}, {"replay_bytes", v.replay_bytes},
              {"created_unix_ms", v.created_unix_ms},
              {"scan_id", v.scan_id},         {"metrics", v.metrics},
              {"deployed", v.version == deployed}, {"unavailable", v.unavailable}};
}

json JobJson(const JobStatus& j) {
  json o = JobToJson(j);
  o["done"] = IsFinal(j.phase);
  o["eta_seconds"] = j.eta_seconds;
  o["cancel_requested"] = j.cancel_requested;
  for (const char* k : {"loss", "psnr"}) {
    if (!std::isfinite(o[k].get<double>())) o[k] = nullptr;
  }
  return o;
}

// Every version, the deployed one marked, and the deployed version's number.
absl::StatusOr<json> VersionsJson(const ModelHost& host, int64_t* deployed) {
  absl::StatusOr<std::vector<VersionInfo>> all = host.ListVersions();
  if (!all.ok()) return all.status();
  *deployed = host.deployed_version();
  json list = json::array();
  for (const VersionInfo& v : *all) list.push_back(VersionJson(v, *deployed));
  return list;
}

// An optional integer query parameter in [lo, hi].
absl::StatusOr<int64_t> IntParam(const httplib::Request& req, const char* name, int64_t fallback, int64_t lo,
                                 int64_t hi) {
  if (!req.has_param(name)) return fallback;
  if (req.get_param_value_count(name) > 1) {
    return absl::InvalidArgumentError(absl::StrCat("parameter '", name, "' is given more than once"));
  }
  const std::string v = req.get_param_value(name);
  int64_t x = 0;
  if (!absl::SimpleAtoi(v, &x) || x < lo || x > hi) {
    return absl::InvalidArgumentError(
        absl::StrCat("parameter '", name, "': '", EscapeForLog(v, 64), "' is not an integer in ", lo, "..", hi));
  }
  return x;
}

// The cameras of a list as JSON (only time step `t`, unless t < 0): pose
// row-major 3x4 camera-to-world, OpenCV convention, the place's frame.
json CamerasJson(const CameraList& list, int t) {
  json cams = json::array();
  for (size_t k = 0; k < list.cameras.size(); ++k) {
    const Camera& c = list.cameras[k];
    if (t >= 0 && c.time_step != t) continue;
    json pose = json::array();
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < 4; ++k) pose.push_back(c.c2w(r, k));
    const Intrinsics& in = c.intrinsics;
    cams.push_back(json{{"time_step", c.time_step}, {"index", list.index[k]}, {"name", list.names[k]}, {"c2w_opencv", pose},
                        {"width", in.width}, {"height", in.height}, {"fx", in.fx}, {"fy", in.fy},
                        {"cx", in.cx}, {"cy", in.cy}, {"k1", in.k1}, {"k2", in.k2}, {"p1", in.p1}, {"p2", in.p2}});
  }
  return json{{"version", list.version}, {"time_steps", list.time_steps}, {"convention", "opencv"},
              {"cameras", cams}};
}

json LocalizeJson(const LocalizeResult& r) {
  json photos = json::array();
  for (const PhotoLocation& l : r.report.photos) {
    json p{{"name", l.name}, {"placed", l.found.placed}, {"matches", l.found.matches},
           {"inliers", l.found.inliers}, {"intrinsics_guessed", l.intrinsics_guessed}};
    if (l.found.placed) {
      json pose = json::array();
      for (int i = 0; i < 3; ++i)
        for (int k = 0; k < 4; ++k) pose.push_back(l.camera.c2w(i, k));
      p["c2w_opencv"] = pose;
      p["fx"] = l.camera.intrinsics.fx;
      p["fy"] = l.camera.intrinsics.fy;
      p["reprojection_px"] = l.found.reprojection_px;
    }
    photos.push_back(std::move(p));
  }
  return json{{"version", r.version}, {"photos", photos}, {"references", r.report.references},
              {"seconds", r.seconds}};
}

// The photos of a multipart localisation request ('image' parts), with the
// optional ?fx= (pinhole, centred principal point) for all of them.
absl::StatusOr<std::vector<PhotoQuery>> PhotosOf(const httplib::Request& req) {
  std::vector<PhotoQuery> out;
  double fx = 0;
  if (req.has_param("fx") && (!absl::SimpleAtod(req.get_param_value("fx"), &fx) || !(fx > 0 && fx < 1e6))) {
    return absl::InvalidArgumentError("parameter 'fx' must be a focal length in pixels (> 0)");
  }
  for (const auto& [field, part] : req.files) {
    if (field != "image") {
      return absl::InvalidArgumentError(absl::StrCat("unknown form field '", EscapeForLog(field, 64), "' (image)"));
    }
    if (int(out.size()) >= 32) return absl::InvalidArgumentError("at most 32 photos per request");
    PhotoQuery q;
    q.name = part.filename.empty() ? absl::StrCat("photo_", out.size()) : EscapeForLog(part.filename, 128);
    const std::string ext = SniffImageExtension(part.content);
    if (ext.empty()) return absl::InvalidArgumentError(absl::StrCat("photo '", q.name, "' is not an image"));
    absl::StatusOr<Image> img = DecodeImage(part.content, q.name + ext);
    if (!img.ok()) return absl::InvalidArgumentError(absl::StrCat("photo '", q.name, "': ", img.status().message()));
    q.image = *std::move(img);
    if (fx > 0) {
      q.intrinsics = Intrinsics{q.image.width, q.image.height, float(fx), float(fx), q.image.width / 2.0f,
                                q.image.height / 2.0f};
    }
    out.push_back(std::move(q));
  }
  if (out.empty()) return absl::InvalidArgumentError("no photos: send them as multipart 'image' parts");
  return out;
}

// Streams a multipart scan into a ScanUpload and hands it to the place.
absl::StatusOr<UploadAck> AcceptMultipartScan(ModelHost& host, const httplib::ContentReader& content) {
  if (absl::Status s = host.WritableStatus(); !s.ok()) return s;
  char scratch[] = "/tmp/clnerf-http-upload-XXXXXX";
  if (mkdtemp(scratch) == nullptr) return absl::InternalError("cannot create a scratch folder in /tmp");
  MultipartScanReader reader(host.options().upload_limits(), scratch);
  const bool read = content([&](const httplib::MultipartFormData& part) { return reader.BeginPart(part.name, part.filename); },
                            [&](const char* data, size_t n) { return reader.AddBytes(data, n); });
  if (!reader.status().ok()) return reader.status();
  if (!read) return absl::InvalidArgumentError("the upload was cut short (truncated or malformed multipart body)");
  absl::StatusOr<ScanUpload> upload = reader.Finish();
  if (!upload.ok()) return upload.status();
  return host.AcceptScan(*upload);
}

}  // namespace

HttpApi::ProbeReply HttpApi::Probe(bool readiness) const {
  if (!readiness) return {200, "text/plain; charset=utf-8", "ok\n"};
  const bool ready = !places_->shutting_down() && !stopping_.load();
  const json body = {{"ready", ready}, {"places", places_->Names().size()}};
  return {ready ? 200 : 503, "application/json", body.dump(-1, ' ', false, json::error_handler_t::replace)};
}

std::optional<std::string> HttpApi::AnswerProbe(const std::string& method, const std::string& target) const {
  if (method != "GET" || (target != "/healthz" && target != "/readyz")) return std::nullopt;
  const ProbeReply r = Probe(target == "/readyz");
  return absl::StrCat("HTTP/1.1 ", r.status, r.status == 200 ? " OK" : " Service Unavailable",
                      "\r\nContent-Type: ", r.type, "\r\nCache-Control: no-store\r\nConnection: close",
                      "\r\nContent-Length: ", r.body.size(), "\r\n\r\n", r.body);
}

void HttpApi::Register(httplib::Server* server) {
  auto authorized = [this](const httplib::Request& req, httplib::Response& res) {
    if (token_.empty()) return true;
    if (!req.has_header("Authorization")) {
      SendError(res, absl::UnauthenticatedError("this call needs 'Authorization: Bearer <token>'"));
      return false;
    }
    if (!BearerTokenMatches(req.get_header_value("Authorization"), token_)) {
      SendError(res, absl::UnauthenticatedError("invalid bearer token"));
      return false;
    }
    return true;
  };

  // Operations: Prometheus metrics, liveness (the process answers) and
  // readiness (it takes traffic: not shutting down; a read-only store or an
  // empty one still serves what it can).
  server->Get("/metrics", [this](const httplib::Request&, httplib::Response& res) {
    places_->metrics().SetModelBytes(places_->models().stats().bytes);
    res.set_content(places_->metrics().Text(), "text/plain; version=0.0.4; charset=utf-8");
  });
  // Behind the door (http_connection_guard.h) these are answered by
  // AnswerProbe; the routes stay for completeness.
  for (const char* path : {"/healthz", "/readyz"}) {
    const bool readiness = std::string_view(path) == "/readyz";
    server->Get(path, [this, readiness](const httplib::Request&, httplib::Response& res) {
      const ProbeReply r = Probe(readiness);
      res.status = r.status;
      res.set_header("Cache-Control", "no-store");
      res.set_content(r.body, r.type);
    });
  }
  server->Get("/api/places", [this](const httplib::Request&, httplib::Response& res) {
    json list = json::array();
    for (const std::string& name : places_->Names()) {
      absl::StatusOr<std::shared_ptr<ModelHost>> h = places_->Get(name);
      if (!h.ok()) continue;  // Deleted meanwhile.
      const HostInfo i = (*h)->Info();
      list.push_back(json{{"name", name},
                          {"deployed_version", i.deployed_version},
                          {"time_steps", i.time_steps},
                          {"queued_jobs", i.queued_jobs},
                          {"running_job", i.running_job},
                          {"loaded", i.loaded},
                          {"model_bytes", i.model_bytes},
                          {"memory_bytes", i.memory_bytes},
                          {"store_error", i.store_error}});
    }
    SendJson(res, json{{"places", list}});
  });

  server->Get("/api/info", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    const HostInfo h = host->Info();
    SendJson(res, json{{"server_version", "clnerf-server 0.1.0"},
                       {"deployed_version", h.deployed_version},
                       {"time_steps", h.time_steps},
                       {"queued_jobs", h.queued_jobs},
                       {"running_job", h.running_job},
                       {"store_error", h.store_error},
                       {"model_bytes", h.model_bytes},
                       {"replay_cameras", h.replay_cameras},
                       {"uptime_seconds", h.uptime_seconds},
                       {"max_render_pixels", host->max_pixels_per_render()},
                       {"auth_required", !token_.empty()}});
  });

  server->Get("/api/versions", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    int64_t deployed = 0;
    absl::StatusOr<json> list = VersionsJson(*host, &deployed);
    if (!list.ok()) return SendError(res, list.status());
    SendJson(res, json{{"deployed_version", deployed}, {"versions", *list}});
  });

  server->Get("/api/scene", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    absl::StatusOr<int64_t> v = IntParam(req, "version", 0, 0, int64_t(1) << 62);
    if (!v.ok()) return SendError(res, v.status());
    absl::StatusOr<SceneSummary> s = host->Scene(*v);
    if (!s.ok()) return SendError(res, s.status());
    int64_t deployed = 0;
    absl::StatusOr<json> versions = VersionsJson(*host, &deployed);
    if (!versions.ok()) return SendError(res, versions.status());
    json scans = json::array();
    for (const Camera& c : s->scan_cameras) scans.push_back(CameraJson(c, *s));
    SendJson(res, json{{"version", s->version},
                       {"deployed_version", deployed},
                       {"time_steps", s->time_steps},
                       {"bounded", s->bounded},
                       {"up", Vec(s->up)},
                       {"focus", Vec(s->focus)},
                       {"radius", s->radius},
                       {"cameras", s->cameras},
                       {"scans", scans},
                       {"default_camera", CameraJson(s->default_camera, *s)},
                       {"versions", *versions},
                       {"max_render_pixels", host->max_pixels_per_render()},
                       {"auth_required", !token_.empty()}});
  });

  server->Get("/api/render", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    if (stopping_.load()) return SendError(res, absl::UnavailableError("server is shutting down"));
    if (host->shutting_down()) return SendError(res, host->StoppedStatus());
    absl::StatusOr<HttpRenderRequest> r = ParseRenderQuery(req.params);
    if (!r.ok()) return SendError(res, r.status());
    const ViewSessions::Ticket ticket = views_.Begin(r->view_id);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(r->timeout_ms);
    auto client_left = [&] { return client_gone_ && client_gone_(req.remote_port); };
    auto stop = [&] {
      return ticket.superseded() || stopping_.load() || host->shutting_down() ||
             std::chrono::steady_clock::now() >= deadline || client_left();
    };
    auto why = [&]() -> absl::Status {
      if (client_left()) return absl::CancelledError("the client went away");
      if (ticket.superseded()) {
        return absl::CancelledError(absl::StrCat("superseded by a newer render of view '", r->view_id, "'"));
      }
      if (stopping_.load()) return absl::UnavailableError("server is shutting down");
      if (host->shutting_down()) return host->StoppedStatus();
      if (std::chrono::steady_clock::now() >= deadline) {
        return absl::DeadlineExceededError(
            absl::StrCat("the render did not finish within timeout_ms ", r->timeout_ms, " and was stopped"));
      }
      return absl::OkStatus();
    };
    absl::StatusOr<RenderResult> out = host->Render(r->camera, r->time_step, r->version, stop, why);
    if (!out.ok()) return SendError(res, out.status());
    absl::StatusOr<std::string> bytes = r->format == HttpImageFormat::kPng ? EncodePng(out->image)
                                                                           : EncodeJpeg(out->image, r->quality);
    if (!bytes.ok()) return SendError(res, bytes.status());
    res.set_header("Cache-Control", "no-store");
    res.set_header("X-Clnerf-Version", std::to_string(out->version));
    res.set_header("X-Clnerf-Time-Step", std::to_string(out->time_step));
    res.set_header("X-Clnerf-Render-Ms", absl::StrCat(std::lround(out->seconds * 1000)));
    res.set_content(*std::move(bytes), r->format == HttpImageFormat::kPng ? "image/png" : "image/jpeg");
  });

  // A version's baked asset for the browser (issue 41): ?version=N (0 =
  // deployed) &time=T (default latest) &file=manifest.json|index.bin.gz|
  // atlas.bin.gz|view.bin.gz. The arrays are gzip streams sent as they are (no
  // Content-Encoding: the page decodes them with DecompressionStream).
  server->Get("/api/asset", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    auto fail = [&](const absl::Status& s) {
      host->metrics().AssetServed(s.code(), 0);
      SendError(res, s);
    };
    absl::StatusOr<int64_t> v = IntParam(req, "version", 0, 0, int64_t(1) << 62);
    if (!v.ok()) return fail(v.status());
    absl::StatusOr<int64_t> t = IntParam(req, "time", -1, -1, 1 << 20);
    if (!t.ok()) return fail(t.status());
    const std::string file = req.has_param("file") ? req.get_param_value("file") : "manifest.json";
    absl::StatusOr<AssetFile> a =
        host->Asset(*v, *t < 0 ? std::nullopt : std::optional<int>(int(*t)), file);
    if (!a.ok()) return fail(a.status());
    // An explicit version never changes; "the deployed one" may.
    res.set_header("Cache-Control", *v > 0 ? "public, max-age=31536000, immutable" : "no-cache");
    res.set_header("ETag", a->etag);
    res.set_header("X-Clnerf-Version", std::to_string(a->version));
    res.set_header("X-Clnerf-Time-Step", std::to_string(a->time_step));
    if (req.get_header_value("If-None-Match") == a->etag) {
      host->metrics().AssetServed(absl::StatusCode::kOk, 0);
      res.status = 304;
      return;
    }
    const std::shared_ptr<const AssetBlob> blob = a->blob;
    host->metrics().AssetServed(absl::StatusCode::kOk, int64_t(blob->bytes.size()));
    const char* type = file == "manifest.json" ? "application/json" : "application/octet-stream";
    // Sent from the shared, cached bytes (no copy per viewer).
    res.set_content_provider(blob->bytes.size(), type,
                             [blob](size_t offset, size_t length, httplib::DataSink& sink) {
                               return sink.write(blob->bytes.data() + offset, std::min<size_t>(length, 1 << 16));
                             });
  });

  server->Get("/api/jobs", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    absl::StatusOr<int64_t> limit = IntParam(req, "limit", 100, 1, 1000);
    if (!limit.ok()) return SendError(res, limit.status());
    absl::StatusOr<int64_t> offset = IntParam(req, "offset", 0, 0, int64_t(1) << 40);
    if (!offset.ok()) return SendError(res, offset.status());
    const std::string order = req.has_param("order") ? req.get_param_value("order") : "newest";
    if (order != "newest" && order != "oldest") {
      return SendError(res, absl::InvalidArgumentError(absl::StrCat("parameter 'order': '", EscapeForLog(order, 64),
                                                                    "' is not newest or oldest")));
    }
    size_t total = 0;
    host->ListJobs(0, 0, &total);
    std::vector<JobStatus> page;
    if (order == "oldest") {
      page = host->ListJobs(size_t(*offset), size_t(*limit), &total);
    } else if (size_t(*offset) < total) {
      // Newest first: the page [offset, offset + limit) counted from the end.
      const size_t end = total - size_t(*offset);
      const size_t begin = end > size_t(*limit) ? end - size_t(*limit) : 0;
      page = host->ListJobs(begin, end - begin, &total);
      std::reverse(page.begin(), page.end());
    }
    json list = json::array();
    for (const JobStatus& j : page) list.push_back(JobJson(j));
    SendJson(res, json{{"jobs", list}, {"total", total}, {"order", order}});
  });

  server->Get(R"(/api/jobs/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    absl::StatusOr<JobStatus> j = host->GetJob(req.matches[1].str());
    if (!j.ok()) return SendError(res, j.status());
    SendJson(res, JobJson(*j));
  });

  server->Post(R"(/api/jobs/([^/]+)/cancel)", [this, authorized](const httplib::Request& req, httplib::Response& res) {
    if (!authorized(req, res)) return;
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    absl::StatusOr<JobStatus> j = host->CancelJob(req.matches[1].str());
    if (!j.ok()) return SendError(res, j.status());
    SendJson(res, JobJson(*j));
  });

  server->Get("/api/cameras", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    absl::StatusOr<int64_t> v = IntParam(req, "version", 0, 0, int64_t(1) << 62);
    if (!v.ok()) return SendError(res, v.status());
    absl::StatusOr<int64_t> t = IntParam(req, "time_step", -1, 0, 1 << 20);
    if (!t.ok()) return SendError(res, t.status());
    absl::StatusOr<CameraList> list = (*place)->Cameras(*v);
    if (!list.ok()) return SendError(res, list.status());
    if (*t >= list->time_steps) {
      return SendError(res, absl::NotFoundError(absl::StrCat("version ", list->version, " has ", list->time_steps,
                                                             " time steps; there is no time step ", *t)));
    }
    SendJson(res, CamerasJson(*list, int(*t)));
  });

  server->Post("/api/localize", [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    absl::StatusOr<int64_t> v = IntParam(req, "version", 0, 0, int64_t(1) << 62);
    if (!v.ok()) return SendError(res, v.status());
    absl::StatusOr<std::vector<PhotoQuery>> photos = PhotosOf(req);
    if (!photos.ok()) return SendError(res, photos.status());
    absl::StatusOr<LocalizeResult> r =
        (*place)->Localize(*v, *photos, [this, &place] { return stopping_.load() || (*place)->shutting_down(); });
    if (!r.ok()) return SendError(res, r.status());
    SendJson(res, LocalizeJson(*r));
  });

  server->Post("/api/scans", [this, authorized](const httplib::Request& req, httplib::Response& res,
                                                const httplib::ContentReader& content) {
    if (!authorized(req, res)) return;
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    if (!req.is_multipart_form_data()) {
      return SendError(res, absl::InvalidArgumentError(
                                "send the scan as multipart/form-data: image=@photo.jpg (repeated) or video=@walk.mp4"));
    }
    absl::StatusOr<UploadAck> ack = AcceptMultipartScan(**place, content);
    if (!ack.ok()) return SendError(res, ack.status());
    SendJson(res, json{{"scan_id", ack->scan_id}, {"job_id", ack->job_id}, {"time_step", ack->time_step},
                       {"bytes", ack->bytes}});
  });

  server->Post("/api/deploy", [this, authorized](const httplib::Request& req, httplib::Response& res) {
    if (!authorized(req, res)) return;
    absl::StatusOr<std::shared_ptr<ModelHost>> place = PlaceOf(*places_, req);
    if (!place.ok()) return SendError(res, place.status());
    ModelHost* const host = place->get();
    if (!req.has_param("version")) return SendError(res, absl::InvalidArgumentError("parameter 'version' is required"));
    absl::StatusOr<int64_t> v = IntParam(req, "version", 0, 1, int64_t(1) << 62);
    if (!v.ok()) return SendError(res, v.status());
    absl::StatusOr<VersionInfo> info = host->SetDeployedVersion(*v);
    if (!info.ok()) return SendError(res, info.status());
    SendJson(res, VersionJson(*info, host->deployed_version()));
  });
}

}  // namespace clnerf
