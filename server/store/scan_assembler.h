// ScanAssembler: turns one upload stream (a header declaring every frame and
// its byte sizes, then chunks of bytes) into a ScanUpload, and is the one
// place where the upload limits are checked:
//
//   Begin(header)  frame count, names (length, control characters), declared
//                  sizes (non-negative, overflow-safe sum <= max_scan_bytes)
//   Add(chunk)     frame index, chunk size, contiguous offsets, no byte
//                  beyond what the header declared
//   Finish()       every declared byte arrived (no truncated frame)
//
// Memory is bounded by the declared (already checked) total. Nothing here
// knows gRPC or protobuf, so every limit is tested directly; UploadScan is a
// thin shell that feeds messages in. Image decoding and camera validation
// stay with ValidateScanUpload (scan_store.h), which the host runs on the
// finished upload.
//
// Thread-safety: one assembler per upload stream; not thread-safe.
#ifndef CLNERF_SERVER_SCAN_ASSEMBLER_H_
#define CLNERF_SERVER_SCAN_ASSEMBLER_H_

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "server/store/scan_store.h"

namespace clnerf {

struct UploadLimits {
  int max_frames = 4000;                        // Train + test frames per scan.
  int max_points = 250000;                      // Sparse points (3 MB, under gRPC's 4 MB message).
  int64_t max_scan_bytes = int64_t(1) << 30;    // Declared image + mask bytes.
  int64_t max_chunk_bytes = int64_t(1) << 20;   // Bytes per chunk message.
  static constexpr size_t kMaxNameBytes = 256;  // Scan and frame names.
};

// A frame as the header declares it: camera and name (in `frame`, bytes
// empty) and the sizes of the bytes that follow.
struct DeclaredFrame {
  ScanFrame frame;
  int64_t image_bytes = 0;
  int64_t mask_bytes = 0;
};

struct ScanHeaderDecl {
  std::string name;
  std::string scene_kind;
  bool mask_nonzero_is_exclude = false;
  std::string pose_frame;  // "" / "own", "place" or "unposed" (ScanUpload::pose_frame).
  bool sequential = false;
  std::vector<DeclaredFrame> frames;  // Training frames first, then test frames.
  std::vector<Eigen::Vector3f> points;  // Optional sparse point cloud.
};

// INVALID_ARGUMENT unless `name` has at most UploadLimits::kMaxNameBytes
// bytes and no control characters (so it cannot forge log lines). `what`
// names the field in the message ("scan name", "frame 3 name").
absl::Status ValidateName(std::string_view name, const std::string& what);

// The limits on a whole upload (frame count, bytes, names), for an upload
// handed to the host in one piece. ScanAssembler checks the same limits on
// the declared header, before any byte is buffered.
absl::Status CheckUploadLimits(const ScanUpload& upload, const UploadLimits& limits);

class ScanAssembler {
 public:
  explicit ScanAssembler(const UploadLimits& limits) : limits_(limits) {}

  absl::Status Begin(ScanHeaderDecl header);
  absl::Status Add(int frame_index, bool is_mask, int64_t offset, std::string_view data);
  // The assembled upload. INVALID_ARGUMENT naming the first frame with
  // missing bytes.
  absl::StatusOr<ScanUpload> Finish();

  bool begun() const { return begun_; }
  int64_t received_bytes() const { return received_; }
  const std::string& name() const { return upload_.name; }

 private:
  const UploadLimits limits_;
  bool begun_ = false;
  ScanUpload upload_;
  std::vector<int64_t> want_image_, want_mask_;
  int64_t received_ = 0;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_SCAN_ASSEMBLER_H_
