// The coordinator of replicas (coordinator.h) against a real etcd on
// loopback: one trainer per place, fenced commits after a lost lease, a
// moved head refused, and an unreachable etcd a clear error. The local
// coordinator (no etcd) keeps the generation check.
#include "server/cluster/coordinator.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <mutex>
#include <optional>
#include <thread>

#include "gtest/gtest.h"
#include "server/cluster/etcd_client.h"
#include "server/testing/etcd_test_util.h"
#include "server/common/metrics.h"
#include "server/places/model_host.h"
#include "server/testing/server_test_util.h"

namespace clnerf {
namespace {

using testing_util::LocalEtcd;

class EtcdTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (LocalEtcd::Find().empty()) GTEST_SKIP() << "no etcd binary (Debian etcd-server; scripts/install-deps.sh)";
    const std::string why = etcd_.Start(testing_util::TempDir("etcd"));
    ASSERT_EQ(why, "");
  }
  EtcdCoordinatorOptions Options(const std::string& id, int64_t ttl = 1) {
    EtcdCoordinatorOptions o;
    o.endpoint = etcd_.endpoint();
    o.replica_id = id;
    o.lease_ttl_seconds = ttl;
    o.metrics = &metrics_;
    return o;
  }
  // What a replica named `id` shares with ModelHost::Open: an etcd
  // coordinator with a 5 s lease.
  absl::StatusOr<SharedServices> Replica(const std::string& id) {
    absl::StatusOr<std::unique_ptr<Coordinator>> c = MakeEtcdCoordinator(Options(id, 5));
    if (!c.ok()) return c.status();
    SharedServices s;
    s.coordinator = std::move(*c);
    return s;
  }
  LocalEtcd etcd_;
  Metrics metrics_;
};

TEST_F(EtcdTest, ClientPutsGetsAndCompareAndSets) {
  auto c = EtcdClient::Connect(etcd_.endpoint());
  ASSERT_TRUE(c.ok()) << c.status();
  EtcdClient& e = **c;
  auto none = e.Get("/t/a");
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(none->has_value());
  ASSERT_TRUE(e.Put("/t/a", "1").ok());
  ASSERT_TRUE(e.Put("/t/b", "2").ok());
  ASSERT_TRUE(e.Put("/u", "3").ok());
  auto a = e.Get("/t/a");
  ASSERT_TRUE(a.ok() && a->has_value());
  EXPECT_EQ((*a)->value, "1");
  auto list = e.GetPrefix("/t/");
  ASSERT_TRUE(list.ok());
  ASSERT_EQ(list->size(), 2u);
  EXPECT_EQ((*list)[1].key, "/t/b");
  // CAS on the mod revision: the first wins, a second with the old revision fails.
  etcdserverpb::TxnRequest txn;
  *txn.add_compare() = EtcdClient::ModRevisionIs("/t/a", (*a)->mod_revision);
  *txn.add_success() = EtcdClient::PutOp("/t/a", "x");
  auto r1 = e.Txn(txn);
  ASSERT_TRUE(r1.ok());
  EXPECT_TRUE(r1->succeeded());
  auto r2 = e.Txn(txn);
  ASSERT_TRUE(r2.ok());
  EXPECT_FALSE(r2->succeeded());
  EXPECT_EQ((*e.Get("/t/a"))->value, "x");
  // A key on a lease goes with the lease.
  auto lease = e.GrantLease(1);
  ASSERT_TRUE(lease.ok());
  ASSERT_TRUE(e.Put("/t/leased", "v", *lease).ok());
  auto ttl = e.KeepAliveOnce(*lease);
  ASSERT_TRUE(ttl.ok()) << ttl.status();
  EXPECT_GT(*ttl, 0);
  ASSERT_TRUE(e.RevokeLease(*lease).ok());
  EXPECT_FALSE(e.Get("/t/leased")->has_value());
  auto gone = e.KeepAliveOnce(*lease);
  ASSERT_TRUE(gone.ok());
  EXPECT_LE(*gone, 0);
}

