#include "server/places/asset_files.h"

#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>

#include "gtest/gtest.h"
#include "server/testing/store_test_util.h"

namespace clnerf {
namespace {

void Write(const std::string& path, const std::string& bytes) { std::ofstream(path, std::ios::binary) << bytes; }

TEST(AssetFilesTest, AFileIsReadOnceAndServedFromMemory) {
  const std::string dir = testing_util::TempDir("asset_files");
  Write(dir + "/atlas.bin.gz", "first bytes");
  auto metrics = std::make_shared<Metrics>();
  AssetFiles files(1 << 20, metrics);
  absl::StatusOr<std::shared_ptr<const AssetBlob>> a = files.Get(dir + "/atlas.bin.gz");
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ((*a)->bytes, "first bytes");
  absl::StatusOr<std::shared_ptr<const AssetBlob>> b = files.Get(dir + "/atlas.bin.gz");
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(a->get(), b->get());  // The same bytes in memory, not a second read.
  EXPECT_EQ(files.stats().loads, 1);
  EXPECT_EQ(files.stats().hits, 1);

  // Rewritten in place (a place made again under its old name): read again.
  Write(dir + "/atlas.bin.gz", "other, longer bytes");
  absl::StatusOr<std::shared_ptr<const AssetBlob>> c = files.Get(dir + "/atlas.bin.gz");
  ASSERT_TRUE(c.ok());
  EXPECT_EQ((*c)->bytes, "other, longer bytes");
  EXPECT_NE((*c)->digest, (*a)->digest);
  EXPECT_EQ((*a)->bytes, "first bytes");  // A request still sending the old bytes keeps them.

  EXPECT_TRUE(absl::IsNotFound(files.Get(dir + "/view.bin.gz").status()));
}

TEST(AssetFilesTest, UnderItsBudgetTheLeastRecentlyUsedFileGoes) {
  const std::string dir = testing_util::TempDir("asset_files_budget");
  const std::string kb(1000, 'x');
  for (const char* f : {"a", "b", "c"}) Write(dir + "/" + f, kb);
  AssetFiles files(2500, nullptr);  // Room for two.
  ASSERT_TRUE(files.Get(dir + "/a").ok());
  ASSERT_TRUE(files.Get(dir + "/b").ok());
  ASSERT_TRUE(files.Get(dir + "/a").ok());  // b is now the least recently used.
  ASSERT_TRUE(files.Get(dir + "/c").ok());
  EXPECT_EQ(files.stats().evictions, 1);
  EXPECT_LE(files.stats().bytes, 2500);
  const int64_t loads = files.stats().loads;
  ASSERT_TRUE(files.Get(dir + "/a").ok());
  EXPECT_EQ(files.stats().loads, loads);  // Still held.
  ASSERT_TRUE(files.Get(dir + "/b").ok());
  EXPECT_EQ(files.stats().loads, loads + 1);  // Was evicted: read again.
}

TEST(AssetFilesTest, ABudgetOfZeroReadsEveryTime) {
  const std::string dir = testing_util::TempDir("asset_files_none");
  Write(dir + "/m", "{}");
  auto metrics = std::make_shared<Metrics>();
  AssetFiles files(0, metrics);
  absl::StatusOr<std::shared_ptr<const AssetBlob>> a = files.Get(dir + "/m");
  absl::StatusOr<std::shared_ptr<const AssetBlob>> b = files.Get(dir + "/m");
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_NE(a->get(), b->get());
  EXPECT_EQ((*a)->digest, (*b)->digest);
  EXPECT_EQ(files.stats().entries, 0);
}

}  // namespace
}  // namespace clnerf
