// HttpScanUpload: a scan uploaded over HTTP as multipart/form-data, the way a
// browser's <input type=file multiple> or `curl -F` sends it, turned into
// the same ScanUpload the gRPC path builds. Only unposed scans come this way
// (photos, or one video); posed datasets go through `clnerf upload` (gRPC).
//
//   image=@IMG_0001.jpg  (repeated)  the photos, in capture order by name
//   video=@walk.mp4      (once)      a video instead: its frames are taken
//                                    with ffmpeg (core/pose/video_frames.h)
//   name=...                         scan name (default: "http-upload")
//   sequential=1                     photos are in capture order
//
// Parts are streamed: images are kept as their encoded bytes (bounded by
// UploadLimits::max_scan_bytes, counted as they arrive, so an oversized
// body is refused without being buffered), a video goes to a scratch file.
//
// Thread-safety: one reader per request; not shared.
#ifndef CLNERF_SERVER_HTTP_SCAN_UPLOAD_H_
#define CLNERF_SERVER_HTTP_SCAN_UPLOAD_H_

#include <cstdint>
#include <fstream>
#include <string>

#include "absl/status/statusor.h"
#include "core/pose/video_frames.h"
#include "server/store/scan_assembler.h"
#include "server/store/scan_store.h"

namespace clnerf {

class MultipartScanReader {
 public:
  // `scratch`: a folder of its own for a video and its frames (created on
  // demand, removed by the destructor).
  MultipartScanReader(const UploadLimits& limits, std::string scratch, VideoFrameOptions video = {})
      : limits_(limits), scratch_(std::move(scratch)), video_(std::move(video)) {}
  ~MultipartScanReader();

  // The multipart callbacks: a part begins (form field `field`, `filename`
  // empty for plain fields), then its bytes arrive. false stops the read;
  // status() says why.
  bool BeginPart(const std::string& field, const std::string& filename);
  bool AddBytes(const char* data, size_t size);

  // The scan: frames from the images or the video's frames, unposed.
  // INVALID_ARGUMENT for an unknown field, no images, both images and a
  // video, or what the reading stopped on.
  absl::StatusOr<ScanUpload> Finish();
  const absl::Status& status() const { return status_; }
  int64_t received_bytes() const { return received_; }

 private:
  enum class Part { kNone, kImage, kVideo, kField };
  const UploadLimits limits_;
  const std::string scratch_;
  const VideoFrameOptions video_;
  absl::Status status_;
  ScanUpload upload_;
  Part part_ = Part::kNone;
  std::string field_, field_value_;
  std::ofstream video_file_;
  bool has_video_ = false;
  int64_t received_ = 0;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_HTTP_SCAN_UPLOAD_H_
