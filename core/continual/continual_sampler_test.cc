// ContinualRaySampler with error sampling (view_error_sampler.h): replay
// labels θ_t already matches get few rays and the new scan's photo most;
// when a replay view drifts its share comes back; every ray still carries
// its own label or pixel colour.
#include "core/continual/continual_sampler.h"

#include "core/continual/continual_test_util.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

class ContinualSamplerErrorTest : public ::testing::Test {
 protected:
  void SetUp() override {
    seq_ = TinySequence(2, 16, 2);
    const Scene scan = seq_.ScanScene(0);
    const UpdateOptions uo = TinyOptions(ContinualMethod::kCLNeRF, 1);
    absl::StatusOr<NgpModel> m =
        NgpModel::Create(uo.model, ComputeNormalization(scan), scan.kind, scan.background, 2, 7);
    ASSERT_TRUE(m.ok()) << m.status();
    model_ = std::make_unique<NgpModel>(std::move(*m));
    // A replay view of step 0 with labels for every other pixel (colour
    // 0.25), and the new scan's photo at step 1 (its own image).
    for (uint32_t p = 0; p < 256; p += 2) label_pixels_.push_back(p);
    labels_ = Image(int(label_pixels_.size()), 1, 0.25f);
    photo_ = seq_.scans[1].train[0];
  }

  std::vector<SamplerView> Views() {
    SamplerView replay{seq_.scans[0].train[0].camera, &labels_, nullptr, true, true};
    replay.label_pixels = &label_pixels_;
    SamplerView photo{photo_.camera, &photo_.image, nullptr, false, false};
    return {replay, photo};
  }
  // Share of the batch's rays from the photo (time step 1).
  static double PhotoShare(const RayBatch& b) {
    int n = 0;
    for (int i = 0; i < b.size(); ++i) n += b.time_step[i] == 1;
    return double(n) / b.size();
  }

  ScanSequence seq_;
  std::unique_ptr<NgpModel> model_;
  std::vector<uint32_t> label_pixels_;
  Image labels_;
  View photo_;
};

TEST_F(ContinualSamplerErrorTest, RaysGoWhereTheErrorIsAndComeBackWhenReplayDrifts) {
  ContinualRaySampler sampler(Views(), *model_, nullptr, 0.0f);
  ViewErrorOptions o;
  o.error_share = 0.8f;
  o.tiles = 2;
  o.decay = 0.5f;
  sampler.SetViewErrorSampling(o);
  std::mt19937_64 rng(9);
  RayBatch b;
  sampler.Sample(4000, &rng, &b);
  EXPECT_NEAR(PhotoShare(b), 0.5, 0.03) << "uniform over views before any error";
  // θ_t matches the replay labels exactly; the photo is all wrong.
  auto errors = [&](float replay, float photo) {
    std::vector<float> e(b.size());
    for (int i = 0; i < b.size(); ++i) e[i] = b.time_step[i] == 1 ? photo : replay;
    return e;
  };
  sampler.ObserveErrors(b, errors(0.0f, 0.1f));
  sampler.Sample(4000, &rng, &b);
  EXPECT_GT(PhotoShare(b), 0.85);
  EXPECT_GT(sampler.ViewProbabilities()[1], 0.85);
  for (int i = 0; i < b.size(); ++i) {
    if (b.time_step[i] == 0) {
      EXPECT_EQ(b.target[3 * size_t(i)], 0.25f) << "a replay ray carries its label";
      EXPECT_EQ(b.view[i], -1);
    } else {
      EXPECT_EQ(b.view[i], 1);
    }
  }
  // The replay view drifts while the photo is learnt: its share returns.
  for (int k = 0; k < 6; ++k) {
    sampler.ObserveErrors(b, errors(0.1f, 0.0f));
    sampler.Sample(4000, &rng, &b);
  }
  EXPECT_LT(PhotoShare(b), 0.2);
  EXPECT_NEAR(sampler.ViewProbabilities()[0] + sampler.ViewProbabilities()[1], 1.0, 1e-9);
}

TEST_F(ContinualSamplerErrorTest, OffOrWithAFixedNewShareTheDrawsAreUnchanged) {
  std::mt19937_64 r1(5), r2(5);
  RayBatch a, b;
  ContinualRaySampler plain(Views(), *model_, nullptr, 0.0f);
  ContinualRaySampler off(Views(), *model_, nullptr, 0.0f);
  off.SetViewErrorSampling(ViewErrorOptions());  // error_share 0.
  plain.Sample(500, &r1, &a);
  off.Sample(500, &r2, &b);
  EXPECT_EQ(a.origin, b.origin);
  EXPECT_EQ(a.target, b.target);
  // With a fixed new-scan share (or MEIL) the share wins: half the rays
  // stay on the photo whatever the errors.
  ContinualRaySampler shared(Views(), *model_, nullptr, 0.0f, 0.5f);
  ViewErrorOptions o;
  o.error_share = 0.8f;
  shared.SetViewErrorSampling(o);
  shared.Sample(4000, &r1, &a);
  std::vector<float> e(a.size());
  for (int i = 0; i < a.size(); ++i) e[i] = a.time_step[i] == 0 ? 0.1f : 0.0f;
  shared.ObserveErrors(a, e);
  shared.Sample(4000, &r1, &a);
  EXPECT_NEAR(PhotoShare(a), 0.5, 0.001);
}

}  // namespace
}  // namespace clnerf
