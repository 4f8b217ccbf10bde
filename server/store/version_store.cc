#include "server/store/version_store.h"

#include <algorithm>
#include <filesystem>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/io/byte_io.h"
#include "core/io/checkpoint.h"
#include "core/io/durable_file.h"
#include "nlohmann/json.hpp"

namespace clnerf {

namespace fs = std::filesystem;

namespace {

constexpr char kMemorySection[] = "replay_memory";
constexpr char kOptimizerFile[] = "optimizer.bin";
constexpr char kOptimizerMagic[] = "CLNOPT01";  // 8 bytes, then the version (i64) it belongs to.

// version.json: "file_bytes" (the checkpoint on disk), "model_bytes" (the
// parameters) and "replay_bytes" (the replay memory as stored) are reported as by `clnerf train --json`; "size_bytes" repeats
// file_bytes for readers of the original layout.
nlohmann::json InfoToJson(const VersionInfo& v) {
  return {{"version", v.version},       {"parent", v.parent},
          {"time_steps", v.time_steps}, {"size_bytes", v.size_bytes},
          {"file_bytes", v.size_bytes}, {"model_bytes", v.model_bytes}, {"replay_bytes", v.replay_bytes},
          {"memory_bytes", v.memory_bytes},
          {"created_unix_ms", v.created_unix_ms}, {"scan_id", v.scan_id},
          {"job_id", v.job_id},         {"scan_name", v.scan_name},
          {"metrics", v.metrics},       {"frame_names", v.frame_names}};
}

absl::StatusOr<VersionInfo> InfoFromJson(const std::string& text, const std::string& source) {
  try {
    const nlohmann::json j = nlohmann::json::parse(text);
    VersionInfo v;
    v.version = j.at("version");
    v.parent = j.at("parent");
    v.time_steps = j.at("time_steps");
    v.size_bytes = j.at("size_bytes");
    v.model_bytes = j.value("model_bytes", int64_t(0));  // Absent in older stores.
    v.replay_bytes = j.value("replay_bytes", int64_t(0));
    v.memory_bytes = j.value("memory_bytes", int64_t(0));
    v.created_unix_ms = j.at("created_unix_ms");
    v.scan_id = j.at("scan_id");
    v.job_id = j.value("job_id", std::string());  // Absent in older stores.
    v.scan_name = j.value("scan_name", std::string());
    v.metrics = j.at("metrics").get<std::map<std::string, double>>();
    v.frame_names = j.value("frame_names", std::vector<std::string>());
    return v;
  } catch (const std::exception& e) {
    return absl::DataLossError(absl::StrCat("corrupt ", source, ": ", e.what()));
  }
}

}  // namespace

absl::StatusOr<std::unique_ptr<VersionStore>> VersionStore::Open(const std::string& root, bool clean_temps) {
  const std::string dir = (fs::path(root) / "versions").string();
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create '", dir, "': ", ec.message()));
  if (clean_temps) RemoveTempEntries(dir);
  return std::unique_ptr<VersionStore>(new VersionStore(root, dir));
}

std::string VersionStore::VersionDir(int64_t v) const {
  return (fs::path(dir_) / absl::StrFormat("%06d", v)).string();
}

namespace {
std::string StagedName(int64_t version, const std::string& tag) {
  return absl::StrFormat(".staged-%06d-%s", version, tag);
}
}  // namespace

std::string VersionStore::BakedDir(int64_t version, int time_step) const {
  return (fs::path(VersionDir(version)) / "baked" / std::to_string(time_step)).string();
}

absl::Status VersionStore::WriteBaked(int64_t version, int time_step, const BakedAsset& asset,
                                      const std::string& staged_tag) {
  absl::StatusOr<std::vector<std::pair<std::string, std::string>>> files = SerializeBakedAsset(asset);
  if (!files.ok()) return files.status();
  const fs::path parent = (staged_tag.empty() ? fs::path(VersionDir(version))
                                              : fs::path(dir_) / StagedName(version, staged_tag)) / "baked";
  std::error_code ec;
  if (!fs::exists(parent.parent_path(), ec)) return absl::NotFoundError(absl::StrCat("version ", version, " does not exist"));
  fs::create_directories(parent, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create ", parent.string(), ": ", ec.message()));
  std::vector<std::pair<std::string, std::string_view>> views;
  for (const auto& [name, bytes] : *files) views.emplace_back(name, bytes);
  return WriteDirectoryAtomically((parent / std::to_string(time_step)).string(), views);
}

absl::StatusOr<VersionInfo> VersionStore::Write(const NgpModel& model, const ReplayMemory& memory,
                                                VersionInfo info) {
  return WriteInto(VersionDir(info.version), model, memory, std::move(info));
}

absl::StatusOr<VersionInfo> VersionStore::WriteStaged(const NgpModel& model, const ReplayMemory& memory,
                                                      VersionInfo info, const std::string& tag) {
  const std::string dir = (fs::path(dir_) / StagedName(info.version, tag)).string();
  return WriteInto(dir, model, memory, std::move(info));
}

absl::Status VersionStore::PromoteStaged(int64_t version, const std::string& tag) {
  const fs::path staged = fs::path(dir_) / StagedName(version, tag);
  std::error_code ec;
  if (!fs::exists(staged, ec)) return absl::NotFoundError(absl::StrCat("no staged version ", version, " '", tag, "'"));
  if (fs::exists(VersionDir(version), ec)) return absl::AlreadyExistsError(absl::StrCat("version ", version, " exists"));
  fs::rename(staged, VersionDir(version), ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot promote staged version ", version, ": ", ec.message()));
  return SyncDirectory(dir_);
}

void VersionStore::RemoveStaged(int64_t version, const std::string& tag) {
  std::error_code ec;
  fs::remove_all(fs::path(dir_) / StagedName(version, tag), ec);
}

std::vector<std::string> VersionStore::StagedTags(int64_t version) const {
  const std::string prefix = StagedName(version, "");
  std::vector<std::string> tags;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir_, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind(prefix, 0) == 0) tags.push_back(name.substr(prefix.size()));
  }
  return tags;
}

absl::StatusOr<VersionInfo> VersionStore::WriteInto(const std::string& dir, const NgpModel& model,
                                                    const ReplayMemory& memory, VersionInfo info) {
  CheckpointExtras extras;
  extras.metadata["version"] = absl::StrCat(info.version);
  extras.metadata["parent"] = absl::StrCat(info.parent);
  std::string replay = memory.Serialize();
  info.replay_bytes = int64_t(replay.size());
  extras.sections.emplace_back(kMemorySection, std::move(replay));
  absl::StatusOr<std::string> bytes = SerializeCheckpoint(model, extras);
  if (!bytes.ok()) return bytes.status();
  info.size_bytes = int64_t(bytes->size());
  info.model_bytes = int64_t(model.num_bytes());
  info.memory_bytes = int64_t(model.resident_bytes());
  const std::string json = InfoToJson(info).dump(1);
  std::vector<std::pair<std::string, std::string_view>> files = {{"model.ckpt", *bytes}, {"version.json", json}};
  absl::Status s = WriteDirectoryAtomically(dir, files);
  if (!s.ok()) return absl::Status(s.code(), absl::StrCat("cannot publish version ", info.version, ": ", s.message()));
  return info;
}

absl::StatusOr<VersionInfo> VersionStore::Info(int64_t version) const {
  const std::string path = VersionDir(version) + "/version.json";
  absl::StatusOr<std::string> text = ReadFileToString(path, "version");
  if (!text.ok()) {
    if (absl::IsNotFound(text.status())) return absl::NotFoundError(absl::StrCat("version ", version, " does not exist"));
    return text.status();
  }
  return InfoFromJson(*text, path);
}

absl::StatusOr<LoadedVersion> VersionStore::Load(int64_t version) const {
  absl::StatusOr<VersionInfo> info = Info(version);
  if (!info.ok()) return info.status();
  absl::StatusOr<LoadedCheckpoint> ck = LoadCheckpoint(VersionDir(version) + "/model.ckpt");
  if (!ck.ok()) return ck.status();
  const std::string* mem = ck->extras.FindSection(kMemorySection);
  if (mem == nullptr) return absl::DataLossError(absl::StrCat("version ", version, " has no replay memory"));
  // One rule for stored data: whatever check it fails (corrupt bytes, a
  // format this build does not read, a memory that does not belong to its
  // model), a stored version that cannot be used is DATA_LOSS.
  absl::StatusOr<ReplayMemory> memory = ReplayMemory::Deserialize(*mem);
  if (!memory.ok()) {
    return absl::DataLossError(absl::StrCat("version ", version, ": ", memory.status().message()));
  }
  const int max_step = memory->MaxTimeStep();
  if (max_step >= 0 && max_step != ck->model.num_time_steps() - 1) {
    return absl::DataLossError(absl::StrCat("version ", version, ": its replay memory does not match its model (cameras "
                                            "reach time step ", max_step, ", the model has ",
                                            ck->model.num_time_steps(), " time steps)"));
  }
  return LoadedVersion{*std::move(info), std::move(ck->model), *std::move(memory)};
}

absl::Status VersionStore::WriteOptimizer(int64_t version, const OptimizerState& state) {
  std::string bytes(kOptimizerMagic, 8);
  ByteWriter w(&bytes);
  w.Put(int64_t(version));
  bytes += state.Serialize();
  if (absl::Status s = AtomicWriteFile((fs::path(root_) / kOptimizerFile).string(), bytes); !s.ok()) return s;
  // Stores written before the state moved out of the versions held one per
  // version: only this one is ever read again.
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir_, ec)) fs::remove(e.path() / kOptimizerFile, ec);
  return absl::OkStatus();
}