TEST_F(EtcdTest, OneTrainerPerPlaceAndCommitsAreFenced) {
  auto a = MakeEtcdCoordinator(Options("A", 5));
  auto b = MakeEtcdCoordinator(Options("B", 5));
  ASSERT_TRUE(a.ok()) << a.status();
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_TRUE(*(*a)->TryAcquire("shop"));
  EXPECT_TRUE(*(*a)->TryAcquire("shop"));  // Idempotent for the holder.
  EXPECT_FALSE(*(*b)->TryAcquire("shop"));
  EXPECT_TRUE(*(*b)->TryAcquire("flat"));  // Leases are per place.
  EXPECT_TRUE((*a)->Holds("shop"));
  EXPECT_FALSE((*b)->Holds("shop"));

  auto head = (*a)->ReadHead("shop");
  ASSERT_TRUE(head.ok());
  EXPECT_EQ(head->version, 0);
  EXPECT_EQ(head->generation, 0);
  auto v1 = (*a)->CommitHead("shop", *head, 1);
  ASSERT_TRUE(v1.ok()) << v1.status();
  EXPECT_EQ(v1->version, 1);
  EXPECT_GT(v1->generation, 0);
  EXPECT_EQ((*b)->ReadHead("shop")->version, 1);
  // A commit from a stale read of the head is refused.
  auto stale = (*a)->CommitHead("shop", *head, 2);
  EXPECT_EQ(stale.status().code(), absl::StatusCode::kAborted);
  EXPECT_NE(stale.status().message().find("head moved"), std::string::npos) << stale.status();
  // A replica without the lease cannot commit, even with the current generation.
  auto not_owner = (*b)->CommitHead("shop", *v1, 2);
  EXPECT_EQ(not_owner.status().code(), absl::StatusCode::kAborted);
  EXPECT_NE(not_owner.status().message().find("holds it now"), std::string::npos) << not_owner.status();
  EXPECT_EQ((*a)->ReadHead("shop")->version, 1);
  // Released, the other may take it.
  (*a)->Release("shop");
  EXPECT_TRUE(*(*b)->TryAcquire("shop"));
  EXPECT_NE(metrics_.Text().find("clnerf_fenced_commits_total 2"), std::string::npos) << metrics_.Text();
}

// A SIGSTOP in miniature: A's renewals stop past its TTL, B takes the place
// and publishes; when A resumes, its publish (from the head it read while it
// owned the place) is refused and the head stays B's; A learns it lost the
// place and opens a new session.
TEST_F(EtcdTest, APausedOwnerLosesThePlaceAndItsLateCommitIsRefused) {
  auto a = MakeEtcdCoordinator(Options("A", 1));
  auto b = MakeEtcdCoordinator(Options("B", 1));
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_TRUE(*(*a)->TryAcquire("shop"));
  const PlaceHead read_by_a = *(*a)->ReadHead("shop");
  PauseRenewalsForTesting(a->get(), true);
  bool taken = false;
  for (int i = 0; i < 100 && !taken; ++i) {  // etcd's lease expiry: ~TTL plus up to a second.
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    taken = *(*b)->TryAcquire("shop");
  }
  ASSERT_TRUE(taken) << "B never got the expired lease";
  auto by_b = (*b)->CommitHead("shop", read_by_a, 1);
  ASSERT_TRUE(by_b.ok()) << by_b.status();
  PauseRenewalsForTesting(a->get(), false);
  EXPECT_TRUE((*a)->Holds("shop")) << "A cannot know yet: it was paused";
  auto late = (*a)->CommitHead("shop", read_by_a, 1);
  EXPECT_EQ(late.status().code(), absl::StatusCode::kAborted);
  EXPECT_NE(late.status().message().find("lease expired"), std::string::npos) << late.status();
  EXPECT_FALSE((*a)->Holds("shop"));
  const PlaceHead now = *(*b)->ReadHead("shop");
  EXPECT_EQ(now.version, 1);
  EXPECT_EQ(now.generation, by_b->generation);
  // A's session was renewed or replaced: it can take other places again.
  bool a_alive = false;
  for (int i = 0; i < 50 && !a_alive; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    absl::StatusOr<bool> r = (*a)->TryAcquire("other");
    a_alive = r.ok() && *r;
  }
  EXPECT_TRUE(a_alive);
}

TEST_F(EtcdTest, IdsAreUniqueAcrossReplicasAndTheFirstHeadSticks) {
  auto a = MakeEtcdCoordinator(Options("A", 5));
  auto b = MakeEtcdCoordinator(Options("B", 5));
  ASSERT_TRUE(a.ok() && b.ok());
  std::vector<int64_t> ids;
  std::mutex mu;
  std::vector<std::thread> threads;
  for (Coordinator* c : {a->get(), b->get()}) {
    threads.emplace_back([&, c] {
      for (int i = 0; i < 20; ++i) {
        absl::StatusOr<int64_t> id = c->NextId("shop", 7);
        ASSERT_TRUE(id.ok()) << id.status();
        std::lock_guard<std::mutex> lock(mu);
        ids.push_back(*id);
      }
    });
  }
  for (auto& t : threads) t.join();
  std::sort(ids.begin(), ids.end());
  ASSERT_EQ(ids.size(), 40u);
  for (size_t i = 0; i < ids.size(); ++i) EXPECT_EQ(ids[i], 7 + int64_t(i));  // Unique and dense from 7.
  EXPECT_EQ(*(*a)->NextId("shop", 100), 100);  // A floor above the counter moves it.
  EXPECT_EQ(*(*b)->NextId("other", 1), 1);
  auto h = (*a)->InitHead("shop", 3);
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->version, 3);
  auto again = (*b)->InitHead("shop", 9);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->version, 3);
  EXPECT_EQ(again->generation, h->generation);
}

