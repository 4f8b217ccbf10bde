// HttpApi: the JSON + image API of clnerf-server over HTTP, which the web
// viewer uses and curl users can call. Every handler is a thin front end over
// the ModelHost of the request's place (?place=NAME on every /api route;
// absent = "default"), the same service layer the gRPC service calls: there is no
// second implementation of rendering, versions or jobs, and no hop through
// gRPC. Routes (docs/service.md "The web viewer" has curl examples):
//
//   GET  /api/places                  every place with its deployed version
//   GET  /api/info                    server state (deployed version, queue)
//   GET  /api/scene[?version=N]       time steps, versions, scans' cameras,
//                                     up, focus, a default camera
//   GET  /api/versions                every version, the deployed one marked
//   GET  /api/render?...              one view as JPEG or PNG (see
//                                     http_render_request.h for parameters)
//   GET  /api/jobs[?limit=&offset=]   jobs, newest first, with progress
//   GET  /api/jobs/ID                 one job
//   POST /api/jobs/ID/cancel          cancel (needs the token, if one is set)
//   POST /api/deploy?version=N        roll back / pin (needs the token)
//   POST /api/scans                   upload an unposed scan, multipart:
//                                     image=@a.jpg ... or video=@walk.mp4
//                                     (needs the token; http_scan_upload.h)
//   GET  /api/cameras[?version=&time_step=]  every trained camera, place frame
//   POST /api/localize[?version=&fx=] where photos (multipart 'image'
//                                     parts) were taken, place frame
//   GET  /metrics                     Prometheus text format (metrics.h)
//   GET  /healthz, /readyz            liveness; readiness (503 once shutting
//                                     down)
//
// Errors are JSON {"error": message, "code": "INVALID_ARGUMENT"} with the
// HTTP status of the absl code (400, 401, 404, 409, 429, 503, 504, ...).
// Renders keep every limit of the gRPC path: the per-request pixel budget,
// the render slots, a deadline (timeout_ms) and cancellation, here by a
// newer render of the same view (view_sessions.h) or server shutdown.
//
// Thread-safety: handlers run concurrently on the HTTP server's threads;
// HttpApi holds only thread-safe state.
#ifndef CLNERF_SERVER_HTTP_API_H_
#define CLNERF_SERVER_HTTP_API_H_

#include <atomic>
#include <functional>
#include <optional>
#include <string>

#include "absl/status/status.h"
#include "server/places/model_host.h"
#include "server/places/places.h"
#include "server/frontends/view_sessions.h"

namespace httplib {
class Server;
}

namespace clnerf {

// The HTTP status for an absl status code.
int HttpStatusFor(absl::StatusCode code);

class HttpApi {
 public:
  // `token` empty = no auth; otherwise mutating routes need
  // `Authorization: Bearer <token>`, as on gRPC.
  HttpApi(Places* places, std::string token) : places_(places), token_(std::move(token)) {}
  void Register(httplib::Server* server);
  // Makes renders in flight stop (server shutdown).
  void Stop() { stopping_.store(true); }
  // The health probes, answered without a worker of the HTTP library (the
  // door calls it: HttpGuardOptions::answer): a complete HTTP response for
  // GET /healthz and GET /readyz, nothing for anything else. Thread-safe.
  std::optional<std::string> AnswerProbe(const std::string& method, const std::string& target) const;
  // Tells renders whether their client left (by the request's remote port,
  // HttpConnectionGuard::ClientGone); such a render stops and frees its
  // slot. Set before serving.
  void SetClientGone(std::function<bool(int remote_port)> gone) { client_gone_ = std::move(gone); }

 private:
  Places* const places_;
  const std::string token_;
  // A probe's status, content type and body: liveness, or readiness (503
  // once shutting down). Served by AnswerProbe at the door and by the
  // routes behind it.
  struct ProbeReply {
    int status;
    const char* type;
    std::string body;
  };
  ProbeReply Probe(bool readiness) const;
  ViewSessions views_;
  std::function<bool(int)> client_gone_;
  std::atomic<bool> stopping_{false};
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_HTTP_API_H_
