// Replay weights (replay_weights.h): the visibility rule on hand-made
// geometry where the answer is known, then end to end on a tiny trained
// model: a new camera that sees a past view's surface unchanged lowers those
// labels' weight, a changed surface or a camera looking away does not, and
// the sampler's rays carry the weights.
#include "core/continual/replay_weights.h"

#include <set>

#include "core/continual/continual_sampler.h"
#include "core/continual/continual_test_util.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

Camera TenByTen() {
  Camera c;
  c.intrinsics.width = c.intrinsics.height = 10;
  c.intrinsics.fx = c.intrinsics.fy = 10;
  c.intrinsics.cx = c.intrinsics.cy = 5;
  return c;  // At the origin, looking along +z (OpenCV).
}

TEST(ReplayWeightsTest, OptionsAreValidated) {
  EXPECT_TRUE(ReplayWeightOptions().Validate().ok());
  ReplayWeightOptions o;
  o.seen_weight = 1.5f;
  EXPECT_FALSE(o.Validate().ok());
  o = ReplayWeightOptions();
  o.colour_tolerance = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = ReplayWeightOptions();
  o.depth_map_max_side = 1;
  EXPECT_FALSE(o.Validate().ok());
  o = ReplayWeightOptions();
  o.min_opacity = std::nanf("");
  EXPECT_FALSE(o.Validate().ok());
}

TEST(ReplayWeightsTest, SeenMeansInFrontInsideUnoccludedAndUnchanged) {
  const Camera cam = TenByTen();
  View view;
  view.camera = cam;
  view.image = Image(10, 10, 0.3f);
  NewViewDepth dm;
  dm.small = cam;
  dm.small.intrinsics = cam.intrinsics.Scaled(5, 5);
  dm.depth.assign(25, 2.0f);
  ReplayWeightOptions o;
  const float label[3] = {0.32f, 0.3f, 0.28f};
  const Eigen::Vector3f x(0.1f, -0.1f, 2.0f);
  EXPECT_TRUE(SeenByNewView(x, label, view, cam, dm, o));
  // Behind the camera, or outside its image.
  EXPECT_FALSE(SeenByNewView(Eigen::Vector3f(0, 0, -2), label, view, cam, dm, o));
  EXPECT_FALSE(SeenByNewView(Eigen::Vector3f(3, 0, 2), label, view, cam, dm, o));
  // Occluded: θ_{t-1} puts a surface at 1.5 along that new ray.
  NewViewDepth nearer = dm;
  nearer.depth.assign(25, 1.5f);
  EXPECT_FALSE(SeenByNewView(x, label, view, cam, nearer, o));
  // Changed: the new photo shows another colour there.
  View changed = view;
  changed.image = Image(10, 10, 0.8f);
  EXPECT_FALSE(SeenByNewView(x, label, changed, cam, dm, o));
  // Masked out in the new photo.
  View masked = view;
  masked.mask.width = masked.mask.height = 10;
  masked.mask.keep.assign(100, 0);
  EXPECT_FALSE(SeenByNewView(x, label, masked, cam, dm, o));
}

