#include "server/jobs/training_scheduler.h"

#include <atomic>
#include <chrono>
#include <thread>
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

// One worker per place asking for a slot (the server's use): a worker that
// comes back for its place's next scan queues behind places already waiting.
TEST(TrainingSchedulerTest, WorkersTakeTurnsAndACancelledWaitLeavesNoSlot) {
  TrainingScheduler s(1);
  std::atomic<bool> no{false};
  ASSERT_TRUE(s.Acquire("a", &no));
  std::future<bool> b = std::async(std::launch::async, [&] { return s.Acquire("b", &no); });
  EXPECT_EQ(b.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  s.Finish("a");
  ASSERT_EQ(b.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_TRUE(b.get());
  // a asks again while b trains; c asks after a: a goes next, then c.
  std::future<bool> a2 = std::async(std::launch::async, [&] { return s.Acquire("a", &no); });
  while (s.queued("a") == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  std::future<bool> c = std::async(std::launch::async, [&] { return s.Acquire("c", &no); });
  while (s.queued("c") == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  s.Finish("b");
  ASSERT_EQ(a2.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_TRUE(a2.get());
  EXPECT_EQ(c.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  // A waiting worker that is stopped gives up without taking a slot.
  std::atomic<bool> stop_d{false};
  std::future<bool> d = std::async(std::launch::async, [&] { return s.Acquire("d", &stop_d); });
  while (s.queued("d") == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  stop_d = true;
  s.Wake();
  ASSERT_EQ(d.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_FALSE(d.get());
  EXPECT_EQ(s.queued("d"), 0);
  s.Finish("a");
  ASSERT_EQ(c.wait_for(std::chrono::seconds(5)), std::future_status::ready);
  EXPECT_TRUE(c.get());
  EXPECT_EQ(s.running(), 1);
}

}  // namespace
}  // namespace clnerf
