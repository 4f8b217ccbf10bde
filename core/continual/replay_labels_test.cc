#include "core/continual/replay_labels.h"

#include <atomic>
#include <set>

#include "core/continual/continual_sampler.h"
#include "core/continual/continual_test_util.h"
#include "core/render/renderer.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(ReplayLabelsTest, OptionsAndBudget) {
  EXPECT_TRUE(ReplayLabelOptions().Validate().ok());
  ReplayLabelOptions bad;
  bad.labels_per_draw = -1;
  EXPECT_FALSE(bad.Validate().ok());
  bad.labels_per_draw = NAN;
  EXPECT_FALSE(bad.Validate().ok());
  bad = ReplayLabelOptions();
  bad.probe_rays = 0;
  EXPECT_FALSE(bad.Validate().ok());

  ReplayLabelOptions o;  // 4 labels per draw.
  EXPECT_EQ(LabelsPerView(1000.0, 10, o), 400);
  EXPECT_EQ(LabelsPerView(1.0, 10, o), 1);  // At least one label per view.
  o.labels_per_draw = 0;                    // Every pixel.
  EXPECT_GE(LabelsPerView(1000.0, 10, o), 1LL << 40);
  EXPECT_GE(LabelsPerView(0.0, 10, ReplayLabelOptions()), 1LL << 40);  // No estimate: every pixel.
}

// A subset's labels are θ_{t-1}'s renders of exactly those pixels; a budget
// at least a view's pixel count renders the whole view; the sampler draws
// only labelled pixels and pairs each with its own label.
TEST(ReplayLabelsTest, LabelsAreTheModelsRendersOfTheirPixels) {
  const ScanSequence seq = TinySequence(1, 16, 8);
  absl::StatusOr<ContinualState> s0 = ContinualUpdate(seq.ScanScene(0), nullptr, TinyOptions(ContinualMethod::kCLNeRF, 30),
                                                      nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok()) << s0.status();
  const NgpModel& model = *s0->model;
  std::vector<Camera> cams;
  for (uint32_t i = 0; i < 3; ++i) cams.push_back(s0->memory.GetCamera(i));
  const long long npix = 16 * 16;

  EXPECT_GT(ProbeSamplesPerRay(model, cams, 256, 7), 0.0);
  EXPECT_EQ(ProbeSamplesPerRay(model, {}, 256, 7), 0.0);

  ReplayLabelReport rep;
  int calls = 0;
  absl::StatusOr<std::vector<ReplayLabelView>> part =
      RenderReplayLabels(model, cams, 40, 11, nullptr, [&](int done, int total) {
        ++calls;
        EXPECT_EQ(total, 3);
        EXPECT_EQ(done, calls);
      }, &rep);
  ASSERT_TRUE(part.ok()) << part.status();
  ASSERT_EQ(part->size(), 3u);
  EXPECT_EQ(calls, 3);
  EXPECT_EQ(rep.labels, 3 * 40);
  EXPECT_EQ(rep.view_pixels, 3 * npix);
  // RGB, depth and opacity per label, and its pixel index.
  EXPECT_EQ(rep.bytes, 3 * 40 * (5 * sizeof(float) + sizeof(uint32_t)));
  for (size_t v = 0; v < cams.size(); ++v) {
    const ReplayLabelView& lv = (*part)[v];
    ASSERT_EQ(lv.pixels.size(), 40u);
    ASSERT_EQ(lv.rgb.num_pixels(), 40u);
    ASSERT_EQ(lv.depth.size(), 40u);
    ASSERT_EQ(lv.opacity.size(), 40u);
    EXPECT_EQ(std::set<uint32_t>(lv.pixels.begin(), lv.pixels.end()).size(), 40u) << "drawn without replacement";
    EXPECT_TRUE(std::is_sorted(lv.pixels.begin(), lv.pixels.end()));
    RenderOptions ro;
    ro.time_step = cams[v].time_step;
    absl::StatusOr<RenderedView> full = RenderView(model, cams[v], ro);
    ASSERT_TRUE(full.ok());
    for (size_t k = 0; k < lv.pixels.size(); ++k) {
      ASSERT_LT(lv.pixels[k], uint32_t(npix));
      // Different batch sizes may take different GEMM kernels: float
      // precision, not bit equality.
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(lv.rgb.rgb[3 * k + c], full->rgb.rgb[3 * size_t(lv.pixels[k]) + c], 1e-5f) << v << " " << k;
      }
    }
  }
  // Different views get different subsets.
  EXPECT_NE((*part)[0].pixels, (*part)[1].pixels);

  absl::StatusOr<std::vector<ReplayLabelView>> whole = RenderReplayLabels(model, cams, npix, 11, nullptr, {}, &rep);
  ASSERT_TRUE(whole.ok());
  EXPECT_TRUE((*whole)[0].pixels.empty());
  EXPECT_EQ((*whole)[0].rgb.num_pixels(), size_t(npix));
  EXPECT_EQ(rep.labels, 3 * npix);

  // The sampler: every drawn ray is a labelled pixel's ray, with its label.
  ContinualRaySampler sampler({{cams[0], &(*part)[0].rgb, nullptr, true, true, nullptr, &(*part)[0].pixels}}, model,
                              nullptr, 0.0f);
  std::mt19937_64 rng(5);
  RayBatch b;
  sampler.Sample(64, &rng, &b);
  const Camera mcam = model.ToModelCamera(cams[0]);
  int matched = 0;
  for (int i = 0; i < b.size(); ++i) {
    for (size_t k = 0; k < (*part)[0].pixels.size(); ++k) {
      float o[3], d[3];
      PixelRay(mcam, (*part)[0].pixels[k], o, d);
      if (std::abs(o[0] - b.origin[3 * i]) + std::abs(d[0] - b.dir[3 * i]) + std::abs(d[1] - b.dir[3 * i + 1]) +
              std::abs(d[2] - b.dir[3 * i + 2]) >
          1e-6f) {
        continue;
      }
      ++matched;
      for (int c = 0; c < 3; ++c) EXPECT_EQ(b.target[3 * i + c], (*part)[0].rgb.rgb[3 * k + c]);
      break;
    }
  }
  EXPECT_EQ(matched, b.size());

  std::atomic<bool> cancel{true};
  EXPECT_EQ(RenderReplayLabels(model, cams, 40, 11, &cancel, {}, nullptr).status().code(),
            absl::StatusCode::kCancelled);
}

