#include "server/jobs/job_tracker.h"

#include <thread>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

JobStatus Job(const std::string& id) {
  JobStatus j;
  j.job_id = id;
  j.scan_id = "scan-" + id;
  return j;
}

TEST(JobTrackerTest, FifoQueueWithBoundAndCancel) {
  JobTracker t(2);
  ASSERT_TRUE(t.Enqueue(Job("a")).ok());
  ASSERT_TRUE(t.Enqueue(Job("b")).ok());
  EXPECT_EQ(t.Enqueue(Job("c")).code(), absl::StatusCode::kResourceExhausted);
  EXPECT_TRUE(t.Enqueue(Job("c"), /*force=*/true).ok());
  EXPECT_EQ(*t.WaitNext(), "a");
  EXPECT_EQ(t.running(), "a");
  // Cancelling a queued job removes it; a running one only gets the flag.
  EXPECT_TRUE(*t.Cancel("b"));
  EXPECT_EQ(t.Get("b")->phase, JobPhase::kCancelled);
  EXPECT_FALSE(*t.Cancel("a"));
  EXPECT_TRUE(t.Get("a")->cancel_requested);
  t.Update("a", [](JobStatus* j) { j->phase = JobPhase::kCancelled; });
  EXPECT_EQ(t.running(), "");
  EXPECT_EQ(t.Cancel("a").status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(t.Cancel("zz").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(*t.WaitNext(), "c");
  EXPECT_EQ(t.List().size(), 3u);
}

TEST(JobTrackerTest, WatchersWakeOnChangeAndShutdownReleasesWorker) {
  JobTracker t(4);
  ASSERT_TRUE(t.Enqueue(Job("a")).ok());
  const uint64_t rev = t.Get("a")->revision;
  std::thread writer([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    t.Update("a", [](JobStatus* j) { j->iteration = 7; });
  });
  auto changed = t.WaitForChange("a", rev, std::chrono::steady_clock::now() + std::chrono::seconds(10));
  writer.join();
  ASSERT_TRUE(changed.ok());
  EXPECT_EQ(changed->iteration, 7);
  EXPECT_GT(changed->revision, rev);
  // A deadline without change returns the unchanged state.
  auto same = t.WaitForChange("a", changed->revision, std::chrono::steady_clock::now() + std::chrono::milliseconds(5));
  EXPECT_EQ(same->revision, changed->revision);
  EXPECT_EQ(t.WaitForChange("nope", 0, std::chrono::steady_clock::now()).status().code(), absl::StatusCode::kNotFound);

  JobTracker empty(1);
  std::thread worker([&] { EXPECT_FALSE(empty.WaitNext().has_value()); });
  std::this_thread::sleep_for(std::chrono::milliseconds(10));
  empty.Shutdown();
  worker.join();
  EXPECT_EQ(empty.Enqueue(Job("x")).code(), absl::StatusCode::kUnavailable);
}

}  // namespace
}  // namespace clnerf
