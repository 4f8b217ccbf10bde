#include "core/bake/baker.h"

#include <algorithm>
#include <cmath>

#include "core/bake/baked_renderer.h"
#include "core/data/image.h"
#include "core/data/procedural_scene.h"
#include "core/render/metrics.h"
#include "core/render/renderer.h"
#include "core/train/fit.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// A small procedural scene (an object scene, or with `backdrop` an
// unbounded one) and a model trained on it for a few seconds.
struct Trained {
  Scene scene;
  std::unique_ptr<NgpModel> model;
  std::vector<Camera> cameras;
};

Trained Train(bool backdrop) {
  ProceduralSceneOptions po;
  po.width = po.height = 40;
  po.num_train_views = 24;
  po.num_test_views = 2;
  po.num_time_steps = 1;
  po.backdrop = backdrop;
  po.seed = 5;
  absl::StatusOr<Scene> s = GenerateProceduralScene(po);
  EXPECT_TRUE(s.ok()) << s.status();
  FitOptions fo;
  fo.train.iterations = 300;
  fo.train.threads = 2;
  fo.train.seed = 1;
  fo.train.target_samples = 1 << 13;
  fo.train.batch_rays = 512;
  fo.model.grid.levels = 8;
  fo.capacity.max_log2_table_size = 14;
  fo.model.occupancy.warmup_iterations = 64;
  absl::StatusOr<FitResult> fit = FitScene(*s, fo, nullptr);
  EXPECT_TRUE(fit.ok()) << fit.status();
  Trained t;
  t.scene = *s;
  t.model = std::move(fit->model);
  for (const View& v : s->train) t.cameras.push_back(v.camera);
  return t;
}

// Each kind trained once for all the tests.
const Trained& TrainTiny(bool backdrop) {
  static Trained* cache[2] = {nullptr, nullptr};
  if (cache[backdrop] == nullptr) cache[backdrop] = new Trained(Train(backdrop));
  return *cache[backdrop];
}

// The bytes of the asset's files as SaveBakedAsset writes them: its arrays,
// and its manifest too when `with_manifest`.
size_t StoredBytes(const BakedAsset& a, bool with_manifest = false) {
  absl::StatusOr<std::vector<std::pair<std::string, std::string>>> files = SerializeBakedAsset(a);
  EXPECT_TRUE(files.ok()) << files.status();
  size_t bytes = 0;
  for (size_t k = 0; files.ok() && k < files->size(); ++k) {
    if (with_manifest || (*files)[k].first != "manifest.json") bytes += (*files)[k].second.size();
  }
  return bytes;
}

// PSNR of the baked asset's reference render against the model's own render
// of `cameras` (default: every 6th training camera).
double BakedAgainstModel(const BakedAsset& asset, const Trained& t, std::vector<Camera> cameras = {}) {
  if (cameras.empty()) {
    for (size_t i = 0; i < t.cameras.size(); i += 6) cameras.push_back(t.cameras[i]);
  }
  double sum = 0;
  for (const Camera& c : cameras) {
    absl::StatusOr<RenderedView> m = RenderView(*t.model, c, RenderOptions());
    absl::StatusOr<RenderedView> b = RenderBakedView(asset, c);
    EXPECT_TRUE(m.ok() && b.ok());
    sum += Psnr(b->rgb, m->rgb);
  }
  return sum / double(cameras.size());
}

TEST(BakerTest, AnObjectBakesIntoAnAssetThatRendersLikeTheModel) {
  const Trained& t = TrainTiny(false);
  ASSERT_FALSE(t.model->contracted());
  BakeOptions o;
  o.resolution = 128;
  BakeReport rep;
  absl::StatusOr<BakedAsset> a = BakeModel(*t.model, -1, t.cameras, o, &rep);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_GT(rep.kept_blocks, 0);
  EXPECT_LE(rep.kept_blocks, rep.candidate_blocks);
  EXPECT_LT(rep.candidate_blocks, 16 * 16 * 16);  // The occupancy grid culls empty space.
  EXPECT_EQ(a->num_bricks(), rep.kept_blocks);
  const double psnr = BakedAgainstModel(*a, t);
  EXPECT_GT(psnr, 25.0) << "the baked asset does not render like its model";
  // Culling every block gives the background: the bake is what draws.
  o.min_block_weight = 0.999f;
  absl::StatusOr<BakedAsset> none = BakeModel(*t.model, -1, t.cameras, o, &rep);
  ASSERT_TRUE(none.ok());
  EXPECT_LT(BakedAgainstModel(*none, t), psnr - 5.0);
}

