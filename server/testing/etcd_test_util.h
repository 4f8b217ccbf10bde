// LocalEtcd: a real etcd server (Debian's etcd-server) on loopback for tests,
// with its own data directory and free ports, and short raft timers so that
// one-second leases are allowed. Killed (SIGKILL) and reaped on destruction.
// `Find()` is empty when no etcd binary is installed: tests then skip, and
// CI installs it (scripts/install-deps.sh), so there they run.
//
// Not thread-safe; one per test.
#ifndef CLNERF_SERVER_ETCD_TEST_UTIL_H_
#define CLNERF_SERVER_ETCD_TEST_UTIL_H_

#include <netinet/in.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "server/cluster/etcd_client.h"

namespace clnerf::testing_util {

// A port that was free a moment ago (bound to 0, read, closed).
inline int FreeLoopbackPort() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  socklen_t len = sizeof(a);
  int port = 0;
  if (bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0 &&
      getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0) {
    port = ntohs(a.sin_port);
  }
  close(fd);
  return port;
}

class LocalEtcd {
 public:
  // The etcd binary ($CLNERF_ETCD, else etcd on the PATH or in /usr/bin), or "".
  static std::string Find() {
    if (const char* e = std::getenv("CLNERF_ETCD"); e != nullptr && *e != '\0') return e;
    for (const char* p : {"/usr/bin/etcd", "/usr/local/bin/etcd"}) {
      if (access(p, X_OK) == 0) return p;
    }
    return "";
  }

  // Starts etcd with its data in `dir`; waits until it answers. Returns "" on
  // success, else why it failed.
  std::string Start(const std::string& dir) {
    const std::string bin = Find();
    if (bin.empty()) return "no etcd binary";
    std::filesystem::create_directories(dir);
    client_port_ = FreeLoopbackPort();
    const int peer = FreeLoopbackPort();
    const std::string client_url = absl::StrCat("http://127.0.0.1:", client_port_);
    const std::string peer_url = absl::StrCat("http://127.0.0.1:", peer);
    std::vector<std::string> args = {bin,
                                     "--name", "test",
                                     "--data-dir", dir + "/data",
                                     "--listen-client-urls", client_url,
                                     "--advertise-client-urls", client_url,
                                     "--listen-peer-urls", peer_url,
                                     "--initial-advertise-peer-urls", peer_url,
                                     "--initial-cluster", "test=" + peer_url,
                                     "--heartbeat-interval", "50",
                                     "--election-timeout", "500",
                                     "--log-level", "error"};
    const std::string log = dir + "/etcd.log";
    pid_ = fork();
    if (pid_ == 0) {
      prctl(PR_SET_PDEATHSIG, SIGKILL);  // Never outlives the test, even one that aborts.
      FILE* f = std::freopen(log.c_str(), "w", stdout);
      (void)f;
      dup2(STDOUT_FILENO, STDERR_FILENO);
      std::vector<char*> argv;
      for (std::string& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      execv(bin.c_str(), argv.data());
      _exit(127);
    }
    if (pid_ < 0) return "fork failed";
    absl::StatusOr<std::unique_ptr<EtcdClient>> c = EtcdClient::Connect(endpoint(), 15, 5);
    if (!c.ok()) return absl::StrCat(c.status().ToString(), " (log: ", log, ")");
    return "";
  }

  std::string endpoint() const { return absl::StrCat("127.0.0.1:", client_port_); }

  ~LocalEtcd() {
    if (pid_ > 0) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
  }

 private:
  pid_t pid_ = -1;
  int client_port_ = 0;
};

}  // namespace clnerf::testing_util

#endif  // CLNERF_SERVER_ETCD_TEST_UTIL_H_
