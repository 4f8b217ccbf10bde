// VersionStore: published model versions and the deployment manifest.
//
//   <store>/versions/<000007>/model.ckpt   θ (checkpoint) + replay memory M
//   <store>/versions/<000007>/version.json metadata (parent, metrics, ...)
//   <store>/optimizer.bin                  the Adam state of the newest
//                                          published version's training
//                                          (with UpdateOptions::carry_optimizer),
//                                          tagged with that version: one per
//                                          place, not one per version, since
//                                          an update only ever starts from the
//                                          deployed version. After a rollback
//                                          the tag differs and the next update
//                                          starts a fresh optimiser. Never read
//                                          by serving.
//   <store>/manifest.json                  deployed version and id counters
//
// A version is written into versions/.tmp-<n>/ (files fsync'd), renamed to
// versions/<n> and versions/ is fsync'd, so a version directory is complete
// or absent. The manifest is replaced atomically (temp file, fsync, rename).
// The deployed version changes only through WriteManifest, after the
// version it names is durable.
//
// Thread-safety: Write/Load/List are safe concurrently for different
// versions; the manifest has a single writer (the server serialises it).
#ifndef CLNERF_SERVER_VERSION_STORE_H_
#define CLNERF_SERVER_VERSION_STORE_H_

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/bake/baked_asset.h"
#include "core/field/ngp_model.h"
#include "core/continual/replay_memory.h"
#include "core/train/optimizer_state.h"

namespace clnerf {

struct VersionInfo {
  int64_t version = 0;
  int64_t parent = 0;  // 0 = none.
  int time_steps = 0;
  int64_t size_bytes = 0;   // Checkpoint size on disk (file bytes).
  int64_t model_bytes = 0;  // The model's parameter bytes (NgpModel::num_bytes()).
  int64_t replay_bytes = 0; // The replay memory as stored (cameras + 8-bit PNG buffer; 0 = not recorded).
  int64_t memory_bytes = 0; // What it holds in memory once loaded (NgpModel::resident_bytes(); 0 = not recorded).
  int64_t created_unix_ms = 0;
  std::string scan_id;  // The scan this version was trained on.
  // The job that trained it and the scan's name ("" in stores written before
  // they were recorded): start-up recovery restores that job's record as
  // DONE from here when a crash lost it (model_host.h).
  std::string job_id, scan_name;
  std::map<std::string, double> metrics;
  // The names of its scan's training frames, in the order their cameras were
  // recorded (the last time step's cameras in the replay memory); empty in
  // stores written before they were recorded.
  std::vector<std::string> frame_names;
  // Why this version cannot be used ("" = it can): its version.json is
  // missing or corrupt. List() reports such versions instead of failing, so
  // one bad version never stops the others from serving.
  std::string unavailable;
};

struct Manifest {
  int64_t deployed = 0;  // 0 = nothing deployed yet.
  int64_t next_version = 1;
  int64_t next_scan = 1;
  int64_t next_job = 1;
};

struct LoadedVersion {
  VersionInfo info;
  NgpModel model;
  ReplayMemory memory;
};

class VersionStore {
 public:
  // `clean_temps`: remove what interrupted writes left (false when other
  // replicas may be writing into the same store right now).
  static absl::StatusOr<std::unique_ptr<VersionStore>> Open(const std::string& root, bool clean_temps = true);

  // Writes version `info.version` durably; fills info.size_bytes,
  // info.model_bytes and info.replay_bytes.
  absl::StatusOr<VersionInfo> Write(const NgpModel& model, const ReplayMemory& memory, VersionInfo info);
  // Write()'s bytes into `dir`.
  absl::StatusOr<VersionInfo> WriteInto(const std::string& dir, const NgpModel& model, const ReplayMemory& memory,
                                        VersionInfo info);
  // Replaces the place's optimiser state with `state`, the training state of
  // version `version` (atomically), and removes the per-version copies older
  // builds kept.
  absl::Status WriteOptimizer(int64_t version, const OptimizerState& state);
  // NOT_FOUND for a version that does not exist.
  absl::StatusOr<LoadedVersion> Load(int64_t version) const;
  // The optimiser state of `version`'s training; null when the place's state
  // belongs to another version (a rollback, a crash before it was written),
  // or there is none (carry_optimizer off). Reads the per-version file of
  // stores written by older builds. DATA_LOSS when the file is corrupt.
  absl::StatusOr<std::shared_ptr<const OptimizerState>> LoadOptimizer(int64_t version) const;
  absl::StatusOr<VersionInfo> Info(int64_t version) const;
  // All versions, ascending. A version whose version.json cannot be read is
  // listed with only its number and `unavailable` set (the reason).
  absl::StatusOr<std::vector<VersionInfo>> List() const;

  // Deletes a version's folder (renamed aside first, so a crash leaves it
  // whole or gone). NOT_FOUND if it does not exist.
  absl::Status Remove(int64_t version);

  // Replicas (publisher.h): version `info.version` written durably as the
  // hidden directory versions/.staged-N-TAG, which List and Load ignore until
  // PromoteStaged renames it to versions/N once the publish is committed.
  absl::StatusOr<VersionInfo> WriteStaged(const NgpModel& model, const ReplayMemory& memory, VersionInfo info,
                                          const std::string& tag);
  // ALREADY_EXISTS if versions/N exists; NOT_FOUND if the staged one does not.
  absl::Status PromoteStaged(int64_t version, const std::string& tag);
  void RemoveStaged(int64_t version, const std::string& tag);
  // The tags of staged directories of `version` (normally none).
  std::vector<std::string> StagedTags(int64_t version) const;

  // Baked assets (issue 41; core/bake/baked_asset.h) beside a version's
  // checkpoint, one folder per time step:
  //   versions/<n>/baked/<t>/{manifest.json, index.bin.gz, atlas.bin.gz}
  // A derived cache: the latest time step is written when the version is
  // published, others on first request. Each folder is written whole
  // (WriteDirectoryAtomically): present means complete. ALREADY_EXISTS when
  // it is there already (another writer won); `staged_tag` non-empty writes
  // into that staged version instead (replicas, before promotion).
  absl::Status WriteBaked(int64_t version, int time_step, const BakedAsset& asset, const std::string& staged_tag = "");
  std::string BakedDir(int64_t version, int time_step) const;

  absl::StatusOr<Manifest> ReadManifest() const;  // Defaults if absent.
  absl::Status WriteManifest(const Manifest& manifest);

 private:
  VersionStore(std::string root, std::string dir) : root_(std::move(root)), dir_(std::move(dir)) {}
  std::string VersionDir(int64_t v) const;
  std::string root_, dir_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_VERSION_STORE_H_
