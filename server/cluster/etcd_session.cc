#include "server/cluster/etcd_session.h"

#include <algorithm>

#include "spdlog/spdlog.h"

namespace clnerf {

EtcdSession::EtcdSession(EtcdClient* client, int64_t lease, int64_t ttl_seconds, std::string replica_id,
                         std::function<void()> on_expired)
    : client_(client),
      ttl_seconds_(ttl_seconds),
      replica_id_(std::move(replica_id)),
      on_expired_(std::move(on_expired)),
      lease_(lease),
      last_renewed_(Clock::now()) {
  renewer_ = std::thread([this] { RenewLoop(); });
}

EtcdSession::~EtcdSession() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  renewer_.join();
  if (absl::Status s = client_->RevokeLease(id()); !s.ok()) spdlog::warn("etcd: {}", s.ToString());
}

int64_t EtcdSession::id() const {
  std::lock_guard<std::mutex> lock(mu_);
  return lease_;
}

void EtcdSession::Lost(int64_t lease) {
  std::lock_guard<std::mutex> lock(mu_);
  if (lease != lease_) return;
  lost_ = true;
  cv_.notify_all();
}

void EtcdSession::SetPaused(bool paused) {
  std::lock_guard<std::mutex> lock(mu_);
  paused_ = paused;
  cv_.notify_all();
}

void EtcdSession::RenewLoop() {
  const auto period = std::chrono::milliseconds(std::max<int64_t>(100, ttl_seconds_ * 1000 / 3));
  std::unique_lock<std::mutex> lock(mu_);
  while (!stop_) {
    cv_.wait_for(lock, period, [&] { return stop_ || (lost_ && !paused_); });
    if (stop_) break;
    if (paused_) continue;
    const int64_t s = lease_;
    absl::StatusOr<int64_t> ttl = int64_t(0);
    if (!lost_) {
      lock.unlock();
      ttl = client_->KeepAliveOnce(s);
      lock.lock();
      if (s != lease_) continue;
    }
    if (ttl.ok() && *ttl > 0) {
      last_renewed_ = Clock::now();
      continue;
    }
    // etcd answered that the lease is gone, or it could not be renewed for a
    // whole TTL (then etcd has expired it too).
    const bool expired = ttl.ok() || Clock::now() - last_renewed_ > std::chrono::seconds(ttl_seconds_);
    if (!ttl.ok()) spdlog::warn("etcd: renewing the session: {}", ttl.status().ToString());
    if (expired) Replace(&lock);
  }
}

void EtcdSession::Replace(std::unique_lock<std::mutex>* lock) {
  lock->unlock();
  if (on_expired_) on_expired_();
  absl::StatusOr<int64_t> fresh = client_->GrantLease(ttl_seconds_);
  lock->lock();
  if (fresh.ok()) {
    lease_ = *fresh;
    lost_ = false;
    last_renewed_ = Clock::now();
    spdlog::info("etcd: replica {} opened a new session", replica_id_);
  }
}

}  // namespace clnerf
