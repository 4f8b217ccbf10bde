#include "server/model_registry.h"

#include "absl/strings/str_cat.h"

namespace clnerf {

std::shared_ptr<const Servable> ModelRegistry::Deployed() const {
  std::lock_guard<std::mutex> lock(mu_);
  return deployed_;
}

int64_t ModelRegistry::deployed_version() const {
  std::lock_guard<std::mutex> lock(mu_);
  return deployed_ ? deployed_->info.version : 0;
}

void ModelRegistry::CacheLocked(std::shared_ptr<const Servable> s) const {
  for (auto it = cache_.begin(); it != cache_.end(); ++it) {
    if ((*it)->info.version == s->info.version) {
      cache_.erase(it);
      break;
    }
  }
  cache_.push_front(std::move(s));
  while (int(cache_.size()) > cache_size_) cache_.pop_back();
}

absl::StatusOr<std::shared_ptr<const Servable>> ModelRegistry::Get(int64_t version) const {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (version == 0) {
      if (!deployed_) return absl::FailedPreconditionError("no model is deployed yet: upload a scan first");
      return deployed_;
    }
    if (deployed_ && deployed_->info.version == version) return deployed_;
    for (auto it = cache_.begin(); it != cache_.end(); ++it) {
      if ((*it)->info.version == version) {
        auto s = *it;
        cache_.splice(cache_.begin(), cache_, it);
        return s;
      }
    }
  }
  if (version < 0) return absl::InvalidArgumentError(absl::StrCat("version ", version, " is negative"));
  absl::StatusOr<std::shared_ptr<const Servable>> loaded = loader_(version);
  if (!loaded.ok()) return loaded.status();
  std::lock_guard<std::mutex> lock(mu_);
  if (cache_size_ > 0) CacheLocked(*loaded);
  return *loaded;
}

void ModelRegistry::Evict(int64_t version) {
  std::lock_guard<std::mutex> lock(mu_);
  cache_.remove_if([&](const std::shared_ptr<const Servable>& s) { return s->info.version == version; });
}

void ModelRegistry::Deploy(std::shared_ptr<const Servable> servable) {
  std::shared_ptr<const Servable> old;
  {
    std::lock_guard<std::mutex> lock(mu_);
    old = std::move(deployed_);
    deployed_ = std::move(servable);
    if (old && cache_size_ > 0) CacheLocked(old);
  }
  // `old` (if not cached) is released here, outside the lock; readers that
  // still hold it keep it alive.
}

}  // namespace clnerf