// The visibility pass marches a strided grid of pixel centres and, since
// the grid's centres miss up to half a stride at each edge, every pixel of
// each photo's border: what only the photos' edges saw is kept too.
TEST(BakerTest, VisibilityMarchesEveryBorderPixel) {
  const Trained& t = TrainTiny(false);
  const int W = t.cameras[0].intrinsics.width, H = t.cameras[0].intrinsics.height;
  BakeOptions o;
  o.resolution = 64;
  o.fit.rays = 0;
  o.in_between_views = false;  // The training cameras' rays alone, counted below.
  o.visibility_rays = int(t.cameras.size()) * 4;  // A stride of half the image: a 2 x 2 grid per photo.
  BakeReport rep;
  ASSERT_TRUE(BakeModel(*t.model, -1, t.cameras, o, &rep).ok());
  const long long border = 2LL * W + 2LL * (H - 2);
  EXPECT_EQ(rep.visibility_rays, (long long)t.cameras.size() * (4 + border));
  // At stride 2 the grid's last column and row are border pixels: each
  // pixel is marched once.
  o.visibility_rays = int(t.cameras.size()) * W * H / 4;
  ASSERT_TRUE(BakeModel(*t.model, -1, t.cameras, o, &rep).ok());
  const long long grid = (long long)((W - 1) / 2) * ((H - 1) / 2);  // Centres 1, 3, ... below the last.
  EXPECT_EQ(rep.visibility_rays, (long long)t.cameras.size() * (grid + border));
  // Every pixel once: nothing is added at stride 1.
  o.visibility_rays = int(t.cameras.size()) * W * H;
  ASSERT_TRUE(BakeModel(*t.model, -1, t.cameras, o, &rep).ok());
  EXPECT_EQ(rep.visibility_rays, (long long)t.cameras.size() * W * H);
}

// A bake is a function of its model and options: two bakes (same thread
// count) give the same bytes, so replicas that bake one time step each
// serve one asset under one ETag. The visibility pass sums directions in
// fixed point and the fit's dot products in fixed chunks; before, the order
// threads finished in moved a few texels by one level.
TEST(BakerTest, TwoBakesOfOneModelAreTheSameBytes) {
  const Trained& t = TrainTiny(true);
  BakeOptions o;
  o.resolution = 128;
  o.threads = 2;
  absl::StatusOr<BakedAsset> a = BakeModel(*t.model, -1, t.cameras, o, nullptr);
  absl::StatusOr<BakedAsset> b = BakeModel(*t.model, -1, t.cameras, o, nullptr);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->index, b->index);
  EXPECT_TRUE(a->atlas == b->atlas);
  EXPECT_TRUE(a->view == b->view);
}

TEST(BakerTest, AnUnboundedSceneBakesItsFarShellToo) {
  const Trained& t = TrainTiny(true);
  ASSERT_TRUE(t.model->contracted());
  BakeOptions o;
  o.resolution = 256;
  absl::StatusOr<BakedAsset> a = BakeModel(*t.model, 0, t.cameras, o, nullptr);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_TRUE(a->contracted);
  EXPECT_GT(BakedAgainstModel(*a, t), 22.0);
}

