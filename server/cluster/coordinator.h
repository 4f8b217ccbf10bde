// Coordinator: how the replicas that share one store agree on who trains a
// place and which of its versions is deployed (issue 22, "scale-out").
//
//   training lease  at most one replica trains a given place at a time. A
//                   replica takes a place's lease with TryAcquire and holds
//                   it while its session lives: the session is renewed in
//                   the background, and one that a paused, partitioned or
//                   dead replica stops renewing expires after the TTL, which
//                   frees all of its places for the others.
//   head            the place's deployed version and its generation (a
//                   number that grows with every change of the head).
//   fenced commit   CommitHead moves the head only if this replica still
//                   holds the place's lease AND the head is still at the
//                   generation the caller read; both are checked in one
//                   atomic transaction, so a replica whose lease expired
//                   cannot publish over a newer owner's version. A refused
//                   commit is ABORTED and counted (clnerf_fenced_commits_total).
//
// Two implementations:
//   local  (no --etcd)   one process: it always holds every lease and keeps
//                        the head in memory; the store's manifest stays the
//                        record. Today's single server, no dependencies.
//   etcd   (--etcd H:P)  etcd's v3 API (etcd_client.h): the session is an
//                        etcd lease, a place's owner key is attached to it
//                        (created only if absent), and the head is a key
//                        whose mod_revision is the generation. The same
//                        primitives Kubernetes stands on.
// Keys (etcd): PREFIX/places/NAME/owner   (value: replica id, lease: session),
//              PREFIX/places/NAME/head    (value: deployed version),
//              PREFIX/places/NAME/next_id (the next scan and job number).
//
// Files: coordinator.cc (local), etcd_coordinator.cc (etcd), etcd_session.h
// (the etcd session and its renewal).
//
// Thread-safety: every method is thread-safe.
#ifndef CLNERF_SERVER_COORDINATOR_H_
#define CLNERF_SERVER_COORDINATOR_H_

#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include "absl/status/statusor.h"

namespace clnerf {

class Metrics;

struct PlaceHead {
  int64_t version = 0;     // Deployed version (0 = none yet).
  int64_t generation = 0;  // Grows with every commit; 0 = never committed.
  // The staged directory the version was committed from ("" = it was on
  // disk already, e.g. a rollback): whoever finds it unpromoted after a
  // crash promotes exactly that one (publisher.h).
  std::string tag;
};

class Coordinator {
 public:
  virtual ~Coordinator() = default;
  // This replica's name in owner keys and logs (e.g. "host:pid").
  virtual const std::string& replica_id() const = 0;
  // Takes (or confirms) the training lease of `place`. false: another
  // replica holds it. UNAVAILABLE: the coordinator cannot be reached.
  virtual absl::StatusOr<bool> TryAcquire(const std::string& place) = 0;
  // Whether this replica holds `place`'s lease, as far as it knows now (a
  // paused replica may not know yet that it lost it: CommitHead is the check
  // that cannot be fooled).
  virtual bool Holds(const std::string& place) const = 0;
  // Gives the lease of `place` up (idempotent).
  virtual void Release(const std::string& place) = 0;
  virtual absl::StatusOr<PlaceHead> ReadHead(const std::string& place) = 0;
  // Fenced publish of `version` as `place`'s head (see above). The new head,
  // or ABORTED naming why it was refused.
  virtual absl::StatusOr<PlaceHead> CommitHead(const std::string& place, const PlaceHead& expected,
                                               int64_t version, const std::string& tag = "") = 0;
  // Every place's head, by place name (one round trip).
  virtual absl::StatusOr<std::map<std::string, PlaceHead>> ReadHeads() = 0;
  // Sets the head of a place that has none yet (a store from a single
  // server joining replicas); returns the head now (its own if it had one).
  virtual absl::StatusOr<PlaceHead> InitHead(const std::string& place, int64_t version) = 0;
  // A number unique to this call among all replicas, >= `at_least`, for the
  // ids of `place`'s scans and jobs.
  virtual absl::StatusOr<int64_t> NextId(const std::string& place, int64_t at_least) = 0;
  // Whether replicas share the store through this coordinator (etcd).
  virtual bool replicated() const = 0;
  // Forgets `place` (deleted): releases its lease and removes its keys.
  virtual absl::Status Forget(const std::string& place) = 0;
};

// One process, no dependencies (see above).
std::unique_ptr<Coordinator> MakeLocalCoordinator(const std::string& replica_id = "local");

struct EtcdCoordinatorOptions {
  std::string endpoint;             // etcd client URL as HOST:PORT.
  std::string prefix = "/clnerf";   // Keys of this deployment (several may share one etcd).
  std::string replica_id;           // "" = hostname:pid.
  // Session TTL: how long a silent replica keeps its places before another
  // may take them over. Renewed every ttl/3. etcd enforces a minimum (about
  // 1.5 x its election timeout).
  int64_t lease_ttl_seconds = 10;
  double call_timeout_seconds = 3;  // Per etcd call.
  Metrics* metrics = nullptr;       // Counts fenced commits and lease changes (optional; must outlive it).
  absl::Status Validate() const;
};

// Connects to etcd and opens a session (UNAVAILABLE if etcd cannot be reached).
absl::StatusOr<std::unique_ptr<Coordinator>> MakeEtcdCoordinator(const EtcdCoordinatorOptions& options);

// For tests: stops (true) or resumes (false) an etcd coordinator's session
// renewals, as a SIGSTOP would; no-op for others.
void PauseRenewalsForTesting(Coordinator* coordinator, bool paused);

}  // namespace clnerf

#endif  // CLNERF_SERVER_COORDINATOR_H_
