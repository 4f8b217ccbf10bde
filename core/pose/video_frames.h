// Video frames: turns a phone video into the photos of one unposed scan,
// as nerfstudio's ns-process-data and instant-ngp's colmap2nerf.py do:
// Debian's ffprobe reads the video's length and size, ffmpeg decodes frames
// at a steady rate (window candidates per frame wanted, scaled down to
// max_side), and of every `window` consecutive candidates the sharpest
// (highest variance of the Laplacian, OpenCV) is kept. Both tools run as
// real processes (process.h).
// Thread-safety: each call is independent (its own output folder).
#ifndef CLNERF_CORE_POSE_VIDEO_FRAMES_H_
#define CLNERF_CORE_POSE_VIDEO_FRAMES_H_

#include <atomic>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace clnerf {

struct VideoFrameOptions {
  // Frames kept from the whole video (fewer when it is short: at most every
  // decoded frame). 30-60 pose in about 90 s on 2 cores.
  int frames = 60;
  // Candidates decoded per kept frame: the sharpest of each window is kept.
  int window = 3;
  // The longer image side after scaling (never scaled up).
  int max_side = 640;
  std::string ffmpeg = "ffmpeg", ffprobe = "ffprobe";
  absl::Status Validate() const;
};

struct VideoFrames {
  std::vector<std::string> files;  // JPEGs in `out_dir`, in video order.
  double duration_seconds = 0;
  int width = 0, height = 0;       // Of the video as stored (before rotation).
  double frame_rate = 0;           // Frames per second (0 = unknown).
  int candidates = 0;              // Frames decoded.
  double seconds = 0;              // Wall time of the whole extraction.
};

// Writes the kept frames to `out_dir` (created; must be empty or absent).
// INVALID_ARGUMENT when the file is not a video ffprobe can read; NOT_FOUND
// when ffmpeg is not installed or the file does not exist.
absl::StatusOr<VideoFrames> ExtractVideoFrames(const std::string& video, const std::string& out_dir,
                                               const VideoFrameOptions& options,
                                               const std::atomic<bool>* cancel = nullptr);

// Variance of the Laplacian of an image file's grey levels (higher =
// sharper); -1 when it cannot be read.
double Sharpness(const std::string& image_file);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_VIDEO_FRAMES_H_
