#include "core/continual/continual_update.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "core/io/checkpoint.h"
#include "core/continual/continual_sampler.h"
#include "core/continual/continual_test_util.h"
#include "core/render/evaluate.h"
#include "core/data/procedural_scene.h"
#include "core/render/renderer.h"
#include "core/continual/scan_sequence.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(ContinualUpdateTest, PreviousModelAndMemoryAreUntouched) {
  const ScanSequence seq = TinySequence(2, 16, 8);
  absl::StatusOr<ContinualState> s0 =
      ContinualUpdate(seq.ScanScene(0), nullptr, TinyOptions(ContinualMethod::kCLNeRF, 10), nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok()) << s0.status();
  // The checkpoint quantises occupancy densities: compare them separately.
  const std::string model_before = *SerializeCheckpoint(*s0->model);
  const std::vector<float> density_before = s0->model->occupancy().density();
  const std::string memory_before = s0->memory.Serialize();
  for (InitMode init : {InitMode::kWarm, InitMode::kReinit}) {
    UpdateOptions o = TinyOptions(ContinualMethod::kCLNeRF, 10);
    o.init = init;
    UpdateReport rep;
    absl::StatusOr<ContinualState> s1 = ContinualUpdate(seq.ScanScene(1), &*s0, o, nullptr, nullptr, &rep);
    ASSERT_TRUE(s1.ok()) << s1.status();
    EXPECT_EQ(*SerializeCheckpoint(*s0->model), model_before);
    EXPECT_EQ(s0->model->occupancy().density(), density_before);
    EXPECT_EQ(s0->memory.Serialize(), memory_before);
    EXPECT_EQ(s1->model->num_time_steps(), 2);
    EXPECT_EQ(s1->memory.num_cameras(), 16u);
    EXPECT_EQ(rep.replay_views + rep.buffer_views, 8);
  }
}

// Stability: an update whose training blows up (learning rate 1e30: the
// parameters overflow) fails with INTERNAL naming the divergence, produces no
// model and leaves θ_{t-1} and M_{t-1} bit-identical, for every init and for
// EWC (which the paper could not run on NGP). A non-finite θ_{t-1} is refused
// up front, and a scan with a NaN pixel is rejected as bad input.
TEST(ContinualUpdateTest, DivergenceFailsCleanlyAndKeepsThePreviousState) {
  const ScanSequence seq = TinySequence(2, 16, 8);
  absl::StatusOr<ContinualState> s0 =
      ContinualUpdate(seq.ScanScene(0), nullptr, TinyOptions(ContinualMethod::kEWC, 20), nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok()) << s0.status();
  ASSERT_NE(s0->ewc, nullptr);
  // The checkpoint quantises occupancy densities: compare them separately.
  const std::string model_before = *SerializeCheckpoint(*s0->model);
  const std::vector<float> density_before = s0->model->occupancy().density();
  const std::string memory_before = s0->memory.Serialize();
  for (ContinualMethod method : {ContinualMethod::kCLNeRF, ContinualMethod::kEWC}) {
    for (InitMode init : {InitMode::kWarm, InitMode::kReinit}) {
      UpdateOptions o = TinyOptions(method, 20);
      o.init = init;
      o.train.learning_rate = 1e30f;
      absl::StatusOr<ContinualState> s1 = ContinualUpdate(seq.ScanScene(1), &*s0, o, nullptr, nullptr, nullptr);
      ASSERT_FALSE(s1.ok()) << ContinualMethodName(method);
      EXPECT_EQ(s1.status().code(), absl::StatusCode::kInternal);
      EXPECT_NE(s1.status().message().find("diverged"), std::string::npos) << s1.status();
      EXPECT_EQ(*SerializeCheckpoint(*s0->model), model_before);
      EXPECT_EQ(s0->model->occupancy().density(), density_before);
      EXPECT_EQ(s0->memory.Serialize(), memory_before);
    }
  }
  // Control: the same update with the default learning rate succeeds.
  ASSERT_TRUE(ContinualUpdate(seq.ScanScene(1), &*s0, TinyOptions(ContinualMethod::kEWC, 20), nullptr, nullptr, nullptr).ok());

  ContinualState bad = *s0;
  auto poisoned = std::make_shared<NgpModel>(*s0->model);
  poisoned->mutable_params().mlp[3] = NAN;
  bad.model = poisoned;
  absl::StatusOr<ContinualState> s2 =
      ContinualUpdate(seq.ScanScene(1), &bad, TinyOptions(ContinualMethod::kCLNeRF, 20), nullptr, nullptr, nullptr);
  EXPECT_EQ(s2.status().code(), absl::StatusCode::kFailedPrecondition) << s2.status();

  Scene nan_scan = seq.ScanScene(1);
  nan_scan.train[2].image.rgb[7] = NAN;
  absl::StatusOr<ContinualState> s3 =
      ContinualUpdate(nan_scan, &*s0, TinyOptions(ContinualMethod::kCLNeRF, 20), nullptr, nullptr, nullptr);
  EXPECT_EQ(s3.status().code(), absl::StatusCode::kInvalidArgument) << s3.status();
}

