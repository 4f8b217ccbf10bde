// EtcdSession: one replica's session with etcd, an etcd lease that every key
// the replica owns (its places' owner keys) is attached to. A background
// thread renews it every ttl/3. When etcd says it expired (the replica was
// paused or cut off for longer than the TTL), or a caller reports it lost,
// every key attached to it is gone: `on_expired` runs (the coordinator
// forgets the places it held) and a new session replaces it.
//
// Thread-safety: every method is thread-safe. `on_expired` runs on the
// renewal thread with no lock of the session held.
#ifndef CLNERF_SERVER_CLUSTER_ETCD_SESSION_H_
#define CLNERF_SERVER_CLUSTER_ETCD_SESSION_H_

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "server/cluster/etcd_client.h"

namespace clnerf {

class EtcdSession {
 public:
  // `client` must outlive the session; `lease` is an etcd lease granted with
  // `ttl_seconds`; `replica_id` names this replica in logs.
  EtcdSession(EtcdClient* client, int64_t lease, int64_t ttl_seconds, std::string replica_id,
              std::function<void()> on_expired);
  // Stops renewing and revokes the lease, which frees this replica's keys at
  // once instead of after the TTL.
  ~EtcdSession();
  EtcdSession(const EtcdSession&) = delete;
  EtcdSession& operator=(const EtcdSession&) = delete;

  // The current lease id.
  int64_t id() const;
  // etcd said lease `lease` is gone (e.g. "requested lease not found"): if it
  // is still the current one, replace it now rather than at the next renewal.
  void Lost(int64_t lease);
  // For tests: stops (true) or resumes (false) renewals, as a SIGSTOP would.
  void SetPaused(bool paused);

 private:
  using Clock = std::chrono::steady_clock;
  void RenewLoop();
  // Under mu_ (released meanwhile): a new lease in place of the expired one.
  void Replace(std::unique_lock<std::mutex>* lock);

  EtcdClient* const client_;
  const int64_t ttl_seconds_;
  const std::string replica_id_;
  const std::function<void()> on_expired_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  int64_t lease_;
  Clock::time_point last_renewed_;
  bool stop_ = false;
  bool paused_ = false;
  bool lost_ = false;  // etcd said the lease is gone; the renewer replaces it.
  std::thread renewer_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_CLUSTER_ETCD_SESSION_H_