absl::StatusOr<std::shared_ptr<const OptimizerState>> VersionStore::LoadOptimizer(int64_t version) const {
  std::error_code ec;
  std::string path = (fs::path(root_) / kOptimizerFile).string();
  bool tagged = true;
  if (!fs::exists(path, ec)) {  // A store written by an older build: the state inside the version.
    path = VersionDir(version) + "/" + kOptimizerFile;
    tagged = false;
    if (!fs::exists(path, ec)) return std::shared_ptr<const OptimizerState>();
  }
  absl::StatusOr<std::string> bytes = ReadFileToString(path, "optimizer state");
  if (!bytes.ok()) return bytes.status();
  std::string_view payload = *bytes;
  if (tagged) {
    ByteReader r(payload);
    std::string_view magic;
    int64_t of = 0;
    if (!r.Bytes(8, &magic) || magic != std::string_view(kOptimizerMagic, 8) || !r.Get(&of)) {
      return absl::DataLossError("the place's optimizer state is corrupt (bad header)");
    }
    if (of != version) return std::shared_ptr<const OptimizerState>();  // Another version's (e.g. after a rollback).
    payload.remove_prefix(16);
  }
  absl::StatusOr<OptimizerState> s = OptimizerState::Deserialize(std::string(payload));
  if (!s.ok()) return absl::DataLossError(absl::StrCat("version ", version, ": ", s.status().message()));
  return std::make_shared<const OptimizerState>(*std::move(s));
}

