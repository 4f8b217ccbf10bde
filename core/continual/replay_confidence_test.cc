// Replay confidence (replay_confidence.h): the factor's rule where the
// answer is known, then on real renders: a teacher that agrees with itself
// keeps every label at full weight, a label whose two teachers' renders
// differ loses exactly the rule's share, a view θ_{t-2} never had keeps its
// weight, half-opaque labels lose the most, and factors multiply the seen
// weights already there.
#include "core/continual/replay_confidence.h"

#include <cmath>

#include "core/continual/continual_test_util.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(ReplayConfidenceTest, OptionsAreValidated) {
  EXPECT_TRUE(ReplayConfidenceOptions().Validate().ok());
  EXPECT_FALSE(ReplayConfidenceOptions().enabled());
  ReplayConfidenceOptions o;
  o.agreement_tolerance = -0.1f;
  EXPECT_FALSE(o.Validate().ok());
  o.agreement_tolerance = std::nanf("");
  EXPECT_FALSE(o.Validate().ok());
  o = ReplayConfidenceOptions();
  o.transmittance_weight = 1.5f;
  EXPECT_FALSE(o.Validate().ok());
  o.transmittance_weight = 1.0f;
  EXPECT_TRUE(o.Validate().ok());
  EXPECT_TRUE(o.enabled());
}

TEST(ReplayConfidenceTest, FactorRule) {
  ReplayConfidenceOptions off;
  EXPECT_EQ(ConfidenceFactor(0.5f, 0.5f, off), 1.0f);
  ReplayConfidenceOptions agree;
  agree.agreement_tolerance = 0.1f;
  EXPECT_FLOAT_EQ(ConfidenceFactor(0.0f, 0.5f, agree), 1.0f);
  EXPECT_FLOAT_EQ(ConfidenceFactor(0.1f, 0.5f, agree), 0.5f);   // Halves at the tolerance.
  EXPECT_FLOAT_EQ(ConfidenceFactor(0.3f, 0.5f, agree), 0.1f);   // 1 / (1 + 9).
  EXPECT_FLOAT_EQ(ConfidenceFactor(-1.0f, 0.5f, agree), 1.0f);  // No older render: untouched.
  EXPECT_LT(ConfidenceFactor(0.2f, 1.0f, agree), ConfidenceFactor(0.05f, 1.0f, agree));
  ReplayConfidenceOptions tr;
  tr.transmittance_weight = 0.8f;
  EXPECT_FLOAT_EQ(ConfidenceFactor(-1.0f, 0.0f, tr), 1.0f);  // Clear: the background shows.
  EXPECT_FLOAT_EQ(ConfidenceFactor(-1.0f, 1.0f, tr), 1.0f);  // Opaque.
  EXPECT_NEAR(ConfidenceFactor(-1.0f, 0.5f, tr), 0.2f, 1e-6f);
  EXPECT_LT(ConfidenceFactor(-1.0f, 0.5f, tr), ConfidenceFactor(-1.0f, 0.9f, tr));
}

// Two untrained models of the tiny scene (the rule needs renders, not good
// ones): `a` is θ_{t-1}, and the older teacher is `a` itself (agreement) or
// `b`, another initialisation (disagreement).
class ReplayConfidenceModelTest : public ::testing::Test {
 protected:
  void SetUp() override {
    seq_ = TinySequence(2, 16, 4);
    const Scene scan = seq_.ScanScene(0);
    const Normalization norm = ComputeNormalization(scan);
    const UpdateOptions uo = TinyOptions(ContinualMethod::kCLNeRF, 1);
    absl::StatusOr<NgpModel> a = NgpModel::Create(uo.model, norm, scan.kind, scan.background, 2, 7);
    absl::StatusOr<NgpModel> b = NgpModel::Create(uo.model, norm, scan.kind, scan.background, 1, 8);
    ASSERT_TRUE(a.ok() && b.ok());
    a_ = std::make_unique<NgpModel>(std::move(*a));
    b_ = std::make_unique<NgpModel>(std::move(*b));
    cams_ = {seq_.scans[0].train[0].camera, seq_.scans[1].train[0].camera};  // Time steps 0 and 1.
    ASSERT_EQ(cams_[1].time_step, 1);
    absl::StatusOr<std::vector<ReplayLabelView>> l = RenderReplayLabels(*a_, cams_, 40, 3, nullptr, nullptr, nullptr);
    ASSERT_TRUE(l.ok()) << l.status();
    labels_ = std::move(*l);
    ASSERT_EQ(labels_[0].pixels.size(), 40u);
  }

