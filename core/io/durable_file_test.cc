// Durable files: atomic replacement and the clean-up of crash leftovers.
#include "core/io/durable_file.h"

#include <filesystem>
#include <fstream>
#include <random>

#include "core/testing/temp_dir.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

std::string FreshDir() { return testing_util::FreshTempDir("durable"); }

void Touch(const std::string& path) { std::ofstream(path) << "x"; }

TEST(DurableFileTest, AtomicWriteReplacesAndLeavesNoTemporary) {
  const std::string dir = FreshDir(), path = dir + "/manifest.json";
  ASSERT_TRUE(AtomicWriteFile(path, "one").ok());
  ASSERT_TRUE(AtomicWriteFile(path, "two").ok());
  absl::StatusOr<std::string> got = ReadFileToString(path);
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(*got, "two");
  int files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 1);
}

TEST(DurableFileTest, CrashLeftoversOfAtomicWritesAreRemovedAndNothingElse) {
  const std::string dir = FreshDir(), path = dir + "/manifest.json";
  ASSERT_TRUE(AtomicWriteFile(path, "kept").ok());
  // What a kill -9 between write and rename leaves behind.
  Touch(dir + "/manifest.json.tmp.1234.0");
  Touch(dir + "/manifest.json.tmp.99.17");
  // Look-alikes that are not ours.
  Touch(dir + "/manifest.json.tmp.notes");
  Touch(dir + "/other.json.tmp.1.2");
  EXPECT_EQ(RemoveAtomicWriteTemps(path), 2);
  EXPECT_TRUE(fs::exists(path));
  EXPECT_FALSE(fs::exists(dir + "/manifest.json.tmp.1234.0"));
  EXPECT_FALSE(fs::exists(dir + "/manifest.json.tmp.99.17"));
  EXPECT_TRUE(fs::exists(dir + "/manifest.json.tmp.notes"));
  EXPECT_TRUE(fs::exists(dir + "/other.json.tmp.1.2"));
  EXPECT_EQ(RemoveAtomicWriteTemps(path), 0);
}

TEST(DurableFileTest, TempDirectoriesOfInterruptedDirectoryWritesAreRemoved) {
  const std::string dir = FreshDir();
  ASSERT_TRUE(WriteDirectoryAtomically(dir + "/000001", {{"a", "1"}}).ok());
  fs::create_directories(dir + "/.tmp-000002");
  Touch(dir + "/.tmp-000002/a");
  RemoveTempEntries(dir);
  EXPECT_FALSE(fs::exists(dir + "/.tmp-000002"));
  EXPECT_TRUE(fs::exists(dir + "/000001/a"));
  EXPECT_EQ(WriteDirectoryAtomically(dir + "/000001", {{"a", "2"}}).code(), absl::StatusCode::kAlreadyExists);
}

}  // namespace
}  // namespace clnerf
