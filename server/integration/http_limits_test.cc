// The HTTP port's limits on request heads (frontends/http_connection_guard.h),
// tested from outside with raw sockets against a real clnerf-server process
// on loopback: a header that never ends, slow clients, and shutdown with a
// client in the middle of its headers.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "gtest/gtest.h"
#include "server/testing/server_process_test_util.h"
#include "server/testing/store_test_util.h"

namespace clnerf {
namespace {

using testing_util::ServerProcess;
using testing_util::TempDir;

int RawConnect(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(uint16_t(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0) {
    close(fd);
    return -1;
  }
  return fd;
}

// What the server sent within `timeout_ms` (until it closed or went quiet).
std::string RawReadReply(int fd, int timeout_ms) {
  std::string out;
  char buf[4096];
  pollfd p{fd, POLLIN, 0};
  while (poll(&p, 1, timeout_ms) > 0) {
    const ssize_t n = recv(fd, buf, sizeof(buf), 0);
    if (n <= 0) break;
    out.append(buf, size_t(n));
  }
  return out;
}

// A whole GET on a fresh connection: the status line, or "" after `timeout_ms`.
std::string RawGet(int port, const std::string& path, int timeout_ms) {
  const int fd = RawConnect(port);
  if (fd < 0) return "";
  const std::string req = absl::StrFormat("GET %s HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", path);
  (void)send(fd, req.data(), req.size(), MSG_NOSIGNAL);
  const std::string reply = RawReadReply(fd, timeout_ms);
  close(fd);
  return reply.substr(0, reply.find("\r\n"));
}

class HttpLimitsTest : public ::testing::Test {
 protected:
  void StartServer(const std::string& name, const std::string& flags = "") {
    store_ = TempDir(name);
    server_ = std::make_unique<ServerProcess>(
        "", absl::StrFormat("--store %s --listen 127.0.0.1:0 --http 127.0.0.1:0 %s", store_, flags), store_ + ".log");
    ASSERT_GT(server_->http_port(), 0) << "the server did not start; see " << store_ << ".log";
  }
  std::string store_;
  std::unique_ptr<ServerProcess> server_;
};

// A header line that never ends was kept growing (200 x 1 MiB took the RSS
// from 151 to 356 MB); now the server answers 431 once the head passes its
// limit and closes, so the client cannot send more than that.
TEST_F(HttpLimitsTest, AHeaderThatNeverEndsIsRefusedEarly) {
  StartServer("http_long_header");
  const int fd = RawConnect(server_->http_port());
  ASSERT_GE(fd, 0);
  std::string chunk = "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Long: ";
  chunk.resize(64 * 1024, 'a');
  size_t sent = 0;
  std::string reply;
  while (sent < (8u << 20) && reply.empty()) {
    const ssize_t n = send(fd, chunk.data(), chunk.size(), MSG_NOSIGNAL);
    if (n <= 0) break;  // Closed by the server.
    sent += size_t(n);
    chunk.assign(chunk.size(), 'a');
    reply = RawReadReply(fd, 20);
  }
  if (reply.empty()) reply = RawReadReply(fd, 2000);
  close(fd);
  EXPECT_LT(sent, size_t(1) << 20) << "the server kept reading a header without end";
  EXPECT_EQ(reply.rfind("HTTP/1.1 431", 0), 0u) << reply.substr(0, 200);
  EXPECT_NE(reply.find("\"code\""), std::string::npos) << reply;
}

// Slow clients that trickle their headers held the HTTP library's worker
// threads: eight of them took the health probes down. Sixteen now leave the
// port answering.
TEST_F(HttpLimitsTest, ClientsThatNeverFinishTheirHeadersLeaveTheProbesAnswering) {
  StartServer("http_slow_headers");
  std::vector<int> slow;
  for (int i = 0; i < 16; ++i) {
    const int fd = RawConnect(server_->http_port());
    ASSERT_GE(fd, 0);
    const std::string part = "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ";
    ASSERT_GT(send(fd, part.data(), part.size(), MSG_NOSIGNAL), 0);
    slow.push_back(fd);
  }
  for (int probe = 0; probe < 5; ++probe) {
    const auto t0 = std::chrono::steady_clock::now();
    EXPECT_EQ(RawGet(server_->http_port(), "/healthz", 2000).rfind("HTTP/1.1 200", 0), 0u) << "probe " << probe;
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 2.0);
  }
  for (int fd : slow) close(fd);
}

// A head that does not arrive in time gets 408 and is closed (the door's
// deadline runs from connecting, so trickling bytes do not extend it).
TEST_F(HttpLimitsTest, AHeadThatTricklesInIsTimedOut) {
  StartServer("http_head_timeout", "--http-head-timeout 1");
  const int fd = RawConnect(server_->http_port());
  ASSERT_GE(fd, 0);
  const auto t0 = std::chrono::steady_clock::now();
  std::string reply;
  const std::string head = "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n";
  for (size_t i = 0; i < head.size() && reply.empty(); ++i) {
    if (send(fd, head.data() + i, 1, MSG_NOSIGNAL) <= 0) break;
    reply = RawReadReply(fd, 200);  // One byte every 0.2 s.
  }
  if (reply.empty()) reply = RawReadReply(fd, 3000);
  close(fd);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_EQ(reply.rfind("HTTP/1.1 408", 0), 0u) << reply.substr(0, 200);
  EXPECT_GT(seconds, 0.9);
  EXPECT_LT(seconds, 3.0);
}

// SIGTERM with a client in the middle of its headers never completed (the
// process was alive 60 s later); now it exits promptly and cleanly.
TEST_F(HttpLimitsTest, SigtermWithAClientMidHeadersExitsPromptly) {
  StartServer("http_sigterm_mid_header");
  const int fd = RawConnect(server_->http_port());
  ASSERT_GE(fd, 0);
  const std::string part = "GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: 1";
  ASSERT_GT(send(fd, part.data(), part.size(), MSG_NOSIGNAL), 0);
  ASSERT_EQ(RawGet(server_->http_port(), "/healthz", 2000).rfind("HTTP/1.1 200", 0), 0u);
  const auto t0 = std::chrono::steady_clock::now();
  server_->Signal(SIGTERM);
  const int status = server_->Wait();
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 5.0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status;
  close(fd);
}

}  // namespace
}  // namespace clnerf
