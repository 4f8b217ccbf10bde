// GrpcServer: a running clnerf-server — its places (places.h) plus a grpc::Server
// with the ClnerfService, the standard grpc.health.v1 health service and
// server reflection (so grpcurl works), and, with options.http_listen, the
// HTTP front end (http_server.h: the web viewer and its JSON API) over the
// same ModelHost. Used by main() and, in-process on localhost:0, by the
// integration tests.
//
// Shutdown: health goes NOT_SERVING, new calls get UNAVAILABLE, in-flight
// calls get `shutdown_grace_seconds` to finish, then the update worker is
// cancelled (its scan stays stored and is retrained on the next start). The
// server stops as soon as no ClnerfService call is in flight (counted by an
// interceptor), not at the end of the grace: gRPC's own Shutdown(deadline)
// also waited for idle client channels to answer its GOAWAY ping, 5 s each
// time a client held one.
//
// Thread-safety: Start/Shutdown/Wait from one controlling thread;
// Shutdown() may also be called from another thread while Wait() blocks.
#ifndef CLNERF_SERVER_GRPC_SERVER_H_
#define CLNERF_SERVER_GRPC_SERVER_H_

#include <atomic>
#include <memory>
#include <mutex>

#include "absl/status/statusor.h"
#include "grpcpp/server.h"
#include "server/frontends/grpc_service.h"
#include "server/frontends/http_server.h"
#include "server/places/model_host.h"
#include "server/places/places.h"
#include "server/server_options.h"

namespace clnerf {

class GrpcServer {
 public:
  static absl::StatusOr<std::unique_ptr<GrpcServer>> Start(const ServerOptions& options);
  ~GrpcServer();

  int port() const { return port_; }  // The bound port (useful with port 0).
  // The bound HTTP port; 0 when HTTP is off.
  int http_port() const { return http_ ? http_->port() : 0; }
  // The place "default" (what requests without a place reach).
  ModelHost& host() { return *places_->Default(); }
  Places& places() { return *places_; }
  // False if the update worker did not stop within the grace period (the
  // caller should then exit the process without running destructors).
  bool Shutdown();
  void Wait();

 private:
  GrpcServer() = default;
  std::unique_ptr<Places> places_;
  bool clean_ = true;
  std::unique_ptr<ClnerfServiceImpl> service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<HttpServer> http_;  // Destroyed before places_.
  int port_ = 0;
  std::once_flag shutdown_once_;
  // ClnerfService calls in flight (health and reflection streams not counted).
  std::shared_ptr<std::atomic<int>> in_flight_ = std::make_shared<std::atomic<int>>(0);
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_GRPC_SERVER_H_
