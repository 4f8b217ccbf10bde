// FreshTempDir: a new, empty directory for one test, removed when the test
// passes; kept (and named on stdout) when it fails, so its files can be
// looked at. Without this, each run of the suite left ~100 directories (GBs
// of stores, scans and COLMAP workspaces) under /tmp.
//
// Header-only, test code only. Thread-safe: tests may create directories from
// several threads; the removal runs in GoogleTest's OnTestEnd, after the
// fixture's TearDown (servers are stopped by then).
#ifndef CLNERF_CORE_TESTING_TEMP_DIR_H_
#define CLNERF_CORE_TESTING_TEMP_DIR_H_

#include <filesystem>
#include <iostream>
#include <mutex>
#include <random>
#include <string>
#include <vector>

#include "gtest/gtest.h"

namespace clnerf {
namespace testing_util {

class TempDirCleaner : public ::testing::EmptyTestEventListener {
 public:
  // The process's cleaner, appended to GoogleTest's listeners on first use.
  static TempDirCleaner& Get() {
    static TempDirCleaner* cleaner = [] {
      auto* c = new TempDirCleaner;
      ::testing::UnitTest::GetInstance()->listeners().Append(c);  // GoogleTest owns it.
      return c;
    }();
    return *cleaner;
  }
  void Add(const std::string& dir) {
    std::lock_guard<std::mutex> lock(mu_);
    dirs_.push_back(dir);
  }
  void OnTestEnd(const ::testing::TestInfo& info) override { Flush(info.result()->Passed()); }
  void OnTestProgramEnd(const ::testing::UnitTest& unit) override { Flush(unit.Passed()); }

 private:
  void Flush(bool passed) {
    std::vector<std::string> dirs;
    {
      std::lock_guard<std::mutex> lock(mu_);
      dirs.swap(dirs_);
    }
    for (const std::string& d : dirs) {
      std::error_code ec;
      if (passed) {
        std::filesystem::remove_all(d, ec);
      } else {
        std::cout << "kept the failed test's directory " << d << "\n";
      }
    }
  }
  std::mutex mu_;
  std::vector<std::string> dirs_;
};

// A fresh empty directory ::testing::TempDir()/clnerf_<name>_<random>.
inline std::string FreshTempDir(const std::string& name) {
  const std::string dir = (std::filesystem::path(::testing::TempDir()) /
                           ("clnerf_" + name + "_" + std::to_string(std::random_device{}())))
                              .string();
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  TempDirCleaner::Get().Add(dir);
  return dir;
}

}  // namespace testing_util
}  // namespace clnerf

#endif  // CLNERF_CORE_TESTING_TEMP_DIR_H_
