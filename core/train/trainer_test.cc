// Whole-pipeline tests of the trainer: the loss gradient of one batch
// (march -> encode -> MLPs -> compositing with early termination -> MSE +
// opacity entropy) against central differences of the loss, NaN handling in
// Step(), and run-to-run determinism.
#include "core/train/trainer.h"
#include "core/train/view_colour.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <random>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Dense"
#include "Eigen/Geometry"
#include "core/data/contraction.h"
#include "core/field/field.h"
#include "core/field/proposal_sampler.h"
#include "core/field/ray_marcher.h"
#include "core/render/renderer.h"
#include "core/train/ray_sampler.h"
#include "core/render/volume_rendering.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

ModelOptions TinyOptions() {
  ModelOptions o;
  o.grid.levels = 4;
  o.grid.log2_table_size = 10;
  o.grid.base_resolution = 4;
  o.grid.finest_resolution = 32;
  o.network.density_hidden = 16;
  o.network.density_hidden_layers = 1;
  o.network.density_out = 16;
  o.network.colour_hidden = 16;
  o.network.colour_hidden_layers = 2;
  o.network.appearance_dim = 8;
  o.network.geometry_dim = 4;
  o.occupancy.resolution = 16;
  o.march.steps_per_diagonal = 64;  // <= 64 samples per ray.
  o.march.near = 0.05f;
  o.proposal.samples0 = 16;
  o.proposal.samples1 = 12;
  o.proposal.nerf_samples = 16;
  for (ProposalFieldOptions* f : {&o.proposal.field0, &o.proposal.field1}) {
    f->levels = 3;
    f->log2_table_size = 10;
    f->base_resolution = 4;
    f->finest_resolution = 16;
    f->hidden = 8;
  }
  return o;
}

NgpModel TinyModel(uint64_t seed, int time_steps = 2, SceneKind kind = SceneKind::kBounded,
                   SamplerKind sampler = SamplerKind::kOccupancy) {
  Normalization norm;
  ModelOptions o = TinyOptions();
  o.sampler = sampler;
  if (kind == SceneKind::kUnbounded) {
    norm.bound = kContractedBound;
    // The contracted cube is 4 units wide: keep rays at <= ~50 samples.
    o.march.steps_per_diagonal = 32;
  }
  auto m = NgpModel::Create(o, norm, kind, Eigen::Vector3f(0.3f, 0.6f, 0.9f), time_steps, seed);
  EXPECT_TRUE(m.ok()) << m.status();
  return *std::move(m);
}

// A sampler that never samples and has no cameras, so the trainer leaves the
// occupancy grid fully occupied (ComputeLossAndGradients takes its batch
// directly).
class NoSampler : public RaySampler {
 public:
  explicit NoSampler(int photos = 0) : photos_(photos) {}
  void Sample(int, std::mt19937_64*, RayBatch*) override { ADD_FAILURE() << "not used"; }
  std::vector<Camera> Cameras() const override { return {}; }
  int NumPhotoViews() const override { return photos_; }

 private:
  int photos_;
};

// Rays from a sphere of radius 1.3 aimed near the centre, random targets,
// time steps and loss weights.
RayBatch MakeBatch(int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> g(0.0f, 1.0f);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  RayBatch b;
  b.Resize(n);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3f o = 1.3f * Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector3f aim = 0.15f * Eigen::Vector3f(g(rng), g(rng), g(rng));
    const Eigen::Vector3f d = (aim - o).normalized();
    for (int k = 0; k < 3; ++k) {
      b.origin[3 * i + k] = o[k];
      b.dir[3 * i + k] = d[k];
      b.target[3 * i + k] = u(rng);
    }
    b.time_step[i] = i % 2;
    b.weight[i] = 0.5f + u(rng);
  }
  return b;
}

// The composited colour of ray i exactly as the trainer computes it, read
// back through the loss of single-ray batches (weight 1): L(t) = |c - t|^2 / 3
// + entropy, so L(0) - L(e_k) = (2 c_k - 1) / 3.
Eigen::Vector3f TrainerColour(Trainer* trainer, const RayBatch& batch, const std::vector<float>& jitter, int i) {
  RayBatch one;
  one.Resize(1);
  std::copy_n(&batch.origin[3 * i], 3, one.origin.begin());
  std::copy_n(&batch.dir[3 * i], 3, one.dir.begin());
  one.time_step[0] = batch.time_step[i];
  one.weight[0] = 1.0f;
  const std::vector<float> j = {jitter[i]};
  Trainer::Gradients g;
  std::fill(one.target.begin(), one.target.end(), 0.0f);
  const double l0 = trainer->ComputeLossAndGradients(one, j, &g);
  Eigen::Vector3f c;
  for (int k = 0; k < 3; ++k) {
    std::fill(one.target.begin(), one.target.end(), 0.0f);
    one.target[k] = 1.0f;
    const double lk = trainer->ComputeLossAndGradients(one, j, &g);
    c[k] = float((3 * (l0 - lk) + 1) / 2);
  }
  return c;
}

// Single-threaded trainer for the gradient checks. With TrainOptions::threads
// = 1 the trainer's OpenMP regions have one thread, and Eigen (built with
// -fopenmp) then parallelises the larger GEMMs itself with all cores; keep
// Eigen serial while these tests run so they are not slowed down by spinning
// threads on a loaded machine. Results do not depend on it.
class SerialEigen {
 public:
  SerialEigen() : saved_(Eigen::nbThreads()) { Eigen::setNbThreads(1); }
  ~SerialEigen() { Eigen::setNbThreads(saved_); }

 private:
  int saved_;
};

// Per ray, the transmittance after each marched sample, recomputed
// independently of the trainer: same marching (public IntersectBox /
// StepAt / MarchRay with the same jitter) and NgpModel::Density at the
// samples (one call per time step).
std::vector<std::vector<double>> Transmittances(const NgpModel& model, const RayBatch& batch,
                                                const std::vector<float>& jitter) {
  const MarchOptions& mo = model.options().march;
  std::vector<std::vector<RaySample>> samples(batch.size());
  for (int r = 0; r < batch.size(); ++r) {
    const Eigen::Vector3f o(&batch.origin[3 * r]), d(&batch.dir[3 * r]);
    float t0, t1;
    if (!model.RayInterval(o, d, &t0, &t1)) continue;
    if (model.uses_proposals()) {  // Bin-centre placement, as ComputeLossAndGradients uses.
      const FieldEvaluator field(model);
      ProposalContext ctx;
      std::vector<int> seg = {0}, ray;
      ProposalSampler(field).Place(o.data(), d.data(), 1, 0, nullptr, 1.0f, &ctx, &samples[r], &seg, &ray);
      continue;
    }
    const float t = t0 + jitter[r] * model.StepAt(o, d, t0);
    model.March(o, d, t, t1, mo.max_samples, &samples[r]);
  }
  std::vector<std::vector<double>> out(batch.size());
  for (int step = 0; step < model.num_time_steps(); ++step) {
    std::vector<float> pts;
    for (int r = 0; r < batch.size(); ++r) {
      if (batch.time_step[r] != step) continue;
      const Eigen::Vector3f o(&batch.origin[3 * r]), d(&batch.dir[3 * r]);
      for (const RaySample& s : samples[r]) {
        const Eigen::Vector3f x = o + s.t * d;
        const Eigen::Vector3f p = model.contracted() ? Contract(x) : x;  // Density takes field space.
        pts.insert(pts.end(), p.data(), p.data() + 3);
      }
    }
    std::vector<float> sigma(pts.size() / 3);
    model.Density(pts.data(), int(sigma.size()), step, sigma.data());
    size_t k = 0;
    for (int r = 0; r < batch.size(); ++r) {
      if (batch.time_step[r] != step) continue;
      double tau = 0;
      for (const RaySample& s : samples[r]) {
        tau += double(sigma[k++]) * s.dt;
        out[r].push_back(std::exp(-tau));
      }
    }
  }
  return out;
}

