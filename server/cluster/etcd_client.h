// EtcdClient: a small client of etcd's v3 gRPC API (proto/etcd/), for the
// coordination of replicas that share one store (coordinator.h): keys,
// compare-and-set transactions and leases. Every call has a deadline
// (`call_timeout_seconds`); an unreachable etcd is UNAVAILABLE or
// DEADLINE_EXCEEDED, never a hang.
//
// Thread-safety: every method is thread-safe (gRPC stubs are; KeepAliveOnce
// serialises on one stream).
#ifndef CLNERF_SERVER_ETCD_CLIENT_H_
#define CLNERF_SERVER_ETCD_CLIENT_H_

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "etcd/etcd_kv_lease.grpc.pb.h"

namespace grpc {
class Channel;
class ClientContext;
}  // namespace grpc

namespace clnerf {

struct EtcdKeyValue {
  std::string key, value;
  int64_t create_revision = 0, mod_revision = 0, version = 0, lease = 0;
};

class EtcdClient {
 public:
  // `endpoint`: HOST:PORT of etcd's client URL. Fails (UNAVAILABLE) if etcd
  // does not answer within `connect_timeout_seconds`.
  static absl::StatusOr<std::unique_ptr<EtcdClient>> Connect(const std::string& endpoint,
                                                             double connect_timeout_seconds = 5,
                                                             double call_timeout_seconds = 5);
  ~EtcdClient();

  const std::string& endpoint() const { return endpoint_; }

  // The key, or nullopt if it does not exist.
  absl::StatusOr<std::optional<EtcdKeyValue>> Get(const std::string& key);
  // Every key starting with `prefix`, sorted by key.
  absl::StatusOr<std::vector<EtcdKeyValue>> GetPrefix(const std::string& prefix);
  // Returns the store's revision after the put.
  absl::StatusOr<int64_t> Put(const std::string& key, const std::string& value, int64_t lease = 0);
  absl::Status Delete(const std::string& key);
  // Compare-and-set: runs `txn` atomically; the response says whether the
  // compares held (succeeded) and what the ops returned.
  absl::StatusOr<etcdserverpb::TxnResponse> Txn(const etcdserverpb::TxnRequest& txn);

  // A lease of `ttl_seconds` (etcd may raise it to its minimum); its id.
  absl::StatusOr<int64_t> GrantLease(int64_t ttl_seconds);
  // Renews `lease` once; returns the seconds it has left (<= 0: it expired
  // or was revoked, so the keys attached to it are gone).
  absl::StatusOr<int64_t> KeepAliveOnce(int64_t lease);
  absl::Status RevokeLease(int64_t lease);

  // Compare helpers for Txn.
  static etcdserverpb::Compare KeyAbsent(const std::string& key);
  static etcdserverpb::Compare ModRevisionIs(const std::string& key, int64_t mod_revision);
  static etcdserverpb::Compare LeaseIs(const std::string& key, int64_t lease);
  static etcdserverpb::RequestOp PutOp(const std::string& key, const std::string& value, int64_t lease = 0);
  static etcdserverpb::RequestOp DeleteOp(const std::string& key);

 private:
  EtcdClient(std::string endpoint, std::shared_ptr<grpc::Channel> channel, double call_timeout_seconds);
  void SetDeadline(grpc::ClientContext* ctx) const;

  const std::string endpoint_;
  const std::shared_ptr<grpc::Channel> channel_;
  const double call_timeout_seconds_;
  std::unique_ptr<etcdserverpb::KV::Stub> kv_;
  std::unique_ptr<etcdserverpb::Lease::Stub> lease_;
  std::mutex keepalive_mu_;  // One keep-alive at a time (each on its own short stream).
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_ETCD_CLIENT_H_
