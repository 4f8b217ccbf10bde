#include "server/frontends/http_connection_guard.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <map>
#include <vector>

#include "absl/strings/str_cat.h"
#include "spdlog/spdlog.h"

namespace clnerf {

absl::Status HttpGuardOptions::Validate() const {
  if (max_head_bytes < 1024) return absl::InvalidArgumentError("http max_head_bytes must be at least 1024");
  if (!(head_timeout_seconds > 0)) return absl::InvalidArgumentError("http head_timeout_seconds must be > 0");
  if (max_waiting < 1 || max_active < 1) return absl::InvalidArgumentError("http connection limits must be >= 1");
  return absl::OkStatus();
}

namespace {

using Clock = std::chrono::steady_clock;

void SetNonBlocking(int fd, bool on) {
  const int flags = fcntl(fd, F_GETFL, 0);
  fcntl(fd, F_SETFL, on ? (flags | O_NONBLOCK) : (flags & ~O_NONBLOCK));
}

// Best effort: a short JSON error ({error, code}, as the API's) and close
// (the client may be gone).
void Refuse(int fd, int status, const char* reason, const char* code, const std::string& message) {
  const std::string body = absl::StrCat("{\"error\":\"", message, "\",\"code\":\"", code, "\"}");
  const std::string reply = absl::StrCat("HTTP/1.1 ", status, " ", reason, "\r\nContent-Type: application/json\r\n",
                                         "Connection: close\r\nContent-Length: ", body.size(), "\r\n\r\n", body);
  (void)send(fd, reply.data(), reply.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
  close(fd);
}

int ListenOn(const std::string& host, int port, int* bound_port) {
  addrinfo hints{}, *res = nullptr;
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE;
  if (getaddrinfo(host.empty() ? nullptr : host.c_str(), std::to_string(port).c_str(), &hints, &res) != 0) return -1;
  int fd = -1;
  for (addrinfo* a = res; a != nullptr && fd < 0; a = a->ai_next) {
    fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    const int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    if (bind(fd, a->ai_addr, a->ai_addrlen) != 0 || listen(fd, 128) != 0) {
      close(fd);
      fd = -1;
    }
  }
  freeaddrinfo(res);
  if (fd < 0) return -1;
  sockaddr_storage ss{};
  socklen_t len = sizeof(ss);
  getsockname(fd, reinterpret_cast<sockaddr*>(&ss), &len);
  *bound_port = ss.ss_family == AF_INET6 ? ntohs(reinterpret_cast<sockaddr_in6*>(&ss)->sin6_port)
                                         : ntohs(reinterpret_cast<sockaddr_in*>(&ss)->sin_port);
  return fd;
}

int ConnectLoopback(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(uint16_t(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0) {
    close(fd);
    return -1;
  }
  const int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  return fd;
}

// The local port of a connected IPv4 socket; -1 on error.
int LocalPort(int fd) {
  sockaddr_in a{};
  socklen_t len = sizeof(a);
  return getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0 ? ntohs(a.sin_port) : -1;
}

bool SendAll(int fd, const char* p, size_t n) {
  while (n > 0) {
    const ssize_t k = send(fd, p, n, MSG_NOSIGNAL);
    if (k <= 0) return false;
    p += k;
    n -= size_t(k);
  }
  return true;
}

// A connection still sending its head.
struct Waiting {
  std::string bytes;
  Clock::time_point deadline;
};

// Forwards bytes both ways until the backend's reply is complete (it closes:
// one request per connection) or the client leaves; true when the client
// left first. The reply is read before the request: a backend that answered
// from the headers alone (413 for a body over the cap) and stopped reading
// no longer takes the rest of the body, which is then dropped, so its reply
// still reaches the client.
bool Pump(int client, int backend) {
  pollfd fds[2] = {{client, POLLIN, 0}, {backend, POLLIN, 0}};
  char buf[65536];
  bool backend_reads = true;
  while (poll(fds, 2, -1) > 0) {
    if (fds[1].revents & (POLLIN | POLLHUP | POLLERR)) {
      const ssize_t n = recv(backend, buf, sizeof(buf), 0);
      if (n <= 0) return false;
      if (!SendAll(client, buf, size_t(n))) return true;
    }
    if (fds[0].revents & (POLLIN | POLLHUP | POLLERR)) {
      const ssize_t n = recv(client, buf, sizeof(buf), 0);
      if (n <= 0) return true;
      if (backend_reads) backend_reads = SendAll(backend, buf, size_t(n));
    }
  }
  return true;
}

// A lingering close (as Apache's lingering_close): the reply is sent, so
// send nothing more, then read and drop what the client still sends for up
// to 2 s or until it closes. Closing a socket with unread bytes resets the
// connection, and a client still sending a body it was refused would lose
// the reply (or see its write fail) before reading it.
void LingerBeforeClosing(int fd) {
  shutdown(fd, SHUT_WR);
  const Clock::time_point end = Clock::now() + std::chrono::seconds(2);
  char buf[65536];
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - Clock::now()).count();
    pollfd p{fd, POLLIN, 0};
    if (left <= 0 || poll(&p, 1, int(left)) <= 0 || recv(fd, buf, sizeof(buf), 0) <= 0) return;
  }
}

}  // namespace

absl::StatusOr<std::unique_ptr<HttpConnectionGuard>> HttpConnectionGuard::Start(const std::string& host, int port,
                                                                                int backend_port,
                                                                                const HttpGuardOptions& o) {
  if (absl::Status s = o.Validate(); !s.ok()) return s;
  int bound = 0;
  const int fd = ListenOn(host, port, &bound);
  if (fd < 0) return absl::UnavailableError(absl::StrCat("cannot listen on ", host, ":", port));
  std::unique_ptr<HttpConnectionGuard> g(new HttpConnectionGuard(o, fd, bound, backend_port));
  if (pipe2(g->wake_, O_CLOEXEC | O_NONBLOCK) != 0) return absl::InternalError("cannot create a pipe");
  SetNonBlocking(fd, true);
  g->door_ = std::thread([p = g.get()] { p->DoorLoop(); });
  return g;
}

HttpConnectionGuard::HttpConnectionGuard(const HttpGuardOptions& o, int listen_fd, int port, int backend_port)
    : options_(o), listen_fd_(listen_fd), port_(port), backend_port_(backend_port) {}

HttpConnectionGuard::~HttpConnectionGuard() {
  Stop();
  close(listen_fd_);
  for (int fd : wake_) {
    if (fd >= 0) close(fd);
  }
}

void HttpConnectionGuard::Stop() {
  if (stopping_.exchange(true)) return;
  (void)!write(wake_[1], "x", 1);
  if (door_.joinable()) door_.join();
  std::unique_lock<std::mutex> lock(mu_);
  for (int fd : spliced_) shutdown(fd, SHUT_RDWR);
  cv_.wait(lock, [&] { return active_ == 0; });
}

void HttpConnectionGuard::DoorLoop() {
  std::map<int, Waiting> waiting;
  const auto timeout = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(options_.head_timeout_seconds));
  std::vector<pollfd> fds;
  char buf[16384];
  while (!stopping_) {
    fds.assign({{listen_fd_, POLLIN, 0}, {wake_[0], POLLIN, 0}});
    for (const auto& [fd, w] : waiting) fds.push_back({fd, POLLIN, 0});
    poll(fds.data(), nfds_t(fds.size()), 100);
    const Clock::time_point now = Clock::now();
    if (fds[0].revents & POLLIN) {
      for (int c; (c = accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK)) >= 0;) {
        if (int(waiting.size()) >= options_.max_waiting) {
          Refuse(c, 503, "Service Unavailable", "UNAVAILABLE",
                 "too many connections are still sending their requests");
          continue;
        }
        waiting[c] = Waiting{std::string(), now + timeout};
      }
    }
    for (size_t i = 2; i < fds.size(); ++i) {
      const int fd = fds[i].fd;
      Waiting& w = waiting[fd];
      bool done = false, gone = false;
      if (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) {
        const ssize_t n = recv(fd, buf, sizeof(buf), 0);
        if (n <= 0 && !(n < 0 && (errno == EAGAIN || errno == EINTR))) gone = true;
        if (n > 0) {
          const size_t from = w.bytes.size() >= 3 ? w.bytes.size() - 3 : 0;
          w.bytes.append(buf, size_t(n));
          done = w.bytes.find("\r\n\r\n", from) != std::string::npos;
        }
      }
      if (gone) {
        close(fd);
      } else if (done && w.bytes.find("\r\n\r\n") + 4 <= options_.max_head_bytes) {
        if (!AnswerAtTheDoor(fd, w.bytes)) Hand(fd, std::move(w.bytes));
      } else if (w.bytes.size() > options_.max_head_bytes) {
        Refuse(fd, 431, "Request Header Fields Too Large", "RESOURCE_EXHAUSTED",
               absl::StrCat("the request line and headers exceed ", options_.max_head_bytes, " bytes"));
      } else if (now > w.deadline) {
        Refuse(fd, 408, "Request Timeout", "DEADLINE_EXCEEDED", "the request's headers did not arrive in time");
      } else {
        continue;
      }
      waiting.erase(fd);
    }
  }
  for (const auto& [fd, w] : waiting) close(fd);
}