struct Block {
  const char* name;
  std::vector<float> ModelParams::*params;
  std::vector<float> Trainer::Gradients::*grads;
  float h;  // FD step.
};

// Loss gradient of one batch vs central differences of the loss returned by
// ComputeLossAndGradients. `opaque` makes the density large, so that most
// rays terminate early (exercising the trainer's compaction of the kept
// samples); otherwise no ray gets near the termination threshold.
// `contracted` uses an unbounded scene: contracted space, contracted
// marching, and the distortion loss (on by default there).
// `near_reg` is the occlusion penalty's weight (0: off; `near_distance`
// its reach); the test then also checks that the term changes the loss.
void CheckLossGradient(bool opaque, bool contracted = false, float near_reg = 0.0f, float near_distance = 0.2f,
                       SamplerKind sampler_kind = SamplerKind::kOccupancy, float depth_weight = 0.0f,
                       bool view_colour = false) {
  SerialEigen serial;
  NgpModel model = TinyModel(3, 2, contracted ? SceneKind::kUnbounded : SceneKind::kBounded, sampler_kind);
  ModelParams& p = model.mutable_params();
  // Grid values of O(0.1) instead of 1e-4, so that the grid features (and
  // the MLP weights that read them) matter.
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (float& v : p.grid) v = u(rng) - 0.5f;
  if (opaque) {
    // h0 = W[0, :] relu(...) with a positive first row: sigma = exp(h0) of
    // several tens.
    const Network::Layer& last = model.network().density_layers().back();
    for (int c = 0; c < last.cols; ++c) {
      float& w = p.mlp[last.offset + size_t(c) * last.rows];
      w = std::abs(w) + 0.6f;
    }
  }
  // Per-view colour transforms: three photos (and rays without one).
  constexpr int kPhotos = 3;
  NoSampler sampler(view_colour ? kPhotos : 0);
  TrainOptions to;
  to.threads = 1;
  to.view_colour = view_colour;
  to.view_colour_prior = 0.05f;
  to.proposal_anneal_iterations = 0;  // Proposal weights unannealed, as the renderer uses them.
  to.opacity_reg = 0.01f;  // Entropy gradient comparable to the MSE one.
  // The grid decay has its own check (GridDecayMatchesFiniteDifferences); on
  // this random grid its loss would outweigh the small residual this check
  // needs for the float the loss is returned as.
  to.grid_decay = 0.0f;
  to.near_density_reg = near_reg;
  to.near_density_distance = near_distance;
  to.depth_weight = depth_weight;
  to.depth_sigma = 0.2f;
  // The interlevel loss reads the full field's weights as constants (stop
  // gradient, by design): a finite difference of the full field's parameters
  // would see it move, the gradient would not. Its own gradient is checked in
  // proposal_sampler_test.cc.
  to.interlevel_weight = 0.0f;
  Trainer trainer(&model, &sampler, to);
  ASSERT_EQ(model.occupancy().num_occupied(), model.occupancy().num_cells());
  if (view_colour) {  // Transforms away from the identity, so every term of their gradient matters.
    ASSERT_EQ(trainer.view_colours().size(), size_t(kPhotos * kViewColourParams));
    for (float& v : *trainer.mutable_view_colours()) v += 0.2f * (u(rng) - 0.5f);
  }

  // 16 rays out of 48 candidates: those whose transmittance never comes
  // within a factor e^0.05 of the termination threshold, so that no FD step
  // (which changes log T by ~1e-2) changes the samples kept.
  RayBatch batch;
  std::vector<float> jitter;
  int terminated = 0;
  {
    const RayBatch all = MakeBatch(48, 5);
    std::vector<float> all_jitter(all.size());
    for (float& j : all_jitter) j = u(rng);
    const std::vector<std::vector<double>> T = Transmittances(model, all, all_jitter);
    batch.Resize(16);
    int n = 0;
    for (int r = 0; r < all.size() && n < 16; ++r) {
      if (T[r].empty()) continue;
      bool safe = true;
      for (double t : T[r]) safe &= std::abs(std::log(t / kMinTransmittance)) > 0.05;
      if (!safe) continue;
      terminated += T[r].back() <= kMinTransmittance;
      std::copy_n(&all.origin[3 * r], 3, &batch.origin[3 * n]);
      std::copy_n(&all.dir[3 * r], 3, &batch.dir[3 * n]);
      batch.time_step[n] = all.time_step[r];
      batch.weight[n] = all.weight[r];
      jitter.push_back(all_jitter[r]);
      ++n;
    }
    ASSERT_EQ(n, 16);
    // Sparse depth on every other ray, inside the box (rays start 1.3 from
    // the centre and aim near it).
    if (depth_weight > 0) {
      for (int i = 0; i < n; i += 2) batch.depth[i] = 1.0f + 0.4f * u(rng);
    }
  }
  if (opaque) {
    EXPECT_GE(terminated, 12);
  } else if (!contracted) {  // Contracted rays cross the whole far shell; some terminate.
    EXPECT_EQ(terminated, 0);
  }

  // Targets a small residual (0.02..0.05 per channel) away from the
  // prediction: the loss, and so the rounding of the float it is returned
  // as, is then small compared with its gradient.
  for (int i = 0; i < batch.size(); ++i) {
    Eigen::Vector3f c = TrainerColour(&trainer, batch, jitter, i);
    for (int k = 0; k < 3; ++k) {
      ASSERT_GT(c[k], 0.0f);
      ASSERT_LT(c[k], 1.0f);
    }
    if (view_colour) {  // Rays of photos 0..2 and rays of none (-1).
      batch.view[i] = i % (kPhotos + 1) - 1;
      if (batch.view[i] >= 0) {
        const Eigen::Vector3f field = c;
        ApplyViewColour(&trainer.view_colours()[size_t(batch.view[i]) * kViewColourParams], field.data(), c.data());
      }
    }
    for (int k = 0; k < 3; ++k) {
      const float r = (0.02f + 0.03f * u(rng)) * (rng() % 2 ? 1.0f : -1.0f);
      batch.target[3 * i + k] = c[k] + r;
    }
  }

  Trainer::Gradients grads;
  const float base = trainer.ComputeLossAndGradients(batch, jitter, &grads);
  ASSERT_TRUE(std::isfinite(base));
  ASSERT_GT(base, 0.0f);
  ASSERT_LT(base, 0.01f);
  // The loss of the same batch by a trainer with `off`'s options (a term
  // switched off), on the same model.
  auto loss_with = [&](const TrainOptions& off) {
    NoSampler sampler2(sampler.NumPhotoViews());
    Trainer other(&model, &sampler2, off);
    *other.mutable_view_colours() = trainer.view_colours();
    Trainer::Gradients g0;
    return other.ComputeLossAndGradients(batch, jitter, &g0);
  };
  if (near_reg > 0) {  // The penalty contributes a sizeable part of the loss.
    TrainOptions off = to;
    off.near_density_reg = 0.0f;
    const float l0 = loss_with(off);
    EXPECT_GT(base - l0, 0.1f * base) << "penalty " << base - l0 << " of " << base;
  }
  if (depth_weight > 0) {  // So does the sparse-depth loss.
    TrainOptions off = to;
    off.depth_weight = 0.0f;
    const float l0 = loss_with(off);
    EXPECT_GT(base - l0, 0.1f * base) << "depth loss " << base - l0 << " of " << base;
  }
  const double ulp = double(std::nextafter(base, 1.0f)) - base;
  ASSERT_EQ(grads.grid.size(), p.grid.size());
  ASSERT_EQ(grads.mlp.size(), p.mlp.size());
  ASSERT_EQ(grads.emb.size(), p.emb.size());
  // The gradient call leaves no state behind: a second call gives the same.
  {
    Trainer::Gradients again;
    EXPECT_EQ(trainer.ComputeLossAndGradients(batch, jitter, &again), base);
    EXPECT_EQ(again.grid, grads.grid);
    EXPECT_EQ(again.mlp, grads.mlp);
    EXPECT_EQ(again.emb, grads.emb);
  }

  // Steps: most grid entries feed only a few samples (and the loss is linear
  // in them up to the MLP), so a larger h = 2e-3 keeps the float noise down;
  // MLP weights and embeddings feed every sample (~600 samples x 32 ReLUs)
  // and need h = 1e-3 to keep the number of kinks inside [x - h, x + h] low.
  const Block blocks[3] = {{"grid", &ModelParams::grid, &Trainer::Gradients::grid, 2e-3f},
                           {"mlp", &ModelParams::mlp, &Trainer::Gradients::mlp, 1e-3f},
                           {"emb", &ModelParams::emb, &Trainer::Gradients::emb, 1e-3f}};
  for (const Block& b : blocks) {
    SCOPED_TRACE(b.name);
    std::vector<float>& x = p.*(b.params);
    const std::vector<float>& g = grads.*(b.grads);
    double gmax = 0;
    for (float v : g) gmax = std::max(gmax, double(std::abs(v)));
    ASSERT_GT(gmax, 0.0);
    // Indices: 40 with a gradient of at least 5% of the block's largest (the
    // grid gradient is sparse) and 20 uniformly at random.
    std::vector<size_t> large, picks;
    for (size_t i = 0; i < g.size(); ++i) {
      if (std::abs(g[i]) >= 0.05 * gmax) large.push_back(i);
    }
    ASSERT_GT(large.size(), 10u);
    for (int k = 0; k < 40; ++k) picks.push_back(large[rng() % large.size()]);
    for (int k = 0; k < 20; ++k) picks.push_back(rng() % g.size());
    int skipped = 0;
    for (size_t i : picks) {
      const float x0 = x[i];
      Trainer::Gradients tmp;
      x[i] = x0 + b.h;
      const float hi = x[i];
      const double lp = trainer.ComputeLossAndGradients(batch, jitter, &tmp);
      x[i] = x0 - b.h;
      const float lo = x[i];
      const double lm = trainer.ComputeLossAndGradients(batch, jitter, &tmp);
      x[i] = x0;
      const double up = (lp - base) / (double(hi) - x0), down = (base - lm) / (double(x0) - lo);
      const double fd = (lp - lm) / (double(hi) - double(lo));
      // Noise: the loss is returned as a float (+-1/2 ulp per value) and the
      // per-ray colours and errors are float (~1 ulp of the total over 16
      // rays): ~4 ulp / (2h). On top of it 3% relative (second-order terms
      // and ReLU kinks of a few of the ~600 samples inside [x - h, x + h];
      // FD with h/2, h/4 converges to the analytic value) and 1e-3 of the
      // block's largest gradient. Over several seeds, errors stay below ~80%
      // of this tolerance.
      // Contracted rays composite ~3x more samples (the far shell), and the
      // float forward's rounding noise grows with them: measured FD quanta
      // of ~6 ulp of the loss (halving h doubles the scatter, so it is noise,
      // not a gradient error), hence 16 ulp there.
      const double noise_ulp = contracted ? 16 : 4;
      const double tol = noise_ulp * ulp / (double(hi) - double(lo)) + 3e-2 * std::abs(fd) + 1e-3 * gmax;
      if (std::abs(up - down) > 2 * tol) {
        ++skipped;  // A ReLU kink inside [x - h, x + h].
        continue;
      }
      EXPECT_NEAR(g[i], fd, tol) << b.name << "[" << i << "] one-sided " << up << " " << down;
    }
    EXPECT_LE(skipped, 6);
  }
  if (view_colour) {
    // Every transform parameter; the loss is quadratic in each, so FD is
    // exact up to the float noise.
    std::vector<float>& x = *trainer.mutable_view_colours();
    ASSERT_EQ(grads.view_colour.size(), x.size());
    double gmax = 0;
    for (float v : grads.view_colour) gmax = std::max(gmax, double(std::abs(v)));
    ASSERT_GT(gmax, 0.0);
    const float h = 1e-3f;
    for (size_t i = 0; i < x.size(); ++i) {
      const float x0 = x[i];
      Trainer::Gradients tmp;
      x[i] = x0 + h;
      const float hi = x[i];
      const double lp = trainer.ComputeLossAndGradients(batch, jitter, &tmp);
      x[i] = x0 - h;
      const float lo = x[i];
      const double lm = trainer.ComputeLossAndGradients(batch, jitter, &tmp);
      x[i] = x0;
      const double fd = (lp - lm) / (double(hi) - double(lo));
      const double tol = 4 * ulp / (double(hi) - double(lo)) + 1e-2 * std::abs(fd) + 1e-3 * gmax;
      EXPECT_NEAR(grads.view_colour[i], fd, tol) << "view_colour[" << i << "]";
    }
  }
}

