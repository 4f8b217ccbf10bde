#include "core/continual/deployment_gate.h"

#include <limits>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(DeploymentGateTest, ReplayDropIsMeasuredFromWhatThePlaceGeneralisesTo) {
  const GateOptions o;  // Drop 2 dB, margin 2 dB.
  // The tiny place of the browser test: 45.4 dB memorised on its buffered
  // images, 24.5 on held-out views; after a short update 27.1 on the
  // buffered images is still above 24.5 + 2 - 2.
  EXPECT_TRUE(CheckReplayDrop(45.4, 27.1, 24.5, o).ok());
  // Below the capped baseline by more than the drop: refused, with both figures.
  absl::Status s = CheckReplayDrop(45.4, 22.0, 24.5, o);
  EXPECT_TRUE(absl::IsFailedPrecondition(s)) << s;
  EXPECT_NE(s.message().find("45.40 to 22.00"), std::string::npos) << s;
  EXPECT_NE(s.message().find("24.50"), std::string::npos) << s;
  // A place that generalises (buffered 30.0, held-out 29.0): no cap, the
  // plain 2 dB rule.
  EXPECT_TRUE(CheckReplayDrop(30.0, 28.1, 29.0, o).ok());
  EXPECT_FALSE(CheckReplayDrop(30.0, 27.9, 29.0, o).ok());
  // Unknown place quality, or the cap off: the plain rule.
  EXPECT_FALSE(CheckReplayDrop(45.4, 27.1, 0.0, o).ok());
  GateOptions off = o;
  off.replay_memorised_margin_db = -1;
  EXPECT_FALSE(CheckReplayDrop(45.4, 27.1, 24.5, off).ok());
}

TEST(DeploymentGateTest, OptionsAreValidated) {
  EXPECT_TRUE(GateOptions().Validate().ok());
  GateOptions o;
  o.replay_memorised_margin_db = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(o.Validate().ok());
  o = GateOptions();
  o.max_replay_drop_db = -1;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace clnerf
