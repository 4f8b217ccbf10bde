// The local Coordinator (one process) and the options' checks; the etcd one
// is etcd_coordinator.cc.
#include "server/cluster/coordinator.h"

#include <algorithm>
#include <map>
#include <mutex>

#include "absl/strings/str_cat.h"

namespace clnerf {
namespace {

// One process: it holds every lease; heads live in memory.
class LocalCoordinator final : public Coordinator {
 public:
  explicit LocalCoordinator(std::string id) : id_(std::move(id)) {}
  const std::string& replica_id() const override { return id_; }
  absl::StatusOr<bool> TryAcquire(const std::string&) override { return true; }
  bool Holds(const std::string&) const override { return true; }
  void Release(const std::string&) override {}
  absl::StatusOr<PlaceHead> ReadHead(const std::string& place) override {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = heads_.find(place);
    return it == heads_.end() ? PlaceHead{} : it->second;
  }
  absl::StatusOr<PlaceHead> CommitHead(const std::string& place, const PlaceHead& expected, int64_t version,
                                       const std::string& tag) override {
    std::lock_guard<std::mutex> lock(mu_);
    PlaceHead& h = heads_[place];
    if (h.generation != expected.generation) {
      return absl::AbortedError(absl::StrCat("place ", place, ": the head moved to version ", h.version,
                                             " since it was read"));
    }
    h.version = version;
    h.tag = tag;
    ++h.generation;
    return h;
  }
  absl::StatusOr<std::map<std::string, PlaceHead>> ReadHeads() override {
    std::lock_guard<std::mutex> lock(mu_);
    return heads_;
  }
  absl::StatusOr<PlaceHead> InitHead(const std::string& place, int64_t version) override {
    std::lock_guard<std::mutex> lock(mu_);
    PlaceHead& h = heads_[place];
    if (h.generation == 0) h = PlaceHead{version, 1, ""};
    return h;
  }
  absl::StatusOr<int64_t> NextId(const std::string& place, int64_t at_least) override {
    std::lock_guard<std::mutex> lock(mu_);
    int64_t& n = next_ids_[place];
    n = std::max(n, at_least);
    return n++;
  }
  bool replicated() const override { return false; }
  absl::Status Forget(const std::string& place) override {
    std::lock_guard<std::mutex> lock(mu_);
    heads_.erase(place);
    next_ids_.erase(place);
    return absl::OkStatus();
  }

 private:
  const std::string id_;
  mutable std::mutex mu_;
  std::map<std::string, PlaceHead> heads_;
  std::map<std::string, int64_t> next_ids_;
};

}  // namespace

absl::Status EtcdCoordinatorOptions::Validate() const {
  if (endpoint.empty()) return absl::InvalidArgumentError("etcd: the endpoint is empty (expected HOST:PORT)");
  if (prefix.empty() || prefix[0] != '/') return absl::InvalidArgumentError("etcd: the key prefix must start with '/'");
  if (lease_ttl_seconds < 1 || lease_ttl_seconds > 3600) {
    return absl::InvalidArgumentError("etcd: lease_ttl_seconds must be in [1, 3600]");
  }
  if (!(call_timeout_seconds > 0)) return absl::InvalidArgumentError("etcd: call_timeout_seconds must be > 0");
  return absl::OkStatus();
}

std::unique_ptr<Coordinator> MakeLocalCoordinator(const std::string& replica_id) {
  return std::make_unique<LocalCoordinator>(replica_id);
}

}  // namespace clnerf
