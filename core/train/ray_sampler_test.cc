// ImageRaySampler's sparse-depth rays: the requested share of a batch, each
// with the model-space distance to its known point, and none without points.
#include "core/train/ray_sampler.h"

#include "core/data/sparse_depth.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

NgpModel SmallModel() {
  ModelOptions o;
  o.grid.levels = 2;
  o.grid.log2_table_size = 10;
  o.grid.base_resolution = 4;
  o.grid.finest_resolution = 8;
  o.occupancy.resolution = 8;
  Normalization norm;
  norm.center = Eigen::Vector3f(0.5f, -1.0f, 2.0f);
  norm.scale = 0.4f;
  norm.bound = kContractedBound;
  auto m = NgpModel::Create(o, norm, SceneKind::kUnbounded, Eigen::Vector3f::Zero(), 1, 1);
  EXPECT_TRUE(m.ok()) << m.status();
  return *std::move(m);
}

// A 32x32 view at the origin looking down +z with a gradient image, and
// points on a plane 3 units ahead.
View PlaneView(std::vector<Eigen::Vector3f>* points) {
  View v;
  v.name = "v";
  Intrinsics& in = v.camera.intrinsics;
  in.width = in.height = 32;
  in.fx = in.fy = 24.0f;
  in.cx = in.cy = 16.0f;
  v.image.width = v.image.height = 32;
  for (int i = 0; i < 32 * 32; ++i) {
    for (int c = 0; c < 3; ++c) v.image.rgb.push_back(float((i * (c + 1)) % 97) / 97.0f);
  }
  for (int i = 0; i < 20; ++i) {
    for (int j = 0; j < 20; ++j) points->emplace_back(-1.0f + 0.1f * i, -1.0f + 0.1f * j, 3.0f);
  }
  return v;
}

TEST(RaySamplerTest, DepthRaysCarryTheDistanceToTheirPoint) {
  const NgpModel model = SmallModel();
  std::vector<Eigen::Vector3f> pts;
  std::vector<View> views = {PlaneView(&pts)};
  ASSERT_GT(AttachSparseDepth(pts, SparseDepthOptions(), &views), 100);
  auto sampler = ImageRaySampler::Create({&views[0]}, model, 0.25f);
  ASSERT_TRUE(sampler.ok()) << sampler.status();
  EXPECT_EQ((*sampler)->num_depth_pixels(), (long long)views[0].depth.size());
  std::mt19937_64 rng(3);
  RayBatch b;
  (*sampler)->Sample(64, &rng, &b);
  int with_depth = 0;
  for (int i = 0; i < b.size(); ++i) {
    if (b.depth[i] == 0.0f) continue;
    ++with_depth;
    // The ray passes within a pixel's footprint of a plane point at that
    // distance: z = 3 world units ahead, 1.2 model units.
    const Eigen::Vector3f o(&b.origin[3 * i]), d(&b.dir[3 * i]);
    const Eigen::Vector3f x = o + b.depth[i] * d;
    const Eigen::Vector3f w = model.normalization().center + model.normalization().rotation.transpose() * x / 0.4f;
    EXPECT_NEAR(w.z(), 3.0f, 0.02f) << "ray " << i;
  }
  EXPECT_EQ(with_depth, 16);
  // No points: plain rays only.
  std::vector<View> plain = {PlaneView(&pts)};
  auto s2 = ImageRaySampler::Create({&plain[0]}, model, 0.25f);
  ASSERT_TRUE(s2.ok());
  (*s2)->Sample(64, &rng, &b);
  for (float t : b.depth) EXPECT_EQ(t, 0.0f);
  EXPECT_FALSE(ImageRaySampler::Create({&plain[0]}, model, 1.5f).ok());
}

// Every ray names the photo it came from (RayBatch::view, for that photo's
// colour transform): three views of constant, distinct colours.
TEST(RaySamplerTest, RaysNameTheirPhoto) {
  std::vector<Eigen::Vector3f> unused;
  std::vector<View> views(3, PlaneView(&unused));
  for (int v = 0; v < 3; ++v) {
    for (size_t i = 0; i < views[v].image.rgb.size(); ++i) views[v].image.rgb[i] = 0.25f * float(v + 1);
  }
  std::vector<const View*> ptrs = {&views[0], &views[1], &views[2]};
  NgpModel model = SmallModel();
  auto sampler = ImageRaySampler::Create(ptrs, model);
  ASSERT_TRUE(sampler.ok()) << sampler.status();
  EXPECT_EQ((*sampler)->NumPhotoViews(), 3);
  RayBatch b;
  std::mt19937_64 rng(2);
  (*sampler)->Sample(600, &rng, &b);
  int seen[3] = {0, 0, 0};
  for (int i = 0; i < b.size(); ++i) {
    ASSERT_GE(b.view[i], 0);
    ASSERT_LT(b.view[i], 3);
    ++seen[b.view[i]];
    EXPECT_EQ(b.target[3 * size_t(i)], 0.25f * float(b.view[i] + 1)) << i;
  }
  for (int v = 0; v < 3; ++v) EXPECT_GT(seen[v], 100) << v;
}

// Error sampling: after one batch in which only view 1's top-left tile was
// wrong, most rays come from that tile; each ray's colour is still its own
// pixel's.
TEST(RaySamplerTest, ErrorSamplingDrawsWhereTheErrorIs) {
  std::vector<Eigen::Vector3f> unused;
  std::vector<View> views(3, PlaneView(&unused));
  std::vector<const View*> ptrs = {&views[0], &views[1], &views[2]};
  NgpModel model = SmallModel();
  auto sampler = ImageRaySampler::Create(ptrs, model);
  ASSERT_TRUE(sampler.ok()) << sampler.status();
  ViewErrorOptions o;
  o.error_share = 0.8f;
  o.tiles = 2;
  (*sampler)->SetViewErrorSampling(o);
  RayBatch b;
  std::mt19937_64 rng(4);
  auto in_hot_tile = [&](int i) {
    // The ray's pixel: recover it from its colour's index pattern is
    // fiddly, so use its direction: the top-left tile looks up and left.
    return b.view[i] == 1 && b.dir[3 * size_t(i)] < 0 && b.dir[3 * size_t(i) + 1] < 0;
  };
  (*sampler)->Sample(4000, &rng, &b);
  int hot = 0;
  for (int i = 0; i < b.size(); ++i) hot += in_hot_tile(i);
  EXPECT_NEAR(hot / 4000.0, 1.0 / 12, 0.02) << "before any error: uniform over views and pixels";
  std::vector<float> err(b.size(), 0.0f);
  for (int i = 0; i < b.size(); ++i) err[i] = in_hot_tile(i) ? 0.5f : 0.0f;
  (*sampler)->ObserveErrors(b, err);
  (*sampler)->Sample(4000, &rng, &b);
  hot = 0;
  for (int i = 0; i < b.size(); ++i) {
    hot += in_hot_tile(i);
    ASSERT_GE(b.view[i], 0);
  }
  EXPECT_GT(hot / 4000.0, 0.6);
  int others = 0;
  for (int i = 0; i < b.size(); ++i) others += b.view[i] == 0;
  EXPECT_GT(others, 0) << "the uniform floor keeps every view in the draws";
}

}  // namespace
}  // namespace clnerf
