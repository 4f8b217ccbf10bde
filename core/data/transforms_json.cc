#include "core/data/transforms_json.h"

#include <cstdint>
#include <fstream>
#include <limits>

#include "absl/strings/str_cat.h"

namespace clnerf {

namespace fs = std::filesystem;
using nlohmann::json;

absl::Status Annotate(const absl::Status& s, const std::string& ctx) {
  return absl::Status(s.code(), absl::StrCat(ctx, ": ", s.message()));
}

absl::StatusOr<json> ReadJson(const fs::path& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open ", path.string()));
  try {
    json doc = json::parse(in);
    if (!doc.is_object() || !doc.contains("frames") || !doc["frames"].is_array()) {
      return absl::InvalidArgumentError(
          absl::StrCat(path.string(), ": expected an object with an array field 'frames'"));
    }
    for (size_t i = 0; i < doc["frames"].size(); ++i) {
      const json& f = doc["frames"][i];
      if (!f.is_object() || !f.contains("file_path") || !f["file_path"].is_string()) {
        return absl::InvalidArgumentError(
            absl::StrCat(path.string(), ": frame ", i, ": missing string field 'file_path'"));
      }
    }
    return doc;
  } catch (const json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(path.string(), ": malformed json: ", e.what()));
  }
}

absl::StatusOr<Pose> ParsePose(const json& frame, const std::string& ctx) {
  const auto bad = [&] {
    return absl::InvalidArgumentError(
        absl::StrCat(ctx, ": field 'transform_matrix' must be a 4x4 or 3x4 array of numbers"));
  };
  if (!frame.contains("transform_matrix")) return bad();
  const json& m = frame["transform_matrix"];
  if (!m.is_array() || (m.size() != 3 && m.size() != 4)) return bad();
  Pose pose;
  for (int r = 0; r < 3; ++r) {
    if (!m[r].is_array() || m[r].size() != 4) return bad();
    for (int c = 0; c < 4; ++c) {
      if (!m[r][c].is_number()) return bad();
      pose(r, c) = m[r][c].get<float>();
    }
  }
  return pose;
}

absl::StatusOr<int> ParseTimeStep(const json& frame, const std::string& ctx) {
  if (!frame.contains("time_step")) return 0;
  const json& t = frame["time_step"];
  if (!t.is_number_integer() || t.get<int64_t>() < 0 ||
      t.get<int64_t>() > std::numeric_limits<int>::max()) {
    return absl::InvalidArgumentError(
        absl::StrCat(ctx, ": field 'time_step' must be a non-negative integer"));
  }
  return t.get<int>();
}

fs::path ResolveImagePath(const fs::path& dir, const std::string& file_path) {
  const fs::path p = dir / file_path;
  std::error_code ec;
  if (fs::is_regular_file(p, ec)) return p;
  fs::path png = p;
  png += ".png";
  return fs::is_regular_file(png, ec) ? png : p;
}

}  // namespace clnerf
