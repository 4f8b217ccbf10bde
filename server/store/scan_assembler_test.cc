// ScanAssembler: every upload limit, without gRPC.
#include "server/store/scan_assembler.h"

#include <limits>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

ScanHeaderDecl Header(std::vector<std::pair<int64_t, int64_t>> sizes) {
  ScanHeaderDecl h;
  h.name = "kitchen";
  for (size_t i = 0; i < sizes.size(); ++i) {
    DeclaredFrame f;
    f.frame.name = "f" + std::to_string(i);
    f.image_bytes = sizes[i].first;
    f.mask_bytes = sizes[i].second;
    h.frames.push_back(std::move(f));
  }
  return h;
}

UploadLimits Limits() {
  UploadLimits l;
  l.max_frames = 4;
  l.max_scan_bytes = 1000;
  l.max_chunk_bytes = 64;
  return l;
}

void ExpectInvalid(const absl::Status& s, const std::string& needle) {
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_NE(s.message().find(needle), std::string::npos) << s;
}

TEST(ScanAssemblerTest, AssemblesChunksInOrder) {
  ScanAssembler a(Limits());
  ASSERT_TRUE(a.Begin(Header({{5, 0}, {3, 2}})).ok());
  ASSERT_TRUE(a.Add(0, false, 0, "abc").ok());
  ASSERT_TRUE(a.Add(0, false, 3, "de").ok());
  ASSERT_TRUE(a.Add(1, false, 0, "xyz").ok());
  ASSERT_TRUE(a.Add(1, true, 0, "mm").ok());
  EXPECT_EQ(a.received_bytes(), 10);
  absl::StatusOr<ScanUpload> up = a.Finish();
  ASSERT_TRUE(up.ok()) << up.status();
  EXPECT_EQ(up->name, "kitchen");
  ASSERT_EQ(up->frames.size(), 2u);
  EXPECT_EQ(up->frames[0].image, "abcde");
  EXPECT_EQ(up->frames[1].mask, "mm");
}

// As the README says: chunks of different frames may interleave (each names
// its frame and offset), but within a frame every chunk must start where the
// frame's bytes end.
TEST(ScanAssemblerTest, FramesMayInterleaveButNotReorderWithinAFrame) {
  ScanAssembler a(Limits());
  ASSERT_TRUE(a.Begin(Header({{5, 0}, {3, 2}})).ok());
  ASSERT_TRUE(a.Add(1, false, 0, "xy").ok());
  ASSERT_TRUE(a.Add(0, false, 0, "abc").ok());
  ASSERT_TRUE(a.Add(1, true, 0, "mm").ok());
  ASSERT_TRUE(a.Add(1, false, 2, "z").ok());
  ExpectInvalid(a.Add(0, false, 4, "e"), "chunk at offset 4");  // A gap in frame 0.
  ExpectInvalid(a.Add(0, false, 1, "bc"), "chunk at offset 1");  // An overlap.
  ASSERT_TRUE(a.Add(0, false, 3, "de").ok());
  absl::StatusOr<ScanUpload> up = a.Finish();
  ASSERT_TRUE(up.ok()) << up.status();
  EXPECT_EQ(up->frames[0].image, "abcde");
  EXPECT_EQ(up->frames[1].image, "xyz");
  EXPECT_EQ(up->frames[1].mask, "mm");
}

TEST(ScanAssemblerTest, DeclaredSizesCannotOverflowPastTheLimit) {
  // INT64_MAX + a small frame wraps a signed sum below the limit; the
  // assembler must refuse it before anything is buffered.
  for (const auto& sizes : std::vector<std::vector<std::pair<int64_t, int64_t>>>{
           {{std::numeric_limits<int64_t>::max(), 0}, {10, 0}},
           {{10, 0}, {std::numeric_limits<int64_t>::max(), std::numeric_limits<int64_t>::max()}},
           {{600, 0}, {401, 0}},
           {{500, 501}}}) {
    ScanAssembler a(Limits());
    ExpectInvalid(a.Begin(Header(sizes)), "the limit");
    EXPECT_FALSE(a.begun());
  }
  ScanAssembler exact(Limits());
  EXPECT_TRUE(exact.Begin(Header({{600, 0}, {400, 0}})).ok());
}

