// ModelRegistry: the versions the server can render, and which one is
// deployed, following TF Serving's ServableHandle idea: readers take a
// std::shared_ptr<const Servable> snapshot and keep using it for as long as
// their request runs, so publishing or rolling back never blocks or breaks a
// render in flight; the old model is freed when its last reader lets go.
//
// The deployed servable is always resident. Other versions are loaded on
// first use through the loader and kept in a small LRU cache.
//
// Thread-safety: every method is thread-safe. The mutex guards only pointer
// swaps and the cache map; loading from disk happens outside it.
#ifndef CLNERF_SERVER_MODEL_REGISTRY_H_
#define CLNERF_SERVER_MODEL_REGISTRY_H_

#include <cstdint>
#include <functional>
#include <list>
#include <memory>
#include <mutex>

#include "absl/status/statusor.h"
#include "core/continual/continual_update.h"
#include "core/field/ngp_model.h"
#include "core/continual/replay_memory.h"
#include "server/version_store.h"

namespace clnerf {

// One immutable published version: its metadata and the continual state
// (θ and M) that renders read and the next update trains from.
struct Servable {
  VersionInfo info;
  ContinualState state;
  const NgpModel& model() const { return *state.model; }
  const ReplayMemory& memory() const { return state.memory; }
};

class ModelRegistry {
 public:
  using Loader = std::function<absl::StatusOr<std::shared_ptr<const Servable>>(int64_t version)>;
  ModelRegistry(Loader loader, int cache_size) : loader_(std::move(loader)), cache_size_(cache_size) {}

  // The deployed servable, or null before the first version.
  std::shared_ptr<const Servable> Deployed() const;
  int64_t deployed_version() const;
  // `version` 0 = deployed. FAILED_PRECONDITION if nothing is deployed yet,
  // NOT_FOUND for an unknown version.
  absl::StatusOr<std::shared_ptr<const Servable>> Get(int64_t version) const;
  // Makes `servable` the deployed version (a publish or a rollback).
  void Deploy(std::shared_ptr<const Servable> servable);
  // Drops a (non-deployed) version from the cache, e.g. after it was pruned.
  void Evict(int64_t version);

 private:
  void CacheLocked(std::shared_ptr<const Servable> s) const;

  Loader loader_;
  int cache_size_;
  mutable std::mutex mu_;
  std::shared_ptr<const Servable> deployed_;
  mutable std::list<std::shared_ptr<const Servable>> cache_;  // Most recent first.
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_MODEL_REGISTRY_H_
