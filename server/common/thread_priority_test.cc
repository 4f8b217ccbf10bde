#include "server/common/thread_priority.h"

#include <thread>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

#if defined(__linux__)
// Only the calling thread changes, and threads it then creates inherit the
// value (as the update worker's OpenMP team does).
TEST(ThreadPriorityTest, RaisesOnlyTheCallingThreadAndItsChildren) {
  const int before = CurrentThreadNice();
  int worker = -1, child = -1;
  std::thread t([&] {
    ASSERT_TRUE(SetCurrentThreadNice(std::max(before, 7)).ok());
    worker = CurrentThreadNice();
    std::thread c([&] { child = CurrentThreadNice(); });
    c.join();
  });
  t.join();
  EXPECT_EQ(worker, std::max(before, 7));
  EXPECT_EQ(child, std::max(before, 7));
  EXPECT_EQ(CurrentThreadNice(), before);  // This thread is untouched.
}
#endif

TEST(ThreadPriorityTest, OutOfRangeIsRefused) {
  EXPECT_EQ(SetCurrentThreadNice(-1).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(SetCurrentThreadNice(20).code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace clnerf
