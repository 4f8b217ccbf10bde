#include "core/data/image_codec.h"

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

// Runs this test binary again with `args` and the dynamic loader's file
// trace on, returning everything it printed.
std::string RunSelfTracingLibraries(const std::string& args) {
  const std::string self = fs::read_symlink("/proc/self/exe").string();
  const std::string cmd = absl::StrCat("LD_DEBUG=files '", self, "' ", args, " 2>&1");
  std::string out;
  FILE* p = popen(cmd.c_str(), "r");
  if (p == nullptr) return out;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof(buf), p)) > 0) out.append(buf, n);
  pclose(p);
  return out;
}

TEST(ImageCodecModuleTest, LoadsTheModuleAndRoundTripsAnImage) {
  auto codec = GetImageCodec();
  ASSERT_TRUE(codec.ok()) << codec.status();
  EXPECT_EQ(*codec, *GetImageCodec());  // loaded once
  const uint8_t px[2 * 3 * 4] = {0, 10, 20, 255, 30, 40, 50, 128, 60, 70, 80, 0,
                                 90, 100, 110, 255, 120, 130, 140, 64, 150, 160, 170, 255};
  auto png = (*codec)->Encode("png", 3, 2, 4, px, 0);
  ASSERT_TRUE(png.ok()) << png.status();
  auto back = (*codec)->Decode(*png, ".png", "x.png");
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_EQ(back->width, 3);
  ASSERT_EQ(back->height, 2);
  ASSERT_EQ(back->channels, 4);
  EXPECT_FALSE(back->premultiplied);  // straight alpha, as written
  for (int i = 0; i < 24; ++i) {
    if (i % 4 != 3 && px[(i / 4) * 4 + 3] == 0) continue;  // colour under alpha 0 is free
    EXPECT_NEAR(back->px[i] * 255.0f, float(px[i]), 0.5f) << i;
  }
  EXPECT_FALSE((*codec)->Decode("not an image", ".png", "junk.png").ok());
}

TEST(ImageCodecModuleTest, AMissingModuleIsUnavailableAndNamesWhereItLooked) {
  auto codec = LoadImageCodec({"/nonexistent/libclnerf_oiio.so", "/nonexistent2/libclnerf_oiio.so"});
  ASSERT_FALSE(codec.ok());
  EXPECT_EQ(codec.status().code(), absl::StatusCode::kUnavailable);
  EXPECT_NE(codec.status().message().find("/nonexistent/libclnerf_oiio.so: not found"), std::string::npos)
      << codec.status();
  EXPECT_NE(codec.status().message().find("/nonexistent2/"), std::string::npos);
  EXPECT_NE(codec.status().message().find("CLNERF_IMAGE_CODEC"), std::string::npos);
  EXPECT_FALSE(LoadImageCodec({}).ok());
}

TEST(ImageCodecModuleTest, AFileThatIsNotTheModuleIsRefused) {
  const fs::path junk = fs::temp_directory_path() / absl::StrCat("clnerf_codec_junk_", getpid(), ".so");
  std::ofstream(junk) << "not a shared object";
  auto codec = LoadImageCodec({junk.string()});
  fs::remove(junk);
  ASSERT_FALSE(codec.ok());
  EXPECT_EQ(codec.status().code(), absl::StatusCode::kUnavailable);
  EXPECT_NE(codec.status().message().find(junk.string()), std::string::npos) << codec.status();

  // A real shared library without the entry point; the next candidate wins.
  const std::string libz = "/usr/lib/x86_64-linux-gnu/libz.so.1";
  if (!fs::exists(libz)) GTEST_SKIP() << libz << " not found";
  auto wrong = LoadImageCodec({libz});
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.status().message().find("no entry point"), std::string::npos) << wrong.status();
  auto next = LoadImageCodec({libz, ImageCodecCandidates().back()});
  EXPECT_TRUE(next.ok()) << next.status();
}

// The point of the module: a process that touches no image never loads
// OpenImageIO (and its ~260 libraries); one that does, does.
TEST(ImageCodecModuleTest, OpenImageIOIsLoadedOnlyByAProcessThatUsesImages) {
  const std::string idle = RunSelfTracingLibraries("--gtest_filter=NONE");
  ASSERT_NE(idle.find("file="), std::string::npos) << "LD_DEBUG printed nothing:\n" << idle.substr(0, 2000);
  EXPECT_EQ(idle.find("libOpenImageIO"), std::string::npos);
  const std::string used = RunSelfTracingLibraries(
      "--gtest_filter=ImageCodecModuleTest.LoadsTheModuleAndRoundTripsAnImage");
  EXPECT_NE(used.find("libclnerf_oiio"), std::string::npos);
  EXPECT_NE(used.find("libOpenImageIO"), std::string::npos);
  EXPECT_NE(used.find("[  PASSED  ] 1 test"), std::string::npos) << used.substr(used.size() > 3000 ? used.size() - 3000 : 0);
}

}  // namespace
}  // namespace clnerf