TEST(TrainerGradientTest, LossGradientMatchesFiniteDifferences) { CheckLossGradient(/*opaque=*/false); }

TEST(TrainerGradientTest, LossGradientMatchesFiniteDifferencesWithEarlyTermination) {
  CheckLossGradient(/*opaque=*/true);
}

TEST(TrainerGradientTest, ContractedSceneWithDistortionLossMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/false, /*contracted=*/true);
}

TEST(TrainerGradientTest, ContractedSceneWithEarlyTerminationMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/true, /*contracted=*/true);
}

// Proposal sampling: the full field's gradient with the interlevel loss in
// the total (its own gradient reaches only the proposal fields, checked in
// proposal_sampler_test.cc).
TEST(TrainerGradientTest, ProposalSampledSceneMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/false, /*contracted=*/true, 0.0f, 0.2f, SamplerKind::kProposal);
}

TEST(TrainerGradientTest, ProposalSampledSceneWithEarlyTerminationMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/true, /*contracted=*/true, 0.0f, 0.2f, SamplerKind::kProposal);
}

// The occlusion penalty near the cameras (sigma * dt of samples within the
// given distance of the ray origin), on a bounded and a contracted scene.
TEST(TrainerGradientTest, NearDensityPenaltyMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/false, /*contracted=*/false, /*near_reg=*/0.002f, /*near_distance=*/2.0f);
}

TEST(TrainerGradientTest, ContractedSceneWithNearDensityPenaltyMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/false, /*contracted=*/true, /*near_reg=*/0.002f, /*near_distance=*/2.0f);
}

