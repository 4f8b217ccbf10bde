#include "core/pose/video_frames.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/data/image.h"
#include "core/data/stopwatch.h"
#include "core/pose/process.h"
#include "opencv2/core.hpp"
#include "opencv2/imgproc.hpp"

namespace clnerf {

namespace fs = std::filesystem;

absl::Status VideoFrameOptions::Validate() const {
  if (frames < 1) return absl::InvalidArgumentError("VideoFrameOptions::frames must be >= 1");
  if (window < 1) return absl::InvalidArgumentError("VideoFrameOptions::window must be >= 1");
  if (max_side < 16) return absl::InvalidArgumentError("VideoFrameOptions::max_side must be >= 16");
  return absl::OkStatus();
}

double Sharpness(const std::string& image_file) {
  auto image = ReadImage(image_file);
  if (!image.ok() || image->empty()) return -1;
  // Grey levels on OpenCV's 0..255 scale (Rec. 601 luma, as IMREAD_GRAYSCALE).
  cv::Mat grey(image->height, image->width, CV_32F);
  for (int y = 0; y < image->height; ++y) {
    float* row = grey.ptr<float>(y);
    for (int x = 0; x < image->width; ++x) row[x] = 255.0f * Luma(image->pixel(x, y));
  }
  cv::Mat lap;
  cv::Laplacian(grey, lap, CV_32F);
  cv::Scalar mean, stddev;
  cv::meanStdDev(lap, mean, stddev);
  return stddev[0] * stddev[0];
}

namespace {

// "key=value" lines of ffprobe's default writer.
absl::Status Probe(const std::string& video, const std::string& log, const VideoFrameOptions& o,
                   const std::atomic<bool>* cancel, VideoFrames* out) {
  absl::Status s = RunProcess({o.ffprobe, "-v", "error", "-select_streams", "v:0", "-show_entries",
                               "format=duration:stream=width,height,avg_frame_rate", "-of", "default=noprint_wrappers=1", video},
                              log, cancel);
  if (absl::IsNotFound(s) || absl::IsCancelled(s)) return s;
  if (!s.ok()) return absl::InvalidArgumentError(absl::StrCat(video, " is not a video ffprobe can read: ",
                                                              TailOfFile(log, 2)));
  std::ifstream in(log);
  std::string line;
  while (std::getline(in, line)) {
    const size_t eq = line.find('=');
    if (eq == std::string::npos) continue;
    const std::string key = line.substr(0, eq), value = line.substr(eq + 1);
    if (key == "width") (void)absl::SimpleAtoi(value, &out->width);
    if (key == "height") (void)absl::SimpleAtoi(value, &out->height);
    if (key == "duration") (void)absl::SimpleAtod(value, &out->duration_seconds);
    if (key == "avg_frame_rate") {  // "30000/1001"; "0/0" when unknown.
      const size_t slash = value.find('/');
      double num = 0, den = 1;
      if (slash != std::string::npos && absl::SimpleAtod(value.substr(0, slash), &num) &&
          absl::SimpleAtod(value.substr(slash + 1), &den) && num > 0 && den > 0) {
        out->frame_rate = num / den;
      }
    }
  }
  if (out->width <= 0 || out->height <= 0) {
    return absl::InvalidArgumentError(absl::StrCat(video, " has no video stream"));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<VideoFrames> ExtractVideoFrames(const std::string& video, const std::string& out_dir,
                                               const VideoFrameOptions& o, const std::atomic<bool>* cancel) {
  if (absl::Status s = o.Validate(); !s.ok()) return s;
  const auto t0 = std::chrono::steady_clock::now();
  std::error_code ec;
  if (!fs::is_regular_file(video, ec)) return absl::NotFoundError(absl::StrCat("no video file ", video));
  fs::create_directories(out_dir, ec);
  if (ec || !fs::is_empty(out_dir, ec)) {
    return absl::InvalidArgumentError(absl::StrCat("cannot use ", out_dir, " for frames: not an empty folder"));
  }
  const fs::path cand = fs::path(out_dir) / "candidates";
  fs::create_directories(cand, ec);
  const std::string log = (fs::path(out_dir) / "ffmpeg.log").string();
  VideoFrames out;
  if (absl::Status s = Probe(video, (fs::path(out_dir) / "ffprobe.log").string(), o, cancel, &out); !s.ok()) {
    return s;
  }
  // A steady rate that gives window candidates per wanted frame (the
  // stream's own rate caps it: then every frame is a candidate).
  double rate = out.duration_seconds > 0 ? o.frames * o.window / out.duration_seconds : 2.0;
  if (out.frame_rate > 0) rate = std::min(rate, out.frame_rate);  // Never duplicate frames.
  std::string filter = absl::StrFormat("fps=%.6f", rate);
  if (std::max(out.width, out.height) > o.max_side) {
    // Rotation-proof: the longer side, whichever it is after autorotation.
    filter += absl::StrFormat(",scale=%d:%d:force_original_aspect_ratio=decrease:force_divisible_by=2", o.max_side,
                              o.max_side);
  }
  absl::Status s = RunProcess({o.ffmpeg, "-nostdin", "-v", "error", "-i", video, "-vf", filter, "-vsync", "vfr",
                               "-q:v", "2", (cand / "c_%05d.jpg").string()},
                              log, cancel);
  if (!s.ok()) return s;
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(cand, ec)) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  out.candidates = int(files.size());
  if (files.empty()) return absl::InvalidArgumentError(absl::StrCat("ffmpeg decoded no frame of ", video));
  const int window = std::max(1, int(std::ceil(double(files.size()) / o.frames)));
  for (size_t begin = 0; begin < files.size(); begin += size_t(window)) {
    const size_t end = std::min(files.size(), begin + size_t(window));
    size_t best = begin;
    double best_sharpness = -2;
    for (size_t i = begin; i < end; ++i) {
      const double v = Sharpness(files[i].string());
      if (v > best_sharpness) best_sharpness = v, best = i;
    }
    const fs::path kept = fs::path(out_dir) / absl::StrFormat("frame_%04d.jpg", out.files.size());
    fs::rename(files[best], kept, ec);
    if (ec) return absl::InternalError(absl::StrCat("cannot keep ", files[best].string(), ": ", ec.message()));
    out.files.push_back(kept.string());
  }
  fs::remove_all(cand, ec);
  out.seconds = SecondsSince(t0);
  return out;
}

}  // namespace clnerf
