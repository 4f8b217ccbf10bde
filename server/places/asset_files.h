// AssetFiles: the baked-asset files that GET /api/asset serves (manifest,
// index, atlas, view arrays), read from disk once and then kept in memory
// under one byte budget shared by every place, least recently used evicted
// first (a ModelCache, model_cache.h: single-flight reads, a file a request
// still holds is never freed under it). So twenty viewers of one version
// cost one read and one hash of each file, and a 304 costs neither.
//
// A file is keyed by its path, size and modification time: one rewritten in
// place (a place deleted and made again under its name) is read again,
// never served stale. Published asset files are immutable otherwise.
//
// Thread-safety: every method is thread-safe.
#ifndef CLNERF_SERVER_PLACES_ASSET_FILES_H_
#define CLNERF_SERVER_PLACES_ASSET_FILES_H_

#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "server/common/metrics.h"
#include "server/store/model_cache.h"

namespace clnerf {

struct AssetBlob {
  std::string bytes;
  std::string digest;  // Size and a hash of the bytes, for ETags.
};

class AssetFiles {
 public:
  // budget_bytes 0: nothing is kept (every Get reads the file). `metrics`
  // (may be null) counts the reads.
  AssetFiles(int64_t budget_bytes, std::shared_ptr<Metrics> metrics);

  // The bytes of the file at `path`; NOT_FOUND when there is none.
  absl::StatusOr<std::shared_ptr<const AssetBlob>> Get(const std::string& path);

  ModelCacheStats stats() const { return cache_.stats(); }

 private:
  absl::StatusOr<std::shared_ptr<const AssetBlob>> Read(const std::string& path) const;

  const int64_t budget_;
  const std::shared_ptr<Metrics> metrics_;
  ModelCache<AssetBlob> cache_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_PLACES_ASSET_FILES_H_