// Sparse-depth supervision on half the rays, marched and proposal-sampled.
TEST(TrainerGradientTest, SparseDepthLossMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/false, /*contracted=*/false, 0.0f, 0.2f, SamplerKind::kOccupancy, /*depth_weight=*/2e-3f);
}

TEST(TrainerGradientTest, ContractedSceneWithSparseDepthLossMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/false, /*contracted=*/true, 0.0f, 0.2f, SamplerKind::kOccupancy, /*depth_weight=*/2e-3f);
}

TEST(TrainerGradientTest, ProposalSampledSceneWithSparseDepthLossMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/false, /*contracted=*/true, 0.0f, 0.2f, SamplerKind::kProposal, /*depth_weight=*/2e-3f);
}

// Per-view colour transforms on three photos' rays (a quarter of the rays
// have none): the field's gradient through them, and theirs, prior included.
TEST(TrainerGradientTest, ViewColourTransformsMatchFiniteDifferences) {
  CheckLossGradient(/*opaque=*/false, /*contracted=*/false, 0.0f, 0.2f, SamplerKind::kOccupancy, 0.0f,
                    /*view_colour=*/true);
}

TEST(TrainerGradientTest, ContractedSceneWithViewColourTransformsMatchesFiniteDifferences) {
  CheckLossGradient(/*opaque=*/true, /*contracted=*/true, 0.0f, 0.2f, SamplerKind::kOccupancy, 0.0f,
                    /*view_colour=*/true);
}

// The field evaluator's two callers compute one function: the trainer's
// composited colour of a ray (read back through its loss) equals the
// renderer's, for bounded and contracted scenes.
// Zip-NeRF's normalised grid decay: the decay's share of the loss (the loss
// with it minus the loss without, same batch and model) against central
// differences, on entries of every level, and the same share of the
// gradient. The decay is quadratic, so a large step is exact up to the
// float the loss is returned as.
TEST(TrainerGradientTest, GridDecayMatchesFiniteDifferences) {
  SerialEigen serial;
  NgpModel model = TinyModel(3, 2, SceneKind::kBounded, SamplerKind::kOccupancy);
  ModelParams& p = model.mutable_params();
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (float& v : p.grid) v = u(rng) - 0.5f;
  NoSampler sampler(0);
  TrainOptions on;
  on.threads = 1;
  on.grid_decay = 0.1f;
  TrainOptions off = on;
  off.grid_decay = 0.0f;
  const RayBatch batch = MakeBatch(16, 5);
  std::vector<float> jitter(batch.size(), 0.5f);
  Trainer with(&model, &sampler, on), without(&model, &sampler, off);
  auto decay_loss = [&]() {
    Trainer::Gradients g;
    return double(with.ComputeLossAndGradients(batch, jitter, &g)) -
           double(without.ComputeLossAndGradients(batch, jitter, &g));
  };
  Trainer::Gradients g_on, g_off;
  const double l_on = with.ComputeLossAndGradients(batch, jitter, &g_on);
  const double l_off = without.ComputeLossAndGradients(batch, jitter, &g_off);
  // Its value: 0.1 x (1/12 per level, the mean square of U(-0.5, 0.5)).
  const HashGrid& grid = model.grid();
  EXPECT_NEAR(l_on - l_off, 0.1 * grid.num_levels() / 12.0, 0.1 * grid.num_levels() * 0.01);
  const double ulp = double(std::nextafter(float(l_on), 1.0f)) - l_on;
  const float h = 0.05f;
  int checked = 0;
  for (int l = 0; l < grid.num_levels(); ++l) {
    for (int k = 0; k < 4; ++k) {
      const size_t i = 2 * (grid.level_offset(l) + rng() % grid.level_size(l)) + rng() % 2;
      const float x0 = p.grid[i];
      p.grid[i] = x0 + h;
      const double lp = decay_loss();
      p.grid[i] = x0 - h;
      const double lm = decay_loss();
      p.grid[i] = x0;
      const double fd = (lp - lm) / (2.0 * h);
      const double analytic = double(g_on.grid[i]) - g_off.grid[i];
      EXPECT_NEAR(analytic, 2.0 * 0.1 * x0 / (2.0 * grid.level_size(l)), 1e-6 * std::abs(analytic) + 1e-12);
      EXPECT_NEAR(analytic, fd, 8 * ulp / (2.0 * h) + 1e-3 * std::abs(fd)) << "level " << l << " entry " << i;
      ++checked;
    }
  }
  EXPECT_GE(checked, 8);
  // Validation.
  TrainOptions bad;
  bad.grid_decay = -1.0f;
  EXPECT_FALSE(bad.Validate().ok());
  bad.grid_decay = NAN;
  EXPECT_FALSE(bad.Validate().ok());
}

TEST(FieldCallersTest, TrainerAndRendererAgreeOnEveryRay) {
  SerialEigen serial;
  for (const auto& [kind, sampler_kind] : {std::pair{SceneKind::kBounded, SamplerKind::kOccupancy},
                                          std::pair{SceneKind::kUnbounded, SamplerKind::kOccupancy},
                                          std::pair{SceneKind::kUnbounded, SamplerKind::kProposal}}) {
    SCOPED_TRACE(std::string(kind == SceneKind::kBounded ? "bounded " : "contracted ") +
                 SamplerKindName(sampler_kind));
    NgpModel model = TinyModel(5, 2, kind, sampler_kind);
    std::mt19937_64 rng(6);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (float& v : model.mutable_params().grid) v = u(rng) - 0.5f;
    NoSampler sampler;
    TrainOptions to;
    to.threads = 1;
    to.proposal_anneal_iterations = 0;
    Trainer trainer(&model, &sampler, to);
    const RayBatch batch = MakeBatch(12, 7);
    const std::vector<float> jitter(batch.size(), 0.0f);  // The renderer starts at t0.
    RenderOptions ro;
    ro.min_weight = 0.0f;  // Colour every sample, as training does.
    ro.min_transmittance = kMinTransmittance;  // And stop where training does.
    ro.bf16_mlp = false;                       // With float MLPs, as training runs them.
    ro.threads = 1;
    for (int i = 0; i < batch.size(); ++i) {
      float rgb[3];
      RenderRays(model, &batch.origin[3 * i], &batch.dir[3 * i], 1, batch.time_step[i], ro, rgb, nullptr, nullptr);
      const Eigen::Vector3f c = TrainerColour(&trainer, batch, jitter, i);
      for (int k = 0; k < 3; ++k) EXPECT_NEAR(c[k], rgb[k], 2e-4f) << "ray " << i << " channel " << k;
    }
  }
}

// A 16x16 view of the box from z = -1.3 (OpenCV: looking along +z); half
// field of view atan(8 / 16) = 26.6 degrees covers the whole box.
View MakeView(bool gradient_image) {
  View v;
  v.name = "front";
  v.camera.intrinsics.width = v.camera.intrinsics.height = 16;
  v.camera.intrinsics.fx = v.camera.intrinsics.fy = 16.0f;
  v.camera.intrinsics.cx = v.camera.intrinsics.cy = 8.0f;
  v.camera.c2w = Pose::Identity();
  v.camera.c2w.col(3) = Eigen::Vector3f(0.0f, 0.0f, -1.3f);
  v.image = Image(16, 16, 0.5f);
  if (gradient_image) {
    for (int y = 0; y < 16; ++y) {
      for (int x = 0; x < 16; ++x) {
        float* px = v.image.pixel(x, y);
        px[0] = x / 15.0f;
        px[1] = y / 15.0f;
        px[2] = 0.3f;
      }
    }
  }
  return v;
}

