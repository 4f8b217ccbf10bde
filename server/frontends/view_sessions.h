// ViewSessions: "the newest render of a view wins". A client (the web
// viewer: one id per canvas) tags each render request with a view id; when a
// request starts for a view, every older request of that view still waiting
// for a render slot or rendering becomes superseded, so its render stops and
// frees its slot for the camera the user is looking through now. Requests
// without a view id are never superseded.
//
// Memory is bounded: at most kMaxViews ids are tracked; beyond that, ids
// with no request in flight are forgotten (a forgotten id simply starts
// over).
//
// Thread-safety: all methods are thread-safe; a Ticket may be polled from any
// thread (superseded() is one atomic load).
#ifndef CLNERF_SERVER_VIEW_SESSIONS_H_
#define CLNERF_SERVER_VIEW_SESSIONS_H_

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>

namespace clnerf {

class ViewSessions {
 public:
  static constexpr size_t kMaxViews = 4096;

  class Ticket {
   public:
    Ticket() = default;
    // True once a newer request of the same view has started.
    bool superseded() const { return latest_ && latest_->load(std::memory_order_acquire) != seq_; }

   private:
    friend class ViewSessions;
    Ticket(std::shared_ptr<std::atomic<uint64_t>> latest, uint64_t seq) : latest_(std::move(latest)), seq_(seq) {}
    std::shared_ptr<std::atomic<uint64_t>> latest_;  // Null: not tied to a view.
    uint64_t seq_ = 0;
  };

  // Starts a request of `view_id` ("" = untracked), superseding older ones.
  Ticket Begin(const std::string& view_id);
  size_t tracked_views() const;

 private:
  mutable std::mutex mu_;
  uint64_t next_seq_ = 1;
  std::map<std::string, std::shared_ptr<std::atomic<uint64_t>>> views_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_VIEW_SESSIONS_H_
