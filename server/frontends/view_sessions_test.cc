#include "server/frontends/view_sessions.h"

#include <string>
#include <thread>
#include <vector>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(ViewSessionsTest, ANewerRequestOfTheSameViewSupersedesTheOlder) {
  ViewSessions s;
  ViewSessions::Ticket a1 = s.Begin("left");
  ViewSessions::Ticket b1 = s.Begin("right");
  EXPECT_FALSE(a1.superseded());
  ViewSessions::Ticket a2 = s.Begin("left");
  EXPECT_TRUE(a1.superseded());
  EXPECT_FALSE(a2.superseded());
  EXPECT_FALSE(b1.superseded()) << "another view is not affected";
  ViewSessions::Ticket a3 = s.Begin("left");
  EXPECT_TRUE(a2.superseded());
  EXPECT_FALSE(a3.superseded());
}

TEST(ViewSessionsTest, UntrackedRequestsAreNeverSuperseded) {
  ViewSessions s;
  ViewSessions::Ticket a = s.Begin("");
  ViewSessions::Ticket b = s.Begin("");
  EXPECT_FALSE(a.superseded());
  EXPECT_FALSE(b.superseded());
  EXPECT_EQ(s.tracked_views(), 0u);
}

TEST(ViewSessionsTest, IdleViewsAreForgottenBeyondTheBound) {
  ViewSessions s;
  ViewSessions::Ticket held = s.Begin("held");
  for (size_t i = 0; i < ViewSessions::kMaxViews + 10; ++i) s.Begin("v" + std::to_string(i));
  EXPECT_LE(s.tracked_views(), ViewSessions::kMaxViews);
  EXPECT_FALSE(held.superseded());
  // The held view is still tracked: a newer request supersedes it.
  ViewSessions::Ticket again = s.Begin("held");
  EXPECT_TRUE(held.superseded());
  EXPECT_FALSE(again.superseded());
}

TEST(ViewSessionsTest, ConcurrentBeginsLeaveExactlyOneCurrentTicket) {
  ViewSessions s;
  std::vector<ViewSessions::Ticket> tickets(64);
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int i = t; i < 64; i += 4) tickets[size_t(i)] = s.Begin("one");
    });
  }
  for (auto& th : threads) th.join();
  int current = 0;
  for (const auto& tk : tickets) current += !tk.superseded();
  EXPECT_EQ(current, 1);
}

}  // namespace
}  // namespace clnerf
