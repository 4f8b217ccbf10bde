#include "server/store/model_registry.h"

#include <atomic>

#include "absl/strings/str_cat.h"
#include "server/common/metrics.h"

namespace clnerf {

int64_t ServableBytes(const Servable& s) {
  int64_t bytes = int64_t(sizeof(Servable));
  if (s.state.model) bytes += int64_t(s.model().resident_bytes());
  bytes += int64_t(s.memory().num_cameras()) * int64_t(sizeof(Camera));
  return bytes;
}

std::shared_ptr<ServableCache> MakeServableCache(int64_t budget_bytes, std::shared_ptr<Metrics> metrics) {
  std::function<void()> on_evict;
  if (metrics != nullptr) on_evict = [metrics] { metrics->ModelEvicted(); };
  return std::make_shared<ServableCache>(
      budget_bytes, [](const Servable& s) { return ServableBytes(s); }, std::move(on_evict));
}

namespace {
std::atomic<int64_t> next_registry_id{1};
}  // namespace

ModelRegistry::ModelRegistry(Loader loader, std::shared_ptr<ServableCache> cache, const std::string& place)
    : loader_(std::move(loader)),
      cache_(cache ? std::move(cache) : MakeServableCache(0)),
      prefix_(absl::StrCat(place, "#", next_registry_id.fetch_add(1), "@")) {}

ModelRegistry::~ModelRegistry() { cache_->ErasePrefix(prefix_); }

std::string ModelRegistry::Key(int64_t version) const { return absl::StrCat(prefix_, version); }

int64_t ModelRegistry::deployed_version() const {
  std::lock_guard<std::mutex> lock(mu_);
  return deployed_ ? deployed_->info.version : 0;
}

std::optional<DeployedSummary> ModelRegistry::deployed() const {
  std::lock_guard<std::mutex> lock(mu_);
  return deployed_;
}

std::shared_ptr<const Servable> ModelRegistry::Peek(int64_t version) const {
  if (version == 0) version = deployed_version();
  return version > 0 ? cache_->Peek(Key(version)) : nullptr;
}

absl::StatusOr<std::shared_ptr<const Servable>> ModelRegistry::Get(int64_t version) const {
  if (version == 0) {
    version = deployed_version();
    if (version == 0) return absl::FailedPreconditionError("no model is deployed yet: upload a scan first");
  }
  if (version < 0) return absl::InvalidArgumentError(absl::StrCat("version ", version, " is negative"));
  return cache_->GetOrLoad(Key(version), [&] { return loader_(version); });
}

void ModelRegistry::DeployUnloaded(const VersionInfo& info) {
  std::lock_guard<std::mutex> lock(mu_);
  deployed_ = DeployedSummary{info, info.model_bytes, info.memory_bytes, 0};
}

void ModelRegistry::ClearDeployed(int64_t version) {
  std::lock_guard<std::mutex> lock(mu_);
  if (deployed_ && deployed_->info.version == version) deployed_.reset();
}

void ModelRegistry::Offer(std::shared_ptr<const Servable> servable) {
  const int64_t v = servable->info.version;
  cache_->Offer(Key(v), std::move(servable));
}

void ModelRegistry::Evict(int64_t version) { cache_->Erase(Key(version)); }

void ModelRegistry::Deploy(std::shared_ptr<const Servable> servable, bool keep_loaded) {
  DeployedSummary summary{servable->info, int64_t(servable->model().num_bytes()), ServableBytes(*servable),
                          int64_t(servable->memory().num_cameras())};
  // Into the cache first: a reader that sees the new number finds it loaded.
  if (keep_loaded) {
    cache_->Put(Key(summary.info.version), std::move(servable));
  } else {
    cache_->Offer(Key(summary.info.version), std::move(servable));
  }
  std::lock_guard<std::mutex> lock(mu_);
  deployed_ = std::move(summary);
}

}  // namespace clnerf
