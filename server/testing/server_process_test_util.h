// ServerProcess: the real clnerf-server binary (beside the test binary, in
// build/server/) as a child process, for tests of crashes, signals and
// several replicas on loopback. Started through the shell so `env` can
// prefix it (e.g. "CLNERF_CRASH_AT=x"); stderr goes to a log file; the gRPC
// (and, with --http, HTTP) port is read from stdout; pid() is the server's
// own (the shell execs `timeout`, whose child it is). Both die with the test
// (setpriv --pdeathsig), so a test that aborts leaks no server. Not
// thread-safe.
#ifndef CLNERF_SERVER_SERVER_PROCESS_TEST_UTIL_H_
#define CLNERF_SERVER_SERVER_PROCESS_TEST_UTIL_H_

#include <signal.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/strings/str_format.h"
#include "clnerf/v1/clnerf.grpc.pb.h"

namespace clnerf::testing_util {

inline std::string ServerBinary() {
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  return (self.parent_path().parent_path() / "server" / "clnerf-server").string();
}

class ServerProcess {
 public:
  // `args` must include --listen (and --http if http_port() is wanted);
  // `timeout_s` bounds the process's life (a hung test cannot leak it).
  ServerProcess(const std::string& env, const std::string& args, const std::string& log, int timeout_s = 120) {
    const std::string cmd =
        absl::StrFormat("echo $$; %s exec setpriv --pdeathsig KILL timeout %d setpriv --pdeathsig KILL %s %s 2>%s",
                        env, timeout_s, ServerBinary(), args, log);
    proc_ = popen(cmd.c_str(), "r");
    const bool want_http = args.find("--http") != std::string::npos;
    char line[256];
    while (proc_ != nullptr && (port_ == 0 || (want_http && http_port_ == 0)) &&
           std::fgets(line, sizeof(line), proc_) != nullptr) {
      if (pid_ == 0) {
        std::sscanf(line, "%d", &pid_);  // The shell's `echo $$`.
      } else {
        stdout_lines_.emplace_back(line);
      }
      // Plain, or inside a JSON record's "msg" (--log-format json).
      if (const char* p = std::strstr(line, "clnerf-server listening on port")) {
        std::sscanf(p, "clnerf-server listening on port %d", &port_);
      }
      if (const char* p = std::strstr(line, "clnerf-server http on port")) {
        std::sscanf(p, "clnerf-server http on port %d", &http_port_);
      }
    }
    // The server is `timeout`'s child: signals go to it directly.
    std::ifstream children(absl::StrFormat("/proc/%d/task/%d/children", pid_, pid_));
    if (!(children >> server_pid_)) server_pid_ = pid_;
  }
  ~ServerProcess() {
    if (proc_ != nullptr) {
      if (server_pid_ > 0) kill(server_pid_, SIGKILL);
      pclose(proc_);
    }
  }
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;

  // What the server printed on stdout before it was ready (its port lines).
  const std::vector<std::string>& stdout_lines() const { return stdout_lines_; }
  int port() const { return port_; }
  int http_port() const { return http_port_; }
  // The server's process id (not the `timeout` wrapper's).
  int pid() const { return server_pid_; }
  bool running() const { return proc_ != nullptr; }
  // Sends `sig` to the server.
  void Signal(int sig) const {
    if (server_pid_ > 0) kill(server_pid_, sig);
  }
  // Waits for the process to end; its wait status.
  int Wait() {
    const int status = pclose(proc_);
    proc_ = nullptr;
    return status;
  }
  std::unique_ptr<v1::ClnerfService::Stub> Stub() const {
    return v1::ClnerfService::NewStub(
        grpc::CreateChannel("127.0.0.1:" + std::to_string(port_), grpc::InsecureChannelCredentials()));
  }

 private:
  FILE* proc_ = nullptr;
  int pid_ = 0, server_pid_ = 0, port_ = 0, http_port_ = 0;
  std::vector<std::string> stdout_lines_;
};

}  // namespace clnerf::testing_util

#endif  // CLNERF_SERVER_SERVER_PROCESS_TEST_UTIL_H_