// θ_0 trained once on the tiny scene for the whole suite (training is the
// suite's cost, ten times more under ASan), and its labels of one past view.
class ReplayWeightsModelTest : public ::testing::Test {
 protected:
  struct Shared {
    ScanSequence seq;
    ContinualState state;
    Camera past;
    std::vector<ReplayLabelView> labels;
  };
  static void SetUpTestSuite() {
    shared_ = new Shared;
    shared_->seq = TinySequence(2);
    absl::StatusOr<ContinualState> s = ContinualUpdate(shared_->seq.ScanScene(0), nullptr,
                                                       TinyOptions(ContinualMethod::kCLNeRF, 150), nullptr, nullptr, nullptr);
    ASSERT_TRUE(s.ok()) << s.status();
    shared_->state = std::move(*s);
    shared_->past = shared_->seq.scans[0].train[0].camera;
    absl::StatusOr<std::vector<ReplayLabelView>> l =
        RenderReplayLabels(*shared_->state.model, {shared_->past}, 0, 1, nullptr, nullptr, nullptr);
    ASSERT_TRUE(l.ok()) << l.status();
    shared_->labels = std::move(*l);
  }
  static void TearDownTestSuite() {
    delete shared_;
    shared_ = nullptr;
  }
  void SetUp() override {
    ASSERT_NE(shared_->state.model, nullptr) << "training θ_0 failed";
    ASSERT_EQ(shared_->labels.size(), 1u);
    ASSERT_EQ(labels_[0].depth.size(), labels_[0].rgb.num_pixels());
    ASSERT_EQ(labels_[0].opacity.size(), labels_[0].rgb.num_pixels());
  }
  // Weights of the past view's labels when the new scan is `view`.
  std::vector<float> Weights(const View& view, long long* seen) {
    std::vector<ReplayLabelView> l = labels_;
    ReplayWeightOptions o;
    o.seen_weight = 0.25f;
    ReplayWeightReport r;
    const absl::Status s = WeightReplayLabels(*state_.model, {past_}, {view}, o, nullptr, &l, &r);
    EXPECT_TRUE(s.ok()) << s;
    EXPECT_EQ(r.labels, (long long)labels_[0].rgb.num_pixels());
    *seen = r.seen;
    return l[0].weight;
  }
  long long Opaque() const {
    long long n = 0;
    for (size_t k = 0; k < labels_[0].opacity.size(); ++k) n += labels_[0].opacity[k] >= 0.5f && labels_[0].depth[k] > 0;
    return n;
  }

  static Shared* shared_;
  const ContinualState& state_ = shared_->state;
  const Camera& past_ = shared_->past;
  const std::vector<ReplayLabelView>& labels_ = shared_->labels;
};
ReplayWeightsModelTest::Shared* ReplayWeightsModelTest::shared_ = nullptr;

TEST_F(ReplayWeightsModelTest, ARayTheNewCameraSeesUnchangedGetsTheLowerWeight) {
  const long long opaque = Opaque();
  ASSERT_GT(opaque, (long long)labels_[0].rgb.num_pixels() / 4) << "the tiny scene should have surfaces";
  // The new scan photographs the same surface from the same place, unchanged.
  View same;
  same.camera = past_;
  same.camera.time_step = 1;
  same.image = labels_[0].rgb;
  long long seen = 0;
  std::vector<float> w = Weights(same, &seen);
  ASSERT_EQ(w.size(), labels_[0].rgb.num_pixels());
  EXPECT_GE(seen, opaque * 9 / 10);
  for (size_t k = 0; k < w.size(); ++k) {
    if (labels_[0].opacity[k] < 0.5f) {
      EXPECT_EQ(w[k], 1.0f) << "a ray with no surface has nothing to see, pixel " << k;
    } else {
      EXPECT_TRUE(w[k] == 0.25f || w[k] == 1.0f);
    }
  }
  // The surface changed colour since: replay keeps teaching it.
  View changed = same;
  for (float& c : changed.image.rgb) c = c > 0.5f ? c - 0.5f : c + 0.5f;
  Weights(changed, &seen);
  EXPECT_EQ(seen, 0);
  // A camera at the same place looking the other way sees none of it.
  View away = same;
  away.camera.c2w.leftCols<3>() = -away.camera.c2w.leftCols<3>() * Eigen::Vector3f(1, -1, 1).asDiagonal();
  Weights(away, &seen);
  EXPECT_EQ(seen, 0);
}

