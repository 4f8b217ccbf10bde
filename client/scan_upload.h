// Scan upload: encodes a scene's views into a clnerf.v1 ScanHeader plus PNG
// files, and streams them to UploadScan in chunks of at most 1 MiB. Shared by
// the `upload` verb and `bench serve`.
//
// Thread-safety: functions are reentrant; an EncodedScan is immutable once
// built and may be sent from any thread.
#ifndef CLNERF_CLIENT_SCAN_UPLOAD_H_
#define CLNERF_CLIENT_SCAN_UPLOAD_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "client/progress_bar.h"
#include "client/remote_client.h"
#include "core/data/scene.h"

namespace clnerf {

struct EncodedScan {
  clnerf::v1::UploadScanRequest header;  // Holds the ScanHeader.
  // Per frame (frames, then test frames): encoded image and mask ("" = none).
  std::vector<std::pair<std::string, std::string>> files;
  int64_t total_bytes = 0;
};

// Encodes `train` as frames and `test` as held-out frames (images as RGB PNG,
// masks as greyscale PNG with 255 = keep), and `points` (a sparse point cloud
// in the views' world frame; thinned evenly to the protocol's 250,000) into
// the header. Errors name the view.
absl::StatusOr<EncodedScan> EncodeScan(const std::string& name, SceneKind kind, const std::vector<View>& train,
                                       const std::vector<View>& test,
                                       const std::vector<Eigen::Vector3f>& points = {});
inline constexpr size_t kMaxUploadPoints = 250000;

// Unposed scans (the server poses them with COLMAP): the photo files' own
// bytes (JPEG, PNG, ... as taken) as frames without cameras, named by file.
// `sequential`: the photos are in capture order (a video's frames).
absl::StatusOr<EncodedScan> EncodeUnposedPhotos(const std::string& name, const std::vector<std::string>& files,
                                                bool sequential);
// Makes an encoded posed scan unposed: cameras and points dropped.
void DropPoses(EncodedScan* scan, bool sequential);
// The photos in a folder (.jpg .jpeg .png .tif .tiff .bmp, any case), by
// name; not recursive.
std::vector<std::string> ListPhotos(const std::string& dir);

struct SendResult {
  grpc::Status status;
  clnerf::v1::UploadScanResponse response;
  int64_t bytes_sent = 0;
  double seconds = 0;  // From the first write to the server's answer.
};

// Streams the scan; `bar` (may be null) follows the bytes sent.
SendResult SendScan(RemoteClient& client, const EncodedScan& scan, ProgressBar* bar);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_SCAN_UPLOAD_H_
