// clnerf-server: hosts the deployed model, accepts scans, retrains in the
// background and serves renders. Flags (and an optional JSON config file) are
// parsed here and only here; every default is documented by --help and in
// server/server_options.h.
#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <cstdlib>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "CLI/CLI.hpp"
#include "nlohmann/json.hpp"
#include "server/grpc_server.h"
#include "server/common/log_setup.h"
#include "spdlog/spdlog.h"

namespace {

// "clnerf-server listening on port 50051" on stdout, or in JSON mode
// {"time": ..., "level": "info", "msg": "clnerf-server listening on port
// 50051", "port": 50051}.
void PrintPortLine(const char* text, const char* key, int port, bool json) {
  const std::string msg = absl::StrCat(text, " ", port);
  if (!json) {
    std::printf("%s\n", msg.c_str());
    return;
  }
  const nlohmann::json line = {{"time", absl::FormatTime("%Y-%m-%dT%H:%M:%E3S%z", absl::Now(), absl::LocalTimeZone())},
                               {"level", "info"},
                               {"msg", msg},
                               {key, port}};
  std::printf("%s\n", line.dump().c_str());
}

}  // namespace

int main(int argc, char** argv) {
  using namespace clnerf;
  ServerOptions o;
  std::string config, log_level = "info", log_format = "text";
  int iters = 0;
  CLI::App app{"clnerf-server: continual NeRF model-update service (gRPC)"};
  app.set_version_flag("--version", "clnerf-server 0.1.0");
  app.add_option("--listen", o.listen, "HOST:PORT to listen on (port 0 = any free port)")->capture_default_str();
  app.add_option("--http", o.http_listen,
                 "HOST:PORT for the web viewer and its JSON API (port 0 = any free port; default off)");
  app.add_option("--http-allowed-host", o.http_allowed_hosts,
                 "A name the HTTP front end answers to besides IP addresses and localhost (repeatable; '*' = any)");
  app.add_option("--http-head-timeout", o.http_head_timeout_seconds,
                 "Seconds a client has from connecting to the end of its request's headers (beyond: 408)")
      ->capture_default_str();
  app.add_option("--http-max-head-bytes", o.http_max_head_bytes,
                 "Largest request line + headers accepted (beyond: 431)")
      ->capture_default_str();
  app.add_option("--store", o.store_dir, "Store directory (scans, versions, manifest)")->capture_default_str();
  app.add_option("--token", o.token, "Bearer token required for mutating calls (default: $CLNERF_TOKEN; empty = no auth)");
  app.add_option("--config", config, "JSON config file (keys: docs/service.md > Operation, server/server_options.h); flags override it");
  app.add_option("--tls-cert", o.tls_cert, "PEM certificate chain (enables TLS with --tls-key)");
  app.add_option("--tls-key", o.tls_key, "PEM private key");
  app.add_option("--iters", iters, "Training iterations per update (default 300)");
  int first_iters = -1;
  app.add_option("--first-scan-iters", first_iters,
                 "Training iterations of a place's first scan (default 2000, what `clnerf train` gives a "
                 "capture; 0 = as --iters)");
  app.add_flag("!--no-bake", o.bake_on_publish,
               "Do not bake new versions for the browser when they are published (viewers then get server frames "
               "until a time step is baked on its first request)");
  app.add_option("--max-queue", o.max_queue, "Scans that may wait for training")->capture_default_str();
  app.add_option("--keep-versions", o.keep_versions, "Model versions kept on disk, oldest pruned first (0 = all)")
      ->capture_default_str();
  app.add_option("--render-concurrency", o.render_concurrency, "Renders running at once")->capture_default_str();
  app.add_option("--render-threads", o.render_threads, "Threads per render (0 = adaptive: cores / renders running)")->capture_default_str();
  app.add_option("--train-threads", o.train_threads, "Threads of the update worker")->capture_default_str();
  app.add_option("--max-concurrent-trainings", o.max_concurrent_trainings,
                 "Updates training at once across all places (oldest first, round robin)")
      ->capture_default_str();
  app.add_option("--model-memory-budget", o.model_memory_budget,
                 "Bytes of loaded models kept in memory across places, least recently used evicted first "
                 "(e.g. 512MB, 2GB; 0 = half the machine's memory)")
      ->transform(CLI::AsSizeValue(false))
      ->capture_default_str();
  app.add_option("--asset-memory-budget", o.asset_memory_budget,
                 "Bytes of baked-asset files kept in memory for viewers across places (e.g. 64MB; 0 = none)")
      ->transform(CLI::AsSizeValue(false))
      ->capture_default_str();
  app.add_option("--etcd", o.etcd,
                 "etcd's HOST:PORT: run as one of several replicas sharing --store (default: a single server)");
  app.add_option("--etcd-prefix", o.etcd_prefix, "Key prefix of this deployment in etcd")->capture_default_str();
  app.add_option("--lease-ttl", o.lease_ttl_seconds,
                 "Seconds after which a silent replica's places may be trained by another")
      ->capture_default_str();
  app.add_option("--replica-poll", o.replica_poll_seconds,
                 "Seconds between a replica's checks for scans and versions from the others")
      ->capture_default_str();
  app.add_option("--train-nice", o.train_nice, "Nice value of training (0-19): renders get the cores first")
      ->capture_default_str();
  app.add_option("--log-level", log_level, "trace|debug|info|warn|error")->capture_default_str();
  app.add_option("--log-format", log_format, "text|json (one JSON object per line)")->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  // Config file first, then explicit flags win: the flags are parsed again on
  // top of the file's values (CLI11 writes only the options that are given).
  if (!config.empty()) {
    o = ServerOptions();
    if (absl::Status s = ApplyConfigFile(config, &o); !s.ok()) {
      std::fprintf(stderr, "clnerf-server: %s\n", s.ToString().c_str());
      return 2;
    }
    CLI11_PARSE(app, argc, argv);
  }
  if (iters > 0) o.update.train.iterations = iters;
  if (first_iters >= 0) o.first_scan_iterations = first_iters;
  if (o.token.empty()) {
    if (const char* env = std::getenv("CLNERF_TOKEN")) o.token = env;
  }

  // Block SIGINT/SIGTERM in every thread (so before any is started, the
  // logger's included); the main thread waits for them.
  sigset_t sigs;
  sigemptyset(&sigs);
  sigaddset(&sigs, SIGINT);
  sigaddset(&sigs, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &sigs, nullptr);

  if (absl::Status s = SetUpServerLogging(log_level, log_format); !s.ok()) {
    std::fprintf(stderr, "clnerf-server: %s\n", std::string(s.message()).c_str());
    return 2;
  }

  absl::StatusOr<std::unique_ptr<GrpcServer>> server = GrpcServer::Start(o);
  if (!server.ok()) {
    // Through the logger: in JSON mode fd 2 is the capture pipe, whose reader
    // would not get to run before the exit.
    spdlog::critical("clnerf-server: {}", server.status().ToString());
    spdlog::shutdown();
    return 1;
  }
  // Machine-readable lines for scripts (the port matters with :0); in JSON
  // mode each is a JSON record too (log pipelines read stdout with stderr).
  PrintPortLine("clnerf-server listening on port", "port", (*server)->port(), log_format == "json");
  if ((*server)->http_port() > 0) {
    PrintPortLine("clnerf-server http on port", "http_port", (*server)->http_port(), log_format == "json");
  }
  std::fflush(stdout);
  int sig = 0;
  sigwait(&sigs, &sig);
  spdlog::info("received {}", sig == SIGINT ? "SIGINT" : "SIGTERM");
  if (!(*server)->Shutdown()) {
    // A stuck update (e.g. a pathological scan) must not keep the process
    // alive: the store is crash-safe, so exit as a kill would. The scan's
    // attempt stays recorded; after max_scan_attempts it is parked.
    spdlog::error("exiting without waiting for the update worker");
    spdlog::shutdown();
    std::_Exit(3);
  }
  (*server)->Wait();
  return 0;
}
