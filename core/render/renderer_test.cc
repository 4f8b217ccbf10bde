// Renderer contracts: a view rendered in tiles equals its pixels rendered one
// ray at a time in image order, and the colour MLP's skipping of faint
// samples stays within its stated bound, including on hazy rays.
#include "core/render/renderer.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "core/field/bf16_mlp.h"
#include "core/field/field.h"
#include "core/field/ngp_model.h"
#include "core/render/volume_rendering.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

ModelOptions SmallOptions() {
  ModelOptions o;
  o.grid.levels = 4;
  o.grid.log2_table_size = 10;
  o.grid.base_resolution = 4;
  o.grid.finest_resolution = 32;
  o.network.density_hidden = 16;
  o.network.colour_hidden = 16;
  o.network.appearance_dim = 8;
  o.network.geometry_dim = 4;
  o.occupancy.resolution = 16;
  o.march.steps_per_diagonal = 256;  // ~150 samples across the box.
  o.sampler = SamplerKind::kOccupancy;
  return o;
}

NgpModel SmallModel(uint64_t seed) {
  auto m = NgpModel::Create(SmallOptions(), Normalization{}, SceneKind::kBounded, Eigen::Vector3f(0.2f, 0.4f, 0.6f),
                            /*num_time_steps=*/1, seed);
  EXPECT_TRUE(m.ok()) << m.status();
  return *std::move(m);
}

// A 37 x 23 camera (not a whole number of 32 x 16 tiles) at z = -1.3 looking
// along +z (OpenCV), seeing the whole box [-0.5, 0.5]^3.
Camera FrontCamera() {
  Camera c;
  c.intrinsics.width = 37;
  c.intrinsics.height = 23;
  c.intrinsics.fx = c.intrinsics.fy = 30.0f;
  c.intrinsics.cx = 18.5f;
  c.intrinsics.cy = 11.5f;
  c.c2w = Pose::Identity();
  c.c2w.col(3) = Eigen::Vector3f(0.0f, 0.0f, -1.3f);
  return c;
}

// Random features: density and colour vary along every ray.
NgpModel TexturedModel() {
  NgpModel model = SmallModel(3);
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (float& v : model.mutable_params().grid) v = u(rng);
  return model;
}

// Uniform haze of density sigma: constant features (so colour is constant
// along a ray) and a density MLP that maps them to log(sigma).
NgpModel HazeModel(float sigma) {
  NgpModel model = SmallModel(5);
  ModelParams& p = model.mutable_params();
  std::fill(p.grid.begin(), p.grid.end(), 0.5f);
  const Network& net = model.network();
  const Network::Layer& l0 = net.density_layers()[0];
  const Network::Layer& l1 = net.density_layers()[1];
  std::fill(p.mlp.begin() + l0.offset, p.mlp.begin() + l0.offset + size_t(l0.rows) * l0.cols, 0.0f);
  p.mlp[l0.offset] = 1.0f;  // Hidden unit 0 = relu(feature 0) = 0.5.
  for (int c = 0; c < l1.cols; ++c) p.mlp[l1.offset + size_t(c) * l1.rows] = 0.0f;  // Row 0: h0 ...
  p.mlp[l1.offset] = 2.0f * std::log(sigma);                                     // ... = log(sigma).
  return model;
}

float MaxAbsDiff(const std::vector<float>& a, const std::vector<float>& b) {
  float m = 0.0f;
  for (size_t i = 0; i < a.size(); ++i) m = std::max(m, std::abs(a[i] - b[i]));
  return m;
}

TEST(RendererTest, TiledViewEqualsItsPixelsRenderedOneByOne) {
  const NgpModel model = TexturedModel();
  const Camera cam = FrontCamera();
  RenderOptions ro;
  ro.threads = 2;
  absl::StatusOr<RenderedView> view = RenderView(model, cam, ro);
  ASSERT_TRUE(view.ok()) << view.status();
  const Camera mc = model.ToModelCamera(cam);
  RenderOptions one = ro;
  one.threads = 1;
  double opacity_sum = 0.0;
  for (int y = 0; y < cam.intrinsics.height; ++y) {
    for (int x = 0; x < cam.intrinsics.width; ++x) {
      Eigen::Vector3f o, d;
      mc.Ray(x + 0.5f, y + 0.5f, &o, &d);
      float rgb[3], opacity, depth;
      RenderRays(model, o.data(), d.data(), 1, -1, one, rgb, &opacity, &depth);
      const size_t i = size_t(y) * cam.intrinsics.width + x;
      for (int c = 0; c < 3; ++c) ASSERT_NEAR(view->rgb.rgb[3 * i + c], rgb[c], 1e-5f) << x << "," << y;
      ASSERT_NEAR(view->opacity[i], opacity, 1e-5f) << x << "," << y;
      ASSERT_NEAR(view->depth[i], depth, 1e-4f) << x << "," << y;
      opacity_sum += opacity;
    }
  }
  // Not a blank view: the rays cross the field.
  EXPECT_GT(opacity_sum / (cam.intrinsics.width * cam.intrinsics.height), 0.05);
}

