// Checkpoint: a versioned, self-checking binary file format for NgpModel.
//
// A checkpoint holds everything needed to rebuild a model: every field of the
// model options, the normalisation, scene kind, background, the number of time
// steps, the three parameter blocks, the occupancy grid state, plus
// caller-defined extras (a string metadata map and named opaque binary
// sections, e.g. for the continual-learning replay memory). A model loaded
// from a float32 checkpoint renders exactly the same pixels as the one that
// was saved (the occupancy bits and all parameters are stored exactly).
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
// definition, does not affect the model. Versions 1 and 2 write only critical
// sections; adding a field to an options struct means adding a new section
// (or bumping the version), never changing the payload of an existing one.
//
// Format version 5 (this build writes it; it also reads versions 1 to 4)
// adds SMOP (the sampler: occupancy marching or proposal fields, and the
// proposal options) and PPRP (the proposal fields' parameters, empty for
// occupancy models, encoded like the other blocks); older files load as
// occupancy models, which is what they were trained with.
// Format version 4
// appends the normalisation's rotation (9 float32, row-major) to MODL; older
// files load with the identity, which is what they were trained with.
// Format version 3 has
// the sections MODL HGOP NTOP OGOP MROP PENC PGRD PMLP PEMB OCCP META XSEC*
// (version 1: no PENC, and OCCG with the raw occupancy state instead of OCCP):
//  * parameters may be stored as IEEE binary16 (CheckpointOptions::
//    fp16_params, recorded in section PENC); they load as float32.
//  * the occupancy grid is stored as bits (section OCCP, see checkpoint.cc):
//    the threshold and the occupancy bits exactly (deflated), the visibility
//    flags as a run-length-coded bitfield. The per-cell density EMA, which
//    only warm-started training reads, is stored for the occupied cells
//    only, as 8-bit log codes relative to the threshold (ancillary section
//    occd, 1/8 octave: checkpoint.cc); it loads as those on occupied cells
//    and 0 elsewhere (files without occd: the threshold on occupied cells),
//    and a warm start's occupancy updates (new = max(decay * old, sigma))
//    go on from there. Without occd an update from a stored version trained
//    differently from one from the state in memory (a cell dense in the
//    last training dropped out at its first refresh where the field
//    dipped). Version 2 stored the EMA as 8-bit log codes, which cost up to a byte per
//    cell: a trained fox_8 file was 1.38x its model bytes
//    (NgpModel::num_bytes()); in version 3 it is 0.97x (lego: 0.87x), as
//    measured by `clnerf bench scenes`. Version-2 files still load with their
//    quantised EMA.
//  * versions 2 and 3 also mark the contracted parameterisation of unbounded
//    scenes (SceneKind::kUnbounded); version-1 checkpoints of unbounded scenes
//    used the old, uncontracted one and are refused (FAILED_PRECONDITION:
//    re-train them). Version-1 checkpoints of bounded scenes load unchanged.
// A fp32 save/load round trip is bit-exact except for the density EMA, which
// is restored as described above; re-saving a loaded model reproduces the file
// exactly.
//
// Errors: NOT_FOUND (missing file), INVALID_ARGUMENT (not a clnerf checkpoint:
// bad magic), FAILED_PRECONDITION (unsupported format version, unknown
// critical section, or a version-1 unbounded scene), DATA_LOSS (truncation,
// checksum mismatch, or content that is internally inconsistent), other codes
// from the OS for I/O failures.
//
// Thread safety: all functions are free functions without shared state and
// may be called concurrently. Saving reads the model through a const
// reference, so the model must not be mutated while it is being saved.
// Concurrent saves to the same path from different threads or processes are
// safe: each writes its own temporary file and the last rename wins.
#ifndef CLNERF_CORE_IO_CHECKPOINT_H_
#define CLNERF_CORE_IO_CHECKPOINT_H_

#include <cstddef>
#include <cstdint>
#include <map>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/field/ngp_model.h"

namespace clnerf {

// The format version this build writes, and the newest it reads. Versions 2
// and 3 also mark checkpoints whose unbounded scenes (SceneKind::kUnbounded)
// use contracted unbounded space; version 3 stores occupancy as bits only;
// version 4 adds the normalisation's rotation to MODL (older: identity).
inline constexpr uint32_t kCheckpointFormatVersion = 5;
// The oldest format version this build reads (bounded scenes only).
inline constexpr uint32_t kOldestReadableCheckpointFormatVersion = 1;
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

// How a checkpoint is stored.
struct CheckpointOptions {
  // Store the parameter blocks (grid, MLPs, embeddings) as IEEE binary16,
  // rounded to nearest even: half the parameter bytes, relative error <=
  // 2^-11 (absolute 2^-25 near zero). Loading converts them back to float32.
  // A finite parameter beyond the binary16 range (|x| >= 65520) makes the
  // save fail with FAILED_PRECONDITION rather than store an infinity.
  bool fp16_params = false;
};

struct LoadedCheckpoint {
  NgpModel model;
  CheckpointExtras extras;
  size_t num_bytes = 0;  // Size of the serialized checkpoint (file bytes).
  uint32_t format_version = 0;
  bool fp16_params = false;  // The parameters were stored as binary16.
};

// Encodes `model` and `extras` as a checkpoint in memory. FAILED_PRECONDITION
// if the model is internally inconsistent (e.g. a parameter block whose size
// does not match the options).
absl::StatusOr<std::string> SerializeCheckpoint(const NgpModel& model,
                                                const CheckpointExtras& extras = {},
                                                const CheckpointOptions& options = {});

// Decodes a checkpoint held in memory. `source_name` is only used in error
// messages (e.g. the file path).
absl::StatusOr<LoadedCheckpoint> DeserializeCheckpoint(std::string_view bytes,
                                                       std::string_view source_name = "<memory>");

// Atomically writes a checkpoint to `path`: the bytes go to a temporary file
// in the same directory (`path + ".tmp.<pid>.<n>"`), which is fsync'ed and
// renamed over `path`, after which the directory is fsync'ed. On failure the
// temporary file is removed and an existing file at `path` is left untouched.
// Returns the number of bytes written (the checkpoint's size on disk; compare
// with the parameter bytes, NgpModel::num_bytes()).
absl::StatusOr<size_t> SaveCheckpoint(const NgpModel& model, const std::string& path,
                                      const CheckpointExtras& extras = {},
                                      const CheckpointOptions& options = {});

// Reads and decodes the checkpoint at `path` (errors as described above).
absl::StatusOr<LoadedCheckpoint> LoadCheckpoint(const std::string& path);

}  // namespace clnerf

#endif  // CLNERF_CORE_IO_CHECKPOINT_H_
