#include "server/coordinator.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/etcd_client.h"
#include "server/metrics.h"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

using Clock = std::chrono::steady_clock;

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

std::string DefaultReplicaId() {
  char host[256] = {0};
  if (gethostname(host, sizeof(host) - 1) != 0) host[0] = '\0';
  return absl::StrCat(host[0] != '\0' ? host : "replica", ":", getpid());
}

class EtcdCoordinator final : public Coordinator {
 public:
  EtcdCoordinator(const EtcdCoordinatorOptions& o, std::unique_ptr<EtcdClient> client, int64_t session)
      : options_(o),
        id_(o.replica_id.empty() ? DefaultReplicaId() : o.replica_id),
        client_(std::move(client)),
        session_(session),
        last_renewed_(Clock::now()) {
    renewer_ = std::thread([this] { RenewLoop(); });
  }

  ~EtcdCoordinator() override {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    renewer_.join();
    // Revoking frees this replica's places at once instead of after the TTL.
    if (absl::Status s = client_->RevokeLease(session()); !s.ok()) spdlog::warn("etcd: {}", s.ToString());
  }

  const std::string& replica_id() const override { return id_; }

  absl::StatusOr<bool> TryAcquire(const std::string& place) override {
    const int64_t s = session();
    const std::string owner = OwnerKey(place);
    etcdserverpb::TxnRequest txn;
    *txn.add_compare() = EtcdClient::KeyAbsent(owner);
    *txn.add_success() = EtcdClient::PutOp(owner, id_, s);
    txn.add_failure()->mutable_request_range()->set_key(owner);
    absl::StatusOr<etcdserverpb::TxnResponse> r = client_->Txn(txn);
    if (!r.ok() && absl::IsNotFound(r.status())) {  // "requested lease not found": the session expired.
      SessionLost(s);
      return false;
    }
    if (!r.ok()) return r.status();
    bool held = r->succeeded();
    if (!held && r->responses_size() > 0 && r->responses(0).response_range().kvs_size() > 0) {
      held = r->responses(0).response_range().kvs(0).lease() == s;
    }
    std::lock_guard<std::mutex> lock(mu_);
    if (held && s == session_) {
      if (held_.insert(place).second) {
        spdlog::info("etcd: replica {} took the training lease of place {}", id_, place);
        if (options_.metrics != nullptr) options_.metrics->LeaseChanged();
      }
      return true;
    }
    held_.erase(place);
    return false;
  }

  bool Holds(const std::string& place) const override {
    std::lock_guard<std::mutex> lock(mu_);
    return held_.count(place) > 0;
  }

  void Release(const std::string& place) override {
    const int64_t s = session();
    etcdserverpb::TxnRequest txn;
    *txn.add_compare() = EtcdClient::LeaseIs(OwnerKey(place), s);
    *txn.add_success() = EtcdClient::DeleteOp(OwnerKey(place));
    if (absl::StatusOr<etcdserverpb::TxnResponse> r = client_->Txn(txn); !r.ok()) {
      spdlog::warn("etcd: releasing place {}: {}", place, r.status().ToString());
    }
    std::lock_guard<std::mutex> lock(mu_);
    if (held_.erase(place) > 0 && options_.metrics != nullptr) options_.metrics->LeaseChanged();
  }

  absl::StatusOr<PlaceHead> ReadHead(const std::string& place) override {
    absl::StatusOr<std::optional<EtcdKeyValue>> kv = client_->Get(HeadKey(place));
    if (!kv.ok()) return kv.status();
    if (!kv->has_value()) return PlaceHead{};
    return ParseHead(place, **kv);
  }

  absl::StatusOr<std::map<std::string, PlaceHead>> ReadHeads() override {
    const std::string prefix = absl::StrCat(options_.prefix, "/places/");
    absl::StatusOr<std::vector<EtcdKeyValue>> kvs = client_->GetPrefix(prefix);
    if (!kvs.ok()) return kvs.status();
    std::map<std::string, PlaceHead> heads;
    for (const EtcdKeyValue& kv : *kvs) {
      const std::string rest = kv.key.substr(prefix.size());
      const size_t slash = rest.find('/');
      if (slash == std::string::npos || rest.substr(slash + 1) != "head") continue;
      absl::StatusOr<PlaceHead> h = ParseHead(rest.substr(0, slash), kv);
      if (h.ok()) heads[rest.substr(0, slash)] = *h;
    }
    return heads;
  }

