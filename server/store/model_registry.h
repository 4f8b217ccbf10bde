// ModelRegistry: the versions of one place that the server can render, and
// which one is deployed, following TF Serving's ServableHandle idea: readers
// take a std::shared_ptr<const Servable> snapshot and keep using it for as
// long as their request runs, so publishing, rolling back or evicting never
// blocks or breaks a render in flight; a model is freed when its last reader
// lets go.
//
// Loaded models live in a ServableCache (model_cache.h) that every place of
// the server shares under one memory budget (--model-memory-budget), so the
// registry holds only the deployed version's number and summary. A version
// (the deployed one included) is loaded on first use, one load at a time,
// and the least recently used ones are evicted when the budget is exceeded;
// one that a render or a training holds is never evicted under it. A new
// version is put in the cache beside the old one and then becomes the
// deployed one, so readers switch with no gap.
//
// Thread-safety: every method is thread-safe. The mutex guards only the
// deployed version's number and summary; loading happens outside it.
#ifndef CLNERF_SERVER_MODEL_REGISTRY_H_
#define CLNERF_SERVER_MODEL_REGISTRY_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "core/continual/continual_update.h"
#include "core/continual/replay_memory.h"
#include "core/field/ngp_model.h"
#include "server/store/model_cache.h"
#include "server/store/version_store.h"

namespace clnerf {

class Metrics;

// One immutable published version: its metadata and the continual state
// (θ and M) that renders read and the next update trains from.
struct Servable {
  VersionInfo info;
  ContinualState state;
  const NgpModel& model() const { return *state.model; }
  const ReplayMemory& memory() const { return state.memory; }
};

// The memory a loaded servable holds: its model (parameters and occupancy
// grid, NgpModel::resident_bytes) and its replay cameras.
int64_t ServableBytes(const Servable& s);

using ServableCache = ModelCache<Servable>;
// A cache for servables under `budget_bytes` (<= 0: no limit); `metrics`
// (optional) counts its evictions.
std::shared_ptr<ServableCache> MakeServableCache(int64_t budget_bytes, std::shared_ptr<Metrics> metrics = nullptr);

// What a place reports without loading its model.
struct DeployedSummary {
  VersionInfo info;
  int64_t model_bytes = 0;     // Parameter bytes.
  int64_t memory_bytes = 0;    // Held in memory when loaded (ServableBytes; 0 = unknown).
  int64_t replay_cameras = 0;  // Cameras in its replay memory.
};

class ModelRegistry {
 public:
  using Loader = std::function<absl::StatusOr<std::shared_ptr<const Servable>>(int64_t version)>;
  // `cache`: shared with the server's other places (null: an unbounded cache
  // of its own); `place` names its entries there (for logs and Keys()).
  ModelRegistry(Loader loader, std::shared_ptr<ServableCache> cache, const std::string& place = "default");
  // Drops this place's entries from the cache.
  ~ModelRegistry();
  ModelRegistry(const ModelRegistry&) = delete;
  ModelRegistry& operator=(const ModelRegistry&) = delete;

  // `version` 0 = deployed (loaded if it was evicted). FAILED_PRECONDITION if
  // nothing is deployed yet, NOT_FOUND for an unknown version, the loader's
  // error (e.g. DATA_LOSS) for one that cannot be loaded.
  absl::StatusOr<std::shared_ptr<const Servable>> Get(int64_t version) const;
  int64_t deployed_version() const;
  // The deployed version's summary (nullopt before the first), without loading it.
  std::optional<DeployedSummary> deployed() const;
  // Whether version `version` (0 = deployed) is in memory now.
  bool loaded(int64_t version = 0) const { return Peek(version) != nullptr; }
  // Version `version` (0 = deployed) if it is in memory now, else null (no
  // load, and no change to the eviction order).
  std::shared_ptr<const Servable> Peek(int64_t version = 0) const;
  // Makes `servable` the deployed version (a publish or a rollback). It joins
  // the cache first (evicting others if the budget needs it), or with
  // `keep_loaded` false only if it fits without evicting anything (a version
  // verified at start-up: otherwise it loads on its first use).
  void Deploy(std::shared_ptr<const Servable> servable, bool keep_loaded = true);
  // Makes version `info` the deployed one without loading it (start-up:
  // Publisher::VerifyDeployed loads it later, or its first use does).
  void DeployUnloaded(const VersionInfo& info);
  // Nothing is deployed any more (its model turned out unloadable).
  void ClearDeployed(int64_t version);
  // Keeps a loaded version in the cache if it fits without evicting anything.
  void Offer(std::shared_ptr<const Servable> servable);
  // Drops a version from the cache, e.g. after it was pruned.
  void Evict(int64_t version);

 private:
  std::string Key(int64_t version) const;

  Loader loader_;
  const std::shared_ptr<ServableCache> cache_;
  const std::string prefix_;  // "place#N@": unique per registry, so a re-created place never sees old entries.
  mutable std::mutex mu_;
  std::optional<DeployedSummary> deployed_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_MODEL_REGISTRY_H_