absl::StatusOr<std::vector<VersionInfo>> VersionStore::List() const {
  std::vector<VersionInfo> out;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir_, ec)) {
    int64_t v;
    if (!e.is_directory() || !absl::SimpleAtoi(e.path().filename().string(), &v)) continue;
    absl::StatusOr<VersionInfo> info = Info(v);
    if (!info.ok()) {
      // Isolated to this version, like a corrupt checkpoint: listed with the
      // reason, and every other version keeps serving.
      VersionInfo bad;
      bad.version = v;
      bad.unavailable = std::string(info.status().message());
      out.push_back(std::move(bad));
      continue;
    }
    out.push_back(*std::move(info));
  }
  if (ec) return absl::InternalError(absl::StrCat("cannot list '", dir_, "': ", ec.message()));
  std::sort(out.begin(), out.end(), [](const VersionInfo& a, const VersionInfo& b) { return a.version < b.version; });
  return out;
}

absl::Status VersionStore::Remove(int64_t version) {
  const std::string dir = VersionDir(version);
  const std::string aside = (fs::path(dir_) / absl::StrFormat(".tmp-del-%06d", version)).string();
  std::error_code ec;
  if (!fs::exists(dir, ec)) return absl::NotFoundError(absl::StrCat("version ", version, " does not exist"));
  fs::rename(dir, aside, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot remove version ", version, ": ", ec.message()));
  if (absl::Status s = SyncDirectory(dir_); !s.ok()) return s;
  fs::remove_all(aside, ec);
  return absl::OkStatus();
}

absl::StatusOr<Manifest> VersionStore::ReadManifest() const {
  const std::string path = (fs::path(root_) / "manifest.json").string();
  absl::StatusOr<std::string> text = ReadFileToString(path, "manifest");
  if (absl::IsNotFound(text.status())) return Manifest{};
  if (!text.ok()) return text.status();
  try {
    const nlohmann::json j = nlohmann::json::parse(*text);
    Manifest m;
    m.deployed = j.at("deployed");
    m.next_version = j.at("next_version");
    m.next_scan = j.at("next_scan");
    m.next_job = j.at("next_job");
    return m;
  } catch (const std::exception& e) {
    return absl::DataLossError(absl::StrCat("corrupt ", path, ": ", e.what()));
  }
}

absl::Status VersionStore::WriteManifest(const Manifest& m) {
  const nlohmann::json j = {{"deployed", m.deployed},   {"next_version", m.next_version},
                            {"next_scan", m.next_scan}, {"next_job", m.next_job}};
  return AtomicWriteFile((fs::path(root_) / "manifest.json").string(), j.dump(1));
}

}  // namespace clnerf
