// End-to-end training on procedural scenes with what object scenes like lego
// lack (ProceduralSceneOptions::backdrop, ::thin_structures and the room
// walkthrough layout): each trains
// for a few hundred steps at small size, with the capacity derived from the
// scene, to held-out scores that a broken version cannot reach.
//
//  * Backdrop: an unbounded scene (objects on a slab, a ground plane out to
//    20 units, pillars at 5-10 units, an emissive textured sphere at 20
//    units) trained in contracted space. Besides the constant-colour
//    baseline, the held-out pixels that look above the horizon (backdrop and
//    pillars only) must be rendered far better than a missing (black)
//    backdrop would be.
//  * Thin structures: rods 0.025-0.04 units wide (about half a pixel at
//    48 px) in the bounded object scene. Held-out PSNR must clear the
//    baseline and stay close to the train-view PSNR (no overfitting), and
//    where rods (or their shadows) are, the renders must match the scene with
//    rods much better than the same scene without them.
//
// Thresholds come from measurements (Release, one busy core; numbers in the
// tests) with at least 2 dB of margin, so they hold across CPUs and compilers
// without bit-identical floats. Both scenes and runs use fixed seeds.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "core/render/evaluate.h"
#include "core/train/fit.h"
#include "core/render/metrics.h"
#include "core/data/procedural_scene.h"
#include "core/render/renderer.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// As tests/training_test.cc's TinyFit: the grid and occupancy sizes and the
// march step are derived from the scene (FitOptions::derive_capacity).
FitOptions SmallFit(int iterations) {
  FitOptions fo;
  fo.train.iterations = iterations;
  fo.train.seed = 1;
  fo.train.threads = 2;
  fo.train.target_samples = 1 << 14;
  fo.train.batch_rays = 1024;
  fo.model.grid.levels = 8;
  fo.capacity.max_log2_table_size = 15;
  return fo;
}

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Squared error of the clamped render against `truth` over the pixels where
// `keep(x, y)` holds, added to *se (and the channel count to *n).
template <typename Keep>
void AccumulateSquaredError(const Image& render, const Image& truth, Keep keep, double* se, double* n) {
  for (int y = 0; y < truth.height; ++y) {
    for (int x = 0; x < truth.width; ++x) {
      if (!keep(x, y)) continue;
      for (int c = 0; c < 3; ++c) {
        const double e = std::clamp(render.pixel(x, y)[c], 0.0f, 1.0f) - truth.pixel(x, y)[c];
        *se += e * e;
        *n += 1;
      }
    }
  }
}

