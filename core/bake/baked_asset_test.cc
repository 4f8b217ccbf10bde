#include "core/bake/baked_asset.h"

#include <filesystem>
#include <fstream>

#include "core/io/durable_file.h"
#include "core/io/gzip.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// A 32^3 grid (4^3 blocks) with two bricks of arbitrary texels.
BakedAsset SmallAsset() {
  BakedAsset a;
  a.contracted = true;
  a.half_size = 2.0f;
  a.resolution = 32;
  a.near = 0.05f;
  a.normalization.center = Eigen::Vector3f(1, 2, 3);
  a.normalization.scale = 0.5f;
  a.normalization.bound = 2.0f;
  a.background = Eigen::Vector3f(0.1f, 0.2f, 0.3f);
  a.time_step = 1;
  a.bricks = {2, 1, 1};
  Camera view;
  view.intrinsics = {64, 48, 50, 50, 32, 24};
  view.c2w.col(3) = Eigen::Vector3f(1, 2, -3);
  a.views.push_back(view);
  a.index.assign(64, 0);
  a.index[5] = 1;
  a.index[42] = 2;
  const std::array<int, 3> t = a.atlas_texels();
  a.atlas.resize(4 * size_t(t[0]) * t[1] * t[2]);
  for (size_t i = 0; i < a.atlas.size(); ++i) a.atlas[i] = uint8_t((i * 37) % 251);
  return a;
}

std::string TempDir(const std::string& name) {
  const std::string d = ::testing::TempDir() + "/baked_asset_" + name;
  std::filesystem::remove_all(d);
  return d;
}

TEST(BakedAssetTest, SavedAssetLoadsBackTheSame) {
  const BakedAsset a = SmallAsset();
  ASSERT_TRUE(a.Validate().ok()) << a.Validate();
  const std::string dir = TempDir("roundtrip");
  ASSERT_TRUE(SaveBakedAsset(a, dir).ok());
  EXPECT_TRUE(IsBakedAssetDir(dir));
  // The asset's bytes are its three files, not a viewer page copied beside them.
  uintmax_t files = 0;
  for (const char* f : {"manifest.json", "index.bin.gz", "atlas.bin.gz"}) {
    files += std::filesystem::file_size(std::filesystem::path(dir) / f);
  }
  ASSERT_TRUE(AtomicWriteFile(dir + "/baked.html", std::string(1000, 'x')).ok());
  absl::StatusOr<uint64_t> bytes = BakedAssetBytes(dir);
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  EXPECT_EQ(*bytes, files);
  EXPECT_EQ(BakedAssetBytes(TempDir("missing")).status().code(), absl::StatusCode::kNotFound);
  absl::StatusOr<BakedAsset> b = LoadBakedAsset(dir);
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(b->contracted, a.contracted);
  EXPECT_EQ(b->resolution, a.resolution);
  EXPECT_EQ(b->bricks, a.bricks);
  EXPECT_EQ(b->index, a.index);
  EXPECT_EQ(b->atlas, a.atlas);
  EXPECT_EQ(b->time_step, 1);
  EXPECT_NEAR(b->normalization.scale, 0.5f, 1e-7f);
  EXPECT_NEAR(b->normalization.center.y(), 2.0f, 1e-7f);
  EXPECT_NEAR(b->background.z(), 0.3f, 1e-7f);
  EXPECT_EQ(b->num_bricks(), 2);
  ASSERT_EQ(b->views.size(), 1u);
  EXPECT_EQ(b->views[0].intrinsics.width, 64);
  EXPECT_NEAR(b->views[0].c2w(2, 3), -3.0f, 1e-6f);
}

// Formats 2 and 3 carry the view-dependent term in view.bin.gz (applied at
// every sample, or at the median; older assets step half a cell); a folder
// that lost it, or a term of the wrong size, is refused.
TEST(BakedAssetTest, AViewDependentAssetRoundTripsAsFormat2And3) {
  BakedAsset a = SmallAsset();
  a.view_term = BakedViewTerm::kPerSample;
  a.step_cells = 0.5f;
  a.view.resize(3 * a.atlas.size());
  for (size_t i = 0; i < a.view.size(); ++i) a.view[i] = uint8_t((i * 13) % 253);
  const std::string dir = TempDir("view");
  ASSERT_TRUE(SaveBakedAsset(a, dir).ok());
  absl::StatusOr<BakedAsset> b = LoadBakedAsset(dir);
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_TRUE(b->view_dependent());
  EXPECT_EQ(b->view, a.view);
  EXPECT_EQ(b->atlas, a.atlas);
  EXPECT_EQ(b->view_term, BakedViewTerm::kPerSample);
  EXPECT_EQ(b->step_cells, 0.5f);
  EXPECT_EQ(b->block_distance.size(), b->index.size());  // Derived on load.
  absl::StatusOr<std::string> manifest = ReadFileToString(dir + "/manifest.json", "m");
  ASSERT_TRUE(manifest.ok());
  EXPECT_NE(manifest->find("\"format\": 2"), std::string::npos) << *manifest;
  a.view_term = BakedViewTerm::kAtMedian;
  a.step_cells = 1.0f;
  const std::string dir3 = TempDir("view3");
  ASSERT_TRUE(SaveBakedAsset(a, dir3).ok());
  absl::StatusOr<BakedAsset> c = LoadBakedAsset(dir3);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->view_term, BakedViewTerm::kAtMedian);
  EXPECT_EQ(c->step_cells, 1.0f);
  a.step_cells = 1.5f;  // A derived 768^3 grid: steps of one 512th, read back exactly.
  const std::string dir15 = TempDir("view15");
  ASSERT_TRUE(SaveBakedAsset(a, dir15).ok());
  absl::StatusOr<BakedAsset> d = LoadBakedAsset(dir15);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->step_cells, 1.5f);
  manifest = ReadFileToString(dir3 + "/manifest.json", "m");
  ASSERT_TRUE(manifest.ok());
  EXPECT_NE(manifest->find("\"format\": 3"), std::string::npos) << *manifest;
  EXPECT_TRUE(IsBakedAssetFileName("view.bin.gz"));
  EXPECT_FALSE(IsBakedAssetFileName("../view.bin.gz"));
  absl::StatusOr<uint64_t> bytes = BakedAssetBytes(dir);
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(*bytes, std::filesystem::file_size(dir + "/manifest.json") + std::filesystem::file_size(dir + "/index.bin.gz") +
                        std::filesystem::file_size(dir + "/atlas.bin.gz") + std::filesystem::file_size(dir + "/view.bin.gz"));
  std::filesystem::remove(dir + "/view.bin.gz");
  EXPECT_EQ(LoadBakedAsset(dir).status().code(), absl::StatusCode::kNotFound);
  a.view.pop_back();
  EXPECT_EQ(a.Validate().code(), absl::StatusCode::kInvalidArgument);
}

