#include "server/places/asset_files.h"

#include <sys/stat.h>

#include <functional>
#include <utility>

#include "absl/strings/str_cat.h"
#include "core/io/durable_file.h"

namespace clnerf {

AssetFiles::AssetFiles(int64_t budget_bytes, std::shared_ptr<Metrics> metrics)
    : budget_(budget_bytes),
      metrics_(std::move(metrics)),
      cache_(budget_bytes, [](const AssetBlob& b) { return int64_t(b.bytes.size() + b.digest.size()); }) {}

absl::StatusOr<std::shared_ptr<const AssetBlob>> AssetFiles::Read(const std::string& path) const {
  absl::StatusOr<std::string> bytes = ReadFileToString(path, "baked asset file");
  if (!bytes.ok()) return bytes.status();
  auto blob = std::make_shared<AssetBlob>();
  blob->digest = absl::StrCat(bytes->size(), "-", absl::Hex(std::hash<std::string>()(*bytes)));
  blob->bytes = *std::move(bytes);
  if (metrics_) metrics_->AssetFileRead(int64_t(blob->bytes.size()));
  return std::shared_ptr<const AssetBlob>(std::move(blob));
}

absl::StatusOr<std::shared_ptr<const AssetBlob>> AssetFiles::Get(const std::string& path) {
  if (budget_ <= 0) return Read(path);
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) return Read(path);  // Read says why (NOT_FOUND, ...).
  const std::string key =
      absl::StrCat(path, "|", int64_t(st.st_size), "|", int64_t(st.st_mtim.tv_sec), ".", int64_t(st.st_mtim.tv_nsec));
  return cache_.GetOrLoad(key, [&] { return Read(path); });
}

}  // namespace clnerf
