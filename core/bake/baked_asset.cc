#include "core/bake/baked_asset.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/io/durable_file.h"
#include "core/io/gzip.h"
#include "nlohmann/json.hpp"

namespace clnerf {
namespace {

constexpr char kManifest[] = "manifest.json";
constexpr char kIndexFile[] = "index.bin.gz";
constexpr char kAtlasFile[] = "atlas.bin.gz";
constexpr char kViewFile[] = "view.bin.gz";
// Limits that keep a hostile manifest from asking for absurd allocations:
// 2048 cells per axis, and an atlas within WebGL2's guaranteed 3-D texture
// size on every axis (2048 texels: 227 bricks).
constexpr int kMaxResolution = 2048;
constexpr int kMaxBricksPerAxis = 2048 / kBakeBrick;

nlohmann::json Vec(const Eigen::Vector3f& v) { return {v.x(), v.y(), v.z()}; }

absl::Status ReadVec(const nlohmann::json& j, const char* key, Eigen::Vector3f* v) {
  if (!j.contains(key) || !j[key].is_array() || j[key].size() != 3) {
    return absl::InvalidArgumentError(absl::StrCat("baked asset manifest: '", key, "' must be 3 numbers"));
  }
  for (int i = 0; i < 3; ++i) {
    if (!j[key][i].is_number()) return absl::InvalidArgumentError(absl::StrCat("baked asset manifest: bad '", key, "'"));
    (*v)[i] = j[key][i].get<float>();
  }
  return absl::OkStatus();
}

nlohmann::json ManifestJson(const BakedAsset& a) {
  nlohmann::json rot = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) rot.push_back(a.normalization.rotation(r, c));
  }
  nlohmann::json views = nlohmann::json::array();
  for (const Camera& c : a.views) {
    nlohmann::json m = nlohmann::json::array();
    for (int r = 0; r < 3; ++r) {
      for (int k = 0; k < 4; ++k) m.push_back(c.c2w(r, k));
    }
    const Intrinsics& in = c.intrinsics;
    views.push_back({{"c2w", m}, {"fx", in.fx}, {"fy", in.fy}, {"cx", in.cx}, {"cy", in.cy},
                     {"width", in.width}, {"height", in.height}});
  }
  nlohmann::json files = {{"index", kIndexFile}, {"atlas", kAtlasFile}};
  if (a.view_dependent()) files["view"] = kViewFile;
  const bool per_sample = a.view_term == BakedViewTerm::kPerSample;
  return {{"format", !a.view_dependent() ? kBakeFormat : per_sample ? kBakeFormatViewDependent : kBakeFormatViewAtMedian},
          {"view_dependence", !a.view_dependent() ? "none" : per_sample ? "linear" : "linear at the median sample"},
          {"views", views},
          {"kind", a.contracted ? "unbounded" : "bounded"},
          {"half_size", a.half_size},
          {"resolution", a.resolution},
          {"block", kBakeBlock},
          {"brick", kBakeBrick},
          {"near", a.near},
          {"step", a.step()},
          {"cell", a.cell()},
          {"density_code", "a = round(255 * sqrt(1 - exp(-sigma * cell)))"},
          {"center", Vec(a.normalization.center)},
          {"scale", a.normalization.scale},
          {"bound", a.normalization.bound},
          {"rotation", rot},
          {"background", Vec(a.background)},
          {"time_step", a.time_step},
          {"bricks", {a.bricks[0], a.bricks[1], a.bricks[2]}},
          {"num_bricks", a.num_bricks()},
          {"files", files}};
}