TEST(ContinualUpdateTest, ReplayLabelsAreThePreviousModelsRenders) {
  const ScanSequence seq = TinySequence(2, 16, 8);
  absl::StatusOr<ContinualState> s0 =
      ContinualUpdate(seq.ScanScene(0), nullptr, TinyOptions(ContinualMethod::kCLNeRF, 30), nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok()) << s0.status();
  const NgpModel& prev = *s0->model;
  // Online: every replay ray's label is the frozen model's render of that ray.
  std::vector<SamplerView> views;
  for (uint32_t i = 0; i < s0->memory.num_cameras(); ++i) views.push_back({s0->memory.GetCamera(i), nullptr, nullptr, true});
  ContinualRaySampler sampler(views, prev, &prev, 0.0f);
  std::mt19937_64 rng(5);
  RayBatch b;
  sampler.Sample(64, &rng, &b);
  for (int i = 0; i < b.size(); ++i) {
    float rgb[3];
    RenderRays(prev, &b.origin[3 * i], &b.dir[3 * i], 1, b.time_step[i], RenderOptions{}, rgb, nullptr, nullptr);
    // A batch of rays and a single ray may go through different GEMM
    // kernels (e.g. AVX-512 FP16 paths on Intel), so the property is
    // equality to float precision, not bit equality.
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(b.target[3 * i + c], rgb[c], 1e-6f) << "ray " << i;
    EXPECT_EQ(b.view[i], -1) << "a replay ray has no photo (and no colour transform)";
  }
  // Offline: the cached label of a view is RenderView's image of it, so a
  // sampled pixel equals the same pixel of RenderView.
  const Camera cam = s0->memory.GetCamera(0);
  RenderOptions ro;
  ro.time_step = cam.time_step;
  absl::StatusOr<RenderedView> full = RenderView(prev, cam, ro);
  ASSERT_TRUE(full.ok());
  ContinualRaySampler offline({{cam, &full->rgb, nullptr, true}}, prev, nullptr, 0.0f);
  offline.Sample(32, &rng, &b);
  for (int i = 0; i < b.size(); ++i) {
    float rgb[3];
    RenderRays(prev, &b.origin[3 * i], &b.dir[3 * i], 1, b.time_step[i], RenderOptions{}, rgb, nullptr, nullptr);
    // A batch of rays and a single ray may go through different GEMM
    // kernels (e.g. AVX-512 FP16 paths on Intel), so the property is
    // equality to float precision, not bit equality.
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(b.target[3 * i + c], rgb[c], 1e-6f) << "ray " << i;
  }
}