TrainOptions StepOptions(int threads) {
  TrainOptions to;
  to.iterations = 5;
  to.batch_rays = 512;  // 4 blocks of 128 rays: both threads march rays.
  to.max_batch_rays = 512;
  to.target_samples = 0;  // Fixed batch size.
  to.seed = 11;
  to.threads = threads;
  return to;
}

bool SameBits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

// Coarse to fine on a 4-level grid, 8 steps over all of training: after 4
// real steps levels 0-1 are on, level 2 is half on (BARF's cosine at 0.5)
// and level 3 is off. The gradient there matches central differences on
// every level, and level 3 neither moves the loss nor gets a gradient.
TEST(TrainerGradientTest, CoarseToFineLevelsMatchFiniteDifferences) {
  SerialEigen serial;
  NgpModel model = TinyModel(3, /*time_steps=*/1);
  ModelParams& p = model.mutable_params();
  std::mt19937_64 rng(12);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (float& v : p.grid) v = u(rng) - 0.5f;
  const View view = MakeView(/*gradient_image=*/true);
  auto sampler = ImageRaySampler::Create({&view}, model);
  ASSERT_TRUE(sampler.ok()) << sampler.status();
  TrainOptions to = StepOptions(1);
  to.iterations = 8;
  to.coarse_to_fine = 1.0f;
  to.opacity_reg = 0.0f;
  Trainer trainer(&model, sampler->get(), to);
  const HashGrid& grid = model.grid();
  ASSERT_EQ(grid.num_levels(), 4);
  const std::vector<float> level3_before(p.grid.begin() + 2 * grid.level_offset(3),
                                         p.grid.begin() + 2 * (grid.level_offset(3) + grid.level_size(3)));
  for (int k = 0; k < 4; ++k) ASSERT_TRUE(trainer.Step().ok());
  // Four steps of training never touched the level that was off throughout.
  EXPECT_TRUE(std::equal(level3_before.begin(), level3_before.end(), p.grid.begin() + 2 * grid.level_offset(3)));

  RayBatch batch = MakeBatch(16, 5);
  const std::vector<float> jitter(batch.size(), 0.5f);
  for (int i = 0; i < batch.size(); ++i) {  // Targets a small residual away from the prediction.
    const Eigen::Vector3f c = TrainerColour(&trainer, batch, jitter, i);
    for (int k = 0; k < 3; ++k) batch.target[3 * i + k] = c[k] + (0.02f + 0.03f * u(rng)) * (rng() % 2 ? 1 : -1);
  }
  Trainer::Gradients g;
  const float base = trainer.ComputeLossAndGradients(batch, jitter, &g);
  ASSERT_EQ(trainer.level_weights().size(), 4u);
  EXPECT_FLOAT_EQ(trainer.level_weights()[0], 1.0f);
  EXPECT_FLOAT_EQ(trainer.level_weights()[1], 1.0f);
  EXPECT_NEAR(trainer.level_weights()[2], 0.5f, 1e-6f);
  EXPECT_EQ(trainer.level_weights()[3], 0.0f);
  const double ulp = double(std::nextafter(base, 1.0f)) - base;
  double gmax = 0;
  for (float v : g.grid) gmax = std::max(gmax, double(std::abs(v)));
  ASSERT_GT(gmax, 0.0);
  const float h = 2e-3f;
  for (int l = 0; l < 4; ++l) {
    SCOPED_TRACE(l);
    const size_t begin = 2 * grid.level_offset(l), end = 2 * (grid.level_offset(l) + grid.level_size(l));
    std::vector<size_t> picks;  // The level's 12 largest gradients and 4 at random.
    for (size_t i = begin; i < end; ++i) picks.push_back(i);
    std::partial_sort(picks.begin(), picks.begin() + 12, picks.end(),
                      [&](size_t a, size_t b) { return std::abs(g.grid[a]) > std::abs(g.grid[b]); });
    picks.resize(12);
    for (int k = 0; k < 4; ++k) picks.push_back(begin + rng() % (end - begin));
    if (l == 3) {
      for (size_t i = begin; i < end; ++i) ASSERT_EQ(g.grid[i], 0.0f) << i;
    } else {
      EXPECT_GT(std::abs(g.grid[picks[0]]), 0.05 * gmax);
    }
    int skipped = 0;
    for (size_t i : picks) {
      const float x0 = p.grid[i];
      Trainer::Gradients tmp;
      p.grid[i] = x0 + h;
      const float hi = p.grid[i];
      const double lp = trainer.ComputeLossAndGradients(batch, jitter, &tmp);
      p.grid[i] = x0 - h;
      const float lo = p.grid[i];
      const double lm = trainer.ComputeLossAndGradients(batch, jitter, &tmp);
      p.grid[i] = x0;
      if (l == 3) {  // Off: the loss does not see the level at all.
        EXPECT_EQ(lp, double(base));
        EXPECT_EQ(lm, double(base));
        continue;
      }
      const double up = (lp - base) / (double(hi) - x0), down = (base - lm) / (double(x0) - lo);
      const double fd = (lp - lm) / (double(hi) - double(lo));
      const double tol = 4 * ulp / (double(hi) - double(lo)) + 3e-2 * std::abs(fd) + 1e-3 * gmax;
      if (std::abs(up - down) > 2 * tol) {
        ++skipped;  // A ReLU kink inside [x - h, x + h].
        continue;
      }
      EXPECT_NEAR(g.grid[i], fd, tol) << "grid[" << i << "] one-sided " << up << " " << down;
    }
    EXPECT_LE(skipped, 3);
  }
  // Past the annealing every level is on; and the option is validated.
  for (int k = 0; k < 4; ++k) ASSERT_TRUE(trainer.Step().ok());
  trainer.ComputeLossAndGradients(batch, jitter, &g);
  EXPECT_TRUE(trainer.level_weights().empty());
  TrainOptions bad;
  for (float v : {-0.1f, 1.5f, float(NAN)}) {
    bad.coarse_to_fine = v;
    EXPECT_FALSE(bad.Validate().ok()) << v;
  }
}