TEST(ScanAssemblerTest, HeaderLimits) {
  ScanAssembler a(Limits());
  ExpectInvalid(a.Begin(Header({{1, 0}, {1, 0}, {1, 0}, {1, 0}, {1, 0}})), "5 frames; the limit is 4");
  ExpectInvalid(ScanAssembler(Limits()).Begin(Header({})), "no frames");
  ExpectInvalid(ScanAssembler(Limits()).Begin(Header({{0, 0}})), "image_bytes must be > 0");
  ExpectInvalid(ScanAssembler(Limits()).Begin(Header({{1, -1}})), "mask_bytes must be >= 0");
  ScanHeaderDecl newline = Header({{1, 0}});
  newline.name = "ok\n[error] fake log line";
  ExpectInvalid(ScanAssembler(Limits()).Begin(newline), "scan name contains control character 0x0a");
  // Unicode line breaks and bidi overrides forge lines in Unicode-aware log viewers.
  const std::pair<std::string, std::string> unicode[] = {
      {"nel\xc2\x85[error] fake", "U+0085"},     {"ls\xe2\x80\xa8[error] fake", "U+2028"},
      {"ps\xe2\x80\xa9[error] fake", "U+2029"}, {"rlo\xe2\x80\xaegnp.exe", "U+202E"},
      {"iso\xe2\x81\xa6x", "U+2066"},           {"alm\xd8\x9cx", "U+061C"},
      {"lrm\xe2\x80\x8ex", "U+200E"}};
  for (const auto& [name, says] : unicode) {
    ScanHeaderDecl u = Header({{1, 0}});
    u.name = name;
    ExpectInvalid(ScanAssembler(Limits()).Begin(u), "scan name contains " + says);
  }
  ScanHeaderDecl fine = Header({{1, 0}});
  fine.name = "caf\xc3\xa9 \xe2\x80\x94 \xe6\x97\xa5\xe6\x9c\xac";  // café — 日本: ordinary UTF-8 stays allowed.
  EXPECT_TRUE(ScanAssembler(Limits()).Begin(fine).ok());
  ScanHeaderDecl huge = Header({{1, 0}});
  huge.name = std::string(3 << 20, 'x');
  ExpectInvalid(ScanAssembler(Limits()).Begin(huge), "the limit is 256");
  ScanHeaderDecl frame_name = Header({{1, 0}});
  frame_name.frames[0].frame.name = "a\rb";
  ExpectInvalid(ScanAssembler(Limits()).Begin(frame_name), "frame 0 name contains control character 0x0d");
  ScanHeaderDecl cloud = Header({{1, 0}});
  cloud.points.assign(250001, Eigen::Vector3f::Zero());
  ExpectInvalid(ScanAssembler(Limits()).Begin(cloud), "250001 points; the limit is 250000");
  ScanAssembler twice(Limits());
  ASSERT_TRUE(twice.Begin(Header({{1, 0}})).ok());
  ExpectInvalid(twice.Begin(Header({{1, 0}})), "only one scan header");
}

TEST(ScanAssemblerTest, ChunkErrorsNameTheProblem) {
  ExpectInvalid(ScanAssembler(Limits()).Add(0, false, 0, "a"), "must be the scan header");
  ScanAssembler a(Limits());
  ASSERT_TRUE(a.Begin(Header({{4, 0}})).ok());
  ExpectInvalid(a.Add(1, false, 0, "a"), "chunk for frame 1 but the scan has 1 frames");
  ExpectInvalid(a.Add(-1, false, 0, "a"), "chunk for frame -1");
  ExpectInvalid(a.Add(0, false, 0, std::string(65, 'a')), "exceeds the limit of 64");
  ExpectInvalid(a.Add(0, false, 2, "a"), "missing or reordered chunk");
  ExpectInvalid(a.Add(0, false, 0, "abcde"), "more bytes than the 4 declared");
  ExpectInvalid(a.Add(0, true, 0, "m"), "more bytes than the 0 declared");
  ASSERT_TRUE(a.Add(0, false, 0, "abc").ok());
  ExpectInvalid(a.Finish().status(), "upload is truncated: frame 0 ('f0') has 3 of 4 image bytes");
}

TEST(ScanAssemblerTest, NamesAtTheLimitAndUtf8Pass) {
  EXPECT_TRUE(ValidateName(std::string(256, 'n'), "x").ok());
  EXPECT_TRUE(ValidateName("K\xc3\xbc" "che 3", "x").ok());
  EXPECT_FALSE(ValidateName(std::string(257, 'n'), "x").ok());
  EXPECT_FALSE(ValidateName(std::string("a\x7f", 2), "x").ok());
}

}  // namespace
}  // namespace clnerf
