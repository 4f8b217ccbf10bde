// Video frames: Debian's ffmpeg (run for real) decodes a procedural video in
// which one frame of every three is sharp; the sharpest of each window is
// kept.
#include "core/pose/video_frames.h"

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <filesystem>
#include <random>

#include "core/data/image.h"
#include "core/data/procedural_scene.h"
#include "core/pose/process.h"
#include "core/testing/temp_dir.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

bool FfmpegInstalled() { return std::system("command -v ffmpeg > /dev/null 2>&1 && command -v ffprobe > /dev/null 2>&1") == 0; }

std::string VideoTempDir(const std::string& name) { return testing_util::FreshTempDir(name); }

// A (2r+1)^2 box blur, edges clamped.
Image BoxBlur(const Image& in, int r) {
  Image out(in.width, in.height);
  for (int y = 0; y < in.height; ++y)
    for (int x = 0; x < in.width; ++x)
      for (int c = 0; c < 3; ++c) {
        float sum = 0;
        for (int dy = -r; dy <= r; ++dy)
          for (int dx = -r; dx <= r; ++dx) {
            const int xx = std::clamp(x + dx, 0, in.width - 1), yy = std::clamp(y + dy, 0, in.height - 1);
            sum += in.pixel(xx, yy)[c];
          }
        out.pixel(x, y)[c] = sum / float((2 * r + 1) * (2 * r + 1));
      }
  return out;
}

TEST(VideoFramesTest, KeepsTheSharpestFrameOfEachWindow) {
  if (!FfmpegInstalled()) GTEST_SKIP() << "ffmpeg is not installed (scripts/install-deps.sh installs it)";
  ProceduralSceneOptions po;
  po.backdrop = true;
  po.textured = true;
  po.width = 160;
  po.height = 120;
  po.num_train_views = 30;
  po.num_test_views = 1;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  ASSERT_TRUE(scene.ok()) << scene.status();
  const std::string dir = VideoTempDir("video");
  double sharp_min = 1e30, blurred_max = 0;
  for (int i = 0; i < 30; ++i) {
    const bool sharp = i % 3 == 1;
    const std::string file = dir + "/src_" + std::to_string(100 + i) + ".png";
    ASSERT_TRUE(WriteImage(file, sharp ? scene->train[i].image : BoxBlur(scene->train[i].image, 2)).ok());
    const double s = Sharpness(file);
    ASSERT_GT(s, 0);
    (sharp ? sharp_min : blurred_max) = sharp ? std::min(sharp_min, s) : std::max(blurred_max, s);
  }
  ASSERT_GT(sharp_min, 2 * blurred_max) << "the blur should matter";
  const std::string video = dir + "/walk.mp4";
  ASSERT_TRUE(RunProcess({"ffmpeg", "-nostdin", "-v", "error", "-framerate", "10", "-start_number", "100", "-i",
                          dir + "/src_%03d.png", "-c:v", "libx264", "-crf", "12", "-pix_fmt", "yuv420p", video},
                         dir + "/encode.log")
                  .ok())
      << TailOfFile(dir + "/encode.log", 5);

  VideoFrameOptions o;
  o.frames = 10;
  o.window = 3;
  o.max_side = 80;  // Scaled down (aspect kept) before the sharpness test.
  absl::StatusOr<VideoFrames> v = ExtractVideoFrames(video, dir + "/frames", o);
  ASSERT_TRUE(v.ok()) << v.status();
  EXPECT_EQ(v->width, 160);
  EXPECT_EQ(v->height, 120);
  EXPECT_NEAR(v->duration_seconds, 3.0, 0.2);
  EXPECT_EQ(v->candidates, 30);
  EXPECT_NEAR(v->frame_rate, 10.0, 1e-6);
  ASSERT_EQ(v->files.size(), 10u);
  absl::StatusOr<ImageSize> size = ReadImageSize(v->files[0]);
  ASSERT_TRUE(size.ok()) << size.status();
  EXPECT_EQ(size->width, 80);
  EXPECT_EQ(size->height, 60);
  // Every kept frame is a sharp one: sharper than every blurred candidate
  // at the same scale would be (judged against its window's others).
  std::vector<double> kept;
  for (const std::string& f : v->files) kept.push_back(Sharpness(f));
  ExtractVideoFrames(video, dir + "/all", [] {
    VideoFrameOptions all;
    all.frames = 30;
    all.window = 1;
    all.max_side = 80;
    return all;
  }()).IgnoreError();
  // Asking for more frames than the video has keeps each once (no
  // duplicates, which would give structure from motion zero baselines).
  VideoFrameOptions many;
  many.frames = 60;
  absl::StatusOr<VideoFrames> every = ExtractVideoFrames(video, dir + "/every", many);
  ASSERT_TRUE(every.ok()) << every.status();
  EXPECT_EQ(every->candidates, 30);
  EXPECT_EQ(every->files.size(), 30u);
  for (int w = 0; w < 10; ++w) {
    const double sharp = Sharpness(dir + "/all/frame_" + std::string(w * 3 + 1 < 10 ? "000" : "00") +
                                   std::to_string(w * 3 + 1) + ".jpg");
    EXPECT_NEAR(kept[w], sharp, 1e-6 * sharp) << "window " << w << " kept a blurred frame";
  }
}

TEST(VideoFramesTest, RefusesWhatIsNotAVideo) {
  if (!FfmpegInstalled()) GTEST_SKIP() << "ffmpeg is not installed";
  const std::string dir = VideoTempDir("not_video");
  EXPECT_TRUE(absl::IsNotFound(ExtractVideoFrames(dir + "/missing.mp4", dir + "/a", {}).status()));
  {
    std::ofstream(dir + "/junk.mp4") << "this is not a video";
  }
  absl::Status s = ExtractVideoFrames(dir + "/junk.mp4", dir + "/b", {}).status();
  EXPECT_TRUE(absl::IsInvalidArgument(s)) << s;
  VideoFrameOptions bad;
  bad.frames = 0;
  EXPECT_TRUE(absl::IsInvalidArgument(bad.Validate()));
}

}  // namespace
}  // namespace clnerf