// A replica that never saw a scan queued (uploaded and trained elsewhere
// between two of its polls) still learns its job from the version it
// published: GetJob answers DONE with that version on every replica.
TEST_F(EtcdTest, AJobTrainedBetweenTwoPollsIsKnownDoneOnTheOtherReplica) {
  const std::string store = testing_util::TempDir("srv_follow_unseen");
  absl::StatusOr<SharedServices> sa = Replica("A"), sb = Replica("B");
  ASSERT_TRUE(sa.ok() && sb.ok());
  const ServerOptions o = testing_util::TinyServerOptions(store);
  absl::StatusOr<std::unique_ptr<ModelHost>> a = ModelHost::Open(o, *sa);
  ASSERT_TRUE(a.ok()) << a.status();
  absl::StatusOr<std::unique_ptr<ModelHost>> b = ModelHost::Open(o, *sb);
  ASSERT_TRUE(b.ok()) << b.status();
  absl::StatusOr<UploadAck> ack = (*a)->AcceptScan(testing_util::UploadOf(testing_util::TinyScans(1), 0));
  ASSERT_TRUE(ack.ok()) << ack.status();
  for (int i = 0; i < 1200 && (*a)->deployed_version() == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ASSERT_EQ((*a)->deployed_version(), 1);
  EXPECT_EQ((*b)->GetJob(ack->job_id).status().code(), absl::StatusCode::kNotFound);  // Not polled yet.
  absl::StatusOr<PlaceHead> head = sb->coordinator->ReadHead("default");
  ASSERT_TRUE(head.ok()) << head.status();
  (*b)->FollowReplicas(*head);
  absl::StatusOr<JobStatus> job = (*b)->GetJob(ack->job_id);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->phase, JobPhase::kDone);
  EXPECT_EQ(job->version, 1);
  EXPECT_EQ(job->scan_id, ack->scan_id);
  EXPECT_EQ((*b)->deployed_version(), 1);
  (*b)->FollowReplicas(*head);  // Idempotent: still one record.
  EXPECT_EQ((*b)->ListJobs().size(), 1u);
  (*a)->Shutdown();
  (*b)->Shutdown();
}