// TrainOptions::distortion_warmup: the distortion weight rises from 0 at
// the first step to its value at the warm-up's end (auto weights resolved
// as without it), and the trainer uses it: at step 0 an unbounded scene's
// loss with a warm-up is its loss without the distortion term, and with the
// full weight it is not.
TEST(TrainerStepTest, DistortionWarmupRaisesTheWeightFromZero) {
  TrainOptions to;
  to.iterations = 100;
  to.distortion_reg = 0.04f;
  to.distortion_warmup = 0.5f;
  EXPECT_EQ(to.DistortionWeightAt(0, true), 0.0f);
  EXPECT_FLOAT_EQ(to.DistortionWeightAt(25, true), 0.02f);
  EXPECT_FLOAT_EQ(to.DistortionWeightAt(50, true), 0.04f);
  EXPECT_FLOAT_EQ(to.DistortionWeightAt(90, false), 0.04f);  // Explicit: objects too.
  to.distortion_reg = -1.0f;                                    // Auto.
  EXPECT_FLOAT_EQ(to.DistortionWeightAt(25, true), 0.5f * TrainOptions::kAutoDistortion);
  EXPECT_EQ(to.DistortionWeightAt(25, false), 0.0f);
  to.distortion_warmup = 0.0f;
  EXPECT_FLOAT_EQ(to.DistortionWeightAt(0, true), TrainOptions::kAutoDistortion);
  for (float bad : {-0.1f, float(NAN), float(INFINITY)}) {
    to.distortion_warmup = bad;
    EXPECT_FALSE(to.Validate().ok()) << bad;
  }

  SerialEigen serial;
  const NgpModel start = TinyModel(3, 2, SceneKind::kUnbounded);
  const RayBatch batch = MakeBatch(16, 5);
  const std::vector<float> jitter(batch.size(), 0.5f);
  auto loss_at_step0 = [&](float distortion, float warmup) {
    NgpModel model = start;
    NoSampler sampler(0);
    TrainOptions o;
    o.threads = 1;
    o.distortion_reg = distortion;
    o.distortion_warmup = warmup;
    Trainer trainer(&model, &sampler, o);
    Trainer::Gradients g;
    return trainer.ComputeLossAndGradients(batch, jitter, &g);
  };
  const float none = loss_at_step0(0.0f, 0.0f);
  EXPECT_EQ(loss_at_step0(0.3f, 0.5f), none);
  EXPECT_GT(std::abs(loss_at_step0(0.3f, 0.0f) - none), 1e-4f * std::abs(none));
}

TEST(TrainerStepTest, NanWeightStopsAtStepOneWithoutTouchingParameters) {
  SerialEigen serial;
  NgpModel model = TinyModel(5, /*time_steps=*/1);
  const View view = MakeView(/*gradient_image=*/false);
  auto sampler = ImageRaySampler::Create({&view}, model);
  ASSERT_TRUE(sampler.ok()) << sampler.status();
  Trainer trainer(&model, sampler->get(), StepOptions(1));
  // One weight of the colour MLP's hidden layer becomes NaN.
  const Network::Layer& layer = model.network().colour_layers()[1];
  model.mutable_params().mlp[layer.offset + 5] = NAN;
  const ModelParams before = model.params();

  const absl::Status s = trainer.Step();
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.code(), absl::StatusCode::kInternal);
  EXPECT_NE(s.message().find("diverged at step 1"), std::string::npos) << s.message();
  EXPECT_EQ(trainer.step(), 0);
  // Nothing was applied: bit-identical parameters (the NaN stays where it
  // was, no other value became NaN).
  EXPECT_TRUE(SameBits(model.params().grid, before.grid));
  EXPECT_TRUE(SameBits(model.params().mlp, before.mlp));
  EXPECT_TRUE(SameBits(model.params().emb, before.emb));
  int nans = 0;
  for (float v : model.params().mlp) nans += std::isnan(v);
  EXPECT_EQ(nans, 1);
  for (float v : model.params().grid) ASSERT_TRUE(std::isfinite(v));
  // Retrying fails again at the same step.
  const absl::Status again = trainer.Step();
  EXPECT_EQ(again.code(), absl::StatusCode::kInternal);
  EXPECT_NE(again.message().find("diverged at step 1"), std::string::npos) << again.message();
  EXPECT_TRUE(SameBits(model.params().mlp, before.mlp));

  // Control: with the weight restored the same step succeeds and changes
  // the parameters.
  model.mutable_params().mlp[layer.offset + 5] = 0.1f;
  const std::vector<float> mlp_before = model.params().mlp;
  ASSERT_TRUE(trainer.Step().ok());
  EXPECT_EQ(trainer.step(), 1);
  EXPECT_FALSE(SameBits(model.params().mlp, mlp_before));
  EXPECT_TRUE(model.AllFinite());
}

// A NaN injected into one gradient mid-run (finite parameters) is a bad
// batch: it is skipped, nothing of it is applied, and training goes on. With
// no tolerance (max_bad_batches = 0) the same step fails and leaves the
// parameters of the step before bit-identical; a NaN in every batch fails
// once the tolerance is spent.
TEST(TrainerStepTest, TransientNanGradientIsSkippedPersistentOneFails) {
  SerialEigen serial;
  const View view = MakeView(/*gradient_image=*/true);
  {
    NgpModel model = TinyModel(5, /*time_steps=*/1);
    auto sampler = ImageRaySampler::Create({&view}, model);
    ASSERT_TRUE(sampler.ok()) << sampler.status();
    TrainOptions to = StepOptions(1);
    to.inject_nan_gradient_at_step = 3;
    Trainer trainer(&model, sampler->get(), to);
    ASSERT_TRUE(trainer.Step().ok());
    ASSERT_TRUE(trainer.Step().ok());
    const ModelParams before = model.params();
    ASSERT_TRUE(trainer.Step().ok());  // The poisoned batch: skipped.
    EXPECT_EQ(trainer.step(), 3);
    EXPECT_EQ(trainer.skipped_batches(), 1);
    EXPECT_TRUE(SameBits(model.params().grid, before.grid));
    EXPECT_TRUE(SameBits(model.params().mlp, before.mlp));
    EXPECT_TRUE(SameBits(model.params().emb, before.emb));
    ASSERT_TRUE(trainer.Step().ok());  // The next batch trains again.
    EXPECT_FALSE(SameBits(model.params().mlp, before.mlp));
    EXPECT_TRUE(model.AllFinite());
  }
  {
    NgpModel model = TinyModel(5, /*time_steps=*/1);
    auto sampler = ImageRaySampler::Create({&view}, model);
    ASSERT_TRUE(sampler.ok()) << sampler.status();
    TrainOptions to = StepOptions(1);
    to.inject_nan_gradient_at_step = 2;
    to.max_bad_batches = 0;
    Trainer trainer(&model, sampler->get(), to);
    ASSERT_TRUE(trainer.Step().ok());
    const ModelParams before = model.params();
    const absl::Status s = trainer.Step();
    EXPECT_EQ(s.code(), absl::StatusCode::kInternal);
    EXPECT_NE(s.message().find("diverged at step 2"), std::string::npos) << s.message();
    EXPECT_TRUE(SameBits(model.params().grid, before.grid));
    EXPECT_TRUE(SameBits(model.params().mlp, before.mlp));
  }
  {
    // Every batch bad (an infinite loss from a huge learning rate's
    // overflow is not needed: a NaN pixel target does it).
    View nan_view = view;
    for (float& x : nan_view.image.rgb) x = NAN;
    NgpModel model = TinyModel(5, /*time_steps=*/1);
    auto sampler = ImageRaySampler::Create({&nan_view}, model);
    ASSERT_TRUE(sampler.ok()) << sampler.status();
    TrainOptions to = StepOptions(1);
    to.max_bad_batches = 2;
    Trainer trainer(&model, sampler->get(), to);
    const ModelParams before = model.params();
    EXPECT_TRUE(trainer.Step().ok());
    EXPECT_TRUE(trainer.Step().ok());
    const absl::Status s = trainer.Step();
    EXPECT_EQ(s.code(), absl::StatusCode::kInternal);
    EXPECT_NE(s.message().find("diverged at step 3"), std::string::npos) << s.message();
    EXPECT_EQ(trainer.skipped_batches(), 2);
    EXPECT_TRUE(SameBits(model.params().grid, before.grid));
    EXPECT_TRUE(SameBits(model.params().mlp, before.mlp));
  }
}

