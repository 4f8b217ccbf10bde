// End-to-end: a tiny procedural scene trained for a few hundred steps must
// clear a PSNR bar well above the constant-colour baseline, renders must be
// finite, and a run must be reproducible with a fixed seed.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "core/render/evaluate.h"
#include "core/train/fit.h"
#include "core/train/occupancy_prune.h"
#include "core/train/view_colour.h"
#include "core/render/metrics.h"
#include "core/data/procedural_scene.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

Scene TinyScene() {
  ProceduralSceneOptions po;
  po.width = po.height = 32;
  po.num_train_views = 40;
  po.num_test_views = 6;
  po.seed = 7;
  absl::StatusOr<Scene> s = GenerateProceduralScene(po);
  EXPECT_TRUE(s.ok()) << s.status();
  return *s;
}

FitOptions TinyFit(int iterations) {
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

TEST(TrainingTest, TinyProceduralSceneBeatsConstantColourBaseline) {
  const Scene scene = TinyScene();
  absl::StatusOr<FitResult> fit = FitScene(scene, TinyFit(300), nullptr);
  ASSERT_TRUE(fit.ok()) << fit.status();
  ASSERT_TRUE(fit->model->AllFinite());
  absl::StatusOr<EvalResult> ev = EvaluateViews(*fit->model, scene.test, {});
  ASSERT_TRUE(ev.ok()) << ev.status();
  const double baseline = ConstantColourPsnr(scene.train, scene.test);
  RecordProperty("psnr", std::to_string(ev->psnr));
  RecordProperty("baseline_psnr", std::to_string(baseline));
  // The baseline is ~10 dB on these scenes. 8 dB above it is a 6x lower MSE;
  // this 32x32 scene (hard checker edges and shadows, 40 views) saturates
  // near 21 dB whatever the capacity, so the bar is relative to the baseline.
  EXPECT_GT(ev->psnr, baseline + 8.0) << "baseline " << baseline;
  EXPECT_GT(ev->psnr, 18.0);
  EXPECT_GT(ev->ssim, 0.7);
}

TEST(TrainingTest, FixedSeedIsReproducible) {
  const Scene scene = TinyScene();
  absl::StatusOr<FitResult> a = FitScene(scene, TinyFit(20), nullptr);
  absl::StatusOr<FitResult> b = FitScene(scene, TinyFit(20), nullptr);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->model->params().mlp, b->model->params().mlp);
  EXPECT_EQ(a->model->params().grid, b->model->params().grid);
}

TEST(TrainingTest, CancelStopsTraining) {
  const Scene scene = TinyScene();
  std::atomic<bool> cancel{false};
  int steps = 0;
  absl::StatusOr<FitResult> fit = FitScene(
      scene, TinyFit(1000),
      [&](const StepStats& s, const Trainer&) {
        steps = s.step;
        if (s.step == 5) cancel = true;
      },
      &cancel);
  EXPECT_EQ(fit.status().code(), absl::StatusCode::kCancelled);
  EXPECT_EQ(steps, 5);
}

TEST(TrainingTest, CapacityOverridesWinOverTheDerivedSizes) {
  const Scene scene = TinyScene();
  absl::StatusOr<FitResult> derived = FitScene(scene, TinyFit(1), nullptr);
  ASSERT_TRUE(derived.ok()) << derived.status();
  FitOptions fo = TinyFit(1);
  fo.overrides.log2_table_size = derived->model->options().grid.log2_table_size - 1;
  fo.overrides.occupancy_resolution = 32;
  absl::StatusOr<FitResult> fit = FitScene(scene, fo, nullptr);
  ASSERT_TRUE(fit.ok()) << fit.status();
  EXPECT_EQ(fit->model->options().grid.log2_table_size, *fo.overrides.log2_table_size);
  EXPECT_EQ(fit->capacity.log2_table_size, *fo.overrides.log2_table_size);
  EXPECT_EQ(fit->model->options().occupancy.resolution, 32);
  // What was not overridden is still derived, and the footprint is reported.
  EXPECT_EQ(fit->model->options().grid.finest_resolution, derived->model->options().grid.finest_resolution);
  EXPECT_EQ(fit->capacity.pixel_footprint, derived->capacity.pixel_footprint);
  EXPECT_LT(fit->model->num_bytes(), derived->model->num_bytes());

  fo.overrides.log2_table_size = 40;  // Out of range: refused, not clamped.
  EXPECT_EQ(FitScene(scene, fo, nullptr).status().code(), absl::StatusCode::kInvalidArgument);
  fo.overrides.log2_table_size.reset();
  fo.overrides.occupancy_threshold = 0.0f;  // Not "derive": refused.
  EXPECT_EQ(FitScene(scene, fo, nullptr).status().code(), absl::StatusCode::kInvalidArgument);
}