// Issue 39: a replica polling the store while scans are uploaded through it
// must never mark a scan it just acknowledged as removed elsewhere (its
// listing of the store predated the upload). B polls in a tight loop while
// 12 scans are uploaded through B.
TEST_F(EtcdTest, AScanAcknowledgedDuringAPollIsNotCancelled) {
  const std::string store = testing_util::TempDir("srv_follow_race");
  absl::StatusOr<SharedServices> sa = Replica("A"), sb = Replica("B");
  ASSERT_TRUE(sa.ok() && sb.ok());
  ServerOptions o = testing_util::TinyServerOptions(store);
  o.max_queue = 64;
  absl::StatusOr<std::unique_ptr<ModelHost>> a = ModelHost::Open(o, *sa);
  ASSERT_TRUE(a.ok()) << a.status();
  absl::StatusOr<std::unique_ptr<ModelHost>> b = ModelHost::Open(o, *sb);
  ASSERT_TRUE(b.ok()) << b.status();
  const Scene scene = testing_util::TinyScans(1);
  std::atomic<bool> done{false};
  std::thread poller([&] {
    while (!done) {
      absl::StatusOr<PlaceHead> head = sb->coordinator->ReadHead("default");
      (*b)->FollowReplicas(head.ok() ? std::optional<PlaceHead>(*head) : std::nullopt);
    }
  });
  std::vector<std::string> acked;
  for (int i = 0; i < 12; ++i) {
    absl::StatusOr<UploadAck> ack = (*b)->AcceptScan(testing_util::UploadOf(scene, 0));
    ASSERT_TRUE(ack.ok()) << ack.status();
    acked.push_back(ack->job_id);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  done = true;
  poller.join();
  for (const std::string& id : acked) {
    absl::StatusOr<JobStatus> j = (*b)->GetJob(id);
    ASSERT_TRUE(j.ok()) << j.status();
    EXPECT_NE(j->phase, JobPhase::kCancelled) << id << ": " << j->error;
  }
  (*a)->Shutdown();
  (*b)->Shutdown();
}

// Issue 39: a job that replica A trains cannot be cancelled through replica
// B (B would remove the scan, answer "cancelled", and A would ship it):
// refused with FAILED_PRECONDITION, the scan kept; through A it works.
TEST_F(EtcdTest, AJobAnotherReplicaTrainsIsNotCancelledHere) {
  const std::string store = testing_util::TempDir("srv_cancel_elsewhere");
  absl::StatusOr<SharedServices> sa = Replica("A"), sb = Replica("B");
  ASSERT_TRUE(sa.ok() && sb.ok());
  ServerOptions o = testing_util::TinyServerOptions(store);
  o.update.train.iterations = 100000;  // Still training when cancelled.
  absl::StatusOr<std::unique_ptr<ModelHost>> a = ModelHost::Open(o, *sa);
  ASSERT_TRUE(a.ok()) << a.status();
  const Scene scene = testing_util::TinyScans(1);
  absl::StatusOr<UploadAck> first = (*a)->AcceptScan(testing_util::UploadOf(scene, 0));
  absl::StatusOr<UploadAck> second = (*a)->AcceptScan(testing_util::UploadOf(scene, 0));
  ASSERT_TRUE(first.ok() && second.ok());
  for (int i = 0; i < 300 && (*a)->Info().running_job != first->job_id; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_EQ((*a)->Info().running_job, first->job_id);
  absl::StatusOr<std::unique_ptr<ModelHost>> b = ModelHost::Open(o, *sb);  // Sees both jobs queued.
  ASSERT_TRUE(b.ok()) << b.status();
  (*b)->FollowReplicas(std::nullopt);
  for (const UploadAck* ack : {&*first, &*second}) {
    absl::StatusOr<JobStatus> r = (*b)->CancelJob(ack->job_id);
    EXPECT_EQ(r.status().code(), absl::StatusCode::kFailedPrecondition) << r.status();
    EXPECT_TRUE(std::filesystem::exists(store + "/scans/" + ack->scan_id)) << ack->scan_id;
  }
  absl::StatusOr<JobStatus> on_b = (*b)->GetJob(second->job_id);
  ASSERT_TRUE(on_b.ok());
  EXPECT_NE(on_b->phase, JobPhase::kCancelled);
  // Through the replica that trains the place, both cancel.
  ASSERT_TRUE((*a)->CancelJob(second->job_id).ok());
  ASSERT_TRUE((*a)->CancelJob(first->job_id).ok());
  absl::StatusOr<JobStatus> done = (*a)->WaitJob(first->job_id, 0, std::chrono::steady_clock::now());
  for (int i = 0; i < 300 && !(done.ok() && IsFinal(done->phase)); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    done = (*a)->GetJob(first->job_id);
  }
  ASSERT_TRUE(done.ok());
  EXPECT_EQ(done->phase, JobPhase::kCancelled);
  (*a)->Shutdown();
  (*b)->Shutdown();
}

TEST(CoordinatorTest, UnreachableEtcdIsUnavailableQuickly) {
  EtcdCoordinatorOptions o;
  o.endpoint = "127.0.0.1:" + std::to_string(testing_util::FreeLoopbackPort());
  o.call_timeout_seconds = 0.5;
  const auto t0 = std::chrono::steady_clock::now();
  auto c = MakeEtcdCoordinator(o);
  EXPECT_EQ(c.status().code(), absl::StatusCode::kUnavailable) << c.status();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(3));
  o.lease_ttl_seconds = 0;
  EXPECT_EQ(MakeEtcdCoordinator(o).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(CoordinatorTest, LocalCoordinatorHoldsEverythingAndChecksTheGeneration) {
  auto c = MakeLocalCoordinator();
  EXPECT_TRUE(*c->TryAcquire("any"));
  const PlaceHead h0 = *c->ReadHead("p");
  auto h1 = c->CommitHead("p", h0, 1);
  ASSERT_TRUE(h1.ok());
  EXPECT_EQ(c->CommitHead("p", h0, 2).status().code(), absl::StatusCode::kAborted);
  EXPECT_EQ(c->ReadHead("p")->version, 1);
  ASSERT_TRUE(c->Forget("p").ok());
  EXPECT_EQ(c->ReadHead("p")->version, 0);
}

}  // namespace
}  // namespace clnerf
