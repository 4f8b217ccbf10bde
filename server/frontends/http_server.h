// HttpServer: clnerf-server's optional HTTP front end (--http HOST:PORT): the
// web viewer's page (web_assets.h) and the JSON + image API (http_api.h) on
// cpp-httplib (Debian's libcpp-httplib-dev; no hand-written HTTP parsing).
// It calls the same places and ModelHosts as the gRPC service.
//
// Requests from other web sites are refused (403): a Host header that does
// not name this server (DNS rebinding) and mutating requests a browser marks
// as cross-origin (http_origin_guard.h).
//
// Each request is logged at debug level (method, path, status, time);
// client-supplied text is escaped. Request bodies are capped (the API takes
// no uploads over HTTP), and unknown paths are JSON 404s.
//
// Thread-safety: Start/Stop from one controlling thread; requests are served
// on the server's own thread pool.
#ifndef CLNERF_SERVER_HTTP_SERVER_H_
#define CLNERF_SERVER_HTTP_SERVER_H_

#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "server/frontends/http_api.h"
#include "server/frontends/http_connection_guard.h"
#include "server/places/model_host.h"

namespace httplib {
class Server;
}

namespace clnerf {

class HttpServer {
 public:
  // Binds `listen` ("HOST:PORT"; port 0 = any free port) and starts serving.
  // `allowed_hosts`: names it answers to besides IP addresses and localhost
  // (http_origin_guard.h). `door`: the limits on request heads
  // (http_connection_guard.h).
  static absl::StatusOr<std::unique_ptr<HttpServer>> Start(const std::string& listen, Places* places,
                                                           const std::string& token,
                                                           const std::vector<std::string>& allowed_hosts = {},
                                                           const HttpGuardOptions& door = {});
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  int port() const { return port_; }
  // Stops accepting, stops renders in flight, joins the serving thread.
  void Stop();

 private:
  HttpServer() = default;
  std::unique_ptr<httplib::Server> server_;
  std::unique_ptr<HttpApi> api_;
  std::thread thread_;
  // The public port's door (limits on request heads); httplib listens on
  // loopback behind it.
  std::unique_ptr<HttpConnectionGuard> guard_;
  int port_ = 0;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_HTTP_SERVER_H_