// The MLPs in bfloat16 tiles (the default where the CPU has them) render
// what float renders up to their rounding: weights and layer inputs within
// 2^-9 of their floats, so a pre-activation moves by ~2^-8 of its
// magnitude. On this random field (features uniform in [-1, 1], a coarse
// 16-wide network) the pixels moved by at most 0.058/255 and 0.018/255 on
// average (session 76, a Xeon with tiles): asserted within 0.5/255 and
// 0.1/255. Weights with the two inputs of each pair swapped moved them by
// 33/255 and 12/255. Where the CPU has no tiles both renders are float.
TEST(RendererTest, Bf16MlpRendersWhatFloatRenders) {
  const NgpModel model = TexturedModel();
  RecordProperty("amx_tiles", Bf16TilesAvailable() ? "yes" : "no");
  EXPECT_EQ(FieldEvaluator(model, true).bf16_mlp(), Bf16TilesAvailable());
  EXPECT_FALSE(FieldEvaluator(model).bf16_mlp());
  RenderOptions f32;
  f32.bf16_mlp = false;
  absl::StatusOr<RenderedView> ref = RenderView(model, FrontCamera(), f32);
  absl::StatusOr<RenderedView> bf = RenderView(model, FrontCamera(), RenderOptions{});
  ASSERT_TRUE(ref.ok() && bf.ok());
  double mean = 0.0;
  for (size_t i = 0; i < ref->rgb.rgb.size(); ++i) mean += std::abs(ref->rgb.rgb[i] - bf->rgb.rgb[i]);
  mean /= ref->rgb.rgb.size();
  EXPECT_LE(MaxAbsDiff(bf->rgb.rgb, ref->rgb.rgb), 0.5f / 255.0f);
  EXPECT_LE(mean, 0.1 / 255.0);
  EXPECT_LE(MaxAbsDiff(bf->opacity, ref->opacity), 0.5f / 255.0f);
}

// Skipping the colour of faint samples changes a pixel by at most
// max_skipped_weight times the colour's spread along the ray.
TEST(RendererTest, SkippingFaintSamplesStaysWithinTheSkippedWeight) {
  const NgpModel model = TexturedModel();
  RenderOptions all;
  all.min_weight = 0.0f;
  absl::StatusOr<RenderedView> ref = RenderView(model, FrontCamera(), all);
  absl::StatusOr<RenderedView> fast = RenderView(model, FrontCamera(), RenderOptions{});
  ASSERT_TRUE(ref.ok() && fast.ok());
  EXPECT_LE(MaxAbsDiff(fast->rgb.rgb, ref->rgb.rgb), RenderOptions{}.max_skipped_weight + 1e-5f);
  EXPECT_LT(MaxAbsDiff(fast->opacity, ref->opacity), 1e-5f);  // Opacity and depth use every sample.
  EXPECT_LT(MaxAbsDiff(fast->depth, ref->depth), 1e-4f);
}

// A hazy ray is made of samples that are each below min_weight. Once their
// weight passes max_skipped_weight they are coloured, and the skipped ones
// take the coloured ones' mean, so constant-colour haze renders exactly
// where the ray has coloured samples (the centre) and within
// max_skipped_weight everywhere (a short chord near the box's edge may not
// reach the cap). Without the cap (max_skipped_weight = 1) the haze would go
// black.
TEST(RendererTest, HazeOfFaintSamplesKeepsItsColour) {
  const NgpModel model = HazeModel(0.05f);
  RenderOptions all;
  all.min_weight = 0.0f;
  absl::StatusOr<RenderedView> ref = RenderView(model, FrontCamera(), all);
  ASSERT_TRUE(ref.ok());
  const size_t centre = size_t(11) * 37 + 18;
  ASSERT_GT(ref->opacity[centre], 0.03f);  // ~1 unit of sigma 0.05 haze.
  ASSERT_LT(ref->opacity[centre], 0.1f);
  RenderOptions capped;
  ASSERT_GT(capped.min_weight, 0.05f * SmallOptions().march.min_step());  // Each sample's weight is below it.
  absl::StatusOr<RenderedView> fast = RenderView(model, FrontCamera(), capped);
  ASSERT_TRUE(fast.ok());
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(fast->rgb.rgb[3 * centre + c], ref->rgb.rgb[3 * centre + c], 1e-5f);
  EXPECT_LE(MaxAbsDiff(fast->rgb.rgb, ref->rgb.rgb), capped.max_skipped_weight);
  RenderOptions uncapped;
  uncapped.max_skipped_weight = 1.0f;
  absl::StatusOr<RenderedView> dark = RenderView(model, FrontCamera(), uncapped);
  ASSERT_TRUE(dark.ok());
  EXPECT_GT(MaxAbsDiff(dark->rgb.rgb, ref->rgb.rgb), 2.0f * capped.max_skipped_weight);
}

