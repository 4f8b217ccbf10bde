// RemoteClient: the one place where the CLI talks gRPC. It owns the channel
// to a clnerf server (plaintext, or TLS with a caller-given root certificate)
// and the generated stubs, and hands out ClientContexts that carry the
// "authorization: Bearer <token>" metadata and the verb's deadline.
//
// Deadlines: every remote verb takes --timeout SECONDS. When it is not given
// (negative) a unary call gets the caller's default (30 s for bookkeeping
// calls, longer for renders) and a long-lived stream (upload, watch, render
// stream) gets no deadline at all; when it is given it bounds every call.
//
// Errors: remote verbs fail with one line on stderr,
// "clnerf <verb>: <CODE>: <message>", where CODE is the canonical status name
// (NOT_FOUND, UNAVAILABLE, ...) of a grpc::Status or an absl::Status.
//
// Thread safety: a RemoteClient may be shared by threads once created (the
// channel and stubs are thread-safe); each ClientContext belongs to one call.
#ifndef CLNERF_CLIENT_REMOTE_CLIENT_H_
#define CLNERF_CLIENT_REMOTE_CLIENT_H_

#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/remote_commands.h"
#include "clnerf/v1/clnerf.grpc.pb.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "proto/wire/wire.h"
#include "grpcpp/grpcpp.h"

namespace clnerf {

// Default deadlines (seconds) for calls whose --timeout is not given.
inline constexpr double kUnaryTimeoutSeconds = 30;
inline constexpr double kRenderTimeoutSeconds = 600;
inline constexpr double kNoDeadline = 0;

class RemoteClient {
 public:
  // Builds the channel (no connection is made yet). Fails only when the TLS
  // root certificate cannot be read.
  static absl::StatusOr<std::unique_ptr<RemoteClient>> Create(const RemoteOptions& options);

  // A context for one call: auth metadata plus a deadline of --timeout, or of
  // `default_seconds` when --timeout is not given (0 = no deadline).
  std::unique_ptr<grpc::ClientContext> Context(double default_seconds) const;

  clnerf::v1::ClnerfService::Stub& service() { return *service_; }
  grpc::health::v1::Health::Stub& health() { return *health_; }
  const RemoteOptions& options() const { return options_; }

 private:
  RemoteClient() = default;
  RemoteOptions options_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<clnerf::v1::ClnerfService::Stub> service_;
  std::unique_ptr<grpc::health::v1::Health::Stub> health_;
};

// "OK", "CANCELLED", ..., "UNAUTHENTICATED" (the canonical names).
// StatusCodeName is in proto/wire/wire.h.

// Prints "clnerf <verb>: <CODE>: <message>" (one line) to stderr and returns
// exit code 1. The gRPC form names the server when it cannot be reached.
int FailRemote(const std::string& verb, const grpc::Status& status, const RemoteOptions& options);
int FailRemote(const std::string& verb, const absl::Status& status);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_REMOTE_CLIENT_H_
