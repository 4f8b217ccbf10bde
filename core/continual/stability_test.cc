#include "core/continual/stability.h"

#include <cstdio>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

StabilityOptions Tiny() {
  StabilityOptions o;
  o.scans = 3;
  o.chain_scans = 4;
  o.image_size = 12;
  o.train_views = 6;
  o.test_views = 2;
  o.iterations = 12;
  o.buffer = 2;
  o.batch_samples = 1 << 12;
  o.model.grid.levels = 8;
  o.capacity.min_log2_table_size = 10;
  o.capacity.max_log2_table_size = 12;
  o.seed = 3;
  o.gate.min_new_psnr = 5.0f;  // Tiny budgets: the gate's floors scaled down.
  o.gate.min_replay_consistency_psnr = 5.0f;
  o.gate.max_replay_drop_db = 30.0f;
  return o;
}

// Every stressor class at tiny scale, through CLNeRF: each stressed update
// either is deployed with finite parameters or is refused with a reason; in
// every case θ_{t-1} and M_{t-1} are bit-identical afterwards and nothing
// non-finite is ever deployed.
TEST(StabilityTest, EveryStressorSucceedsFinitelyOrFailsCleanly) {
  const StabilityOptions o = Tiny();
  for (Stressor s : AllStressors()) {
    SCOPED_TRACE(StressorName(s));
    absl::StatusOr<StabilityCell> c = RunStabilityCell("clnerf", s, o);
    ASSERT_TRUE(c.ok()) << c.status();
    EXPECT_TRUE(c->applicable);
    EXPECT_TRUE(c->deployed_always_finite);
    EXPECT_TRUE(c->previous_always_intact);
    EXPECT_TRUE(c->has_model);  // The unstressed first scan is always deployed.
    EXPECT_EQ(c->updates, s == Stressor::kChain20 ? o.chain_scans : o.scans);
    if (!c->stressed_deployed) {
      EXPECT_FALSE(c->reason.empty());
    }
    if (c->has_model) {
      EXPECT_TRUE(std::isfinite(c->psnr) && c->psnr > 0) << c->psnr;
    }
    EXPECT_FALSE(c->Summary().empty());
    std::printf("%-13s %-22s %.2fs\n", StressorName(s), c->Summary().c_str(), c->seconds);
  }
}

// What the stressors must do, specifically.
TEST(StabilityTest, StressorsHaveTheirIntendedEffect) {
  const StabilityOptions o = Tiny();
  // Control.
  absl::StatusOr<StabilityCell> none = RunStabilityCell("clnerf", Stressor::kNone, o);
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_TRUE(none->stressed_deployed) << none->reason;
  EXPECT_EQ(none->scored_scans, o.scans);
  EXPECT_EQ(none->skipped_batches, 0);
  // A NaN in one gradient is skipped, not fatal.
  absl::StatusOr<StabilityCell> nan = RunStabilityCell("clnerf", Stressor::kNanGradient, o);
  ASSERT_TRUE(nan.ok()) << nan.status();
  EXPECT_TRUE(nan->stressed_deployed) << nan->reason;
  EXPECT_EQ(nan->skipped_batches, 1);
  // θ_{t-1} with an older version's replay memory is refused with a reason,
  // and θ_{t-1} stays deployed (two scans held).
  absl::StatusOr<StabilityCell> stale = RunStabilityCell("clnerf", Stressor::kStaleMemory, o);
  ASSERT_TRUE(stale.ok()) << stale.status();
  EXPECT_FALSE(stale->stressed_deployed);
  EXPECT_EQ(stale->failed, 1);
  EXPECT_NE(stale->reason.find("replay memory"), std::string::npos) << stale->reason;
  EXPECT_EQ(stale->scored_scans, o.scans - 1);
  EXPECT_EQ(stale->Summary(), "failed -> refused");
  // The upper bound has no memory.
  absl::StatusOr<StabilityCell> ub_stale = RunStabilityCell("ub", Stressor::kStaleMemory, o);
  ASSERT_TRUE(ub_stale.ok());
  EXPECT_FALSE(ub_stale->applicable);
  EXPECT_EQ(ub_stale->Summary(), "n/a");
  absl::StatusOr<StabilityCell> ub = RunStabilityCell("ub", Stressor::kNone, o);
  ASSERT_TRUE(ub.ok()) << ub.status();
  EXPECT_TRUE(ub->stressed_deployed) << ub->reason;
  EXPECT_EQ(ub->scored_scans, o.scans);
  EXPECT_FALSE(RunStabilityCell("sgd", Stressor::kNone, o).ok());
}

TEST(StabilityTest, NamesRoundTripAndOptionsAreValidated) {
  for (Stressor s : AllStressors()) EXPECT_EQ(*ParseStressor(StressorName(s)), s);
  EXPECT_EQ(AllStressors().size(), 10u);
  EXPECT_FALSE(ParseStressor("lr_x100").ok());
  StabilityOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.scans = 1;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace clnerf
