// Whole-pipeline tests of the trainer: the loss gradient of one batch
// (march -> encode -> MLPs -> compositing with early termination -> MSE +
// opacity entropy) against central differences of the loss, NaN handling in
// Step(), and run-to-run determinism.
#include "core/trainer.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <random>
#include <vector>

#include "Eigen/Dense"
#include "core/ray_sampler.h"
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
  return o;
}

NgpModel TinyModel(uint64_t seed, int time_steps = 2) {
  auto m = NgpModel::Create(TinyOptions(), Normalization{}, SceneKind::kBounded,
                            Eigen::Vector3f(0.3f, 0.6f, 0.9f), time_steps, seed);
  EXPECT_TRUE(m.ok()) << m.status();
  return *std::move(m);
}

// A sampler that never samples and has no cameras, so the trainer leaves the
// occupancy grid fully occupied (ComputeLossAndGradients takes its batch
// directly).
class NoSampler : public RaySampler {
 public:
  void Sample(int, std::mt19937_64*, RayBatch*) override { ADD_FAILURE() << "not used"; }
  std::vector<Camera> Cameras() const override { return {}; }
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

struct Block {
  const char* name;
  std::vector<float> ModelParams::*params;
  std::vector<float> Trainer::Gradients::*grads;
  float h;  // FD step.
};

TEST(TrainerGradientTest, LossGradientMatchesFiniteDifferences) {
  NgpModel model = TinyModel(3);
  // Grid values of O(0.1) instead of 1e-4, so that the grid features (and
  // the MLP weights that read them) matter.
  {
    std::mt19937_64 rng(4);
    std::uniform_real_distribution<float> u(-0.5f, 0.5f);
    for (float& v : model.mutable_params().grid) v = u(rng);
  }
  NoSampler sampler;
  TrainOptions to;
  to.threads = 1;
  to.opacity_reg = 0.01f;  // Entropy gradient comparable to the MSE one.
  Trainer trainer(&model, &sampler, to);
  ASSERT_EQ(model.occupancy().num_occupied(), model.occupancy().num_cells());

  RayBatch batch = MakeBatch(16, 5);
  std::vector<float> jitter(batch.size());
  std::mt19937_64 rng(6);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (float& j : jitter) j = u(rng);
  // Targets a small residual (0.02..0.05 per channel) away from the
  // prediction: the loss, and so the rounding of the float it is returned
  // as, is then small compared with its gradient.
  for (int i = 0; i < batch.size(); ++i) {
    const Eigen::Vector3f c = TrainerColour(&trainer, batch, jitter, i);
    for (int k = 0; k < 3; ++k) {
      ASSERT_GT(c[k], 0.0f);
      ASSERT_LT(c[k], 1.0f);
      const float r = (0.02f + 0.03f * u(rng)) * (rng() % 2 ? 1.0f : -1.0f);
      batch.target[3 * i + k] = c[k] + r;
    }
  }

  Trainer::Gradients grads;
  const float base = trainer.ComputeLossAndGradients(batch, jitter, &grads);
  ASSERT_TRUE(std::isfinite(base));
  ASSERT_GT(base, 0.0f);
  ASSERT_LT(base, 0.01f);
  const double ulp = double(std::nextafter(base, 1.0f)) - base;
  ModelParams& p = model.mutable_params();
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

  // Steps: the loss is linear in a grid entry up to the MLP, and an entry
  // feeds only a few samples, so h = 1e-2 rarely meets a ReLU kink. MLP
  // weights and embeddings feed every sample (~600 samples x 32 ReLUs), so
  // they need h = 1e-3 to keep the chance of straddling kinks low.
  const Block blocks[3] = {{"grid", &ModelParams::grid, &Trainer::Gradients::grid, DBG_HG},
                           {"mlp", &ModelParams::mlp, &Trainer::Gradients::mlp, DBG_H},
                           {"emb", &ModelParams::emb, &Trainer::Gradients::emb, DBG_H}};
  for (const Block& b : blocks) {
    SCOPED_TRACE(b.name);
    std::vector<float>& x = p.*(b.params);
    const std::vector<float>& g = grads.*(b.grads);
    double gmax = 0;
    for (float v : g) gmax = std::max(gmax, double(std::abs(v)));
    ASSERT_GT(gmax, 0.0);
    // Indices: 40 with a gradient of at least 1% of the block's largest (the
    // grid gradient is sparse) and 20 uniformly at random.
    std::vector<size_t> large, picks;
    for (size_t i = 0; i < g.size(); ++i) {
      if (std::abs(g[i]) >= 0.01 * gmax) large.push_back(i);
    }
    ASSERT_GT(large.size(), 10u);
    for (int k = 0; k < 40; ++k) picks.push_back(large[rng() % large.size()]);
    for (int k = 0; k < 20; ++k) picks.push_back(rng() % g.size());
    int skipped = 0, checked = 0;
    double worst = 0;
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
      // The loss is returned as a float: each value is off by <= 1/2 ulp
      // (plus the float arithmetic inside), hence 2 ulp / (2h) of noise.
      // On top of it 2% relative (second-order terms, float backward) and
      // 1e-3 of the block's largest gradient.
      const double tol = 2 * ulp / (double(hi) - double(lo)) + DBG_RTOL * std::abs(fd) + DBG_ATOL * gmax;
      if (std::abs(up - down) > 2 * tol) {
        ++skipped;  // A ReLU kink (or the exp clamp) inside [x - h, x + h].
        continue;
      }
      ++checked;
      EXPECT_NEAR(g[i], fd, tol) << b.name << "[" << i << "] one-sided " << up << " " << down;
      if (std::abs(g[i] - fd) / tol > 0.5) {
        for (float hh : {4e-2f, 2e-2f, 1e-2f, 5e-3f, 2.5e-3f}) {
          x[i] = x0 + hh; const float a1 = x[i];
          const double l1 = trainer.ComputeLossAndGradients(batch, jitter, &tmp);
          x[i] = x0 - hh; const float a2 = x[i];
          const double l2 = trainer.ComputeLossAndGradients(batch, jitter, &tmp);
          x[i] = x0;
          printf("   h %g fd %.6g\n", hh, (l1 - l2) / (double(a1) - a2));
        }
      }
      if (std::abs(g[i] - fd) / tol > worst) printf("DBGW %s g %g fd %g up %g down %g noise %g\n", b.name, g[i], fd, up, down, 2 * ulp / (double(hi) - double(lo)));
      worst = std::max(worst, std::abs(g[i] - fd) / tol);
    }
    printf("DBG %s gmax %g ulp %g skipped %d checked %d worst %g\n", b.name, gmax, ulp, skipped, checked, worst);
    EXPECT_LE(skipped, 6);
  }
}

}  // namespace
}  // namespace clnerf
