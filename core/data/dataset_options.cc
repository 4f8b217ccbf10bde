#include "core/data/dataset_options.h"

#include <filesystem>

#include "absl/strings/str_cat.h"

namespace clnerf {

absl::Status DatasetOptions::Validate() const {
  if (!(downscale >= 1.0f && downscale <= 64.0f)) {
    return absl::InvalidArgumentError(
        absl::StrCat("DatasetOptions.downscale must be in [1, 64], got ", downscale));
  }
  if (test_every < 0) return absl::InvalidArgumentError("DatasetOptions.test_every must be >= 0");
  if (max_images_per_split < 0) {
    return absl::InvalidArgumentError("DatasetOptions.max_images_per_split must be >= 0");
  }
  return absl::OkStatus();
}

absl::Status CheckDatasetDir(const std::string& dir, const DatasetOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) {
    return absl::NotFoundError(absl::StrCat("dataset directory not found: ", dir));
  }
  return absl::OkStatus();
}

std::string DatasetName(const std::string& dir) {
  const std::filesystem::path norm = std::filesystem::path(dir).lexically_normal();
  return norm.has_filename() ? norm.filename().string() : norm.parent_path().filename().string();
}

}  // namespace clnerf