// new_share: that fraction of a batch comes from the new scan's views, the
// rest from past views; 0 is uniform over all views.
TEST(ContinualUpdateTest, NewScanShareSplitsTheBatch) {
  const ScanSequence seq = TinySequence(1, 16, 8);
  absl::StatusOr<ContinualState> s0 =
      ContinualUpdate(seq.ScanScene(0), nullptr, TinyOptions(ContinualMethod::kCLNeRF, 5), nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok()) << s0.status();
  // One current view (time step 1 marks it) and seven past views.
  std::vector<SamplerView> views;
  for (int k = 0; k < 8; ++k) {
    const View& v = seq.scans[0].train[k];
    SamplerView sv{v.camera, &v.image, nullptr, false, k > 0};
    sv.camera.time_step = k == 0 ? 1 : 0;
    views.push_back(sv);
  }
  auto current_fraction = [&](float share) {
    ContinualRaySampler sampler(views, *s0->model, nullptr, 0.0f, share);
    std::mt19937_64 rng(3);
    RayBatch b;
    sampler.Sample(4000, &rng, &b);
    int cur = 0;
    for (int i = 0; i < b.size(); ++i) {
      cur += b.time_step[i] == 1;
      // Photos name their view (view 0 is the current one).
      EXPECT_EQ(b.view[i] == 0, b.time_step[i] == 1) << i;
      EXPECT_GE(b.view[i], 0);
    }
    return double(cur) / b.size();
  };
  EXPECT_NEAR(current_fraction(0.5f), 0.5, 1e-3);    // Exactly round(n * share) rays.
  EXPECT_NEAR(current_fraction(0.25f), 0.25, 1e-3);
  EXPECT_NEAR(current_fraction(0.0f), 1.0 / 8, 0.02);  // Uniform: 1 view in 8.
  UpdateOptions bad = TinyOptions(ContinualMethod::kCLNeRF, 5);
  bad.new_scan_share = 1.0f;
  EXPECT_FALSE(bad.Validate().ok());
}

TEST(ContinualUpdateTest, TimeStepsRouteToTheirEmbeddingRows) {
  const ScanSequence seq = TinySequence(1, 16, 8);
  absl::StatusOr<ContinualState> s0 =
      ContinualUpdate(seq.ScanScene(0), nullptr, TinyOptions(ContinualMethod::kCLNeRF, 20), nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok());
  NgpModel m = *s0->model;
  m.AddTimeStep(99);
  const Camera cam = seq.scans[0].test[0].camera;
  RenderOptions r0, r1;
  r0.time_step = 0;
  r1.time_step = 1;
  const Image a = RenderView(m, cam, r0)->rgb, b = RenderView(m, cam, r1)->rgb;
  EXPECT_NE(a.rgb, b.rgb);  // Different rows, different renders.
  // Copy row 0 into row 1: the renders become identical.
  const int row = m.network().embedding_row_size();
  std::copy(m.params().emb.begin(), m.params().emb.begin() + row, m.mutable_params().emb.begin() + row);
  {
    // Rows 0 and 1 go through different columns of one GEMM: equal to float
    // precision, not necessarily bit for bit.
    const Image c = RenderView(m, cam, r1)->rgb;
    ASSERT_EQ(c.rgb.size(), a.rgb.size());
    for (size_t i = 0; i < a.rgb.size(); ++i) ASSERT_NEAR(c.rgb[i], a.rgb[i], 1e-6f) << "value " << i;
  }
  {
    // AddTimeStepCopyingLast appends a copy of the last row.
    NgpModel copied = *s0->model;
    copied.AddTimeStepCopyingLast();
    ASSERT_EQ(copied.num_time_steps(), 2);
    const std::vector<float>& e = copied.params().emb;
    ASSERT_EQ(e.size(), size_t(2 * row));
    EXPECT_TRUE(std::equal(e.begin(), e.begin() + row, e.begin() + row));
  }
  // Training rays of step 1 only produce gradients in row 1.
  std::vector<const View*> vs;
  std::vector<View> views = seq.scans[0].train;
  for (View& v : views) {
    v.camera.time_step = 1;
    vs.push_back(&v);
  }
  auto sampler = ImageRaySampler::Create(vs, m);
  ASSERT_TRUE(sampler.ok());
  Trainer tr(&m, sampler->get(), TinyOptions(ContinualMethod::kCLNeRF, 1).train);
  RayBatch batch;
  std::mt19937_64 rng(1);
  (*sampler)->Sample(256, &rng, &batch);
  Trainer::Gradients g;
  tr.ComputeLossAndGradients(batch, std::vector<float>(batch.size(), 0.5f), &g);
  double row0 = 0, row1 = 0;
  for (int i = 0; i < row; ++i) row0 += std::abs(g.emb[i]), row1 += std::abs(g.emb[row + i]);
  EXPECT_EQ(row0, 0.0);
  EXPECT_GT(row1, 0.0);
}

