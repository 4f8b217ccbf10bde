// MultipartScanReader: multipart parts become an unposed ScanUpload; what a
// careless or hostile client sends is refused with a reason, and the limits
// hold while the body streams.
#include "server/frontends/http_scan_upload.h"

#include <filesystem>

#include "core/data/image.h"
#include "gtest/gtest.h"
#include "server/testing/store_test_util.h"

namespace clnerf {
namespace {

using testing_util::TempDir;

std::string Png() {
  absl::StatusOr<std::string> png = EncodePng(Image(8, 6, 0.5f));
  EXPECT_TRUE(png.ok());
  return *png;
}

bool Part(MultipartScanReader* r, const std::string& field, const std::string& file, const std::string& bytes) {
  if (!r->BeginPart(field, file)) return false;
  // Two pieces, as a body arrives.
  const size_t half = bytes.size() / 2;
  return r->AddBytes(bytes.data(), half) && r->AddBytes(bytes.data() + half, bytes.size() - half);
}

TEST(MultipartScanReaderTest, PhotosAndFieldsBecomeAnUnposedScan) {
  MultipartScanReader r(UploadLimits(), TempDir("multipart_ok"));
  const std::string png = Png();
  ASSERT_TRUE(Part(&r, "name", "", "kitchen"));
  ASSERT_TRUE(Part(&r, "image", "a.png", png));
  ASSERT_TRUE(Part(&r, "image", "b.png", png));
  ASSERT_TRUE(Part(&r, "sequential", "", "1"));
  ASSERT_TRUE(Part(&r, "image", "c.png", png));
  absl::StatusOr<ScanUpload> up = r.Finish();
  ASSERT_TRUE(up.ok()) << up.status();
  EXPECT_EQ(up->name, "kitchen");
  EXPECT_TRUE(up->sequential);
  EXPECT_EQ(up->pose_frame, "unposed");
  ASSERT_EQ(up->frames.size(), 3u);
  EXPECT_EQ(up->frames[1].name, "b.png");
  EXPECT_FALSE(up->frames[1].posed);
  EXPECT_EQ(up->frames[2].image, png);
  EXPECT_TRUE(ValidateScanUpload(*up).ok());
}

TEST(MultipartScanReaderTest, RefusesWhatIsNotAScan) {
  const std::string png = Png();
  {
    MultipartScanReader r(UploadLimits(), TempDir("multipart_field"));
    EXPECT_FALSE(Part(&r, "password", "", "x"));
    EXPECT_TRUE(absl::IsInvalidArgument(r.Finish().status()));
  }
  {
    MultipartScanReader r(UploadLimits(), TempDir("multipart_none"));
    ASSERT_TRUE(Part(&r, "name", "", "empty"));
    absl::Status s = r.Finish().status();
    EXPECT_TRUE(absl::IsInvalidArgument(s));
    EXPECT_NE(s.message().find("no images"), std::string::npos) << s;
  }
  {
    MultipartScanReader r(UploadLimits(), TempDir("multipart_both"));
    ASSERT_TRUE(Part(&r, "image", "a.png", png));
    ASSERT_TRUE(Part(&r, "video", "v.mp4", "not really a video"));
    EXPECT_TRUE(absl::IsInvalidArgument(r.Finish().status()));
  }
  {
    MultipartScanReader r(UploadLimits(), TempDir("multipart_name"));
    EXPECT_FALSE(r.BeginPart("image", std::string("bad\nname.png")));
  }
  {
    MultipartScanReader r(UploadLimits(), TempDir("multipart_long_field"));
    EXPECT_FALSE(Part(&r, "name", "", std::string(5000, 'x')));
  }
}

TEST(MultipartScanReaderTest, LimitsHoldWhileTheBodyStreams) {
  UploadLimits small;
  small.max_scan_bytes = 1000;
  small.max_frames = 2;
  const std::string scratch = TempDir("multipart_limits");
  {
    MultipartScanReader r(small, scratch);
    ASSERT_TRUE(r.BeginPart("image", "a.png"));
    const std::string chunk(600, 'x');
    EXPECT_TRUE(r.AddBytes(chunk.data(), chunk.size()));
    EXPECT_FALSE(r.AddBytes(chunk.data(), chunk.size()));  // 1200 > 1000: stops here.
    EXPECT_LE(r.received_bytes(), 1200);
    EXPECT_TRUE(absl::IsInvalidArgument(r.status()));
  }
  {
    MultipartScanReader r(small, scratch);
    EXPECT_TRUE(r.BeginPart("image", "a.png"));
    EXPECT_TRUE(r.BeginPart("image", "b.png"));
    EXPECT_FALSE(r.BeginPart("image", "c.png"));
  }
  {
    MultipartScanReader r(small, scratch);
    ASSERT_TRUE(Part(&r, "video", "v.mp4", "abc"));
  }
  EXPECT_FALSE(std::filesystem::exists(scratch)) << "the scratch folder goes with the reader";
}

}  // namespace
}  // namespace clnerf