// Parses the manifest; *view_dependent says whether it names a view file.
absl::Status ParseManifest(const std::string& text, BakedAsset* a, bool* view_dependent) {
  nlohmann::json j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) return absl::InvalidArgumentError("baked asset manifest: not a JSON object");
  const int format = j.contains("format") && j["format"].is_number_integer() ? j["format"].get<int>() : -1;
  if (format != kBakeFormat && format != kBakeFormatViewDependent && format != kBakeFormatViewAtMedian) {
    return absl::FailedPreconditionError(absl::StrCat("baked asset manifest: format must be ", kBakeFormat, ", ",
                                                      kBakeFormatViewDependent, " or ", kBakeFormatViewAtMedian));
  }
  *view_dependent = format != kBakeFormat;
  a->view_term = format == kBakeFormatViewDependent ? BakedViewTerm::kPerSample : BakedViewTerm::kAtMedian;
  try {
    a->contracted = j.at("kind").get<std::string>() == "unbounded";
    a->half_size = j.at("half_size").get<float>();
    a->resolution = j.at("resolution").get<int>();
    a->near = j.at("near").get<float>();
    a->normalization.scale = j.at("scale").get<float>();
    a->normalization.bound = j.at("bound").get<float>();
    a->time_step = j.at("time_step").get<int>();
    // The step in cells (0.5 before format 3; absent in none of them).
    a->step_cells = 0.5f;
    if (j.contains("step") && a->resolution > 0 && a->half_size > 0.0f) {
      const float ratio = j.at("step").get<float>() * float(a->resolution) / (2.0f * a->half_size);
      const float snapped = RoundBakedStep(ratio);
      a->step_cells = std::abs(ratio - snapped) < 1e-3f ? snapped : ratio;
    }
    const auto& rot = j.at("rotation");
    if (!rot.is_array() || rot.size() != 9) return absl::InvalidArgumentError("baked asset manifest: bad rotation");
    for (int k = 0; k < 9; ++k) a->normalization.rotation(k / 3, k % 3) = rot[k].get<float>();
    const auto& b = j.at("bricks");
    if (!b.is_array() || b.size() != 3) return absl::InvalidArgumentError("baked asset manifest: bad bricks");
    for (int k = 0; k < 3; ++k) a->bricks[k] = b[k].get<int>();
    if (j.contains("views")) {
      for (const auto& v : j.at("views")) {
        Camera c;
        const auto& m = v.at("c2w");
        if (!m.is_array() || m.size() != 12) return absl::InvalidArgumentError("baked asset manifest: bad view");
        for (int k = 0; k < 12; ++k) c.c2w(k / 4, k % 4) = m[k].get<float>();
        c.intrinsics.fx = v.at("fx").get<float>();
        c.intrinsics.fy = v.at("fy").get<float>();
        c.intrinsics.cx = v.at("cx").get<float>();
        c.intrinsics.cy = v.at("cy").get<float>();
        c.intrinsics.width = v.at("width").get<int>();
        c.intrinsics.height = v.at("height").get<int>();
        if (!ValidateCamera(c).ok() || a->views.size() >= 64) {
          return absl::InvalidArgumentError("baked asset manifest: bad view");
        }
        a->views.push_back(c);
      }
    }
  } catch (const nlohmann::json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("baked asset manifest: ", e.what()));
  }
  if (absl::Status s = ReadVec(j, "center", &a->normalization.center); !s.ok()) return s;
  return ReadVec(j, "background", &a->background);
}

// Checks the scalar fields, before any array is sized from them.
absl::Status ValidateShape(const BakedAsset& a) {
  if (!(a.half_size > 0.0f) || !std::isfinite(a.half_size) || !(a.near >= 0.0f) || !std::isfinite(a.near)) {
    return absl::InvalidArgumentError("baked asset: bad half size or near plane");
  }
  if (a.resolution < kBakeBlock || a.resolution > kMaxResolution || a.resolution % kBakeBlock != 0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("baked asset: resolution %d must be a multiple of %d in [%d, %d]", a.resolution, kBakeBlock,
                        kBakeBlock, kMaxResolution));
  }
  for (int k = 0; k < 3; ++k) {
    if (a.bricks[k] < 1 || a.bricks[k] > kMaxBricksPerAxis) {
      return absl::InvalidArgumentError(absl::StrFormat("baked asset: %d bricks on atlas axis %d", a.bricks[k], k));
    }
  }
  if (!IsBakedStep(a.step_cells)) {  // Also what a manifest's "step" must give.
    return absl::InvalidArgumentError(
        absl::StrFormat("baked asset: step of %g cells (must be a multiple of 1/32 in [0.5, 2])", a.step_cells));
  }
  if (!(a.normalization.scale > 0.0f) || !a.normalization.center.allFinite() ||
      !a.normalization.rotation.allFinite() || !a.background.allFinite() || a.time_step < 0) {
    return absl::InvalidArgumentError("baked asset: bad normalisation, background or time step");
  }
  return absl::OkStatus();
}

}  // namespace

int BakedAsset::num_bricks() const {
  int n = 0;
  for (uint32_t e : index) n += e != 0;
  return n;
}