TEST(ContinualUpdateTest, MasksExcludePixels) {
  // Left half red, right half blue; the mask keeps only the left half.
  View v;
  v.name = "masked";
  v.camera.intrinsics = {8, 8, 10, 10, 4, 4};
  v.camera.c2w.col(3) = Eigen::Vector3f(0, 0, -3);
  v.image = Image(8, 8);
  v.mask = {8, 8, std::vector<uint8_t>(64, 0)};
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) {
      float* p = v.image.pixel(x, y);
      p[0] = x < 4 ? 1.0f : 0.0f;
      p[2] = x < 4 ? 0.0f : 1.0f;
      v.mask.keep[y * 8 + x] = x < 4;
    }
  Normalization norm;
  absl::StatusOr<NgpModel> m = NgpModel::Create(TinyOptions(ContinualMethod::kNT, 1).model, norm,
                                                SceneKind::kBounded, Eigen::Vector3f::Ones(), 1, 0);
  ASSERT_TRUE(m.ok());
  ContinualRaySampler s({{v.camera, &v.image, &v.mask, false}}, *m, nullptr, 0.0f);
  auto img = ImageRaySampler::Create({&v}, *m);
  ASSERT_TRUE(img.ok());
  std::mt19937_64 rng(2);
  for (RaySampler* sampler : {static_cast<RaySampler*>(&s), static_cast<RaySampler*>(img->get())}) {
    RayBatch b;
    sampler->Sample(500, &rng, &b);
    for (int i = 0; i < b.size(); ++i) {
      ASSERT_EQ(b.target[3 * i], 1.0f);
      ASSERT_EQ(b.target[3 * i + 2], 0.0f);
    }
  }
}

// On a tiny 3-scan changing scene, clnerf keeps the first scan while nt
// forgets it. The images are anti-aliased (3x3 samples per pixel): with one
// ray per pixel the 24 px checkerboard floor aliases differently in every
// view, which capped scan 0 at ~17 dB and left only a ~3 dB margin. Measured
// here (150 steps per scan): scan 0 after step 0 20.4 dB; after step 2
// clnerf 19.8 / nt 15.5 dB (warm start) and 19.2 / 15.6 dB (re-init).
class FirstScanTest : public ::testing::TestWithParam<InitMode> {};