// The colour fit (stage 5) matches the asset's renders of training rays to
// the model's; it must bring held-out views closer too, not only the rays it
// saw.
TEST(BakerTest, TheColourFitBringsHeldOutViewsCloserToTheModel) {
  const Trained& t = TrainTiny(false);
  std::vector<Camera> held_out;
  for (const View& v : t.scene.test) held_out.push_back(v.camera);
  BakeOptions o;
  o.resolution = 64;  // Coarse, so that the first guess has much to gain.
  o.fit.rays = 0;
  absl::StatusOr<BakedAsset> plain = BakeModel(*t.model, -1, t.cameras, o, nullptr);
  ASSERT_TRUE(plain.ok()) << plain.status();
  EXPECT_FALSE(plain->view_dependent());  // No fit, no view-dependent term.
  o.fit = ColourFitOptions();
  o.view_dependent = false;
  BakeReport diffuse_rep;
  absl::StatusOr<BakedAsset> diffuse = BakeModel(*t.model, -1, t.cameras, o, &diffuse_rep);
  ASSERT_TRUE(diffuse.ok()) << diffuse.status();
  EXPECT_FALSE(diffuse->view_dependent());
  o.view_dependent = true;
  BakeReport rep;
  absl::StatusOr<BakedAsset> fitted = BakeModel(*t.model, -1, t.cameras, o, &rep);
  ASSERT_TRUE(fitted.ok()) << fitted.status();
  EXPECT_GT(rep.fit.rays, 1000);
  EXPECT_GT(rep.fit.unknowns, 0);
  EXPECT_LT(rep.fit.rms_after, 0.9 * rep.fit.rms_before);
  EXPECT_TRUE(fitted->view_dependent());
  EXPECT_TRUE(rep.fit.view_dependent);
  EXPECT_LT(rep.fit.rms_after, diffuse_rep.fit.rms_after);
  const double before = BakedAgainstModel(*plain, t, held_out), after = BakedAgainstModel(*fitted, t, held_out);
  const double mid = BakedAgainstModel(*diffuse, t, held_out);
  std::printf("held-out PSNR against the model: %.2f dB without the fit, %.2f with the diffuse fit, %.2f with the "
              "view-dependent one; rays' rms %.4f -> %.4f (diffuse %.4f)\n",
              before, mid, after, rep.fit.rms_before, rep.fit.rms_after, diffuse_rep.fit.rms_after);
  EXPECT_GT(mid, before + 0.2) << "the diffuse fit does not help held-out views";
  EXPECT_GT(after, mid + 0.1) << "the view-dependent term does not help held-out views";
  EXPECT_EQ(fitted->index, plain->index);  // Only colours change.
}

// The density fit (stage 5a, off by default) refits the codes to the same
// targets before the colour fit: the training rays' residual falls, the
// blocks stay, and the asset still renders held-out views of the model.
TEST(BakerTest, TheDensityFitLowersTheTrainingRaysResidual) {
  const Trained& t = TrainTiny(false);
  std::vector<Camera> held_out;
  for (const View& v : t.scene.test) held_out.push_back(v.camera);
  BakeOptions o;
  o.resolution = 64;
  absl::StatusOr<BakedAsset> plain = BakeModel(*t.model, -1, t.cameras, o, nullptr);
  ASSERT_TRUE(plain.ok()) << plain.status();
  o.density_fit.rays = 1 << 14;
  BakeReport rep;
  absl::StatusOr<BakedAsset> fitted = BakeModel(*t.model, -1, t.cameras, o, &rep);
  ASSERT_TRUE(fitted.ok()) << fitted.status();
  EXPECT_GT(rep.density_fit.rays, 1000);
  EXPECT_EQ(rep.density_fit.accepted_steps, 1);
  EXPECT_LT(rep.density_fit.rms_after, 0.95 * rep.density_fit.rms_before);
  EXPECT_EQ(fitted->index, plain->index);  // The same blocks.
  const double before = BakedAgainstModel(*plain, t, held_out), after = BakedAgainstModel(*fitted, t, held_out);
  std::printf("density fit: rays' rms %.4f -> %.4f; held-out PSNR against the model %.2f -> %.2f dB\n",
              rep.density_fit.rms_before, rep.density_fit.rms_after, before, after);
  EXPECT_GT(after, before - 0.5) << "the density fit spoils held-out views";
}