TEST(ProceduralTrainingTest, UnboundedBackdropSceneTrainsInContractedSpace) {
  ProceduralSceneOptions po;
  po.width = po.height = 48;
  // Many views (generation is cheap): training sees ~64k rays in all, so
  // more viewpoints rather than more pixels per view help held-out views.
  po.num_train_views = 100;
  po.num_test_views = 4;
  po.seed = 5;
  // Low cameras, so the top of many views looks above the horizon.
  po.min_elevation_deg = 5.0f;
  po.max_elevation_deg = 35.0f;
  po.backdrop = true;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->kind, SceneKind::kUnbounded);

  FitOptions fo = SmallFit(250);
  // Contracted space gets 3 cascades of 128^3 occupancy cells; a shorter
  // warm-up (every cell refreshed) and sparser refreshes cut ~10 % of the
  // time at no cost in PSNR here.
  fo.model.occupancy.update_interval = 32;
  fo.model.occupancy.warmup_iterations = 64;
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<FitResult> fit = FitScene(*scene, fo, nullptr);
  ASSERT_TRUE(fit.ok()) << fit.status();
  const double fit_seconds = SecondsSince(t0);
  ASSERT_TRUE(fit->model->AllFinite());
  ASSERT_TRUE(fit->model->contracted());

  EvalOptions eo;
  eo.render.threads = 2;
  absl::StatusOr<EvalResult> ev = EvaluateViews(*fit->model, scene->test, eo);
  ASSERT_TRUE(ev.ok()) << ev.status();
  const double baseline = ConstantColourPsnr(scene->train, scene->test);

  // Above the horizon (pixel-centre ray pointing up) there is only far
  // content: pillars and the backdrop sphere.
  double se = 0, se_black = 0, n = 0, n_black = 0;
  for (const View& v : scene->test) {
    RenderOptions ro;
    ro.threads = 2;
    absl::StatusOr<RenderedView> r = RenderView(*fit->model, v.camera, ro);
    ASSERT_TRUE(r.ok()) << r.status();
    auto above_horizon = [&](int x, int y) {
      Eigen::Vector3f o, d;
      v.camera.Ray(x + 0.5f, y + 0.5f, &o, &d);
      return d.z() > 0.0f;
    };
    AccumulateSquaredError(r->rgb, v.image, above_horizon, &se, &n);
    AccumulateSquaredError(Image(v.image.width, v.image.height), v.image, above_horizon, &se_black, &n_black);
  }
  ASSERT_GT(n, 3 * 500);  // ~10 % of the test pixels.
  const double sky_psnr = PsnrFromMse(se / n);
  const double black_sky_psnr = PsnrFromMse(se_black / n_black);
  RecordProperty("psnr", std::to_string(ev->psnr));
  RecordProperty("baseline_psnr", std::to_string(baseline));
  RecordProperty("sky_psnr", std::to_string(sky_psnr));
  RecordProperty("black_sky_psnr", std::to_string(black_sky_psnr));
  RecordProperty("fit_seconds", std::to_string(fit_seconds));
  // Measured: fit 25 s (one busy core, ~27 s CPU), 2^15-entry 8-level grid
  // at finest resolution 1167, test PSNR 18.6 dB (SSIM 0.55) vs baseline
  // 14.3 dB; above the horizon 24.7 dB vs 3.7 dB for a black backdrop. (Seeds
  // 3 and 9: +3.9 / +1.9 dB over the baseline, +18 / +11 dB above the horizon;
  // this short run is far from converged: 1000 steps give ~21 dB.)
  EXPECT_GT(ev->psnr, baseline + 2.0) << "baseline " << baseline;
  EXPECT_GT(ev->ssim, 0.35);
  EXPECT_GT(sky_psnr, black_sky_psnr + 12.0) << "black backdrop " << black_sky_psnr;
  EXPECT_GT(sky_psnr, 17.0);
}

// A room walkthrough (ProceduralLayout::kRoom): cameras inside a closed room
// with white, textureless walls and ceiling, a plank floor, a door, a
// picture and the objects on their rug, looking around. Unbounded (every ray
// hits the shell), no normalisation hints: the box comes from the cameras and
// the images' own content points (content_sweep.h).
TEST(ProceduralTrainingTest, RoomWalkthroughTrainsToHeldOutViews) {
  ProceduralSceneOptions po;
  po.width = po.height = 48;
  po.num_train_views = 100;
  po.num_test_views = 6;
  po.seed = 5;
  po.layout = ProceduralLayout::kRoom;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_EQ(scene->kind, SceneKind::kUnbounded);

  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<FitResult> fit = FitScene(*scene, SmallFit(300), nullptr);
  ASSERT_TRUE(fit.ok()) << fit.status();
  const double fit_seconds = SecondsSince(t0);
  ASSERT_TRUE(fit->model->AllFinite());
  EvalOptions eo;
  eo.render.threads = 2;
  absl::StatusOr<EvalResult> ev = EvaluateViews(*fit->model, scene->test, eo);
  ASSERT_TRUE(ev.ok()) << ev.status();
  const double baseline = ConstantColourPsnr(scene->train, scene->test);
  RecordProperty("psnr", std::to_string(ev->psnr));
  RecordProperty("baseline_psnr", std::to_string(baseline));
  RecordProperty("fit_seconds", std::to_string(fit_seconds));
  // Measured (2 cores shared with another training run): seed 5 24.14 dB
  // (SSIM 0.704) vs the constant-colour baseline 15.93 dB; seeds 3 and 9:
  // 24.25 / 27.08 dB (SSIM 0.677 / 0.728), baselines 16.02 / 15.96; fit
  // 32-35 s. A room read as an object (white background, the box around the
  // camera loop's centre) stays near the baseline.
  EXPECT_GT(ev->psnr, baseline + 5.0) << "baseline " << baseline;
  EXPECT_GT(ev->ssim, 0.5);
}

