// Remote verbs on model versions and the server: versions, rollback, info.
#include <cstdio>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/progress_bar.h"
#include "client/verb_set.h"
#include "client/proto_json.h"
#include "client/remote_client.h"
#include "client/remote_commands.h"
#include "client/remote_format.h"
#include "client/text_table.h"

namespace clnerf {

CLI::App* BindVersions(CLI::App* parent, ListArgs* a) {
  CLI::App* c = parent->add_subcommand("versions", "List the server's model versions");
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunVersions(const ListArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("versions", client.status());
  clnerf::v1::ListVersionsResponse response;
  clnerf::v1::ListVersionsRequest request;
  request.set_place(a.remote.place);
  grpc::Status s = (*client)->service().ListVersions((*client)->Context(kUnaryTimeoutSeconds).get(), request,
                                                     &response);
  if (!s.ok()) return FailRemote("versions", s, a.remote);
  if (a.remote.json) {
    std::printf("%s\n", ProtoToJson(response).dump(2).c_str());
    return 0;
  }
  if (response.versions().empty()) {
    std::printf("no versions yet (upload a scan first)\n");
    return 0;
  }
  // SIZE: the stored checkpoint; MODEL + REPLAY: what it holds (parameters,
  // and the replay memory's cameras and 8-bit buffer images).
  TextTable table({"", "VERSION", "PARENT", "TIME STEPS", "SIZE", "MODEL + REPLAY", "CREATED", "SCAN", "METRICS"});
  for (const clnerf::v1::Version& v : response.versions()) {
    const bool deployed = v.deployed() || v.version() == response.deployed_version();
    if (!v.unavailable().empty()) {
      table.AddRow({deployed ? "*" : "", absl::StrCat(v.version()), "-", "-", "-", "-", "-", "-",
                    "UNAVAILABLE: " + v.unavailable()});
      continue;
    }
    table.AddRow({deployed ? "*" : "", absl::StrCat(v.version()), v.parent() > 0 ? absl::StrCat(v.parent()) : "-",
                  absl::StrCat(v.time_steps()), FormatBytes(v.size_bytes()),
                  v.model_bytes() > 0 ? absl::StrCat(FormatBytes(v.model_bytes()), " + ", FormatBytes(v.replay_bytes()))
                                      : "-",
                  FormatUnixMs(v.created_unix_ms()),
                  v.scan_id().empty() ? "-" : v.scan_id(), FormatMetrics(v.metrics())});
  }
  table.Print();
  std::printf("(* = deployed: version %lld)\n", (long long)response.deployed_version());
  return 0;
}

CLI::App* BindRollback(CLI::App* parent, RollbackArgs* a) {
  CLI::App* c = parent->add_subcommand("rollback", "Deploy an existing model version");
  c->add_option("version", a->version, "Version to deploy")->required();
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunRollback(const RollbackArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("rollback", client.status());
  clnerf::v1::SetDeployedVersionRequest request;
  request.set_version(a.version);
  request.set_place(a.remote.place);
  clnerf::v1::Version v;
  grpc::Status s =
      (*client)->service().SetDeployedVersion((*client)->Context(kUnaryTimeoutSeconds).get(), request, &v);
  if (!s.ok()) return FailRemote("rollback", s, a.remote);
  if (a.remote.json) {
    std::printf("%s\n", ProtoToJson(v).dump(2).c_str());
  } else {
    std::printf("deployed version %lld (parent %lld, %d time step(s), %s) | %s\n", (long long)v.version(),
                (long long)v.parent(), v.time_steps(), FormatBytes(v.size_bytes()).c_str(),
                FormatMetrics(v.metrics()).c_str());
  }
  return 0;
}

CLI::App* BindInfo(CLI::App* parent, ListArgs* a) {
  CLI::App* c = parent->add_subcommand("info", "Show the server's state and health");
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunInfo(const ListArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("info", client.status());
  clnerf::v1::ServerInfo info;
  clnerf::v1::GetServerInfoRequest info_request;
  info_request.set_place(a.remote.place);
  grpc::Status s =
      (*client)->service().GetServerInfo((*client)->Context(kUnaryTimeoutSeconds).get(), info_request, &info);
  if (!s.ok()) return FailRemote("info", s, a.remote);
  // The overall health ("" = the whole server).
  grpc::health::v1::HealthCheckResponse health;
  grpc::Status hs = (*client)->health().Check((*client)->Context(kUnaryTimeoutSeconds).get(),
                                              grpc::health::v1::HealthCheckRequest(), &health);
  const std::string health_text =
      hs.ok() ? grpc::health::v1::HealthCheckResponse::ServingStatus_Name(health.status())
              : absl::StrFormat("%s (%s)", StatusCodeName(hs.error_code()), hs.error_message());
  if (a.remote.json) {
    nlohmann::json j = ProtoToJson(info);
    j["server"] = a.remote.server;
    j["health"] = health_text;
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    std::printf("server     %s (%s)\n", a.remote.server.c_str(), info.server_version().c_str());
    std::printf("health     %s\n", health_text.c_str());
    std::printf("store      %s\n", info.store_error().empty() ? "writable"
                                                            : ("READ-ONLY: " + info.store_error()).c_str());
    std::printf("deployed   version %lld, %d time step(s), model %s\n", (long long)info.deployed_version(),
                info.time_steps(), FormatBytes(info.model_bytes()).c_str());
    std::printf("method     %s, %d iterations per update, %lld replay camera(s)\n", info.method().c_str(),
                info.iterations_per_update(), (long long)info.replay_cameras());
    std::printf("jobs       running %s, %d queued (max %d)\n",
                info.running_job().empty() ? "none" : info.running_job().c_str(), info.queued_jobs(),
                info.max_queue());
    std::printf("threads    render %d, train %d\n", info.render_threads(), info.train_threads());
    std::printf("auth       %s\n", info.auth_required() ? "required for uploads, cancels and rollbacks" : "off");
    std::printf("uptime     %s\n", FormatDuration(double(info.uptime_seconds())).c_str());
  }
  if (!hs.ok()) return FailRemote("info", hs, a.remote);
  if (health.status() != grpc::health::v1::HealthCheckResponse::SERVING) {
    return FailRemote("info", absl::UnavailableError("server health is " + health_text));
  }
  return 0;
}

}  // namespace clnerf