TEST(BakedAssetTest, InconsistentAssetsAreRefused) {
  BakedAsset a = SmallAsset();
  a.index[7] = 3;  // Only two bricks fit the atlas.
  EXPECT_EQ(a.Validate().code(), absl::StatusCode::kInvalidArgument);
  a = SmallAsset();
  a.resolution = 36;
  EXPECT_EQ(a.Validate().code(), absl::StatusCode::kInvalidArgument);
  a = SmallAsset();
  a.step_cells = 0.7f;  // Only 32nds of a cell (exact in binary) ...
  EXPECT_EQ(a.Validate().code(), absl::StatusCode::kInvalidArgument);
  a.step_cells = 2.5f;  // ... in [0.5, 2].
  EXPECT_EQ(a.Validate().code(), absl::StatusCode::kInvalidArgument);
  a.step_cells = 1.25f;  // A derived grid's step (640 cells, one 512th of the field).
  EXPECT_TRUE(a.Validate().ok());
  a = SmallAsset();
  a.block_distance.assign(3, 0);
  EXPECT_EQ(a.Validate().code(), absl::StatusCode::kInvalidArgument);
  a = SmallAsset();
  a.atlas.pop_back();
  EXPECT_EQ(a.Validate().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(SerializeBakedAsset(a).ok());
}

TEST(BakedAssetTest, CorruptFoldersGiveClearErrors) {
  const std::string dir = TempDir("corrupt");
  EXPECT_EQ(LoadBakedAsset(dir).status().code(), absl::StatusCode::kNotFound);
  ASSERT_TRUE(SaveBakedAsset(SmallAsset(), dir).ok());
  // A truncated array.
  absl::StatusOr<std::string> atlas = ReadFileToString(dir + "/atlas.bin.gz");
  ASSERT_TRUE(atlas.ok());
  ASSERT_TRUE(AtomicWriteFile(dir + "/atlas.bin.gz", atlas->substr(0, atlas->size() / 2)).ok());
  absl::StatusOr<BakedAsset> b = LoadBakedAsset(dir);
  EXPECT_EQ(b.status().code(), absl::StatusCode::kDataLoss) << b.status();
  // An array larger than its manifest says (it cannot inflate past it).
  absl::StatusOr<std::string> big = GzipCompress(std::string(1 << 20, 'x'));
  ASSERT_TRUE(big.ok());
  ASSERT_TRUE(AtomicWriteFile(dir + "/atlas.bin.gz", *big).ok());
  EXPECT_EQ(LoadBakedAsset(dir).status().code(), absl::StatusCode::kDataLoss);
  // A hostile manifest: absurd sizes are refused before anything is read.
  ASSERT_TRUE(AtomicWriteFile(dir + "/manifest.json",
                              R"({"format":1,"kind":"bounded","half_size":1,"resolution":1048576,"near":0,)"
                              R"("scale":1,"bound":1,"time_step":0,"rotation":[1,0,0,0,1,0,0,0,1],)"
                              R"("bricks":[1,1,1],"center":[0,0,0],"background":[1,1,1]})")
                  .ok());
  EXPECT_EQ(LoadBakedAsset(dir).status().code(), absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE(AtomicWriteFile(dir + "/manifest.json", R"({"format":9})").ok());
  EXPECT_EQ(LoadBakedAsset(dir).status().code(), absl::StatusCode::kFailedPrecondition);
  ASSERT_TRUE(AtomicWriteFile(dir + "/manifest.json", "{not json").ok());
  EXPECT_EQ(LoadBakedAsset(dir).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(GzipTest, RoundTripsAndRefusesCorruptStreams) {
  std::string data;
  for (int i = 0; i < 100000; ++i) data.push_back(char(i % 7 == 0 ? i : 0));
  absl::StatusOr<std::string> gz = GzipCompress(data);
  ASSERT_TRUE(gz.ok());
  EXPECT_LT(gz->size(), data.size() / 4);
  EXPECT_EQ(uint8_t((*gz)[0]), 0x1f);  // The gzip magic browsers expect.
  EXPECT_EQ(uint8_t((*gz)[1]), 0x8b);
  absl::StatusOr<std::string> back = GzipDecompress(*gz, data.size());
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(*back, data);
  EXPECT_EQ(GzipDecompress(*gz, data.size() - 1).status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_EQ(GzipDecompress(gz->substr(0, gz->size() - 9), data.size()).status().code(),
            absl::StatusCode::kDataLoss);
  EXPECT_EQ(GzipDecompress("not gzip at all", 100).status().code(), absl::StatusCode::kDataLoss);
}

}  // namespace
}  // namespace clnerf