TEST(ProceduralTrainingTest, ThinStructuresTrainAndGeneralise) {
  ProceduralSceneOptions po;
  po.width = po.height = 48;
  po.num_train_views = 60;
  po.num_test_views = 4;
  po.seed = 3;
  po.thin_structures = true;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  ASSERT_TRUE(scene.ok()) << scene.status();
  ProceduralSceneOptions plain = po;
  plain.thin_structures = false;
  absl::StatusOr<Scene> plain_scene = GenerateProceduralScene(plain);
  ASSERT_TRUE(plain_scene.ok()) << plain_scene.status();

  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<FitResult> fit = FitScene(*scene, SmallFit(300), nullptr);
  ASSERT_TRUE(fit.ok()) << fit.status();
  const double fit_seconds = SecondsSince(t0);
  ASSERT_TRUE(fit->model->AllFinite());

  EvalOptions eo;
  eo.render.threads = 2;
  absl::StatusOr<EvalResult> test = EvaluateViews(*fit->model, scene->test, eo);
  ASSERT_TRUE(test.ok()) << test.status();
  eo.max_views = 8;  // An evenly spaced subset of the training views.
  absl::StatusOr<EvalResult> train = EvaluateViews(*fit->model, scene->train, eo);
  ASSERT_TRUE(train.ok()) << train.status();
  const double baseline = ConstantColourPsnr(scene->train, scene->test);

  // Pixels where the rods (or their shadows) change the held-out images.
  double se_thin = 0, se_plain = 0, n = 0, n_plain = 0;
  for (size_t i = 0; i < scene->test.size(); ++i) {
    const Image& with = scene->test[i].image;
    const Image& without = plain_scene->test[i].image;
    RenderOptions ro;
    ro.threads = 2;
    absl::StatusOr<RenderedView> r = RenderView(*fit->model, scene->test[i].camera, ro);
    ASSERT_TRUE(r.ok()) << r.status();
    auto rod = [&](int x, int y) {
      float d = 0;
      for (int c = 0; c < 3; ++c) d = std::max(d, std::abs(with.pixel(x, y)[c] - without.pixel(x, y)[c]));
      return d > 0.1f;
    };
    AccumulateSquaredError(r->rgb, with, rod, &se_thin, &n);
    AccumulateSquaredError(r->rgb, without, rod, &se_plain, &n_plain);
  }
  ASSERT_GT(n, 3 * 100);
  const double rod_psnr = PsnrFromMse(se_thin / n);
  const double rod_psnr_vs_plain = PsnrFromMse(se_plain / n_plain);
  RecordProperty("psnr", std::to_string(test->psnr));
  RecordProperty("train_psnr", std::to_string(train->psnr));
  RecordProperty("baseline_psnr", std::to_string(baseline));
  RecordProperty("rod_psnr", std::to_string(rod_psnr));
  RecordProperty("rod_psnr_vs_plain", std::to_string(rod_psnr_vs_plain));
  RecordProperty("fit_seconds", std::to_string(fit_seconds));
  // Measured: fit 18 s (one busy core), test 21.5 dB (SSIM 0.86) vs baseline
  // 9.6 dB, train views 21.9 dB; on the ~380 rod pixels 17.5 dB against the
  // scene with rods vs 11.0 dB against the one without. (Seeds 5 and 9 with
  // 36 views: +9.4 / +10.0 dB over the baseline, train-test gap 0.9 / 1.5 dB,
  // rods +6.5 / +5.6 dB.)
  EXPECT_GT(test->psnr, baseline + 9.0) << "baseline " << baseline;
  EXPECT_GT(test->psnr, 18.5);
  EXPECT_GT(test->ssim, 0.75);
  EXPECT_GT(test->psnr, train->psnr - 2.5) << "train views " << train->psnr;
  EXPECT_GT(rod_psnr, rod_psnr_vs_plain + 3.5) << "the renders miss the rods";
  EXPECT_GT(rod_psnr, 14.5);
}

}  // namespace
}  // namespace clnerf