absl::Status BakedAsset::Validate() const {
  if (absl::Status s = ValidateShape(*this); !s.ok()) return s;
  const size_t nb = size_t(blocks_per_axis());
  if (index.size() != nb * nb * nb) {
    return absl::InvalidArgumentError(absl::StrFormat("baked asset: index has %zu entries, expected %zu",
                                                      index.size(), nb * nb * nb));
  }
  const std::array<int, 3> t = atlas_texels();
  const size_t texels = size_t(t[0]) * t[1] * t[2];
  if (atlas.size() != 4 * texels) {
    return absl::InvalidArgumentError(
        absl::StrFormat("baked asset: atlas has %zu bytes, expected %zu", atlas.size(), 4 * texels));
  }
  if (!view.empty() && view.size() != 3 * atlas.size()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("baked asset: view term has %zu bytes, expected %zu", view.size(), 3 * atlas.size()));
  }
  if (!block_distance.empty() && block_distance.size() != index.size()) {
    return absl::InvalidArgumentError("baked asset: block distances do not match the index");
  }
  const uint32_t capacity = uint32_t(bricks[0]) * bricks[1] * bricks[2];
  for (uint32_t e : index) {
    if (e > capacity) return absl::InvalidArgumentError("baked asset: index names a brick outside the atlas");
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<std::pair<std::string, std::string>>> SerializeBakedAsset(const BakedAsset& asset) {
  if (absl::Status s = asset.Validate(); !s.ok()) return s;
  std::string index(asset.index.size() * 4, '\0');
  for (size_t i = 0; i < asset.index.size(); ++i) {
    const uint32_t v = asset.index[i];  // Little-endian whatever the host.
    for (int b = 0; b < 4; ++b) index[4 * i + size_t(b)] = char((v >> (8 * b)) & 0xff);
  }
  absl::StatusOr<std::string> index_gz = GzipCompress(index);
  if (!index_gz.ok()) return index_gz.status();
  absl::StatusOr<std::string> atlas_gz = GzipCompress(
      std::string_view(reinterpret_cast<const char*>(asset.atlas.data()), asset.atlas.size()));
  if (!atlas_gz.ok()) return atlas_gz.status();
  std::vector<std::pair<std::string, std::string>> files;
  files.emplace_back(kManifest, ManifestJson(asset).dump(1));
  files.emplace_back(kIndexFile, std::move(*index_gz));
  files.emplace_back(kAtlasFile, std::move(*atlas_gz));
  if (asset.view_dependent()) {
    absl::StatusOr<std::string> view_gz = GzipCompress(
        std::string_view(reinterpret_cast<const char*>(asset.view.data()), asset.view.size()));
    if (!view_gz.ok()) return view_gz.status();
    files.emplace_back(kViewFile, std::move(*view_gz));
  }
  return files;
}

absl::Status SaveBakedAsset(const BakedAsset& asset, const std::string& dir) {
  absl::StatusOr<std::vector<std::pair<std::string, std::string>>> files = SerializeBakedAsset(asset);
  if (!files.ok()) return files.status();
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return absl::PermissionDeniedError(absl::StrCat("cannot create ", dir, ": ", ec.message()));
  // The manifest last: a reader that finds it finds the arrays it names.
  for (size_t k = 1; k <= files->size(); ++k) {
    const auto& [name, bytes] = (*files)[k % files->size()];  // manifest.json (entry 0) last.
    if (absl::Status s = AtomicWriteFile(dir + "/" + name, bytes); !s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::StatusOr<uint64_t> BakedAssetBytes(const std::string& dir) {
  uint64_t n = 0;
  for (const char* name : {kManifest, kIndexFile, kAtlasFile, kViewFile}) {
    std::error_code ec;
    const bool optional = std::string_view(name) == kViewFile;  // Formats 2 and 3 only.
    if (optional && !std::filesystem::exists(std::filesystem::path(dir) / name, ec)) continue;
    const uintmax_t size = std::filesystem::file_size(std::filesystem::path(dir) / name, ec);
    if (ec) return absl::NotFoundError(absl::StrCat("baked asset: ", dir, "/", name, ": ", ec.message()));
    n += size;
  }
  return n;
}

bool IsBakedAssetFileName(const std::string& name) {
  return name == kManifest || name == kIndexFile || name == kAtlasFile || name == kViewFile;
}

bool IsBakedAssetDir(const std::string& dir) {
  std::error_code ec;
  return std::filesystem::is_regular_file(std::filesystem::path(dir) / kManifest, ec);
}

absl::StatusOr<BakedAsset> LoadBakedAsset(const std::string& dir) {
  absl::StatusOr<std::string> manifest = ReadFileToString(dir + "/" + kManifest, "baked asset manifest");
  if (!manifest.ok()) return manifest.status();
  BakedAsset a;
  bool view_dependent = false;
  if (absl::Status s = ParseManifest(*manifest, &a, &view_dependent); !s.ok()) return s;
  if (absl::Status s = ValidateShape(a); !s.ok()) return s;
  const size_t nb = size_t(a.blocks_per_axis());
  const std::array<int, 3> t = a.atlas_texels();
  const size_t index_bytes = nb * nb * nb * 4, atlas_bytes = 4 * size_t(t[0]) * t[1] * t[2];
  absl::StatusOr<std::string> index_gz = ReadFileToString(dir + "/" + kIndexFile, "baked asset index");
  if (!index_gz.ok()) return index_gz.status();
  absl::StatusOr<std::string> index = GzipDecompress(*index_gz, index_bytes);
  if (!index.ok()) return absl::DataLossError(absl::StrCat("baked asset index: ", index.status().message()));
  absl::StatusOr<std::string> atlas_gz = ReadFileToString(dir + "/" + kAtlasFile, "baked asset atlas");
  if (!atlas_gz.ok()) return atlas_gz.status();
  absl::StatusOr<std::string> atlas = GzipDecompress(*atlas_gz, atlas_bytes);
  if (!atlas.ok()) return absl::DataLossError(absl::StrCat("baked asset atlas: ", atlas.status().message()));
  if (index->size() != index_bytes || atlas->size() != atlas_bytes) {
    return absl::DataLossError("baked asset: the arrays do not match the manifest's sizes");
  }
  a.index.resize(nb * nb * nb);
  for (size_t i = 0; i < a.index.size(); ++i) {
    uint32_t v = 0;
    for (int b = 0; b < 4; ++b) v |= uint32_t(uint8_t((*index)[4 * i + size_t(b)])) << (8 * b);
    a.index[i] = v;
  }
  a.atlas.assign(atlas->begin(), atlas->end());
  if (view_dependent) {
    absl::StatusOr<std::string> view_gz = ReadFileToString(dir + "/" + kViewFile, "baked asset view term");
    if (!view_gz.ok()) return view_gz.status();
    absl::StatusOr<std::string> view = GzipDecompress(*view_gz, 3 * atlas_bytes);
    if (!view.ok()) return absl::DataLossError(absl::StrCat("baked asset view term: ", view.status().message()));
    if (view->size() != 3 * atlas_bytes) return absl::DataLossError("baked asset: the view term does not match");
    a.view.assign(view->begin(), view->end());
  }
  if (absl::Status s = a.Validate(); !s.ok()) return s;
  ComputeBlockDistances(&a);
  return a;
}

void ComputeBlockDistances(BakedAsset* asset) {
  const int nb = asset->blocks_per_axis();
  const size_t n = size_t(nb) * nb * nb;
  std::vector<uint8_t>& dist = asset->block_distance;
  dist.assign(n, 255);
  asset->occupied_lo = {nb, nb, nb};
  asset->occupied_hi = {-1, -1, -1};
  for (size_t i = 0; i < n && i < asset->index.size(); ++i) {
    if (asset->index[i] == 0) continue;
    dist[i] = 0;
    const int b[3] = {int(i % size_t(nb)), int((i / size_t(nb)) % size_t(nb)), int(i / (size_t(nb) * nb))};
    for (int k = 0; k < 3; ++k) {
      asset->occupied_lo[size_t(k)] = std::min(asset->occupied_lo[size_t(k)], b[k]);
      asset->occupied_hi[size_t(k)] = std::max(asset->occupied_hi[size_t(k)], b[k]);
    }
  }
  // Forward then backward raster passes, each taking the minimum over the
  // whole 26-neighbourhood plus one: exact for the chessboard metric.
  for (int pass = 0; pass < 2; ++pass) {
    for (size_t s = 0; s < n; ++s) {
      const size_t i = pass == 0 ? s : n - 1 - s;
      if (dist[i] == 0) continue;
      const int x = int(i % size_t(nb)), y = int((i / size_t(nb)) % size_t(nb)), z = int(i / (size_t(nb) * nb));
      int best = dist[i];
      for (int dz = std::max(z - 1, 0); dz <= std::min(z + 1, nb - 1); ++dz) {
        for (int dy = std::max(y - 1, 0); dy <= std::min(y + 1, nb - 1); ++dy) {
          for (int dx = std::max(x - 1, 0); dx <= std::min(x + 1, nb - 1); ++dx) {
            best = std::min(best, int(dist[size_t(dx) + size_t(nb) * (size_t(dy) + size_t(nb) * size_t(dz))]) + 1);
          }
        }
      }
      dist[i] = uint8_t(std::min(best, 255));
    }
  }
}

Camera BakedModelCamera(const BakedAsset& asset, const Camera& world) {
  Camera c = world;
  c.c2w.leftCols<3>() = asset.normalization.rotation * world.c2w.leftCols<3>();
  c.c2w.col(3) = asset.normalization.ToModel(world.c2w.col(3));
  return c;
}

}  // namespace clnerf