// Uniform density sigma from the box's near face on: the transmittance
// falls to 1/2 at ln 2 / sigma past it, where the median depth must be; a
// haze too thin to get there gives the ray's end (the far face), where the
// expected depth stays near the camera.
TEST(RendererTest, MedianDepthIsWhereHalfTheLightIsGone) {
  RenderOptions median;
  median.median_depth = true;
  const size_t centre = size_t(11) * 37 + 18;
  const float near_face = 1.3f - 0.5f, far_face = 1.3f + 0.5f;  // On the axis.
  absl::StatusOr<RenderedView> dense = RenderView(HazeModel(3.0f), FrontCamera(), median);
  ASSERT_TRUE(dense.ok());
  EXPECT_NEAR(dense->depth[centre], near_face + std::log(2.0f) / 3.0f, 0.02f);
  absl::StatusOr<RenderedView> thin = RenderView(HazeModel(0.3f), FrontCamera(), median);
  absl::StatusOr<RenderedView> thin_mean = RenderView(HazeModel(0.3f), FrontCamera(), RenderOptions());
  ASSERT_TRUE(thin.ok() && thin_mean.ok());
  EXPECT_NEAR(thin->depth[centre], far_face, 0.02f);
  EXPECT_LT(thin_mean->depth[centre], 0.5f);
}

// A ray stops once its transmittance reaches min_transmittance, and what is
// left of it takes the colour it saw: in a dense haze of one colour the
// pixel is the same as with the training's stop (1e-4) and the ray opaque,
// for about half the samples (ln 100 against ln 10^4 units of optical
// depth); the expected depth is the seen samples' mean, not cut short.
TEST(RendererTest, StoppingAtAHigherTransmittanceKeepsTheColourItSaw) {
  const NgpModel model = HazeModel(10.0f);  // T = e^-10 at the far face: rays stop inside.
  RenderOptions full;
  full.min_weight = 0.0f;
  full.min_transmittance = kMinTransmittance;  // Training's stop.
  RenderOptions early = full;
  early.min_transmittance = 0.01f;  // The renderer's default.
  absl::StatusOr<RenderedView> ref = RenderView(model, FrontCamera(), full);
  absl::StatusOr<RenderedView> fast = RenderView(model, FrontCamera(), early);
  ASSERT_TRUE(ref.ok() && fast.ok());
  const size_t centre = size_t(11) * 37 + 18;
  ASSERT_GT(ref->opacity[centre], 0.9998f);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(fast->rgb.rgb[3 * centre + c], ref->rgb.rgb[3 * centre + c], 1e-3f);
  EXPECT_EQ(fast->opacity[centre], 1.0f);
  EXPECT_LT(double(fast->samples), 0.65 * double(ref->samples));
  EXPECT_GT(double(fast->samples), 0.35 * double(ref->samples));
  // Expected depth: ~1/sigma past the near face either way.
  EXPECT_NEAR(fast->depth[centre], ref->depth[centre], 0.02f);
  // The training's stop leaves the last 1e-4 to the background, as before.
  RenderOptions bad = full;
  bad.min_transmittance = 0.0f;
  EXPECT_FALSE(RenderView(model, FrontCamera(), bad).ok());
}

TEST(RendererTest, OptionsOutOfRangeAreRefused) {
  RenderOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.min_weight = -1.0f;
  EXPECT_FALSE(o.Validate().ok());
  o = RenderOptions{};
  o.max_skipped_weight = std::nanf("");
  EXPECT_FALSE(o.Validate().ok());
  o = RenderOptions{};
  o.block_rays = 0;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace clnerf