TEST(TrainerStepTest, FixedSeedTwoThreadsIsBitIdentical) {
  const View view = MakeView(/*gradient_image=*/true);
  auto run = [&view]() {
    NgpModel model = TinyModel(9, /*time_steps=*/1);
    auto sampler = ImageRaySampler::Create({&view}, model);
    EXPECT_TRUE(sampler.ok()) << sampler.status();
    Trainer trainer(&model, sampler->get(), StepOptions(2));
    std::vector<float> losses;
    EXPECT_TRUE(trainer.Run([&losses](const StepStats& st) { losses.push_back(st.loss); }).ok());
    EXPECT_EQ(trainer.step(), 5);
    return std::make_pair(model, losses);
  };
  const auto [a, la] = run();
  const auto [b, lb] = run();
  const NgpModel fresh = TinyModel(9, 1);
  EXPECT_FALSE(SameBits(a.params().mlp, fresh.params().mlp));  // Training did something.
  EXPECT_FALSE(SameBits(a.params().grid, fresh.params().grid));
  EXPECT_TRUE(SameBits(a.params().grid, b.params().grid));
  EXPECT_TRUE(SameBits(a.params().mlp, b.params().mlp));
  EXPECT_TRUE(SameBits(a.params().emb, b.params().emb));
  EXPECT_TRUE(SameBits(a.occupancy().density(), b.occupancy().density()));
  EXPECT_EQ(la, lb);
  ASSERT_EQ(la.size(), 5u);
}

// The OpenMP runtime may grant fewer threads than a trainer asks for (here:
// a nested region with nesting off, as under OMP_THREAD_LIMIT). Training must
// then equal a one-thread run bit for bit, not read stale per-thread scratch
// (which crashed before the fix, found by the TSan run of the server tests).
TEST(TrainerStepTest, FewerThreadsThanRequestedEqualsOneThread) {
  const View view = MakeView(/*gradient_image=*/true);
  auto run = [&view](int requested) {
    NgpModel model = TinyModel(9, /*time_steps=*/1);
    std::vector<float> losses;
    const int saved = omp_get_max_active_levels();
    omp_set_max_active_levels(1);
#pragma omp parallel num_threads(2)
    {
      // Only the first thread trains; inside this active region every
      // nested region gets one thread.
      if (omp_get_thread_num() == 0) {
        auto sampler = ImageRaySampler::Create({&view}, model);
        EXPECT_TRUE(sampler.ok()) << sampler.status();
        Trainer trainer(&model, sampler->get(), StepOptions(requested));
        EXPECT_TRUE(trainer.Run([&losses](const StepStats& st) { losses.push_back(st.loss); }).ok());
      }
    }
    omp_set_max_active_levels(saved);
    return std::make_pair(model, losses);
  };
  const auto [one, l1] = run(1);
  const auto [two, l2] = run(2);
  ASSERT_EQ(l1.size(), 5u);
  EXPECT_EQ(l1, l2);
  EXPECT_TRUE(SameBits(one.params().grid, two.params().grid));
  EXPECT_TRUE(SameBits(one.params().mlp, two.params().mlp));
  EXPECT_TRUE(SameBits(one.params().emb, two.params().emb));
}

// Adam resumed from another instance's moments takes the same step as the
// instance that kept going (same code path: bit for bit).
TEST(TrainerResumeTest, AdamWithSetMomentsContinuesExactly) {
  std::mt19937 rng(5);
  std::normal_distribution<float> n(0.0f, 1.0f);
  std::vector<float> p(257), g(257);
  for (float& x : p) x = n(rng);
  Adam a;
  a.ResizeBlock(1, p.size());
  for (int step = 1; step <= 3; ++step) {
    for (float& x : g) x = n(rng);
    a.UpdateDense(1, 1e-2f, step, p.data(), g.data(), p.size());
  }
  Adam b;
  b.ResizeBlock(1, p.size());
  b.SetMoments(1, a.m(1), a.v(1));
  for (float& x : g) x = n(rng);
  std::vector<float> pa = p, pb = p;
  a.UpdateDense(1, 1e-2f, 4, pa.data(), g.data(), p.size());
  b.UpdateDense(1, 1e-2f, 4, pb.data(), g.data(), p.size());
  EXPECT_TRUE(SameBits(pa, pb));
  EXPECT_TRUE(SameBits(a.m(1), b.m(1)));
  EXPECT_TRUE(SameBits(a.v(1), b.v(1)));
}

// A trainer resumed from an exported state counts on from its steps, keeps
// its moments (a new time step's embedding row starts at zero) and trains
// differently from a fresh optimiser on the same model.
TEST(TrainerResumeTest, ResumedTrainerCarriesStepsAndMoments) {
  const View view = MakeView(/*gradient_image=*/true);
  NgpModel model = TinyModel(9, /*time_steps=*/1);
  auto sampler = ImageRaySampler::Create({&view}, model);
  ASSERT_TRUE(sampler.ok()) << sampler.status();
  OptimizerState first;
  {
    Trainer t(&model, sampler->get(), StepOptions(2));
    ASSERT_TRUE(t.Run(nullptr).ok());
    first = t.ExportOptimizerState();
  }
  EXPECT_EQ(first.step, 5u);
  ASSERT_TRUE(first.CompatibleWith(model.params()).ok());
  EXPECT_EQ(first.m[0].size(), model.params().grid.size());
  bool any = false;
  for (float x : first.v[1]) any = any || x > 0;
  EXPECT_TRUE(any);
  model.AddTimeStep(3);  // The next scan's row.
  const NgpModel start = model;
  TrainOptions to = StepOptions(2);
  to.resume = &first;
  NgpModel resumed = start, fresh = start;
  auto s2 = ImageRaySampler::Create({&view}, resumed);
  ASSERT_TRUE(s2.ok());
  Trainer t(&resumed, s2->get(), to);
  ASSERT_TRUE(t.Run(nullptr).ok());
  const OptimizerState second = t.ExportOptimizerState();
  EXPECT_EQ(second.step, 10u);
  ASSERT_EQ(second.m[2].size(), resumed.params().emb.size());
  Trainer f(&fresh, s2->get(), StepOptions(2));
  ASSERT_TRUE(f.Run(nullptr).ok());
  EXPECT_EQ(f.ExportOptimizerState().step, 5u);
  EXPECT_FALSE(SameBits(resumed.params().mlp, fresh.params().mlp));
  // An incompatible state (another model's) is ignored: a fresh optimiser.
  OptimizerState wrong = first;
  wrong.m[1].pop_back();
  wrong.v[1].pop_back();
  to.resume = &wrong;
  NgpModel w = start;
  Trainer tw(&w, s2->get(), to);
  EXPECT_EQ(tw.ExportOptimizerState().step, 0u);
}