  absl::StatusOr<PlaceHead> CommitHead(const std::string& place, const PlaceHead& expected, int64_t version,
                                       const std::string& tag) override {
    const int64_t s = session();
    etcdserverpb::TxnRequest txn;
    *txn.add_compare() = EtcdClient::LeaseIs(OwnerKey(place), s);
    *txn.add_compare() = EtcdClient::ModRevisionIs(HeadKey(place), expected.generation);
    *txn.add_success() = EtcdClient::PutOp(HeadKey(place), HeadValue(version, tag));
    txn.add_failure()->mutable_request_range()->set_key(OwnerKey(place));
    txn.add_failure()->mutable_request_range()->set_key(HeadKey(place));
    absl::StatusOr<etcdserverpb::TxnResponse> r = client_->Txn(txn);
    if (!r.ok()) return r.status();
    if (r->succeeded()) return PlaceHead{version, r->header().revision(), tag};
    // Refused: say why.
    std::string why;
    const auto& owner = r->responses(0).response_range();
    if (owner.kvs_size() == 0 || owner.kvs(0).lease() != s) {
      why = owner.kvs_size() == 0 ? "its training lease expired"
                                  : absl::StrCat("its training lease expired and replica ", owner.kvs(0).value(),
                                                 " holds it now");
      std::lock_guard<std::mutex> lock(mu_);
      held_.erase(place);
    } else {
      const auto& head = r->responses(1).response_range();
      why = absl::StrCat("the head moved to ",
                         head.kvs_size() > 0 ? absl::StrCat("version ", head.kvs(0).value().substr(0, head.kvs(0).value().find(' '))) : "nothing",
                         " since generation ", expected.generation, " was read");
    }
    if (options_.metrics != nullptr) options_.metrics->FencedCommit();
    spdlog::warn("etcd: fenced: replica {} may not publish version {} of place {}: {}", id_, version, place, why);
    return absl::AbortedError(absl::StrCat("fenced: replica ", id_, " may not publish version ", version,
                                           " of place ", place, ": ", why));
  }

  absl::StatusOr<PlaceHead> InitHead(const std::string& place, int64_t version) override {
    etcdserverpb::TxnRequest txn;
    *txn.add_compare() = EtcdClient::KeyAbsent(HeadKey(place));
    *txn.add_success() = EtcdClient::PutOp(HeadKey(place), HeadValue(version, ""));
    txn.add_failure()->mutable_request_range()->set_key(HeadKey(place));
    absl::StatusOr<etcdserverpb::TxnResponse> r = client_->Txn(txn);
    if (!r.ok()) return r.status();
    if (r->succeeded()) return PlaceHead{version, r->header().revision(), ""};
    const auto& range = r->responses(0).response_range();
    if (range.kvs_size() == 0) return absl::AbortedError("etcd: the head vanished during InitHead; retry");
    const etcdserverpb::KeyValue& kv = range.kvs(0);
    return ParseHead(place, EtcdKeyValue{kv.key(), kv.value(), kv.create_revision(), kv.mod_revision(), kv.version(),
                                         kv.lease()});
  }

  absl::StatusOr<int64_t> NextId(const std::string& place, int64_t at_least) override {
    const std::string key = absl::StrCat(options_.prefix, "/places/", place, "/next_id");
    for (int attempt = 0; attempt < 100; ++attempt) {  // Compare-and-set; retried on a race with another replica.
      absl::StatusOr<std::optional<EtcdKeyValue>> kv = client_->Get(key);
      if (!kv.ok()) return kv.status();
      int64_t n = at_least;
      if (kv->has_value() && !absl::SimpleAtoi((*kv)->value, &n)) {
        return absl::DataLossError(absl::StrCat("etcd: ", key, " is not a number"));
      }
      n = std::max(n, at_least);
      etcdserverpb::TxnRequest txn;
      *txn.add_compare() =
          kv->has_value() ? EtcdClient::ModRevisionIs(key, (*kv)->mod_revision) : EtcdClient::KeyAbsent(key);
      *txn.add_success() = EtcdClient::PutOp(key, absl::StrCat(n + 1));
      absl::StatusOr<etcdserverpb::TxnResponse> r = client_->Txn(txn);
      if (!r.ok()) return r.status();
      if (r->succeeded()) return n;
    }
    return absl::AbortedError(absl::StrCat("etcd: could not reserve an id for place ", place, " (contention)"));
  }

  bool replicated() const override { return true; }

  absl::Status Forget(const std::string& place) override {
    (void)client_->Delete(absl::StrCat(options_.prefix, "/places/", place, "/next_id"));
    if (absl::Status s = client_->Delete(HeadKey(place)); !s.ok()) return s;
    if (absl::Status s = client_->Delete(OwnerKey(place)); !s.ok()) return s;
    std::lock_guard<std::mutex> lock(mu_);
    held_.erase(place);
    return absl::OkStatus();
  }

