#include "server/grpc_server.h"

#include <fstream>
#include <sstream>
#include <string_view>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "grpcpp/ext/proto_server_reflection_plugin.h"
#include "grpcpp/health_check_service_interface.h"
#include "grpcpp/resource_quota.h"
#include "grpcpp/security/server_credentials.h"
#include "grpcpp/server_builder.h"
#include "grpcpp/support/server_interceptor.h"
#include "server/frontends/http_server.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {

absl::StatusOr<std::string> ReadPem(const std::string& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read '", path, "'"));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Counts the ClnerfService calls in flight: one interceptor lives exactly as
// long as its call.
class CallCounter final : public grpc::experimental::Interceptor {
 public:
  explicit CallCounter(std::shared_ptr<std::atomic<int>> n) : n_(std::move(n)) { n_->fetch_add(1); }
  ~CallCounter() override { n_->fetch_sub(1); }
  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override { methods->Proceed(); }

 private:
  const std::shared_ptr<std::atomic<int>> n_;
};

class CallCounterFactory final : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit CallCounterFactory(std::shared_ptr<std::atomic<int>> n) : n_(std::move(n)) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(grpc::experimental::ServerRpcInfo* info) override {
    const std::string_view method = info->method() != nullptr ? info->method() : "";
    if (method.rfind("/clnerf.v1.", 0) != 0) return nullptr;  // Health, reflection: long streams, not work.
    return new CallCounter(n_);
  }

 private:
  const std::shared_ptr<std::atomic<int>> n_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<GrpcServer>> GrpcServer::Start(const ServerOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  std::unique_ptr<GrpcServer> srv(new GrpcServer());
  absl::StatusOr<std::unique_ptr<Places>> places = Places::Open(options);
  if (!places.ok()) return places.status();
  srv->places_ = *std::move(places);
  srv->service_ = std::make_unique<ClnerfServiceImpl>(srv->places_.get(), options.token);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  std::shared_ptr<grpc::ServerCredentials> creds = grpc::InsecureServerCredentials();
  if (!options.tls_cert.empty()) {
    absl::StatusOr<std::string> cert = ReadPem(options.tls_cert);
    absl::StatusOr<std::string> key = ReadPem(options.tls_key);
    if (!cert.ok()) return cert.status();
    if (!key.ok()) return key.status();
    grpc::SslServerCredentialsOptions ssl;
    ssl.pem_key_cert_pairs.push_back({*key, *cert});
    creds = grpc::SslServerCredentials(ssl);
  }
  builder.AddListeningPort(options.listen, creds, &srv->port_);
  builder.RegisterService(srv->service_.get());
  builder.SetMaxReceiveMessageSize(options.max_message_bytes);
  builder.SetMaxSendMessageSize(std::max(options.max_message_bytes, int(options.max_render_pixels * 12 + (1 << 16))));
  grpc::ResourceQuota quota("clnerf-server");
  quota.SetMaxThreads(options.grpc_threads);
  builder.SetResourceQuota(quota);
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
  interceptors.push_back(std::make_unique<CallCounterFactory>(srv->in_flight_));
  builder.experimental().SetInterceptorCreators(std::move(interceptors));
  srv->server_ = builder.BuildAndStart();
  if (!srv->server_ || srv->port_ == 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen on ", options.listen, " (address in use or invalid?)"));
  }
  grpc::HealthCheckServiceInterface* health = srv->server_->GetHealthCheckService();
  if (health != nullptr) {
    health->SetServingStatus(true);
    health->SetServingStatus("clnerf.v1.ClnerfService", true);
  }
  spdlog::info("clnerf-server listening on port {} (store {}, auth {}, tls {})", srv->port_, options.store_dir,
               options.token.empty() ? "off" : "on", options.tls_cert.empty() ? "off" : "on");
  if (!options.http_listen.empty()) {
    HttpGuardOptions door;
    door.max_head_bytes = size_t(options.http_max_head_bytes);
    door.head_timeout_seconds = options.http_head_timeout_seconds;
    absl::StatusOr<std::unique_ptr<HttpServer>> http = HttpServer::Start(
        options.http_listen, srv->places_.get(), options.token, options.http_allowed_hosts, door);
    if (!http.ok()) return http.status();
    srv->http_ = *std::move(http);
  }
  return srv;
}

bool GrpcServer::Shutdown() {
  std::call_once(shutdown_once_, [this] {
    spdlog::info("shutting down: health NOT_SERVING, finishing in-flight calls");
    if (grpc::HealthCheckServiceInterface* health = server_->GetHealthCheckService()) {
      health->SetServingStatus(false);
    }
    // The HTTP front end stops first: its renders in flight end, new
    // requests are refused.
    if (http_) http_->Stop();
    // Stop training first so long WatchJob streams and the worker end
    // promptly; new uploads and renders are refused (UNAVAILABLE).
    clean_ = places_->Shutdown();
    // In-flight calls get the grace; then (or once none is left) the server
    // stops at once, without waiting on idle client channels.
    const auto grace_end = std::chrono::steady_clock::now() +
                           std::chrono::milliseconds(int64_t(places_->options().shutdown_grace_seconds * 1000));
    while (in_flight_->load() > 0 && std::chrono::steady_clock::now() < grace_end) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    server_->Shutdown(std::chrono::system_clock::now());
    spdlog::info(clean_ ? "shutdown complete" : "shutdown incomplete: the update worker is still running");
  });
  return clean_;
}

void GrpcServer::Wait() { server_->Wait(); }

GrpcServer::~GrpcServer() {
  if (server_) Shutdown();
}

}  // namespace clnerf
