#include "server/frontends/http_server.h"

#include <chrono>
#include <exception>
#include <set>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "httplib.h"
#include "nlohmann/json.hpp"
#include "server/frontends/http_origin_guard.h"
#include "server/common/log_util.h"
#include "server/frontends/web_assets.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {

// Request bodies: 64 KiB on every route but the two that carry images (the
// scan upload is bounded by the upload limits as it streams).
constexpr size_t kMaxBodyBytes = 64 << 10;
constexpr size_t kMaxLocalizeBodyBytes = 16 << 20;
constexpr size_t kMaxUploadBodyBytes = (size_t(1) << 30) + (16 << 20);

size_t BodyLimitFor(const std::string& path) {
  if (path == "/api/scans") return kMaxUploadBodyBytes;
  if (path == "/api/localize") return kMaxLocalizeBodyBytes;
  return kMaxBodyBytes;
}

// The first query parameter named twice in a request target ("" if none).
// Read from the raw target: cpp-httplib drops a repeat with the same value
// before a handler sees it, and no route takes a parameter twice.
std::string RepeatedQueryParameter(const std::string& target) {
  const size_t q = target.find('?');
  if (q == std::string::npos) return "";
  std::set<std::string> seen;
  for (absl::string_view kv : absl::StrSplit(absl::string_view(target).substr(q + 1), '&', absl::SkipEmpty())) {
    const std::string key = httplib::detail::decode_url(std::string(kv.substr(0, kv.find('='))), true);
    if (!seen.insert(key).second) return key;
  }
  return "";
}

void SendJsonError(httplib::Response& res, int status, const std::string& code, const std::string& msg) {
  res.status = status;
  res.set_content(nlohmann::json{{"error", msg}, {"code", code}}.dump(-1, ' ', false,
                                                                       nlohmann::json::error_handler_t::replace),
                  "application/json");
}

}  // namespace