TEST_P(FirstScanTest, CLNeRFBeatsNaiveTrainingOnTheFirstScan) {
  const InitMode init = GetParam();
  const ScanSequence seq = TinySequence(3, 24, 20, /*samples_per_axis=*/3);
  double psnr[2], first[2];
  int k = 0;
  for (ContinualMethod method : {ContinualMethod::kCLNeRF, ContinualMethod::kNT}) {
    std::optional<ContinualState> state;
    for (int t = 0; t < 3; ++t) {
      UpdateOptions o = TinyOptions(method, 150);
      o.init = init;
      // The margins below were measured at Instant-NGP's occupancy decay;
      // at the default 0.8 naive training forgets ~0.4 dB less on this tiny
      // scene (re-init margin 2.9-3.8 dB over seeds 1-5, docs/render_cost.md),
      // which says little of forgetting and much of the tiny budget.
      o.model.occupancy.decay = 0.95f;
      absl::StatusOr<ContinualState> next =
          ContinualUpdate(seq.ScanScene(t), state ? &*state : nullptr, o, nullptr, nullptr, nullptr);
      ASSERT_TRUE(next.ok()) << next.status();
      state = std::move(*next);
      if (t == 0) {
        absl::StatusOr<EvalResult> e = EvaluateViews(*state->model, seq.scans[0].test, {});
        ASSERT_TRUE(e.ok());
        first[k] = e->psnr;
      }
    }
    absl::StatusOr<EvalResult> ev = EvaluateViews(*state->model, seq.scans[0].test, {});
    ASSERT_TRUE(ev.ok());
    psnr[k++] = ev->psnr;
  }
  RecordProperty("clnerf_psnr", std::to_string(psnr[0]));
  RecordProperty("nt_psnr", std::to_string(psnr[1]));
  EXPECT_GT(psnr[0], psnr[1] + 3.0) << "clnerf " << psnr[0] << " nt " << psnr[1];
  // Both saw the same step 0; clnerf keeps it, nt forgets it.
  EXPECT_EQ(first[0], first[1]);
  EXPECT_GT(psnr[0], first[0] - 2.0) << "clnerf forgot scan 0: " << first[0] << " -> " << psnr[0];
  EXPECT_LT(psnr[1], first[1] - 3.0) << "nt did not forget scan 0: " << first[1] << " -> " << psnr[1];
}

INSTANTIATE_TEST_SUITE_P(ContinualUpdateTest, FirstScanTest, ::testing::Values(InitMode::kWarm, InitMode::kReinit),
                         [](const auto& info) { return info.param == InitMode::kWarm ? "Warm" : "Reinit"; });