// The schedules: a cosine per run; inverse-sqrt over the optimiser's steps
// (resumed ones included), which needs no horizon; and a cosine under it.
TEST(TrainerResumeTest, LearningRateSchedules) {
  NgpModel model = TinyModel(9, 1);
  NoSampler none;
  OptimizerState prior;
  prior.step = 300;
  for (int b = 0; b < OptimizerState::kBlocks; ++b) {
    const std::vector<float>* blocks[] = {&model.params().grid, &model.params().mlp, &model.params().emb,
                                          &model.params().proposal};
    prior.m[b].assign(blocks[b]->size(), 0.0f);
    prior.v[b].assign(blocks[b]->size(), 0.0f);
  }
  TrainOptions to;
  to.iterations = 100;
  to.learning_rate = 1e-2f;
  to.resume = &prior;
  to.lr_schedule = LrSchedule::kCosine;
  EXPECT_FLOAT_EQ(Trainer(&model, &none, to).CurrentLearningRate(), 1e-2f);
  to.lr_schedule = LrSchedule::kInverseSqrt;  // tau = 100: sqrt(100 / 400).
  EXPECT_FLOAT_EQ(Trainer(&model, &none, to).CurrentLearningRate(), 5e-3f);
  to.lr_timescale = 300;  // sqrt(300 / 600).
  EXPECT_FLOAT_EQ(Trainer(&model, &none, to).CurrentLearningRate(), 1e-2f * std::sqrt(0.5f));
  to.lr_timescale = 0;
  to.lr_schedule = LrSchedule::kInverseSqrtCosine;
  EXPECT_FLOAT_EQ(Trainer(&model, &none, to).CurrentLearningRate(), 5e-3f);
  to.resume = nullptr;
  EXPECT_FLOAT_EQ(Trainer(&model, &none, to).CurrentLearningRate(), 1e-2f);
  EXPECT_TRUE(ParseLrSchedule("inverse-sqrt").ok());
  EXPECT_EQ(ParseLrSchedule("linear").status().code(), absl::StatusCode::kInvalidArgument);
}

// The gradients of the loss with respect to each ray's origin and direction
// (ComputeLossAndGradients(..., ray_gradients = true); the camera refiner's
// input) against central differences: the origin moved along each axis, the
// direction turned about each axis (d' = Exp(h e_k) d, so the check is on
// d x dL/dd, what the refiner uses). Rays start inside the model's box, so
// the marcher's first sample sits at `near` whatever the origin and the
// samples' t do not move with it (the gradient holds t fixed, by design);
// bounded steps depend on t only. The directional path through the colour's
// SH encoding is switched on by random colour weights. Single-ray batches:
// each ray's loss alone.
TEST(TrainerGradientTest, RayOriginAndDirectionGradientsMatchFiniteDifferences) {
  SerialEigen serial;
  // A coarse grid (cells of 1/8 of the box at the finest level): trilinear
  // interpolation has a kink at every cell face, and a sample that crosses
  // one inside [x - h, x + h] breaks the difference quotient; with ~40
  // samples per ray over 4 levels up to 32 cells and h = 1e-3, most steps
  // crossed one.
  ModelOptions mo = TinyOptions();
  mo.grid.base_resolution = 2;
  mo.grid.finest_resolution = 8;
  mo.march.steps_per_diagonal = 24;  // ~14 samples per ray: fewer faces to cross.
  absl::StatusOr<NgpModel> created =
      NgpModel::Create(mo, Normalization(), SceneKind::kBounded, Eigen::Vector3f(0.3f, 0.6f, 0.9f), 2, 5);
  ASSERT_TRUE(created.ok()) << created.status();
  NgpModel model = *std::move(created);
  ModelParams& p = model.mutable_params();
  std::mt19937_64 rng(23);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::normal_distribution<float> g(0.0f, 1.0f);
  for (float& v : p.grid) v = u(rng) - 0.5f;
  NoSampler sampler(0);
  TrainOptions to;
  to.threads = 1;
  to.opacity_reg = 0.01f;
  Trainer trainer(&model, &sampler, to);
  ASSERT_EQ(model.occupancy().num_occupied(), model.occupancy().num_cells());
  auto one_ray = [&](const Eigen::Vector3f& o, const Eigen::Vector3f& d, const float* target, int step) {
    RayBatch b;
    b.Resize(1);
    for (int k = 0; k < 3; ++k) {
      b.origin[k] = o[k];
      b.dir[k] = d[k];
      b.target[k] = target[k];
    }
    b.time_step[0] = step;
    b.weight[0] = 1.0f;
    return b;
  };
  int checked = 0, skipped = 0;
  for (int r = 0; r < 12; ++r) {
    const Eigen::Vector3f o = 0.25f * Eigen::Vector3f(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f) * 2.0f;
    const Eigen::Vector3f d = Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const std::vector<float> jitter = {u(rng)};
    float zero[3] = {0, 0, 0};
    RayBatch b = one_ray(o, d, zero, r % 2);
    const Eigen::Vector3f c = TrainerColour(&trainer, b, jitter, 0);
    float target[3];
    for (int k = 0; k < 3; ++k) target[k] = c[k] + (0.05f + 0.05f * u(rng)) * (rng() % 2 ? 1.0f : -1.0f);
    b = one_ray(o, d, target, r % 2);
    Trainer::Gradients grads;
    const float base = trainer.ComputeLossAndGradients(b, jitter, &grads, /*ray_gradients=*/true);
    ASSERT_EQ(grads.ray_origin.size(), 3u);
    ASSERT_EQ(grads.ray_dir.size(), 3u);
    const Eigen::Vector3f go(grads.ray_origin.data()), gd(grads.ray_dir.data());
    const Eigen::Vector3f grot = d.cross(gd);
    ASSERT_GT(go.norm(), 0.0f);
    ASSERT_GT(grot.norm(), 0.0f);
    const double ulp = double(std::nextafter(base, 1.0f)) - base;
    const float h = 5e-4f;
    for (int k = 0; k < 6; ++k) {
      auto loss_at = [&](float s) {
        Eigen::Vector3f o2 = o, d2 = d;
        if (k < 3) {
          o2[k] += s;
        } else {
          d2 = Eigen::AngleAxisf(s, Eigen::Vector3f::Unit(k - 3)) * d;
        }
        Trainer::Gradients tmp;
        return double(trainer.ComputeLossAndGradients(one_ray(o2, d2, target, r % 2), jitter, &tmp));
      };
      const double lp = loss_at(h), lm = loss_at(-h);
      const double up = (lp - base) / h, down = (base - lm) / h, fd = (lp - lm) / (2.0 * h);
      const double analytic = k < 3 ? go[k] : grot[k - 3];
      const double scale = k < 3 ? go.norm() : grot.norm();
      // Float noise of the loss (~4 ulp / 2h), 3% for second-order terms,
      // 1% of the ray's gradient norm. Over seeds 21-28 of this test, seven
      // pass whole (3-12 of 72 components skipped as kinks); the eighth
      // misses on one small component by 1e-5 (1.6 x its tolerance).
      const double tol = 4 * ulp / (2.0 * h) + 3e-2 * std::abs(fd) + 1e-2 * scale;
      // A kink inside [x - h, x + h] puts the central difference about
      // |up - down| / 2 off: compared only where that is at most tol / 2.
      if (std::abs(up - down) > tol) {
        ++skipped;  // A sample crossed a grid cell (a trilinear kink) or the box's exit.
        continue;
      }
      EXPECT_NEAR(analytic, fd, tol) << "ray " << r << (k < 3 ? " origin " : " turn ") << k % 3;
      ++checked;
    }
  }
  EXPECT_GE(checked, 54);
  std::printf("checked %d skipped %d\n", checked, skipped);
  EXPECT_LE(skipped, 18);
  // Without the flag, no ray gradients are computed.
  Trainer::Gradients none;
  trainer.ComputeLossAndGradients(MakeBatch(4, 3), std::vector<float>(4, 0.5f), &none);
  EXPECT_TRUE(none.ray_origin.empty());
}

}  // namespace
}  // namespace clnerf
