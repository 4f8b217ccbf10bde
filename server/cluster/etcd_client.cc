#include "server/cluster/etcd_client.h"

#include <chrono>

#include <grpcpp/grpcpp.h>

#include "absl/strings/str_cat.h"

namespace clnerf {
namespace {

absl::Status FromGrpc(const grpc::Status& s, const std::string& what, const std::string& endpoint) {
  if (s.ok()) return absl::OkStatus();
  const std::string msg = absl::StrCat("etcd at ", endpoint, ": ", what, ": ", s.error_message());
  switch (s.error_code()) {
    case grpc::StatusCode::DEADLINE_EXCEEDED:
      return absl::DeadlineExceededError(msg);
    case grpc::StatusCode::NOT_FOUND:
      return absl::NotFoundError(msg);
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::FAILED_PRECONDITION:
      return absl::FailedPreconditionError(msg);
    default:
      return absl::UnavailableError(msg);
  }
}

EtcdKeyValue FromProto(const etcdserverpb::KeyValue& kv) {
  return EtcdKeyValue{kv.key(), kv.value(), kv.create_revision(), kv.mod_revision(), kv.version(), kv.lease()};
}

// The smallest key greater than every key starting with `prefix`.
std::string PrefixEnd(std::string prefix) {
  for (int i = int(prefix.size()) - 1; i >= 0; --i) {
    if (static_cast<unsigned char>(prefix[i]) < 0xff) {
      prefix[i] = char(static_cast<unsigned char>(prefix[i]) + 1);
      prefix.resize(i + 1);
      return prefix;
    }
  }
  return std::string(1, '\0');  // All 0xff: to the end of the keyspace.
}

}  // namespace

EtcdClient::EtcdClient(std::string endpoint, std::shared_ptr<grpc::Channel> channel, double call_timeout_seconds)
    : endpoint_(std::move(endpoint)),
      channel_(std::move(channel)),
      call_timeout_seconds_(call_timeout_seconds),
      kv_(etcdserverpb::KV::NewStub(channel_)),
      lease_(etcdserverpb::Lease::NewStub(channel_)) {}

EtcdClient::~EtcdClient() = default;

absl::StatusOr<std::unique_ptr<EtcdClient>> EtcdClient::Connect(const std::string& endpoint,
                                                                double connect_timeout_seconds,
                                                                double call_timeout_seconds) {
  if (endpoint.empty()) return absl::InvalidArgumentError("the etcd endpoint is empty (expected HOST:PORT)");
  auto channel = grpc::CreateChannel(endpoint, grpc::InsecureChannelCredentials());
  const auto deadline = std::chrono::system_clock::now() +
                        std::chrono::milliseconds(int64_t(connect_timeout_seconds * 1000));
  if (!channel->WaitForConnected(deadline)) {
    return absl::UnavailableError(
        absl::StrCat("etcd at ", endpoint, " did not answer within ", connect_timeout_seconds, " s"));
  }
  std::unique_ptr<EtcdClient> c(new EtcdClient(endpoint, std::move(channel), call_timeout_seconds));
  // A real round trip: a channel can connect to something that is not etcd.
  if (absl::StatusOr<std::optional<EtcdKeyValue>> probe = c->Get("/clnerf/probe"); !probe.ok()) {
    return probe.status();
  }
  return c;
}

void EtcdClient::SetDeadline(grpc::ClientContext* ctx) const {
  ctx->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::milliseconds(int64_t(call_timeout_seconds_ * 1000)));
}

absl::StatusOr<std::optional<EtcdKeyValue>> EtcdClient::Get(const std::string& key) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  etcdserverpb::RangeRequest req;
  req.set_key(key);
  etcdserverpb::RangeResponse resp;
  if (absl::Status s = FromGrpc(kv_->Range(&ctx, req, &resp), absl::StrCat("get ", key), endpoint_); !s.ok()) {
    return s;
  }
  if (resp.kvs_size() == 0) return std::optional<EtcdKeyValue>();
  return std::optional<EtcdKeyValue>(FromProto(resp.kvs(0)));
}

absl::StatusOr<std::vector<EtcdKeyValue>> EtcdClient::GetPrefix(const std::string& prefix) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  etcdserverpb::RangeRequest req;
  req.set_key(prefix);
  req.set_range_end(PrefixEnd(prefix));
  etcdserverpb::RangeResponse resp;
  if (absl::Status s = FromGrpc(kv_->Range(&ctx, req, &resp), absl::StrCat("list ", prefix), endpoint_); !s.ok()) {
    return s;
  }
  std::vector<EtcdKeyValue> out;
  for (const etcdserverpb::KeyValue& kv : resp.kvs()) out.push_back(FromProto(kv));
  return out;
}