// One optimiser across the sequence: θ_t's Adam state travels with the state,
// round-trips through bytes bit for bit, and an update from a state reloaded
// from disk (checkpoint, M_t and optimiser bytes) equals the update from the
// in-memory state within float tolerance; the carried state changes the
// update (a fresh optimiser trains differently).
TEST(ContinualUpdateTest, CarriedOptimizerRoundTripsAndResumesTheSame) {
  const ScanSequence seq = TinySequence(2, 16, 8);
  UpdateOptions o = TinyOptions(ContinualMethod::kCLNeRF, 12);
  o.carry_optimizer = true;
  o.train.lr_schedule = LrSchedule::kInverseSqrtCosine;
  absl::StatusOr<ContinualState> s0 = ContinualUpdate(seq.ScanScene(0), nullptr, o, nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok()) << s0.status();
  ASSERT_NE(s0->optimizer, nullptr);
  EXPECT_EQ(s0->optimizer->step, 12u);
  EXPECT_TRUE(s0->optimizer->CompatibleWith(s0->model->params()).ok());

  // Reload everything from bytes, as the service does from a version.
  const std::string opt_bytes = s0->optimizer->Serialize();
  absl::StatusOr<OptimizerState> opt = OptimizerState::Deserialize(opt_bytes);
  ASSERT_TRUE(opt.ok()) << opt.status();
  EXPECT_TRUE(*opt == *s0->optimizer);
  absl::StatusOr<LoadedCheckpoint> ck = DeserializeCheckpoint(*SerializeCheckpoint(*s0->model));
  ASSERT_TRUE(ck.ok()) << ck.status();
  absl::StatusOr<ReplayMemory> mem = ReplayMemory::Deserialize(s0->memory.Serialize());
  ASSERT_TRUE(mem.ok()) << mem.status();
  // The checkpoint restores the occupancy density EMA only approximately
  // (checkpoint.h): both runs start from the reloaded model so that what is
  // compared is the optimiser path.
  ContinualState in_memory{std::make_shared<NgpModel>(ck->model), *mem, nullptr, s0->optimizer};
  ContinualState reloaded{std::make_shared<NgpModel>(ck->model), *mem, nullptr,
                          std::make_shared<OptimizerState>(*opt)};
  absl::StatusOr<ContinualState> a = ContinualUpdate(seq.ScanScene(1), &in_memory, o, nullptr, nullptr, nullptr);
  absl::StatusOr<ContinualState> b = ContinualUpdate(seq.ScanScene(1), &reloaded, o, nullptr, nullptr, nullptr);
  ASSERT_TRUE(a.ok() && b.ok()) << a.status() << b.status();
  EXPECT_EQ(a->optimizer->step, 24u);
  EXPECT_EQ(b->optimizer->step, 24u);
  const auto max_diff = [](const std::vector<float>& x, const std::vector<float>& y) {
    float d = x.size() == y.size() ? 0.0f : INFINITY;
    for (size_t i = 0; i < x.size() && i < y.size(); ++i) d = std::max(d, std::abs(x[i] - y[i]));
    return d;
  };
  EXPECT_LE(max_diff(a->model->params().mlp, b->model->params().mlp), 1e-5f);
  EXPECT_LE(max_diff(a->model->params().grid, b->model->params().grid), 1e-5f);
  EXPECT_LE(max_diff(a->model->params().emb, b->model->params().emb), 1e-5f);
  EXPECT_LE(max_diff(a->optimizer->v[1], b->optimizer->v[1]), 1e-6f);

  // Without the carried state the same update trains differently.
  ContinualState no_opt = in_memory;
  no_opt.optimizer = nullptr;
  absl::StatusOr<ContinualState> c = ContinualUpdate(seq.ScanScene(1), &no_opt, o, nullptr, nullptr, nullptr);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->optimizer->step, 12u);
  EXPECT_GT(max_diff(a->model->params().mlp, c->model->params().mlp), 1e-4f);
  // Switched off, no state is produced.
  UpdateOptions off = TinyOptions(ContinualMethod::kCLNeRF, 4);
  off.carry_optimizer = false;
  absl::StatusOr<ContinualState> d = ContinualUpdate(seq.ScanScene(0), nullptr, off, nullptr, nullptr, nullptr);
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->optimizer, nullptr);
}

