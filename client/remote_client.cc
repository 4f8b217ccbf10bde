#include "client/remote_client.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"

namespace clnerf {
namespace {

// Renders and float32 images can exceed gRPC's default 4 MiB receive limit.
constexpr int kMaxReceiveBytes = 256 << 20;

std::string OneLine(std::string s) {
  s = absl::StrReplaceAll(s, {{"\r\n", " "}, {"\n", " "}, {"\r", " "}});
  return s;
}

}  // namespace

std::string DefaultServer() {
  const char* env = std::getenv("CLNERF_SERVER");
  return env != nullptr && *env != '\0' ? env : "localhost:50051";
}

std::string DefaultToken() {
  const char* env = std::getenv("CLNERF_TOKEN");
  return env != nullptr ? env : "";
}

absl::StatusOr<std::unique_ptr<RemoteClient>> RemoteClient::Create(const RemoteOptions& options) {
  std::shared_ptr<grpc::ChannelCredentials> creds;
  if (options.tls_ca.empty()) {
    creds = grpc::InsecureChannelCredentials();
  } else {
    std::ifstream f(options.tls_ca, std::ios::binary);
    if (!f) return absl::NotFoundError(absl::StrFormat("cannot read --tls-ca '%s'", options.tls_ca));
    std::stringstream pem;
    pem << f.rdbuf();
    grpc::SslCredentialsOptions ssl;
    ssl.pem_root_certs = pem.str();
    creds = grpc::SslCredentials(ssl);
  }
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(kMaxReceiveBytes);
  args.SetUserAgentPrefix("clnerf-cli/0.1.0");
  std::unique_ptr<RemoteClient> client(new RemoteClient());
  client->options_ = options;
  client->channel_ = grpc::CreateCustomChannel(options.server, creds, args);
  client->service_ = clnerf::v1::ClnerfService::NewStub(client->channel_);
  client->health_ = grpc::health::v1::Health::NewStub(client->channel_);
  return client;
}

std::unique_ptr<grpc::ClientContext> RemoteClient::Context(double default_seconds) const {
  auto ctx = std::make_unique<grpc::ClientContext>();
  if (!options_.token.empty()) ctx->AddMetadata("authorization", "Bearer " + options_.token);
  const double seconds = options_.timeout_seconds >= 0 ? options_.timeout_seconds : default_seconds;
  if (seconds > 0) {
    ctx->set_deadline(std::chrono::system_clock::now() +
                      std::chrono::duration_cast<std::chrono::system_clock::duration>(
                          std::chrono::duration<double>(seconds)));
  }
  return ctx;
}

int FailRemote(const std::string& verb, const grpc::Status& status, const RemoteOptions& options) {
  std::string message = OneLine(status.error_message());
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE ||
      status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) {
    message += absl::StrFormat(" (server %s)", options.server);
  }
  if (status.error_code() == grpc::StatusCode::UNAUTHENTICATED && options.token.empty()) {
    message += " (no token given: set --token or CLNERF_TOKEN)";
  }
  std::fprintf(stderr, "clnerf %s: %s: %s\n", verb.c_str(), StatusCodeName(status.error_code()), message.c_str());
  return 1;
}

int FailRemote(const std::string& verb, const absl::Status& status) {
  std::fprintf(stderr, "clnerf %s: %s: %s\n", verb.c_str(), absl::StatusCodeToString(status.code()).c_str(),
               OneLine(std::string(status.message())).c_str());
  return 1;
}

}  // namespace clnerf
