// ScanStore: the durable inbox of uploaded scans, <store>/scans/<scan_id>/.
//
// A scan is written to scans/.tmp-<scan_id>/ (every file fsync'd), the
// directory is renamed to scans/<scan_id> and scans/ is fsync'd: the scan is
// either wholly there or absent after a crash, and the server acknowledges an
// upload only after Save() returned OK. A scan stays until the update worker
// has trained it into a published version (or its job failed or was
// cancelled); its buffered real images, if any, live on in the version's
// replay memory, so the folder itself can go.
//
// Thread-safety: Save/Load/List/Remove may be called from any thread; each
// scan id is written once (ids are unique), so no locking is needed beyond
// what the file system gives.
#ifndef CLNERF_SERVER_SCAN_STORE_H_
#define CLNERF_SERVER_SCAN_STORE_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/scene.h"

namespace clnerf {

// One uploaded frame: camera (OpenCV convention) and encoded bytes.
struct ScanFrame {
  std::string name;
  // Unposed frames (an unposed scan) carry only the image's size here, and
  // the server poses them (ScanStore::SetPoses) before they train.
  bool posed = true;
  Camera camera;
  bool test = false;  // Held-out frame (deployment gate), not trained on.
  std::string image;  // Encoded image (PNG, JPEG, EXR, ...).
  std::string mask;   // Encoded mask image, or empty.
};

// An upload after transport: what the server received.
struct ScanUpload {
  std::string name;
  std::string scene_kind;  // "bounded", "unbounded" or "" (inherit / bounded).
  bool mask_nonzero_is_exclude = false;
  // "" / "own": the poses are in the scan's own frame and must be registered
  // into the place's; "place": already in the place's frame (checked when
  // possible). See ScanHeader.pose_frame.
  // "unposed" when no frame has a camera (set by the transport): the server
  // poses the scan itself, then treats it as "own".
  std::string pose_frame;
  bool sequential = false;  // Unposed: the frames are in capture order (video).
  std::vector<ScanFrame> frames;
  // Optional sparse point cloud (world frame); the training views get
  // sparse-depth targets from it when the scan is loaded.
  std::vector<Eigen::Vector3f> points;
  // Encoded image + mask bytes. Inline, so header-only users (the upload
  // fuzz target) need not link the store.
  int64_t num_bytes() const {
    int64_t n = 0;
    for (const ScanFrame& f : frames) n += int64_t(f.image.size() + f.mask.size());
    return n;
  }
};

// What the store records about a scan besides its frames.
struct ScanRecord {
  std::string scan_id;  // "scan-000001": zero-padded, so names sort in upload order.
  std::string job_id;
  std::string name;
  std::string scene_kind;
  bool mask_nonzero_is_exclude = false;
  // As ScanUpload::pose_frame; scans stored before it existed read "place".
  // "unposed" until SetPoses, then "own".
  std::string pose_frame;
  bool sequential = false;
  int64_t created_unix_ms = 0;
  int num_frames = 0, num_test_frames = 0;
  int64_t num_bytes = 0;
};

class ScanStore {
 public:
  // Opens (creating if needed) <root>/scans and removes temporaries left by
  // a crash during Save().
  // `clean_temps`: remove what interrupted saves left (false when other
  // replicas may be saving into the same store right now).
  static absl::StatusOr<std::unique_ptr<ScanStore>> Open(const std::string& root, bool clean_temps = true);

  // Writes the scan durably. `record.scan_id` must be new.
  absl::Status Save(const ScanRecord& record, const ScanUpload& scan);
  // Every stored scan, in scan-id (upload) order.
  absl::StatusOr<std::vector<ScanRecord>> List() const;
  // One stored scan's record (NOT_FOUND when it is not stored).
  absl::StatusOr<ScanRecord> Record(const std::string& scan_id) const;
  // Decodes the scan into views with time step `time_step`, compositing onto
  // `background` (unset: the scan's scene kind's, white for bounded, black
  // for unbounded): train frames into scene.train, test frames into
  // scene.test.
  absl::StatusOr<Scene> Load(const std::string& scan_id, int time_step,
                             const std::optional<Eigen::Vector3f>& background) const;
  absl::Status Remove(const std::string& scan_id);

  // Unposed scans. The stored image file of every frame, in upload order
  // (frames, then test frames), for the pose estimator to read.
  absl::StatusOr<std::vector<std::string>> ImageFiles(const std::string& scan_id) const;
  // Records the poses found for an unposed scan, one per ImageFiles() entry
  // (none: the frame could not be posed and is dropped), and the sparse
  // points in the same frame. The manifest is replaced atomically (temp
  // file, fsync, rename); the scan then reads as posed in its own frame
  // ("own"), scene kind "unbounded" unless the upload named one.
  // FAILED_PRECONDITION when no training frame keeps a pose.
  absl::Status SetPoses(const std::string& scan_id, const std::vector<std::optional<Camera>>& cameras,
                        const std::vector<Eigen::Vector3f>& points);

  // Poison-scan bookkeeping: the update worker records an attempt (durably)
  // before it trains a scan and clears the count when it stops the scan
  // cleanly (shutdown), so the count is the number of attempts that ended in
  // a crash, a kill or a hang. Returns the new count.
  absl::StatusOr<int> RecordAttempt(const std::string& scan_id);
  int Attempts(const std::string& scan_id) const;  // 0 if none recorded.
  void ClearAttempts(const std::string& scan_id);
  // Moves the scan to <root>/parked/<scan_id> with `reason` beside it: kept
  // for the operator, never listed or retried again.
  absl::Status Park(const std::string& scan_id, const std::string& reason);

  const std::string& dir() const { return dir_; }
  std::string parked_dir() const;

 private:
  explicit ScanStore(std::string dir) : dir_(std::move(dir)) {}
  std::string dir_;
};

// Decodes and checks one upload fully (images decode, sizes match the
// intrinsics, masks match the images, cameras are rigid and finite, names are
// unique; an unposed scan: every frame unposed, one image size, at least
// kMinUnposedFrames frames, no points). INVALID_ARGUMENT naming the first bad
// frame otherwise.
absl::Status ValidateScanUpload(const ScanUpload& scan);
inline constexpr int kMinUnposedFrames = 3;

}  // namespace clnerf

#endif  // CLNERF_SERVER_SCAN_STORE_H_