  ScanSequence seq_;
  std::unique_ptr<NgpModel> a_, b_;
  std::vector<Camera> cams_;
  std::vector<ReplayLabelView> labels_;
};

TEST_F(ReplayConfidenceModelTest, AgreeingTeachersKeepFullWeight) {
  ReplayConfidenceOptions o;
  o.agreement_tolerance = 0.05f;
  std::vector<ReplayLabelView> l = labels_;
  ReplayConfidenceReport r;
  ASSERT_TRUE(ApplyReplayConfidence(a_.get(), cams_, o, nullptr, &l, &r).ok());
  EXPECT_EQ(r.labels, 80);
  EXPECT_EQ(r.compared, 80);  // `a` has both time steps.
  for (const ReplayLabelView& v : l) {
    ASSERT_EQ(v.weight.size(), v.pixels.size());
    for (float w : v.weight) EXPECT_NEAR(w, 1.0f, 1e-5f);
  }
}

TEST_F(ReplayConfidenceModelTest, ALabelTheTeachersDisagreeOnGetsTheLowerWeight) {
  ReplayConfidenceOptions o;
  o.agreement_tolerance = 0.05f;
  std::vector<ReplayLabelView> l = labels_;
  l[0].weight.assign(l[0].pixels.size(), 0.25f);  // A seen weight already there is multiplied.
  ReplayConfidenceReport r;
  ASSERT_TRUE(ApplyReplayConfidence(b_.get(), cams_, o, nullptr, &l, &r).ok());
  EXPECT_EQ(r.compared, 40) << "b has no time step 1: only view 0 is compared";
  // View 1 (time step 1, which θ_{t-2} never had) keeps weight 1.
  for (float w : l[1].weight) EXPECT_EQ(w, 1.0f);
  // View 0: each label's factor follows its two renders' difference.
  std::vector<float> older(3 * l[0].pixels.size());
  ASSERT_TRUE(RenderLabelPixels(*b_, cams_[0], l[0].pixels, RenderOptions{}, older.data(), nullptr));
  int lowered = 0;
  float min_d = 1, max_d = 0, w_at_min = 0, w_at_max = 0;
  for (size_t k = 0; k < l[0].pixels.size(); ++k) {
    const float* x = labels_[0].rgb.rgb.data() + 3 * k;
    const float d = (std::abs(x[0] - older[3 * k]) + std::abs(x[1] - older[3 * k + 1]) +
                     std::abs(x[2] - older[3 * k + 2])) / 3.0f;
    const float want = 0.25f / (1.0f + (d / 0.05f) * (d / 0.05f));
    EXPECT_NEAR(l[0].weight[k], want, 1e-4f) << "label " << k << ", difference " << d;
    lowered += l[0].weight[k] < 0.25f * 0.99f;
    if (d < min_d) min_d = d, w_at_min = l[0].weight[k];
    if (d > max_d) max_d = d, w_at_max = l[0].weight[k];
  }
  ASSERT_GT(max_d, min_d) << "two initialisations should render differently";
  EXPECT_GT(lowered, 0);
  EXPECT_LT(w_at_max, w_at_min);
  EXPECT_LT(r.mean_factor, 1.0);
}

TEST_F(ReplayConfidenceModelTest, HalfOpaqueLabelsLoseTheMostAndOffChangesNothing) {
  std::vector<ReplayLabelView> l = labels_;
  l[0].opacity = std::vector<float>(40, 1.0f);
  l[0].opacity[3] = 0.5f;
  l[0].opacity[7] = 0.0f;
  l[0].opacity[9] = 0.9f;
  ReplayConfidenceOptions off;
  ASSERT_TRUE(ApplyReplayConfidence(nullptr, cams_, off, nullptr, &l, nullptr).ok());
  EXPECT_TRUE(l[0].weight.empty()) << "off: labels untouched";
  ReplayConfidenceOptions o;
  o.transmittance_weight = 0.75f;
  ASSERT_TRUE(ApplyReplayConfidence(nullptr, cams_, o, nullptr, &l, nullptr).ok());
  EXPECT_FLOAT_EQ(l[0].weight[3], 0.25f);
  EXPECT_FLOAT_EQ(l[0].weight[7], 1.0f);
  EXPECT_FLOAT_EQ(l[0].weight[0], 1.0f);
  EXPECT_GT(l[0].weight[9], l[0].weight[3]);
  EXPECT_LT(l[0].weight[9], 1.0f);
  // Labels without opacity cannot be weighted.
  l[0].opacity.clear();
  EXPECT_EQ(ApplyReplayConfidence(nullptr, cams_, o, nullptr, &l, nullptr).code(),
            absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace clnerf