// A download budget drops the blocks the training rays weigh least before
// the colour fit: the asset then stores within about the budget (the
// estimate is gzip level 1, which the stored level 6 beats by ~10 %; the
// fit adds 3-10 %), still renders the model, and no budget keeps every
// visible block.
TEST(BakerTest, ADownloadBudgetKeepsTheMostSeenBlocks) {
  const Trained& t = TrainTiny(false);
  BakeOptions o;
  o.resolution = 128;
  o.max_object_asset_bytes = 0;
  BakeReport full_rep;
  absl::StatusOr<BakedAsset> full = BakeModel(*t.model, -1, t.cameras, o, &full_rep);
  ASSERT_TRUE(full.ok()) << full.status();
  EXPECT_EQ(full_rep.kept_blocks, full_rep.visible_blocks);
  const size_t full_bytes = StoredBytes(*full);
  o.max_object_asset_bytes = int64_t(full_bytes / 2);
  BakeReport rep;
  absl::StatusOr<BakedAsset> half = BakeModel(*t.model, -1, t.cameras, o, &rep);
  ASSERT_TRUE(half.ok()) << half.status();
  EXPECT_EQ(rep.visible_blocks, full_rep.visible_blocks);
  EXPECT_LT(rep.kept_blocks, rep.visible_blocks);
  EXPECT_EQ(half->num_bricks(), rep.kept_blocks);
  const size_t bytes = StoredBytes(*half);
  std::printf("budget %lld bytes: %zu bytes stored (%zu without), %d of %d blocks\n", (long long)o.max_object_asset_bytes,
              bytes, full_bytes, rep.kept_blocks, rep.visible_blocks);
  // Near the budget the stored bytes are measured whole (the estimate
  // samples a quarter of the atlas): the files fit it.
  EXPECT_LE(bytes, size_t(o.max_object_asset_bytes));
  EXPECT_LE(rep.stored_bytes, o.max_object_asset_bytes);
  // Every kept block was kept without the budget too, and the asset still
  // shows the object.
  for (size_t i = 0; i < half->index.size(); ++i) {
    if (half->index[i] != 0) {
      EXPECT_NE(full->index[i], 0u) << i;
    }
  }
  EXPECT_GT(BakedAgainstModel(*half, t), 18.0);
}

// A derived grid over its budget is baked coarser, keeping every block the
// training rays see, and shows the object better than the default grid
// with its least-seen blocks dropped to the same budget (lego_100 at 2 MB:
// 31.00 against 17.03 dB).
TEST(BakerTest, ADerivedGridOverItsBudgetIsCoarserNotHoled) {
  const Trained& t = TrainTiny(false);
  BakeOptions o;
  o.max_object_asset_bytes = 0;
  absl::StatusOr<BakedAsset> whole = BakeModel(*t.model, -1, t.cameras, o);
  ASSERT_TRUE(whole.ok()) << whole.status();
  ASSERT_EQ(whole->resolution, 256);  // The object default.
  o.max_object_asset_bytes = int64_t(StoredBytes(*whole) / 2);
  BakeReport rep;
  absl::StatusOr<BakedAsset> coarse = BakeModel(*t.model, -1, t.cameras, o, &rep);
  ASSERT_TRUE(coarse.ok()) << coarse.status();
  EXPECT_LT(coarse->resolution, 256);
  EXPECT_GE(coarse->resolution, 128);
  EXPECT_EQ(rep.kept_blocks, rep.visible_blocks);
  EXPECT_LE(StoredBytes(*coarse), size_t(o.max_object_asset_bytes));
  o.resolution = 256;  // The same budget on the default grid: blocks dropped.
  BakeReport dropped_rep;
  absl::StatusOr<BakedAsset> dropped = BakeModel(*t.model, -1, t.cameras, o, &dropped_rep);
  ASSERT_TRUE(dropped.ok()) << dropped.status();
  EXPECT_LT(dropped_rep.kept_blocks, dropped_rep.visible_blocks);
  const double coarse_db = BakedAgainstModel(*coarse, t), dropped_db = BakedAgainstModel(*dropped, t);
  std::printf("budget %lld bytes: %d^3 %.2f dB against the model, 256^3 with %d of %d blocks %.2f dB\n",
              (long long)o.max_object_asset_bytes, coarse->resolution, coarse_db, dropped_rep.kept_blocks,
              dropped_rep.visible_blocks, dropped_db);
  EXPECT_GT(coarse_db, dropped_db + 1.0);
}

