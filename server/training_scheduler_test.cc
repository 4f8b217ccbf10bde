#include "server/training_scheduler.h"

#include <chrono>
#include <future>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// Runs `n` jobs one slot at a time; returns "place/job" in start order.
std::vector<std::string> Drain(TrainingScheduler* s, int n) {
  std::vector<std::string> order;
  for (int i = 0; i < n; ++i) {
    std::optional<ScheduledJob> j = s->Next();
    if (!j) break;
    order.push_back(j->place + "/" + j->job_id);
    s->Finish(j->place);
  }
  return order;
}

TEST(TrainingSchedulerTest, OnePlaceTrainsInUploadOrder) {
  TrainingScheduler s(1);
  for (int i = 1; i <= 4; ++i) s.Enqueue("shop", absl::StrCat("job-", i));
  EXPECT_EQ(Drain(&s, 4), (std::vector<std::string>{"shop/job-1", "shop/job-2", "shop/job-3", "shop/job-4"}));
}

TEST(TrainingSchedulerTest, ALongQueueDoesNotStarveAQuietPlace) {
  TrainingScheduler s(1);
  for (int i = 1; i <= 10; ++i) s.Enqueue("busy", absl::StrCat("b", i));
  std::optional<ScheduledJob> first = s.Next();  // busy/b1 starts ...
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->job_id, "b1");
  s.Enqueue("quiet", "q1");  // ... then a scan arrives for another place.
  s.Finish("busy");
  // The quiet place goes next, not after the other nine.
  std::vector<std::string> order = Drain(&s, 3);
  EXPECT_EQ(order, (std::vector<std::string>{"quiet/q1", "busy/b2", "busy/b3"}));
  // Under contention the places alternate.
  s.Enqueue("quiet", "q2");
  s.Enqueue("quiet", "q3");
  order = Drain(&s, 4);
  EXPECT_EQ(order, (std::vector<std::string>{"busy/b4", "quiet/q2", "busy/b5", "quiet/q3"}));
}

TEST(TrainingSchedulerTest, WithFreeSlotsTheOldestJobGoesFirst) {
  TrainingScheduler s(1);
  s.Enqueue("b", "1");
  s.Enqueue("a", "2");
  s.Enqueue("c", "3");
  EXPECT_EQ(Drain(&s, 3), (std::vector<std::string>{"b/1", "a/2", "c/3"}));
}

TEST(TrainingSchedulerTest, SlotsAreSharedAndAPlaceNeverTrainsTwiceAtOnce) {
  TrainingScheduler s(2);
  s.Enqueue("a", "a1");
  s.Enqueue("a", "a2");
  s.Enqueue("b", "b1");
  std::optional<ScheduledJob> j1 = s.Next(), j2 = s.Next();
  ASSERT_TRUE(j1 && j2);
  EXPECT_EQ(j1->job_id, "a1");
  EXPECT_EQ(j2->job_id, "b1");  // Not a2: place a is training.
  EXPECT_EQ(s.running(), 2);
  EXPECT_TRUE(s.training("a"));
  // Both slots are busy: the next Next() waits until one frees.
  std::future<std::optional<ScheduledJob>> next = std::async(std::launch::async, [&] { return s.Next(); });
  EXPECT_EQ(next.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  s.Finish("b");  // A slot frees, but a2 must wait for a1.
  EXPECT_EQ(next.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  s.Finish("a");
  ASSERT_EQ(next.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  std::optional<ScheduledJob> j3 = next.get();
  ASSERT_TRUE(j3.has_value());
  EXPECT_EQ(j3->job_id, "a2");
}

TEST(TrainingSchedulerTest, CancelRemovesAQueuedJobAndShutdownWakesWaiters) {
  TrainingScheduler s(1);
  s.Enqueue("a", "a1");
  s.Enqueue("a", "a2");
  EXPECT_TRUE(s.Cancel("a", "a1"));
  EXPECT_FALSE(s.Cancel("a", "a1"));
  EXPECT_FALSE(s.Cancel("nowhere", "x"));
  EXPECT_EQ(s.queued("a"), 1);
  EXPECT_EQ(Drain(&s, 1), (std::vector<std::string>{"a/a2"}));
  std::future<std::optional<ScheduledJob>> next = std::async(std::launch::async, [&] { return s.Next(); });
  EXPECT_EQ(next.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  s.Shutdown();
  ASSERT_EQ(next.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_FALSE(next.get().has_value());
}

}  // namespace
}  // namespace clnerf