absl::StatusOr<std::unique_ptr<HttpServer>> HttpServer::Start(const std::string& listen, Places* places,
                                                              const std::string& token,
                                                              const std::vector<std::string>& allowed_hosts,
                                                              const HttpGuardOptions& door) {
  const size_t colon = listen.rfind(':');
  int port = -1;
  if (colon == std::string::npos || !absl::SimpleAtoi(listen.substr(colon + 1), &port) || port < 0 || port > 65535) {
    return absl::InvalidArgumentError(absl::StrCat("--http '", EscapeForLog(listen, 64), "' is not HOST:PORT"));
  }
  std::string bind_host = listen.substr(0, colon);
  if (bind_host.size() >= 2 && bind_host.front() == '[' && bind_host.back() == ']') {
    bind_host = bind_host.substr(1, bind_host.size() - 2);
  }
  if (bind_host.empty()) bind_host = "0.0.0.0";

  std::unique_ptr<HttpServer> s(new HttpServer());
  s->server_ = std::make_unique<httplib::Server>();
  s->api_ = std::make_unique<HttpApi>(places, token);
  httplib::Server& srv = *s->server_;
  srv.set_payload_max_length(kMaxUploadBodyBytes);
  // Other web sites' requests are refused first (http_origin_guard.h); then
  // each route's own body limit, checked on the headers before any body
  // byte is read (cpp-httplib's payload limit is one for all routes).
  std::vector<std::string> hosts = allowed_hosts;
  hosts.push_back(bind_host);  // A name it was told to listen on is its own.
  srv.set_pre_routing_handler([hosts](const httplib::Request& req, httplib::Response& res) {
    const RequestOrigin origin{req.method, req.get_header_value("Host"), req.get_header_value("Origin"),
                               req.get_header_value("Sec-Fetch-Site")};
    if (absl::Status s = CheckRequestOrigin(origin, hosts); !s.ok()) {
      res.set_header("Connection", "close");
      SendJsonError(res, 403, "PERMISSION_DENIED", std::string(s.message()));
      spdlog::warn("http {} {}: {}", req.method, EscapeForLog(req.path, 128), std::string(s.message()));
      return httplib::Server::HandlerResponse::Handled;
    }
    if (const std::string k = RepeatedQueryParameter(req.target); !k.empty()) {
      SendJsonError(res, 400, "INVALID_ARGUMENT",
                    absl::StrCat("parameter '", EscapeForLog(k, 64), "' is given more than once"));
      return httplib::Server::HandlerResponse::Handled;
    }
    const size_t limit = BodyLimitFor(req.path);
    size_t length = 0;
    const bool has_length = req.has_header("Content-Length");
    if (has_length && (!absl::SimpleAtoi(req.get_header_value("Content-Length"), &length) || length > limit)) {
      res.set_header("Connection", "close");
      SendJsonError(res, 413, "INVALID_ARGUMENT", absl::StrCat("request body over ", limit, " bytes"));
      return httplib::Server::HandlerResponse::Handled;
    }
    if (!has_length && req.has_header("Transfer-Encoding") && limit == kMaxBodyBytes) {
      res.set_header("Connection", "close");
      SendJsonError(res, 411, "INVALID_ARGUMENT", "this route needs a Content-Length (no chunked bodies)");
      return httplib::Server::HandlerResponse::Handled;
    }
    return httplib::Server::HandlerResponse::Unhandled;
  });
  srv.set_read_timeout(std::chrono::seconds(10));
  srv.set_write_timeout(std::chrono::seconds(30));
  // An idle keep-alive connection holds a worker for this long, and Stop()
  // waits for it: keep it short so SIGTERM with a viewer open stays quick
  // (the browser reconnects transparently).
  srv.set_keep_alive_timeout(1);
  s->api_->Register(&srv);

  for (const char* path : {"/", "/index.html", "/viewer.js", "/viewer.css", "/baked.js", "/baked.html"}) {
    srv.Get(path, [](const httplib::Request& req, httplib::Response& res) {
      const WebAsset* a = FindWebAsset(req.path == "/index.html" ? "/" : req.path);
      if (a == nullptr) return SendJsonError(res, 404, "NOT_FOUND", "no such page");
      res.set_header("Cache-Control", "no-cache");
      res.set_content(a->body.data(), a->body.size(), std::string(a->content_type).c_str());
    });
  }
  // Fills in errors that no handler described (unknown paths, bad requests,
  // oversized bodies); JSON errors set by the API are left as they are.
  srv.set_error_handler(httplib::Server::HandlerWithResponse([](const httplib::Request& req, httplib::Response& res) {
    if (!res.body.empty()) return httplib::Server::HandlerResponse::Unhandled;
    if (res.status == 404) {
      SendJsonError(res, 404, "NOT_FOUND", absl::StrCat("no route for ", req.method, " ", EscapeForLog(req.path, 128)));
    } else if (res.status == 413) {
      SendJsonError(res, 413, "INVALID_ARGUMENT",
                    absl::StrCat("request body over ", BodyLimitFor(req.path), " bytes"));
    } else if (req.method.empty()) {  // The request line itself could not be read (414: too long).
      SendJsonError(res, res.status, "INVALID_ARGUMENT",
                    res.status == 414 ? "request line too long (the URI is over 8 KiB)"
                                      : absl::StrCat("HTTP ", res.status, ": the request could not be read"));
    } else {
      SendJsonError(res, res.status, res.status < 500 ? "INVALID_ARGUMENT" : "INTERNAL",
                    absl::StrCat("HTTP ", res.status, " for ", req.method, " ", EscapeForLog(req.path, 128)));
    }
    return httplib::Server::HandlerResponse::Handled;
  }));
  srv.set_exception_handler([](const httplib::Request& req, httplib::Response& res, std::exception_ptr ep) {
    std::string what = "unknown exception";
    try {
      std::rethrow_exception(ep);
    } catch (const std::exception& e) {
      what = e.what();
    } catch (...) {
    }
    spdlog::error("http {} {}: {}", req.method, EscapeForLog(req.path, 128), EscapeForLog(what));
    SendJsonError(res, 500, "INTERNAL", "internal error: " + what);
  });
  srv.set_logger([](const httplib::Request& req, const httplib::Response& res) {
    spdlog::debug("http {} {} -> {}", req.method, EscapeForLog(req.path, 128), res.status);
  });

  // One request per connection, so that every request passes the door
  // (http_connection_guard.h) that stands on the public port.
  srv.set_keep_alive_max_count(1);
  const int backend = srv.bind_to_any_port("127.0.0.1");
  if (backend <= 0) return absl::UnavailableError("cannot listen for HTTP on a loopback port");
  HttpGuardOptions door_options = door;
  door_options.answer = [api = s->api_.get()](const std::string& method, const std::string& target) {
    return api->AnswerProbe(method, target);
  };
  absl::StatusOr<std::unique_ptr<HttpConnectionGuard>> guard =
      HttpConnectionGuard::Start(bind_host, port, backend, door_options);
  if (!guard.ok()) {
    return absl::UnavailableError(absl::StrCat("cannot listen for HTTP on ", EscapeForLog(listen, 64),
                                               " (address in use or not available)"));
  }
  s->guard_ = *std::move(guard);
  s->api_->SetClientGone([g = s->guard_.get()](int port) { return g->ClientGone(port); });
  port = s->guard_->port();
  s->port_ = port;
  s->thread_ = std::thread([srv = s->server_.get()] { srv->listen_after_bind(); });
  // Stop() is only safe once the loop runs (httplib ignores an earlier stop).
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (!srv.is_running() && std::chrono::steady_clock::now() < give_up) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  spdlog::info("http viewer and API on http://{}:{}/", bind_host == "0.0.0.0" ? "localhost" : bind_host, port);
  return s;
}

void HttpServer::Stop() {
  if (!server_) return;
  if (guard_) guard_->Stop();  // No new requests; heads still arriving and requests in flight closed.
  api_->Stop();
  server_->stop();
  if (thread_.joinable()) thread_.join();
}

HttpServer::~HttpServer() { Stop(); }

}  // namespace clnerf
