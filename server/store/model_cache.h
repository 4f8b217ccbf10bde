// ModelCache: the loaded models of many places under one memory budget, as
// in KServe ModelMesh. Entries are keyed by a string (e.g. "place@version")
// and loaded on first use; when the bytes held exceed the budget, the least
// recently used entries are evicted, except any that a reader still holds
// (a render in flight keeps its shared_ptr, so its model is never evicted
// under it, and a model is only counted as freed once nobody uses it).
//
// Loads are single-flight: concurrent GetOrLoad calls for one key run the
// loader once and all get its result; a failed load is returned to every
// waiter and not cached, so the next call tries again. Loading runs outside
// the cache's lock, so a slow load of one place never blocks another's hits.
//
// Thread-safety: every method is thread-safe.
#ifndef CLNERF_SERVER_MODEL_CACHE_H_
#define CLNERF_SERVER_MODEL_CACHE_H_

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace clnerf {

struct ModelCacheStats {
  int64_t hits = 0;
  int64_t loads = 0;          // Successful loads.
  int64_t load_failures = 0;
  int64_t evictions = 0;
  int64_t bytes = 0;          // Bytes of the entries held now.
  int64_t entries = 0;
};

template <typename T>
class ModelCache {
 public:
  using Loader = std::function<absl::StatusOr<std::shared_ptr<const T>>()>;
  using SizeOf = std::function<int64_t(const T&)>;

  // budget_bytes <= 0: no limit. `on_evict` (optional) runs for each entry
  // evicted under the budget, with the cache's lock held: keep it trivial
  // (e.g. a counter).
  ModelCache(int64_t budget_bytes, SizeOf size_of, std::function<void()> on_evict = {})
      : budget_(budget_bytes), size_of_(std::move(size_of)), on_evict_(std::move(on_evict)) {}

  int64_t budget_bytes() const { return budget_; }

  // The cached value of `key`, or the loader's result (cached on success).
  absl::StatusOr<std::shared_ptr<const T>> GetOrLoad(const std::string& key, const Loader& loader) {
    std::unique_lock<std::mutex> lock(mu_);
    auto it = entries_.find(key);
    if (it != entries_.end()) {
      if (it->second.load == nullptr) {
        ++stats_.hits;
        Touch(it);
        return it->second.value;
      }
      const std::shared_ptr<Load> load = it->second.load;  // Another caller is loading it: share its result.
      cv_.wait(lock, [&] { return load->done; });
      if (load->value == nullptr) return load->Error();
      return load->value;
    }
    const auto load = std::make_shared<Load>();
    entries_[key].load = load;
    lock.unlock();
    absl::StatusOr<std::shared_ptr<const T>> loaded = loader();
    lock.lock();
    it = entries_.find(key);
    load->done = true;
    if (!loaded.ok() || *loaded == nullptr) {
      load->code = loaded.ok() ? absl::StatusCode::kInternal : loaded.status().code();
      load->message = loaded.ok() ? "loader returned nothing" : std::string(loaded.status().message());
      entries_.erase(it);
      ++stats_.load_failures;
      cv_.notify_all();
      return load->Error();
    }
    load->value = *loaded;
    Entry& e = it->second;
    e.load = nullptr;
    e.value = *loaded;
    e.bytes = size_of_(**loaded);
    stats_.bytes += e.bytes;
    ++stats_.loads;
    lru_.push_front(key);
    e.lru = lru_.begin();
    EvictLocked(key);
    cv_.notify_all();
    return *loaded;
  }

  // Inserts (or replaces) `key` with an already loaded value, e.g. a version
  // just trained in this process, evicting others to fit the budget.
  void Put(const std::string& key, std::shared_ptr<const T> value) { Insert(key, std::move(value), true); }
  // As Put, but only if it fits the budget without evicting anything (a
  // version verified at start-up: it stays loaded only while there is room,
  // otherwise it loads on first use). Returns whether it was kept.
  bool Offer(const std::string& key, std::shared_ptr<const T> value) { return Insert(key, std::move(value), false); }

  // The cached value, or null (no load).
  std::shared_ptr<const T> Peek(const std::string& key) const {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = entries_.find(key);
    return it == entries_.end() || it->second.load != nullptr ? nullptr : it->second.value;
  }

  // Drops `key` (a deleted place or version); readers keep their copies.
  void Erase(const std::string& key) {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = entries_.find(key);
    if (it == entries_.end() || it->second.load != nullptr) return;
    RemoveLocked(it);
  }

  // Drops every key starting with `prefix` (e.g. "place@").
  void ErasePrefix(const std::string& prefix) {
    std::lock_guard<std::mutex> lock(mu_);
    for (auto it = entries_.lower_bound(prefix); it != entries_.end() && it->first.compare(0, prefix.size(), prefix) == 0;) {
      auto next = std::next(it);
      if (it->second.load == nullptr) RemoveLocked(it);
      it = next;
    }
  }

  ModelCacheStats stats() const {
    std::lock_guard<std::mutex> lock(mu_);
    ModelCacheStats s = stats_;
    s.entries = int64_t(lru_.size());
    return s;
  }

  // Keys from most to least recently used.
  std::vector<std::string> Keys() const {
    std::lock_guard<std::mutex> lock(mu_);
    return std::vector<std::string>(lru_.begin(), lru_.end());
  }

 private:
  // One load in progress, shared with the callers waiting for it. A failure
  // is kept as code and message, and each caller gets its own absl::Status:
  // copies of one Status share a reference count that Debian's uninstrumented
  // libabsl releases out of ThreadSanitizer's sight.
  struct Load {
    bool done = false;
    absl::StatusCode code = absl::StatusCode::kOk;
    std::string message;
    std::shared_ptr<const T> value;
    absl::Status Error() const { return absl::Status(code, message); }
  };
  struct Entry {
    std::shared_ptr<const T> value;
    int64_t bytes = 0;
    std::shared_ptr<Load> load;  // Non-null while loading (then not in lru_).
    std::list<std::string>::iterator lru;
  };
  using Map = std::map<std::string, Entry>;

  bool Insert(const std::string& key, std::shared_ptr<const T> value, bool evict) {
    std::lock_guard<std::mutex> lock(mu_);
    const int64_t bytes = size_of_(*value);
    auto it = entries_.find(key);
    if (it != entries_.end() && it->second.load != nullptr) return false;  // Being loaded: the load wins.
    const int64_t freed = it != entries_.end() ? it->second.bytes : 0;
    if (!evict && budget_ > 0 && stats_.bytes - freed + bytes > budget_) return false;
    if (it != entries_.end()) RemoveLocked(it);
    Entry& e = entries_[key];
    e.value = std::move(value);
    e.bytes = bytes;
    stats_.bytes += bytes;
    lru_.push_front(key);
    e.lru = lru_.begin();
    if (evict) EvictLocked(key);
    return true;
  }

  void Touch(typename Map::iterator it) { lru_.splice(lru_.begin(), lru_, it->second.lru); }

  void RemoveLocked(typename Map::iterator it) {
    stats_.bytes -= it->second.bytes;
    lru_.erase(it->second.lru);
    entries_.erase(it);
  }

  // Evicts least recently used entries nobody else holds (use_count 1: only
  // this cache) until the bytes fit the budget; never `keep` (just loaded).
  void EvictLocked(const std::string& keep) {
    if (budget_ <= 0) return;
    for (auto lit = lru_.end(); stats_.bytes > budget_ && lit != lru_.begin();) {
      --lit;
      if (*lit == keep) continue;
      auto it = entries_.find(*lit);
      if (it->second.value.use_count() > 1) continue;  // In use by a reader.
      lit = std::next(lit);  // RemoveLocked invalidates the current node.
      RemoveLocked(it);
      ++stats_.evictions;
      if (on_evict_) on_evict_();
    }
  }

  const int64_t budget_;
  const SizeOf size_of_;
  const std::function<void()> on_evict_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  Map entries_;
  std::list<std::string> lru_;  // Most recently used first; loaded entries only.
  ModelCacheStats stats_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_MODEL_CACHE_H_