// UpdateOptions::refine_cameras: a rescan of a textured procedural object
// whose photos are the first scan's, with cameras disturbed as registration
// leaves them, comes out of its update closer to the true poses: the first
// scan's replay holds the frame and the photos pull their cameras back.
// Without refinement the kept cameras are the uploaded ones. Two
// disturbances, each checked on what 48 x 48 photos resolve:
//  - turned by 1.5 degrees about a random axis (~1.5 px) and shifted by 1 %
//    of the orbit (~0.6 px): the turn must halve, and the shift, below a
//    pixel, must not grow by more than a tenth (measured: 0.0101 and
//    0.0103 on two builds, where "smaller than uploaded" held on one
//    machine and not on another);
//  - shifted by 3 % of the orbit (~1.7 px) alone: the shift must fall by a
//    quarter (measured 0.0167; part of it goes into a turn of ~0.8 deg,
//    which a shift and a turn trade off at this size).
TEST(ContinualUpdateTest, RefinedCamerasOfARescanMoveTowardsTheTruth) {
  ProceduralSceneOptions po;
  po.width = po.height = 48;
  po.num_train_views = 16;
  po.num_test_views = 2;
  po.num_time_steps = 1;
  po.textured = true;
  po.seed = 5;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  ASSERT_TRUE(scene.ok()) << scene.status();
  UpdateOptions o = TinyOptions(ContinualMethod::kCLNeRF, 600);
  absl::StatusOr<ContinualState> s0 = ContinualUpdate(*scene, nullptr, o, nullptr, nullptr, nullptr);
  ASSERT_TRUE(s0.ok()) << s0.status();
  double extent = 0;
  for (const View& v : scene->train) extent = std::max(extent, double(v.camera.position().norm()));
  auto disturbed = [&](float turn_deg, float shift) {
    Scene rescan = *scene;
    rescan.test.clear();
    std::mt19937_64 rng(9);
    std::normal_distribution<float> g(0.0f, 1.0f);
    for (View& v : rescan.train) {
      v.camera.time_step = 1;
      const Eigen::Vector3f axis = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
      v.camera.c2w.leftCols<3>() = Eigen::AngleAxisf(turn_deg * float(M_PI) / 180, axis) * v.camera.c2w.leftCols<3>();
      v.camera.c2w.col(3) += shift * float(extent) * Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    }
    return rescan;
  };
  auto errors = [&](const ContinualState& s, double* turn, double* shift) {
    std::vector<double> t, c;
    const size_t n = scene->train.size();
    for (size_t i = 0; i < n; ++i) {
      const Camera got = s.memory.GetCamera(uint32_t(s.memory.num_cameras() - n + i));
      const Camera& want = scene->train[i].camera;
      const Eigen::Matrix3d dr = (got.c2w.leftCols<3>().transpose() * want.c2w.leftCols<3>()).cast<double>();
      t.push_back(Eigen::AngleAxisd(dr).angle() * 180 / M_PI);
      c.push_back((got.position() - want.position()).norm() / extent);
    }
    std::sort(t.begin(), t.end());
    std::sort(c.begin(), c.end());
    *turn = t[t.size() / 2];
    *shift = c[c.size() / 2];
  };
  const Scene turned = disturbed(1.5f, 0.01f);
  UpdateOptions off = TinyOptions(ContinualMethod::kCLNeRF, 20);
  off.refine_cameras = false;
  absl::StatusOr<ContinualState> plain = ContinualUpdate(turned, &*s0, off, nullptr, nullptr, nullptr);
  ASSERT_TRUE(plain.ok()) << plain.status();
  double turn0, shift0;
  errors(*plain, &turn0, &shift0);
  EXPECT_NEAR(turn0, 1.5, 1e-3);  // Kept as uploaded.
  EXPECT_NEAR(shift0, 0.01, 1e-4);

  UpdateOptions on = TinyOptions(ContinualMethod::kCLNeRF, 400);
  on.refine_cameras = true;
  UpdateReport rep;
  absl::StatusOr<ContinualState> refined = ContinualUpdate(turned, &*s0, on, nullptr, nullptr, &rep);
  ASSERT_TRUE(refined.ok()) << refined.status();
  double turn1, shift1;
  errors(*refined, &turn1, &shift1);
  EXPECT_EQ(rep.refined_cameras, 16);
  EXPECT_GT(rep.camera_turn_median_deg, 0.0);
  EXPECT_FALSE(rep.camera_refine_summary.empty());
  std::printf("turned cameras, refined: median turn error %.3f deg (uploaded %.3f), shift %.4f (uploaded %.4f) of "
              "the orbit; %s\n",
              turn1, turn0, shift1, shift0, rep.camera_refine_summary.c_str());
  EXPECT_LT(turn1, 0.5 * turn0);
  EXPECT_LT(shift1, 1.1 * shift0);
  // The first scan's cameras never move.
  for (uint32_t i = 0; i < s0->memory.num_cameras(); ++i) {
    EXPECT_EQ(refined->memory.GetCamera(i).c2w, s0->memory.GetCamera(i).c2w);
  }

  absl::StatusOr<ContinualState> moved = ContinualUpdate(disturbed(0.0f, 0.03f), &*s0, on, nullptr, nullptr, nullptr);
  ASSERT_TRUE(moved.ok()) << moved.status();
  double turn2, shift2;
  errors(*moved, &turn2, &shift2);
  std::printf("shifted cameras, refined: median shift %.4f (uploaded 0.0300) of the orbit, turn %.3f deg\n", shift2,
              turn2);
  EXPECT_LT(shift2, 0.75 * 0.03);
}

}  // namespace
}  // namespace clnerf