absl::StatusOr<int64_t> EtcdClient::Put(const std::string& key, const std::string& value, int64_t lease) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  etcdserverpb::PutRequest req;
  req.set_key(key);
  req.set_value(value);
  req.set_lease(lease);
  etcdserverpb::PutResponse resp;
  if (absl::Status s = FromGrpc(kv_->Put(&ctx, req, &resp), absl::StrCat("put ", key), endpoint_); !s.ok()) return s;
  return resp.header().revision();
}

absl::Status EtcdClient::Delete(const std::string& key) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  etcdserverpb::DeleteRangeRequest req;
  req.set_key(key);
  etcdserverpb::DeleteRangeResponse resp;
  return FromGrpc(kv_->DeleteRange(&ctx, req, &resp), absl::StrCat("delete ", key), endpoint_);
}

absl::StatusOr<etcdserverpb::TxnResponse> EtcdClient::Txn(const etcdserverpb::TxnRequest& txn) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  etcdserverpb::TxnResponse resp;
  if (absl::Status s = FromGrpc(kv_->Txn(&ctx, txn, &resp), "transaction", endpoint_); !s.ok()) return s;
  return resp;
}

absl::StatusOr<int64_t> EtcdClient::GrantLease(int64_t ttl_seconds) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  etcdserverpb::LeaseGrantRequest req;
  req.set_ttl(ttl_seconds);
  etcdserverpb::LeaseGrantResponse resp;
  if (absl::Status s = FromGrpc(lease_->LeaseGrant(&ctx, req, &resp), "lease grant", endpoint_); !s.ok()) return s;
  if (!resp.error().empty()) return absl::UnavailableError(absl::StrCat("etcd lease grant: ", resp.error()));
  return resp.id();
}

absl::StatusOr<int64_t> EtcdClient::KeepAliveOnce(int64_t lease) {
  std::lock_guard<std::mutex> lock(keepalive_mu_);
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  auto stream = lease_->LeaseKeepAlive(&ctx);
  etcdserverpb::LeaseKeepAliveRequest req;
  req.set_id(lease);
  etcdserverpb::LeaseKeepAliveResponse resp;
  const bool wrote = stream->Write(req);
  const bool read = wrote && stream->Read(&resp);
  stream->WritesDone();
  if (!read) {
    const grpc::Status st = stream->Finish();
    if (st.ok()) return absl::UnavailableError(absl::StrCat("etcd at ", endpoint_, ": lease keep-alive got no answer"));
    return FromGrpc(st, "lease keep-alive", endpoint_);
  }
  ctx.TryCancel();  // Our one answer is in; end the stream without waiting for etcd.
  (void)stream->Finish();
  return resp.ttl();
}

absl::Status EtcdClient::RevokeLease(int64_t lease) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  etcdserverpb::LeaseRevokeRequest req;
  req.set_id(lease);
  etcdserverpb::LeaseRevokeResponse resp;
  return FromGrpc(lease_->LeaseRevoke(&ctx, req, &resp), "lease revoke", endpoint_);
}

etcdserverpb::Compare EtcdClient::KeyAbsent(const std::string& key) {
  etcdserverpb::Compare c;
  c.set_key(key);
  c.set_target(etcdserverpb::Compare::CREATE);
  c.set_result(etcdserverpb::Compare::EQUAL);
  c.set_create_revision(0);
  return c;
}

etcdserverpb::Compare EtcdClient::ModRevisionIs(const std::string& key, int64_t mod_revision) {
  etcdserverpb::Compare c;
  c.set_key(key);
  c.set_target(etcdserverpb::Compare::MOD);
  c.set_result(etcdserverpb::Compare::EQUAL);
  c.set_mod_revision(mod_revision);
  return c;
}

etcdserverpb::Compare EtcdClient::LeaseIs(const std::string& key, int64_t lease) {
  etcdserverpb::Compare c;
  c.set_key(key);
  c.set_target(etcdserverpb::Compare::LEASE);
  c.set_result(etcdserverpb::Compare::EQUAL);
  c.set_lease(lease);
  return c;
}

etcdserverpb::RequestOp EtcdClient::PutOp(const std::string& key, const std::string& value, int64_t lease) {
  etcdserverpb::RequestOp op;
  op.mutable_request_put()->set_key(key);
  op.mutable_request_put()->set_value(value);
  op.mutable_request_put()->set_lease(lease);
  return op;
}

etcdserverpb::RequestOp EtcdClient::DeleteOp(const std::string& key) {
  etcdserverpb::RequestOp op;
  op.mutable_request_delete_range()->set_key(key);
  return op;
}

}  // namespace clnerf