TEST_F(ReplayWeightsModelTest, ASeenLabelCanTakeThePhotosColour) {
  // The new photo shows the same surface a little brighter (within the
  // colour tolerance): seen labels take the photo's colour, the rest keep
  // θ_{t-1}'s render.
  View brighter;
  brighter.camera = past_;
  brighter.camera.time_step = 1;
  brighter.image = labels_[0].rgb;
  for (float& c : brighter.image.rgb) c = std::min(1.0f, c + 0.05f);
  std::vector<ReplayLabelView> l = labels_;
  ReplayWeightOptions o;
  o.seen_weight = 1.0f;  // Weight unchanged: only the colour moves.
  o.seen_label_from_photo = true;
  ReplayWeightReport r;
  ASSERT_TRUE(WeightReplayLabels(*state_.model, {past_}, {brighter}, o, nullptr, &l, &r).ok());
  ASSERT_GT(r.seen, 0);
  long long moved = 0;
  for (size_t k = 0; k < l[0].rgb.num_pixels(); ++k) {
    const bool same = l[0].rgb.rgb[3 * k] == labels_[0].rgb.rgb[3 * k];
    if (!same) {
      // The photo's pixel this label's surface projects to: the same pixel
      // or a neighbour, so its colour is a brighter label colour nearby.
      EXPECT_GE(l[0].rgb.rgb[3 * k], 0.05f - 1e-6f);
      ++moved;
    }
    EXPECT_EQ(l[0].weight[k], 1.0f);
  }
  // Only seen labels move (a label already at 1 cannot get brighter).
  EXPECT_LE(moved, r.seen);
  EXPECT_GE(moved, r.seen * 9 / 10);
}

TEST_F(ReplayWeightsModelTest, SeenWeightZeroDropsTheLabelsAndTheSamplerCarriesWeights) {
  View same;
  same.camera = past_;
  same.camera.time_step = 1;
  same.image = labels_[0].rgb;
  std::vector<ReplayLabelView> dropped = labels_;
  ReplayWeightOptions o;
  o.seen_weight = 0.0f;
  ReplayWeightReport r;
  ASSERT_TRUE(WeightReplayLabels(*state_.model, {past_}, {same}, o, nullptr, &dropped, &r).ok());
  ASSERT_GT(r.seen, 0);
  EXPECT_EQ((long long)dropped[0].pixels.size() + r.seen, (long long)labels_[0].rgb.num_pixels());
  EXPECT_EQ(dropped[0].rgb.num_pixels(), dropped[0].pixels.size());
  for (size_t k = 0; k < dropped[0].pixels.size(); ++k) {  // Kept labels are the unseen ones, unchanged.
    const uint32_t p = dropped[0].pixels[k];
    EXPECT_EQ(dropped[0].rgb.rgb[3 * k], labels_[0].rgb.rgb[3 * p]);
  }

  // The sampler: every ray of a weighted replay view carries its label's weight.
  std::vector<ReplayLabelView> weighted = labels_;
  o.seen_weight = 0.25f;
  ASSERT_TRUE(WeightReplayLabels(*state_.model, {past_}, {same}, o, nullptr, &weighted, &r).ok());
  SamplerView sv{past_, &weighted[0].rgb, nullptr, true, true};
  sv.label_weight = &weighted[0].weight;
  ContinualRaySampler sampler({sv}, *state_.model, nullptr, 0.0f);
  std::mt19937_64 rng(5);
  RayBatch b;
  sampler.Sample(2000, &rng, &b);
  std::set<float> got;
  for (int i = 0; i < b.size(); ++i) got.insert(b.weight[i]);
  EXPECT_EQ(got, (std::set<float>{0.25f, 1.0f}));
  for (int i = 0; i < b.size(); ++i) EXPECT_EQ(b.depth[i], 0.0f) << "no depth distillation asked";

  // Depth distillation: replay rays of opaque labels carry θ_{t-1}'s surface
  // distance (and their weight), the others none.
  const long long targets = SetDistillationDepths(0.9f, &weighted[0]);
  ASSERT_GT(targets, 0);
  sv.label_depth = &weighted[0].target_depth;
  ContinualRaySampler depth_sampler({sv}, *state_.model, nullptr, 0.0f);
  std::mt19937_64 rng2(5);
  depth_sampler.Sample(2000, &rng2, &b);
  const std::set<float> allowed(weighted[0].target_depth.begin(), weighted[0].target_depth.end());
  int with_depth = 0;
  for (int i = 0; i < b.size(); ++i) {
    EXPECT_TRUE(allowed.count(b.depth[i])) << "ray " << i << " depth " << b.depth[i] << " is no label's target";
    with_depth += b.depth[i] > 0;
  }
  // About the opaque labels' share of the 2000 draws.
  const double share = double(targets) / double(weighted[0].target_depth.size());
  EXPECT_NEAR(with_depth / 2000.0, share, 0.05);
}

}  // namespace
}  // namespace clnerf