// Through the update: the default budget renders a fraction of the past
// pixels when the update is short, and the whole views when asked.
TEST(ReplayLabelsTest, UpdateRendersWhatItCanDraw) {
  const ScanSequence seq = TinySequence(2, 16, 8);
  absl::StatusOr<ContinualState> s0 = ContinualUpdate(seq.ScanScene(0), nullptr, TinyOptions(ContinualMethod::kCLNeRF, 30),
                                                      nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok()) << s0.status();
  UpdateOptions o = TinyOptions(ContinualMethod::kCLNeRFNoER, 1);
  o.buffer_size = 0;
  UpdateReport rep;
  ASSERT_TRUE(ContinualUpdate(seq.ScanScene(1), &*s0, o, nullptr, nullptr, &rep).ok());
  EXPECT_EQ(rep.replay_view_pixels, 8 * 16 * 16);
  EXPECT_GT(rep.replay_probe_samples_per_ray, 0.0);
  // 1 step x (8192 / samples per ray) rays x 1/2 replay share x 4 labels
  // per draw, over 8 views.
  const double batch = std::clamp(8192.0 / rep.replay_probe_samples_per_ray, 256.0, 32768.0);
  const long long expect = std::min<long long>(16 * 16, (long long)std::ceil(4.0 * 1 * batch * 0.5 / 8));
  EXPECT_EQ(rep.replay_labels, 8 * expect);
  EXPECT_LT(rep.replay_labels, rep.replay_view_pixels);
  EXPECT_EQ(rep.replay_depth_labels, 0);  // Depth distillation is off by default.
  o.replay_labels.labels_per_draw = 0;
  o.replay_labels.depth_min_opacity = 0.5f;
  ASSERT_TRUE(ContinualUpdate(seq.ScanScene(1), &*s0, o, nullptr, nullptr, &rep).ok());
  EXPECT_EQ(rep.replay_labels, 8 * 16 * 16);
  EXPECT_GT(rep.replay_depth_labels, 0);  // The tiny scene's object is opaque somewhere.
  EXPECT_LT(rep.replay_depth_labels, rep.replay_labels);  // Its white background is not.
}

// Depth distillation targets: depth / opacity where θ_{t-1} is opaque
// enough, none elsewhere, none at all when off.
TEST(ReplayLabelsTest, DistillationDepthsOnlyWhereOpaque) {
  ReplayLabelOptions bad;
  bad.depth_min_opacity = 1.5f;
  EXPECT_FALSE(bad.Validate().ok());
  bad.depth_min_opacity = NAN;
  EXPECT_FALSE(bad.Validate().ok());
  bad.depth_min_opacity = -0.1f;
  EXPECT_FALSE(bad.Validate().ok());

  ReplayLabelView v;
  v.depth = {1.8f, 0.5f, 0.0f, 2.0f};
  v.opacity = {0.9f, 0.4f, 1.0f, 1.0f};
  EXPECT_EQ(SetDistillationDepths(0.8f, &v), 2);
  ASSERT_EQ(v.target_depth.size(), 4u);
  EXPECT_FLOAT_EQ(v.target_depth[0], 2.0f);  // 1.8 / 0.9: the surface, not the expectation with the background.
  EXPECT_EQ(v.target_depth[1], 0.0f);        // Too translucent to trust.
  EXPECT_EQ(v.target_depth[2], 0.0f);        // No depth.
  EXPECT_FLOAT_EQ(v.target_depth[3], 2.0f);
  EXPECT_EQ(SetDistillationDepths(0.0f, &v), 0);  // Off.
  EXPECT_TRUE(v.target_depth.empty());
  ReplayLabelView no_depth;
  no_depth.opacity = {1.0f};
  EXPECT_EQ(SetDistillationDepths(0.5f, &no_depth), 0);
  EXPECT_TRUE(no_depth.target_depth.empty());
}

}  // namespace
}  // namespace clnerf