  // etcd says session `s` is gone: forget its places and have the renewer
  // open a new session now.
  void SessionLost(int64_t s) {
    std::lock_guard<std::mutex> lock(mu_);
    if (s != session_) return;
    lost_ = true;
    cv_.notify_all();
  }

  void SetPaused(bool paused) {
    std::lock_guard<std::mutex> lock(mu_);
    paused_ = paused;
    cv_.notify_all();
  }

 private:
  std::string OwnerKey(const std::string& place) const {
    return absl::StrCat(options_.prefix, "/places/", place, "/owner");
  }
  std::string HeadKey(const std::string& place) const {
    return absl::StrCat(options_.prefix, "/places/", place, "/head");
  }
  int64_t session() const {
    std::lock_guard<std::mutex> lock(mu_);
    return session_;
  }

  // The head's value: "VERSION" or "VERSION TAG".
  static std::string HeadValue(int64_t version, const std::string& tag) {
    return tag.empty() ? absl::StrCat(version) : absl::StrCat(version, " ", tag);
  }
  static absl::StatusOr<PlaceHead> ParseHead(const std::string& place, const EtcdKeyValue& kv) {
    const size_t space = kv.value.find(' ');
    int64_t v = 0;
    if (!absl::SimpleAtoi(kv.value.substr(0, space), &v) || v < 0) {
      return absl::DataLossError(absl::StrCat("etcd: the head of place ", place, " is not a version: '",
                                              kv.value.substr(0, 32), "'"));
    }
    return PlaceHead{v, kv.mod_revision, space == std::string::npos ? "" : kv.value.substr(space + 1)};
  }

  // Renews the session every ttl/3. If etcd says it expired (this replica was
  // paused or cut off longer than the TTL), every place it held is lost:
  // forget them and open a new session.
  void RenewLoop() {
    const auto period = std::chrono::milliseconds(std::max<int64_t>(100, options_.lease_ttl_seconds * 1000 / 3));
    std::unique_lock<std::mutex> lock(mu_);
    while (!stop_) {
      cv_.wait_for(lock, period, [&] { return stop_ || (lost_ && !paused_); });
      if (stop_) break;
      if (paused_) continue;
      const int64_t s = session_;
      absl::StatusOr<int64_t> ttl = int64_t(0);
      if (!lost_) {
        lock.unlock();
        ttl = client_->KeepAliveOnce(s);
        lock.lock();
        if (s != session_) continue;
      }
      if (ttl.ok() && *ttl > 0) {
        last_renewed_ = Clock::now();
        continue;
      }
      const bool expired = ttl.ok() || Clock::now() - last_renewed_ > std::chrono::seconds(options_.lease_ttl_seconds);
      if (!ttl.ok()) spdlog::warn("etcd: renewing the session: {}", ttl.status().ToString());
      if (!expired) continue;
      if (!held_.empty()) {
        spdlog::warn("etcd: replica {}'s session expired; it no longer trains {} place(s)", id_, held_.size());
        if (options_.metrics != nullptr) options_.metrics->LeaseChanged();
      }
      held_.clear();
      lock.unlock();
      absl::StatusOr<int64_t> fresh = client_->GrantLease(options_.lease_ttl_seconds);
      lock.lock();
      if (fresh.ok()) {
        session_ = *fresh;
        lost_ = false;
        last_renewed_ = Clock::now();
        spdlog::info("etcd: replica {} opened a new session", id_);
      }
    }
  }

  const EtcdCoordinatorOptions options_;
  const std::string id_;
  const std::unique_ptr<EtcdClient> client_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  int64_t session_;
  Clock::time_point last_renewed_;
  std::set<std::string> held_;
  bool stop_ = false;
  bool paused_ = false;
  bool lost_ = false;  // etcd said the session is gone; the renewer replaces it.
  std::thread renewer_;
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

absl::StatusOr<std::unique_ptr<Coordinator>> MakeEtcdCoordinator(const EtcdCoordinatorOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  absl::StatusOr<std::unique_ptr<EtcdClient>> client =
      EtcdClient::Connect(options.endpoint, options.call_timeout_seconds, options.call_timeout_seconds);
  if (!client.ok()) return client.status();
  absl::StatusOr<int64_t> session = (*client)->GrantLease(options.lease_ttl_seconds);
  if (!session.ok()) return session.status();
  return std::unique_ptr<Coordinator>(new EtcdCoordinator(options, *std::move(client), *session));
}

void PauseRenewalsForTesting(Coordinator* coordinator, bool paused) {
  if (auto* e = dynamic_cast<EtcdCoordinator*>(coordinator)) e->SetPaused(paused);
}

}  // namespace clnerf