// Per-view colour transforms (TrainOptions::view_colour, default settings):
// training photos whose exposure varies (gains 0.8 .. 1.2 by view, test
// photos at 1) get transforms whose gains follow the applied ones. Measured
// on this scene: correlation 0.91, and test PSNR 20.37 dB against 20.17
// without transforms. The field still absorbs much of each photo's exposure
// through its view-dependent colour (the learned gains span only
// 0.95 .. 1.00), which is why the gain in PSNR is small; docs/appearance.md.
// A transform indexed by the wrong view gives a correlation near 0, one
// with its gradient's sign flipped a negative one.
TEST(TrainingTest, ViewColourTransformsAbsorbPerPhotoExposure) {
  Scene scene = TinyScene();
  std::vector<double> gains;
  for (size_t v = 0; v < scene.train.size(); ++v) {
    const double g = 0.8 + 0.1 * double(v % 5);
    gains.push_back(g);
    for (float& x : scene.train[v].image.rgb) x = std::min(1.0f, float(g * x));
  }
  FitOptions fo = TinyFit(300);
  absl::StatusOr<FitResult> plain = FitScene(scene, fo, nullptr);
  ASSERT_TRUE(plain.ok()) << plain.status();
  EXPECT_TRUE(plain->view_colours.empty());
  fo.train.view_colour = true;
  absl::StatusOr<FitResult> fit = FitScene(scene, fo, nullptr);
  ASSERT_TRUE(fit.ok()) << fit.status();
  ASSERT_EQ(fit->view_colours.size(), scene.train.size() * kViewColourParams);
  // Correlation of the learned mean diagonal gain with the applied gain.
  std::vector<double> learned;
  for (size_t v = 0; v < scene.train.size(); ++v) {
    const float* p = &fit->view_colours[v * kViewColourParams];
    learned.push_back((p[0] + p[4] + p[8]) / 3.0);
  }
  double ma = 0, mb = 0;
  for (size_t v = 0; v < gains.size(); ++v) {
    ma += gains[v] / gains.size();
    mb += learned[v] / gains.size();
  }
  double sab = 0, saa = 0, sbb = 0;
  for (size_t v = 0; v < gains.size(); ++v) {
    sab += (gains[v] - ma) * (learned[v] - mb);
    saa += (gains[v] - ma) * (gains[v] - ma);
    sbb += (learned[v] - mb) * (learned[v] - mb);
  }
  const double corr = sab / std::sqrt(saa * sbb + 1e-30);
  absl::StatusOr<EvalResult> with = EvaluateViews(*fit->model, scene.test, {});
  absl::StatusOr<EvalResult> without = EvaluateViews(*plain->model, scene.test, {});
  ASSERT_TRUE(with.ok() && without.ok());
  RecordProperty("gain_correlation", std::to_string(corr));
  RecordProperty("psnr_with", std::to_string(with->psnr));
  RecordProperty("psnr_without", std::to_string(without->psnr));
  std::printf("gain correlation %.3f (learned %.3f .. %.3f); test PSNR %.2f with transforms, %.2f without\n", corr,
              *std::min_element(learned.begin(), learned.end()), *std::max_element(learned.begin(), learned.end()),
              with->psnr, without->psnr);
  EXPECT_GT(corr, 0.6);
  EXPECT_GT(with->psnr, without->psnr - 0.5);  // Not a regression on photos of one exposure.
}

// Occupancy pruning after training (FitOptions::prune): the calibration
// contract holds (training-pixel PSNR within max_psnr_drop), fewer cells
// stay occupied and rays march no more samples, and held-out views barely
// change. A ladder that prunes everything is refused by the calibration.
TEST(TrainingTest, PruningKeepsWhatTrainingPixelsNeed) {
  const Scene scene = TinyScene();
  FitOptions fo = TinyFit(300);
  absl::StatusOr<FitResult> fit = FitScene(scene, fo, nullptr);
  ASSERT_TRUE(fit.ok()) << fit.status();
  absl::StatusOr<EvalResult> before = EvaluateViews(*fit->model, scene.test, {});
  ASSERT_TRUE(before.ok());
  std::vector<const View*> views;
  for (const View& v : scene.train) views.push_back(&v);
  NgpModel pruned = *fit->model;
  PruneOptions po;
  // This small scene's grid is nearly tight already: rungs up to 30x the
  // grid's threshold, so that some of them remove cells.
  po.ladder = {0.1f, 0.3f, 1.0f, 3.0f, 10.0f, 30.0f};
  absl::StatusOr<PruneReport> r = PruneOccupancy(&pruned, views, po);
  ASSERT_TRUE(r.ok()) << r.status();
  std::printf("pruned %zu -> %zu cells (threshold %.3g), %.1f -> %.1f samples/ray, calibration %.2f -> %.2f dB\n",
              r->cells_before, r->cells_after, r->threshold, r->samples_before, r->samples_after, r->psnr_before,
              r->psnr_after);
  EXPECT_EQ(r->cells_before, fit->model->occupancy().num_occupied());
  EXPECT_EQ(r->cells_after, pruned.occupancy().num_occupied());
  EXPECT_LT(r->cells_after, r->cells_before);
  EXPECT_LE(r->samples_after, r->samples_before);
  EXPECT_GE(r->psnr_after, r->psnr_before - po.max_psnr_drop);
  absl::StatusOr<EvalResult> after = EvaluateViews(pruned, scene.test, {});
  ASSERT_TRUE(after.ok());
  EXPECT_NEAR(after->psnr, before->psnr, 0.3);
  // The field itself is untouched.
  EXPECT_EQ(pruned.params().grid, fit->model->params().grid);

  // A ladder whose only rung removes every cell costs far more than the
  // allowance, so nothing is pruned.
  NgpModel all = *fit->model;
  po.ladder = {1e12f};
  absl::StatusOr<PruneReport> none = PruneOccupancy(&all, views, po);
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_EQ(none->threshold, 0.0f);
  EXPECT_EQ(all.occupancy().bits(), fit->model->occupancy().bits());

  po.ladder = {0.1f, 0.05f};  // Not increasing.
  EXPECT_EQ(PruneOccupancy(&all, views, po).status().code(), absl::StatusCode::kInvalidArgument);
  po = PruneOptions();
  EXPECT_EQ(PruneOccupancy(&all, {}, po).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace clnerf
