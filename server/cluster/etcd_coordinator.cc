// EtcdCoordinator: the Coordinator over etcd's v3 API (coordinator.h has the
// protocol and the keys). The session and its renewal live in
// etcd_session.h; this file maps leases, heads and ids onto etcd
// transactions.
#include <unistd.h>

#include <algorithm>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/cluster/coordinator.h"
#include "server/cluster/etcd_client.h"
#include "server/cluster/etcd_session.h"
#include "server/common/metrics.h"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

std::string DefaultReplicaId() {
  char host[256] = {0};
  if (gethostname(host, sizeof(host) - 1) != 0) host[0] = '\0';
  return absl::StrCat(host[0] != '\0' ? host : "replica", ":", getpid());
}

class EtcdCoordinator final : public Coordinator {
 public:
  EtcdCoordinator(const EtcdCoordinatorOptions& o, std::unique_ptr<EtcdClient> client, int64_t lease)
      : options_(o),
        id_(o.replica_id.empty() ? DefaultReplicaId() : o.replica_id),
        client_(std::move(client)),
        session_(std::make_unique<EtcdSession>(client_.get(), lease, o.lease_ttl_seconds, id_,
                                               [this] { ForgetHeldPlaces(); })) {}

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
      session_->Lost(s);
      return false;
    }
    if (!r.ok()) return r.status();
    bool held = r->succeeded();
    if (!held && r->responses_size() > 0 && r->responses(0).response_range().kvs_size() > 0) {
      held = r->responses(0).response_range().kvs(0).lease() == s;
    }
    std::lock_guard<std::mutex> lock(mu_);
    if (held && s == session_->id()) {
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

  void SetPaused(bool paused) { session_->SetPaused(paused); }

 private:
  std::string OwnerKey(const std::string& place) const {
    return absl::StrCat(options_.prefix, "/places/", place, "/owner");
  }
  std::string HeadKey(const std::string& place) const {
    return absl::StrCat(options_.prefix, "/places/", place, "/head");
  }
  int64_t session() const { return session_->id(); }

  // The session expired: every owner key attached to it is gone.
  void ForgetHeldPlaces() {
    std::lock_guard<std::mutex> lock(mu_);
    if (!held_.empty()) {
      spdlog::warn("etcd: replica {}'s session expired; it no longer trains {} place(s)", id_, held_.size());
      if (options_.metrics != nullptr) options_.metrics->LeaseChanged();
    }
    held_.clear();
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

  const EtcdCoordinatorOptions options_;
  const std::string id_;
  const std::unique_ptr<EtcdClient> client_;
  mutable std::mutex mu_;
  std::set<std::string> held_;  // Places whose lease this replica took.
  // Last: destroyed first, revoking the lease while client_ still exists.
  const std::unique_ptr<EtcdSession> session_;
};

}  // namespace

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
