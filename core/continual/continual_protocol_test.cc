#include "core/continual/continual_protocol.h"

#include "core/continual/continual_update.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(ContinualProtocolTest, UpperBoundBudgetIsTasksTimesIterationsByDefault) {
  absl::StatusOr<UbBudget> def = ParseUbBudget("total");
  ASSERT_TRUE(def.ok());
  EXPECT_EQ(UpperBoundIterations(*def, 10, 300), 3000);
  EXPECT_EQ(UpperBoundIterations(UbBudget::kTotal, 5, 200), 1000);
  EXPECT_EQ(UpperBoundIterations(UbBudget::kPerStep, 10, 300), 300);
  EXPECT_EQ(UpperBoundIterations(UbBudget::kTotal, 1, 300), 300);
  EXPECT_EQ(UpperBoundIterations(UbBudget::kTotal, 1 << 20, 1 << 20), std::numeric_limits<int>::max());
  EXPECT_EQ(*ParseUbBudget("per-step"), UbBudget::kPerStep);
  EXPECT_FALSE(ParseUbBudget("all").ok());
  EXPECT_STREQ(UbBudgetName(UbBudget::kTotal), "total");
}

// A hand-made 3-task matrix: scan 0 goes 30 -> 28 -> 27, scan 1 25 -> 26.
// BWT = ((27 - 30) + (26 - 25)) / 2 = -1; final mean (27 + 26 + 20) / 3.
TEST(ContinualProtocolTest, BackwardTransferOfAHandMadeMatrix) {
  const std::vector<std::vector<double>> r = {{30}, {28, 25}, {27, 26, 20}};
  absl::StatusOr<ForgettingSummary> s = SummarizeForgetting(r);
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_EQ(s->tasks, 3);
  EXPECT_DOUBLE_EQ(s->backward_transfer, -1.0);
  EXPECT_DOUBLE_EQ(s->final_mean, 73.0 / 3.0);
  EXPECT_DOUBLE_EQ(s->max_drop, 3.0);
  EXPECT_EQ(s->final_per_scan, (std::vector<double>{27, 26, 20}));

  // No forgetting at all: BWT 0; positive transfer is positive.
  EXPECT_DOUBLE_EQ(SummarizeForgetting({{20}, {20, 21}})->backward_transfer, 0.0);
  EXPECT_DOUBLE_EQ(SummarizeForgetting({{20}, {22, 21}})->backward_transfer, 2.0);
  // One task: nothing to forget.
  EXPECT_DOUBLE_EQ(SummarizeForgetting({{20}})->backward_transfer, 0.0);
  EXPECT_DOUBLE_EQ(SummarizeForgetting({{20}})->final_mean, 20.0);
}

TEST(ContinualProtocolTest, MalformedMatricesAreRejected) {
  EXPECT_FALSE(SummarizeForgetting({}).ok());
  EXPECT_FALSE(SummarizeForgetting({{30}, {28}}).ok());          // Row 1 too short.
  EXPECT_FALSE(SummarizeForgetting({{30, 1}, {28, 25}}).ok());   // Row 0 too long.
  EXPECT_FALSE(SummarizeForgetting({{30}, {NAN, 25}}).ok());
}

TEST(ContinualProtocolTest, ModeNamesRoundTripAndUnknownNamesAreRefused) {
  for (InitMode m : {InitMode::kWarm, InitMode::kReinit}) EXPECT_EQ(*ParseInitMode(InitModeName(m)), m);
  for (ReplayMode m : {ReplayMode::kOffline, ReplayMode::kOnline}) EXPECT_EQ(*ParseReplayMode(ReplayModeName(m)), m);
  EXPECT_STREQ(InitModeName(InitMode::kWarm), "warm");
  EXPECT_STREQ(ReplayModeName(ReplayMode::kOffline), "offline");
  EXPECT_EQ(ParseInitMode("cold").status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ParseReplayMode("").status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace clnerf
