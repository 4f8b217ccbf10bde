// Checkpoint: a versioned, self-checking binary file format for NgpModel.
//
// A checkpoint holds everything needed to rebuild a model bit for bit: every
// field of the model options, the normalisation, scene kind, background, the
// number of time steps, the three parameter blocks, the occupancy grid state,
// plus caller-defined extras (a string metadata map and named opaque binary
// sections, e.g. for the continual-learning replay memory). A model loaded
// from a checkpoint renders exactly the same pixels as the one that was saved.
//
// File layout (all integers and floats little-endian):
//
//   offset 0   char[8]  magic "CLNERFCK"
//   offset 8   uint32   format version (kCheckpointFormatVersion)
//   offset 12  uint64   total file size in bytes, including this header and
//                       the trailing checksum
//   offset 20  sections, each: uint32 tag (four ASCII characters, first
//              character in the lowest byte) | uint64 payload length | payload
//   end - 4    uint32   CRC-32 (IEEE 802.3 / zlib polynomial) of every byte
//                       before it
//
// The magic and the version stay at these offsets in every future version, so
// any reader can tell "not a checkpoint" from "a newer checkpoint". The whole
// file is verified (size, then checksum) before any section is interpreted,
// and every length is checked against the bytes that remain before anything is
// allocated, so corrupt or hostile input yields an error, never a crash or an
// absurd allocation.
//
// Unknown sections follow the PNG convention: a tag whose first character is
// an upper-case letter is critical (it may change how the model must be
// interpreted) and a reader that does not know it rejects the file with
// FAILED_PRECONDITION; a tag whose first character is lower case is ancillary
// and is skipped. Skipping is safe only because the checksum has already
// vouched for the integrity of the whole file and ancillary data, by
// definition, does not affect the model. Version 1 writes only critical
// sections; adding a field to an options struct means adding a new section
// (or bumping the version), never changing the payload of an existing one.
//
// Errors: NOT_FOUND (missing file), INVALID_ARGUMENT (not a clnerf checkpoint:
// bad magic), FAILED_PRECONDITION (unsupported format version or unknown
// critical section), DATA_LOSS (truncation, checksum mismatch, or content that
// is internally inconsistent), other codes from the OS for I/O failures.
//
// Thread safety: all functions are free functions without shared state and
// may be called concurrently. Saving reads the model through a const
// reference, so the model must not be mutated while it is being saved.
// Concurrent saves to the same path from different threads or processes are
// safe: each writes its own temporary file and the last rename wins.
#ifndef CLNERF_CORE_CHECKPOINT_H_
#define CLNERF_CORE_CHECKPOINT_H_

#include <cstddef>
#include <cstdint>
#include <map>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/ngp_model.h"

namespace clnerf {

// The format version this build writes, and the newest it reads.
inline constexpr uint32_t kCheckpointFormatVersion = 1;
// The eight magic bytes at the start of every checkpoint.
inline constexpr char kCheckpointMagic[] = "CLNERFCK";  // 8 chars + NUL.

// Caller-defined data stored alongside the model. The format does not
// interpret any of it; both members round-trip exactly (order and duplicate
// section names included).
struct CheckpointExtras {
  // Free-form metadata, e.g. "created_at", "parent_version", or training
  // statistics as JSON text.
  std::map<std::string, std::string> metadata;
  // Named opaque binary sections (e.g. the replay memory), in order.
  std::vector<std::pair<std::string, std::string>> sections;

  // The data of the first section named `name`, or nullptr if there is none.
  const std::string* FindSection(std::string_view name) const;

  bool operator==(const CheckpointExtras&) const = default;
};

struct LoadedCheckpoint {
  NgpModel model;
  CheckpointExtras extras;
  size_t num_bytes = 0;  // Size of the serialized checkpoint.
  uint32_t format_version = 0;
};

// Encodes `model` and `extras` as a checkpoint in memory. FAILED_PRECONDITION
// if the model is internally inconsistent (e.g. a parameter block whose size
// does not match the options).
absl::StatusOr<std::string> SerializeCheckpoint(const NgpModel& model,
                                                const CheckpointExtras& extras = {});

// Decodes a checkpoint held in memory. `source_name` is only used in error
// messages (e.g. the file path).
absl::StatusOr<LoadedCheckpoint> DeserializeCheckpoint(std::string_view bytes,
                                                       std::string_view source_name = "<memory>");

// Atomically writes a checkpoint to `path`: the bytes go to a temporary file
// in the same directory (`path + ".tmp.<pid>.<n>"`), which is fsync'ed and
// renamed over `path`, after which the directory is fsync'ed. On failure the
// temporary file is removed and an existing file at `path` is left untouched.
// Returns the number of bytes written (the checkpoint's size on disk).
absl::StatusOr<size_t> SaveCheckpoint(const NgpModel& model, const std::string& path,
                                      const CheckpointExtras& extras = {});

// Reads and decodes the checkpoint at `path` (errors as described above).
absl::StatusOr<LoadedCheckpoint> LoadCheckpoint(const std::string& path);

}  // namespace clnerf

#endif  // CLNERF_CORE_CHECKPOINT_H_