// The view-dependent codes one step from none are written as none only
// when the asset would otherwise store more than its budget: with room
// they are kept (they are the term's finest steps), over it they go and
// the asset shrinks, with the same blocks.
TEST(BakerTest, TheViewTermsDeadZoneAppliesOnlyOverTheBudget) {
  const Trained& t = TrainTiny(false);
  BakeOptions o;
  o.resolution = 128;
  o.max_object_asset_bytes = int64_t(1) << 40;
  BakeReport roomy;
  absl::StatusOr<BakedAsset> kept = BakeModel(*t.model, -1, t.cameras, o, &roomy);
  ASSERT_TRUE(kept.ok()) << kept.status();
  ASSERT_TRUE(kept->view_dependent());
  EXPECT_FALSE(roomy.view_dead_zone);
  auto one_step = [](const BakedAsset& a) {
    return std::count_if(a.view.begin(), a.view.end(), [](uint8_t v) { return v == 127 || v == 129; });
  };
  EXPECT_GT(one_step(*kept), 0);
  ASSERT_LT(roomy.base_resolution_bytes, roomy.estimated_bytes);
  o.max_object_asset_bytes = (roomy.base_resolution_bytes + roomy.estimated_bytes) / 2;
  BakeReport tight;
  absl::StatusOr<BakedAsset> zoned = BakeModel(*t.model, -1, t.cameras, o, &tight);
  ASSERT_TRUE(zoned.ok()) << zoned.status();
  EXPECT_TRUE(tight.view_dead_zone);
  EXPECT_EQ(tight.kept_blocks, roomy.kept_blocks);
  EXPECT_EQ(one_step(*zoned), 0);
  EXPECT_LT(StoredBytes(*zoned, /*with_manifest=*/true), StoredBytes(*kept, /*with_manifest=*/true));
}

