// StructureFromMotion: poses a set of photos in a frame of their own (an
// unposed upload, or a video's frames), the one interface behind which an
// SfM tool sits (ColmapSfm runs Debian's COLMAP 3.8; another SfM can replace
// it). The poses come out in the run's arbitrary frame and scale: the
// caller registers them into the place's (registration.h).
// Thread-safety: Run may be called from several threads on one instance
// (each run has its own workspace).
#ifndef CLNERF_CORE_POSE_SFM_H_
#define CLNERF_CORE_POSE_SFM_H_

#include <atomic>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "Eigen/Core"

namespace clnerf {

struct SfmOptions {
  // Photos in capture order (video frames): match each with its neighbours
  // (COLMAP's sequential matcher) instead of every pair (exhaustive).
  bool sequential = false;
  // Scratch folder for the tool's database, images and model; removed
  // afterwards unless keep_workspace. Must not exist yet.
  std::string workspace;
  bool keep_workspace = false;
  int threads = 2;
  // COLMAP's guided matching: after a pair's two-view geometry is found,
  // its features are matched again along the epipolar lines. Measured on
  // the 24 frames of a 320 x 240 H.264 orbit (11 runs each): 23 of 24
  // posed, focal within 0.7 % of the truth, median rotation error
  // 0.14-0.20 degrees; without it 20 of 24, focal 1.5 % short with a
  // k1 of -0.04 making up for it, 0.24-0.66 degrees. Same time.
  bool guided_matching = true;
  // The run fails unless at least this share of the photos is posed and the
  // mean reprojection error is at most max_reprojection_px.
  double min_registered_fraction = 0.5;
  double max_reprojection_px = 2.0;
  // COLMAP is not deterministic (its matcher's RANSAC is seeded from the
  // clock), and on a narrow-baseline capture its mapper may start from a
  // pair whose bundle adjustment drifts the focal length: the same 24
  // photos of the procedural forward-facing scene came out 24 of 24 posed
  // in one run and 3 to 6 in others. A run that poses fewer than
  // mapper_retry_fraction of the photos is mapped again (features and
  // matches kept), up to mapper_attempts runs in all, one of them with the
  // camera held while mapping and refined after (colmap_sfm.cc says which
  // comes first); the run posing the most photos is kept.
  int mapper_attempts = 3;
  double mapper_retry_fraction = 0.9;
  // A camera to start from, e.g. the place's own camera scaled to the
  // photos (a later visit is usually taken with the same phone): its focal
  // length (mean of fx, fy), principal point and k1 seed the shared camera
  // instead of the tool's guess from the image size. The tool still refines
  // it; a good start keeps a narrow-baseline capture's self-calibration from
  // drifting. Unset: the tool's own guess.
  std::optional<Intrinsics> initial_camera;
  absl::Status Validate() const;
};

struct SfmResult {
  // Per input photo, in order: its camera (OpenCV convention, one shared
  // intrinsics, distortion as the tool estimated it), or none if the tool
  // could not pose it.
  std::vector<std::optional<Camera>> cameras;
  std::vector<Eigen::Vector3f> points;  // The sparse points (same frame).
  int registered = 0;
  double mean_reprojection_px = 0;
  double features_seconds = 0, matching_seconds = 0, mapping_seconds = 0;
};

// Progress: the stage's name ("features", "matching", "mapping") as it starts.
using SfmProgressFn = std::function<void(const std::string& stage)>;

class StructureFromMotion {
 public:
  virtual ~StructureFromMotion() = default;
  // `photos`: image files (PNG, JPEG, ...). FAILED_PRECONDITION, with what
  // was found, when too few photos are posed or the error is too high;
  // NOT_FOUND when the tool is not installed; CANCELLED on `cancel`.
  virtual absl::StatusOr<SfmResult> Run(const std::vector<std::string>& photos, const SfmOptions& options,
                                        const SfmProgressFn& progress = {},
                                        const std::atomic<bool>* cancel = nullptr) const = 0;
};

// COLMAP 3.8 from Debian, CPU only: feature_extractor (one shared camera,
// SIMPLE_RADIAL), exhaustive_matcher or sequential_matcher, mapper (the
// largest model is kept). SIFT on the GPU is turned off (it crashes on a
// headless machine), and nothing needs a download (no vocabulary tree).
class ColmapSfm : public StructureFromMotion {
 public:
  explicit ColmapSfm(std::string binary = "colmap") : binary_(std::move(binary)) {}
  absl::StatusOr<SfmResult> Run(const std::vector<std::string>& photos, const SfmOptions& options,
                                const SfmProgressFn& progress = {},
                                const std::atomic<bool>* cancel = nullptr) const override;

 private:
  std::string binary_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_SFM_H_