bool HttpConnectionGuard::AnswerAtTheDoor(int fd, const std::string& head) {
  if (!options_.answer) return false;
  const size_t sp1 = head.find(' ');
  const size_t sp2 = sp1 == std::string::npos ? sp1 : head.find(' ', sp1 + 1);
  const size_t eol = head.find("\r\n");
  if (sp2 == std::string::npos || sp2 > eol) return false;
  std::optional<std::string> reply = options_.answer(head.substr(0, sp1), head.substr(sp1 + 1, sp2 - sp1 - 1));
  if (!reply) return false;
  SetNonBlocking(fd, false);
  timeval tv{1, 0};  // A probe's reply is small; never let a stuck reader hold the door.
  setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof(tv));
  (void)SendAll(fd, reply->data(), reply->size());
  close(fd);
  return true;
}

void HttpConnectionGuard::Hand(int fd, std::string head) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (active_ >= options_.max_active) {
      Refuse(fd, 503, "Service Unavailable", "UNAVAILABLE", "too many requests in progress");
      return;
    }
    ++active_;
    spliced_.insert(fd);
  }
  std::thread([this, fd, head = std::move(head)]() mutable { Splice(fd, std::move(head)); }).detach();
}

bool HttpConnectionGuard::ClientGone(int backend_port) const {
  std::lock_guard<std::mutex> lock(mu_);
  return gone_.count(backend_port) > 0;
}

void HttpConnectionGuard::Splice(int client, std::string pending) {
  SetNonBlocking(client, false);
  const int backend = ConnectLoopback(backend_port_);
  const int local = backend >= 0 ? LocalPort(backend) : -1;
  bool client_left = false;
  if (backend >= 0) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      gone_.erase(local);  // A new request on a reused port.
    }
    client_left = SendAll(backend, pending.data(), pending.size()) && Pump(client, backend);
  }
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (client_left && local > 0) {
      if (gone_.size() > 4096) gone_.clear();  // Bounded; a forgotten entry only lets a render finish.
      gone_.insert(local);
    }
  }
  if (backend >= 0) close(backend);
  if (!client_left) LingerBeforeClosing(client);
  std::lock_guard<std::mutex> lock(mu_);
  spliced_.erase(client);
  close(client);
  --active_;
  cv_.notify_all();
}

}  // namespace clnerf