TEST(BakerTest, BadRequestsAreRefused) {
  const Trained& t = TrainTiny(false);
  EXPECT_EQ(BakeModel(*t.model, -1, {}, BakeOptions(), nullptr).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(BakeModel(*t.model, 3, t.cameras, BakeOptions(), nullptr).status().code(),
            absl::StatusCode::kInvalidArgument);
  BakeOptions o;
  o.resolution = 100;  // Not a multiple of 32.
  EXPECT_EQ(BakeModel(*t.model, -1, t.cameras, o, nullptr).status().code(), absl::StatusCode::kInvalidArgument);
  std::vector<Camera> bad = t.cameras;
  bad[0].c2w(1, 3) = std::nanf("");
  EXPECT_EQ(BakeModel(*t.model, -1, bad, BakeOptions(), nullptr).status().code(),
            absl::StatusCode::kInvalidArgument);
  o = BakeOptions();
  o.fit.prior = 0.0f;
  EXPECT_EQ(BakeModel(*t.model, -1, t.cameras, o, nullptr).status().code(), absl::StatusCode::kInvalidArgument);
  o = BakeOptions();
  o.max_asset_bytes = -1;
  EXPECT_EQ(BakeModel(*t.model, -1, t.cameras, o, nullptr).status().code(), absl::StatusCode::kInvalidArgument);
  o = BakeOptions();
  o.max_object_asset_bytes = -1;
  EXPECT_EQ(BakeModel(*t.model, -1, t.cameras, o, nullptr).status().code(), absl::StatusCode::kInvalidArgument);
  o = BakeOptions();
  o.step_cells = 0.25f;
  EXPECT_EQ(BakeModel(*t.model, -1, t.cameras, o, nullptr).status().code(), absl::StatusCode::kInvalidArgument);
}

// Each camera gets one halfway to its nearest neighbour: centre midway,
// rotation halfway; none for a lone or coincident camera or an improper
// rotation.
TEST(InBetweenCamerasTest, HalfwayToEachNearestNeighbour) {
  auto cam = [](float x, float yaw_deg) {
    Camera c;
    c.intrinsics.width = 8;
    c.intrinsics.height = 6;
    c.intrinsics.fx = c.intrinsics.fy = 10.0f;
    c.c2w.leftCols<3>() = Eigen::AngleAxisf(yaw_deg * float(M_PI) / 180.0f, Eigen::Vector3f::UnitY()).toRotationMatrix();
    c.c2w.col(3) = Eigen::Vector3f(x, 0.0f, 0.0f);
    return c;
  };
  // Cameras at x = 0, 1, 3 turned 0, 40, 90 degrees: the nearest pairs are
  // (0, 1), (1, 0), (3, 1).
  const std::vector<Camera> cams = {cam(0, 0), cam(1, 40), cam(3, 90)};
  const std::vector<Camera> mid = InBetweenCameras(cams);
  ASSERT_EQ(mid.size(), 3u);
  const float want_x[3] = {0.5f, 0.5f, 2.0f}, want_yaw[3] = {20.0f, 20.0f, 65.0f};
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(mid[size_t(i)].position().x(), want_x[i], 1e-6f) << i;
    EXPECT_NEAR(mid[size_t(i)].position().tail<2>().norm(), 0.0f, 1e-6f) << i;
    const Eigen::Matrix3f r = mid[size_t(i)].c2w.leftCols<3>();
    const Eigen::Matrix3f want = cam(0, want_yaw[i]).c2w.leftCols<3>();
    EXPECT_LT((r - want).norm(), 1e-5f) << i;
    EXPECT_EQ(mid[size_t(i)].intrinsics.width, 8);
  }
  EXPECT_TRUE(InBetweenCameras({cam(0, 0)}).empty());
  EXPECT_TRUE(InBetweenCameras({cam(1, 0), cam(1, 30)}).empty());  // Coincident: no distinct neighbour.
  Camera mirrored = cam(1, 0);
  mirrored.c2w.col(0) *= -1.0f;
  EXPECT_EQ(InBetweenCameras({cam(0, 0), mirrored}).size(), 0u);
}

}  // namespace
TEST(DerivedResolutionTest, FinerWithinTheBudgetCoarserOverIt) {
  const int64_t budget = 12'000'000;
  // 70 % of the budget is 8.4 MB; the download scales with R^2.
  EXPECT_EQ(DerivedResolution(512, 2'100'000, budget, 1024), 1024);  // 4x the room: capped.
  EXPECT_EQ(DerivedResolution(512, 4'200'000, budget, 1024), 704);   // 512 * sqrt(2) = 724.
  EXPECT_EQ(DerivedResolution(512, 10'000'000, budget, 1024), 512);  // Within the budget, over 70 %.
  EXPECT_EQ(DerivedResolution(512, 12'000'000, budget, 1024), 512);
  EXPECT_EQ(DerivedResolution(512, 15'800'000, budget, 1024), 352);  // 512 * sqrt(8.4 / 15.8) = 373.
  EXPECT_EQ(DerivedResolution(512, 80'000'000, budget, 1024), 256);  // Floored at half.
  EXPECT_EQ(DerivedResolution(512, 0, budget, 1024), 512);           // Not estimated.
  EXPECT_EQ(DerivedResolution(512, 15'800'000, 0, 1024), 512);       // No budget.
  // Objects (finest = their default) only go coarser.
  EXPECT_EQ(DerivedResolution(256, 1'000'000, 4'000'000, 256), 256);
  EXPECT_EQ(DerivedResolution(256, 3'300'000, 2'000'000, 256), 160);  // 256 * sqrt(1.4 / 3.3) = 167.
  EXPECT_EQ(DerivedResolution(256, 4'500'000, 4'000'000, 256), 192);  // 256 * sqrt(2.8 / 4.5) = 202.
  EXPECT_EQ(DerivedResolution(256, 50'000'000, 4'000'000, 256), 128);  // Floored at half.
}

}  // namespace clnerf
