#include "server/frontends/view_sessions.h"

namespace clnerf {

ViewSessions::Ticket ViewSessions::Begin(const std::string& view_id) {
  if (view_id.empty()) return Ticket();
  std::lock_guard<std::mutex> lock(mu_);
  auto it = views_.find(view_id);
  if (it == views_.end()) {
    if (views_.size() >= kMaxViews) {
      // Forget ids that no request holds any more.
      for (auto v = views_.begin(); v != views_.end();) v = v->second.use_count() == 1 ? views_.erase(v) : std::next(v);
    }
    it = views_.emplace(view_id, std::make_shared<std::atomic<uint64_t>>(0)).first;
  }
  const uint64_t seq = next_seq_++;
  it->second->store(seq, std::memory_order_release);
  return Ticket(it->second, seq);
}

size_t ViewSessions::tracked_views() const {
  std::lock_guard<std::mutex> lock(mu_);
  return views_.size();
}

}  // namespace clnerf
