// HttpConnectionGuard: the HTTP port's front door. It accepts the public
// connections itself and reads each request's head (request line and
// headers) under two limits before anything else sees it:
//   * at most max_head_bytes (a line that never ends, or headers without
//     end, get 431 and the connection closes: no memory grows per client);
//   * the whole head within head_timeout_seconds of the connection opening
//     (a client trickling one byte every few seconds gets 408).
// Heads are read by one poll() loop, so slow clients hold no thread. A
// complete head is handed, with the bytes that followed it, to the HTTP
// library listening on a loopback port of its own, and the two connections
// are spliced by one thread per request until either side closes (the
// library serves one request per connection, so every request passes the
// door). After a reply the door closes lingering: it drains what the client
// still sends for up to 2 s, so a client refused while sending a body (413)
// reads its reply instead of a reset. Stop() closes the door and every
// connection still at it, which also frees a shutdown from clients that
// never finish their headers.
//
// cpp-httplib 0.11 (Debian's) applies its own 8 KiB limits only once a line
// ends, and reads heads in its worker threads with a per-read timeout, so
// without the door a header line without end grew without bound and eight
// trickling sockets took every worker.
//
// Thread-safety: Start and Stop from one controlling thread; the door runs
// its own threads.
#ifndef CLNERF_SERVER_FRONTENDS_HTTP_CONNECTION_GUARD_H_
#define CLNERF_SERVER_FRONTENDS_HTTP_CONNECTION_GUARD_H_

#include <atomic>
#include <condition_variable>
#include <functional>
#include <memory>
#include <optional>
#include <mutex>
#include <set>
#include <string>
#include <thread>

#include "absl/status/statusor.h"

namespace clnerf {

struct HttpGuardOptions {
  size_t max_head_bytes = 32 * 1024;   // Request line + headers.
  double head_timeout_seconds = 10;    // From accept to the end of the head.
  int max_waiting = 512;               // Connections still sending their head.
  int max_active = 128;                // Requests being served (spliced).
  // Requests the door answers itself, without a worker of the HTTP library
  // (health probes must answer while every worker waits for a render slot):
  // given the request line's method and target, a complete HTTP response,
  // or nothing to pass the request on. Must be fast and thread-safe.
  std::function<std::optional<std::string>(const std::string& method, const std::string& target)> answer;
  absl::Status Validate() const;
};

class HttpConnectionGuard {
 public:
  // Listens on host:port (port 0: any) and forwards complete heads to
  // 127.0.0.1:`backend_port`. UNAVAILABLE when it cannot listen.
  static absl::StatusOr<std::unique_ptr<HttpConnectionGuard>> Start(const std::string& host, int port,
                                                                    int backend_port, const HttpGuardOptions& o);
  ~HttpConnectionGuard();
  HttpConnectionGuard(const HttpConnectionGuard&) = delete;
  HttpConnectionGuard& operator=(const HttpConnectionGuard&) = delete;

  int port() const { return port_; }
  // Whether the client of the request that reached the backend from local
  // port `backend_port` (what the HTTP library reports as the request's
  // remote port) went away before its reply was complete. Lets a render
  // whose client left stop and free its slot.
  bool ClientGone(int backend_port) const;
  // Stops accepting, closes connections still sending their heads, and
  // closes the spliced ones (their requests end as if the client left).
  void Stop();

 private:
  HttpConnectionGuard(const HttpGuardOptions& o, int listen_fd, int port, int backend_port);
  void DoorLoop();
  // Answers a complete head itself when options_.answer does; false: pass on.
  bool AnswerAtTheDoor(int fd, const std::string& head);
  // A complete head (and what followed it) on `fd`: serve it on a thread.
  void Hand(int fd, std::string head);
  void Splice(int client, std::string pending);

  const HttpGuardOptions options_;
  const int listen_fd_;
  const int port_;
  const int backend_port_;
  int wake_[2] = {-1, -1};  // Self-pipe: Stop() wakes the door loop.
  std::atomic<bool> stopping_{false};
  std::thread door_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::set<int> spliced_;  // Client fds being spliced (shut down on Stop).
  int active_ = 0;
  std::set<int> gone_;  // Backend local ports whose client left early.
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_FRONTENDS_HTTP_CONNECTION_GUARD_H_
