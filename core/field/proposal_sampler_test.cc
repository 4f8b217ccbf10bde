// Proposal fields and sampler: every backward pass against central finite
// differences (the field, the weights, the interlevel loss, and the chain
// from a proposal field's parameters to the interlevel loss with the sample
// placement held fixed, which is the gradient training uses), and the
// placement's invariants.
#include "core/field/proposal_sampler.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "core/data/contraction.h"
#include "core/field/ngp_model.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

ProposalFieldOptions TinyFieldOptions() {
  ProposalFieldOptions o;
  o.levels = 3;
  o.log2_table_size = 10;
  o.base_resolution = 4;
  o.finest_resolution = 16;
  o.hidden = 8;
  return o;
}

NgpModel ProposalModel(uint64_t seed) {
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
  o.sampler = SamplerKind::kProposal;
  o.proposal.samples0 = 16;
  o.proposal.samples1 = 12;
  o.proposal.nerf_samples = 8;
  o.proposal.field0 = TinyFieldOptions();
  o.proposal.field1 = TinyFieldOptions();
  o.proposal.field1.finest_resolution = 32;
  Normalization norm;
  norm.bound = kContractedBound;
  auto m = NgpModel::Create(o, norm, SceneKind::kUnbounded, Eigen::Vector3f(0.5f, 0.5f, 0.5f), 1, seed);
  EXPECT_TRUE(m.ok()) << m.status();
  return *std::move(m);
}

TEST(ProposalModelTest, SamplerIsResolvedAtCreationAndProposalsAreOptIn) {
  ModelOptions o;
  o.grid.levels = 2;
  o.grid.log2_table_size = 10;
  o.grid.finest_resolution = 32;
  o.occupancy.resolution = 16;
  Normalization bounded;
  auto b = NgpModel::Create(o, bounded, SceneKind::kBounded, Eigen::Vector3f::Ones(), 1, 1);
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_FALSE(b->uses_proposals());
  EXPECT_TRUE(b->params().proposal.empty());
  Normalization unbounded;
  unbounded.bound = kContractedBound;
  auto a = NgpModel::Create(o, unbounded, SceneKind::kUnbounded, Eigen::Vector3f::Ones(), 1, 1);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->options().sampler, SamplerKind::kOccupancy);  // kAuto resolved.
  o.sampler = SamplerKind::kProposal;
  auto u = NgpModel::Create(o, unbounded, SceneKind::kUnbounded, Eigen::Vector3f::Ones(), 1, 1);
  ASSERT_TRUE(u.ok()) << u.status();
  EXPECT_TRUE(u->uses_proposals());
  EXPECT_EQ(u->options().sampler, SamplerKind::kProposal);
  EXPECT_EQ(u->params().proposal.size(), u->num_proposal_params());
  EXPECT_GT(u->num_proposal_params(), 0u);
  o.sampler = SamplerKind::kOccupancy;
  auto forced = NgpModel::Create(o, unbounded, SceneKind::kUnbounded, Eigen::Vector3f::Ones(), 1, 1);
  ASSERT_TRUE(forced.ok());
  EXPECT_FALSE(forced->uses_proposals());
  SamplerKind k;
  EXPECT_TRUE(ParseSamplerKind("proposal", &k).ok());
  EXPECT_EQ(k, SamplerKind::kProposal);
  EXPECT_EQ(ParseSamplerKind("grid", &k).code(), absl::StatusCode::kInvalidArgument);
  o.proposal.nerf_samples = 0;
  o.sampler = SamplerKind::kProposal;
  EXPECT_EQ(o.Validate().code(), absl::StatusCode::kInvalidArgument);
}

TEST(ProposalFieldTest, BackwardMatchesFiniteDifferences) {
  const ProposalField field(TinyFieldOptions());
  std::vector<float> params(field.num_params());
  field.Initialize(params.data(), 3);
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  // Grid values of O(0.3) so the features matter.
  for (size_t i = 0; i < field.grid().num_params(); ++i) params[i] = 0.6f * (u(rng) - 0.5f);
  const int n = 24;
  std::vector<float> pos(3 * n), c(n);
  for (float& p : pos) p = u(rng);
  for (float& x : c) x = u(rng) - 0.5f;
  auto loss = [&](const std::vector<float>& prm) {
    ProposalWorkspace ws;
    std::vector<float> sigma(n);
    field.Forward(prm.data(), pos.data(), n, &ws, sigma.data());
    double l = 0;
    for (int j = 0; j < n; ++j) l += double(c[j]) * sigma[j];
    return l;
  };
  ProposalWorkspace ws;
  std::vector<float> sigma(n), grad(params.size(), 0.0f);
  field.Forward(params.data(), pos.data(), n, &ws, sigma.data());
  field.Backward(params.data(), n, c.data(), &ws, grad.data());
  for (int l = 0; l < field.grid().num_levels(); ++l) {
    field.grid().BackwardLevel(l, pos.data(), ws.d_feat.data(), n, grad.data(), nullptr, nullptr);
  }
  // A ReLU whose input crosses zero inside [x - h, x + h] makes the loss
  // kinked there: such entries (one-sided slopes that disagree) are skipped,
  // and there must be few of them.
  const double base = loss(params);
  int checked = 0, nonzero = 0, kinks = 0;
  for (size_t i = 0; i < params.size(); i += (i < field.mlp_offset() ? 7 : 1)) {
    const float h = 1e-3f;
    std::vector<float> p = params;
    p[i] = params[i] + h;
    const double up = loss(p);
    p[i] = params[i] - h;
    const double down = loss(p);
    const double fd = (up - down) / (2 * h);
    const double right = (up - base) / h, left = (base - down) / h;
    if (std::abs(right - left) > 4e-3 + 0.05 * std::abs(fd)) {
      ++kinks;
      continue;
    }
    EXPECT_NEAR(grad[i], fd, 2e-3 + 2e-2 * std::abs(fd)) << "param " << i;
    ++checked;
    nonzero += std::abs(grad[i]) > 1e-4f;
  }
  EXPECT_GT(checked, 200);
  EXPECT_GT(nonzero, 100);
  EXPECT_LE(kinks, 6);
}

TEST(ProposalSamplerTest, WeightsBackwardMatchesFiniteDifferences) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const int n = 12;
  std::vector<float> sigma(n), t(n + 1), g(n);
  t[0] = 0.1f;
  for (int i = 0; i < n; ++i) {
    sigma[i] = 3.0f * u(rng);
    t[i + 1] = t[i] + 0.05f + 0.2f * u(rng);
    g[i] = u(rng) - 0.5f;
  }
  std::vector<double> w(n);
  auto loss = [&](const std::vector<float>& s) {
    std::vector<float> ww(n);
    ProposalSampler::Weights(s.data(), t.data(), n, ww.data());
    double l = 0;
    for (int i = 0; i < n; ++i) l += double(g[i]) * ww[i];
    return l;
  };
  std::vector<float> ww(n), ds(n);
  ProposalSampler::Weights(sigma.data(), t.data(), n, ww.data());
  ProposalSampler::WeightsBackward(sigma.data(), t.data(), ww.data(), g.data(), n, ds.data());
  for (int k = 0; k < n; ++k) {
    std::vector<float> s = sigma;
    const float h = 1e-3f;
    s[k] = sigma[k] + h;
    const double up = loss(s);
    s[k] = sigma[k] - h;
    const double fd = (up - loss(s)) / (2 * h);
    EXPECT_NEAR(ds[k], fd, 1e-4 + 1e-2 * std::abs(fd)) << k;
  }
}

TEST(ProposalSamplerTest, InterlevelLossValueAndGradient) {
  // Proposal intervals [0,1,2,3,4], final intervals [0.5,1.5], [1.5,3.5]:
  // the first overlaps proposal intervals 0 and 1, the second 1..3.
  const float cp[5] = {0, 1, 2, 3, 4};
  const float wp[4] = {0.1f, 0.2f, 0.05f, 0.05f};
  const float c[3] = {0.5f, 1.5f, 3.5f};
  const float w[2] = {0.5f, 0.1f};
  std::vector<float> cum, diff, d(4, 0.0f);
  const float l = ProposalSampler::Interlevel(c, w, 2, cp, wp, 4, 1.0f, d.data(), &cum, &diff);
  // Interval 0: outer = 0.3, excess 0.2 -> 0.04 / 0.5; interval 1: outer 0.3 >= 0.1.
  EXPECT_NEAR(l, 0.04f / 0.5f, 1e-6f);
  EXPECT_NEAR(d[0], -2 * 0.2f / 0.5f, 1e-5f);
  EXPECT_NEAR(d[1], -2 * 0.2f / 0.5f, 1e-5f);
  EXPECT_EQ(d[2], 0.0f);
  EXPECT_EQ(d[3], 0.0f);
  // Random case against central differences.
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const int n = 10, m = 6;
  std::vector<float> cpr(n + 1), wpr(n), cr(m + 1), wr(m);
  for (int i = 0; i <= n; ++i) cpr[i] = float(i);
  for (float& x : wpr) x = 0.1f * u(rng);
  cr[0] = 0.3f;
  for (int j = 0; j < m; ++j) cr[j + 1] = cr[j] + 0.4f + 1.2f * u(rng);
  for (float& x : wr) x = 0.4f * u(rng);
  std::vector<float> dr(n, 0.0f);
  ProposalSampler::Interlevel(cr.data(), wr.data(), m, cpr.data(), wpr.data(), n, 1.0f, dr.data(), &cum, &diff);
  int nonzero = 0;
  for (int k = 0; k < n; ++k) {
    std::vector<float> a = wpr, b = wpr, s1(n), s2(n);
    const float h = 1e-4f;
    a[k] += h;
    b[k] -= h;
    const double fd = (double(ProposalSampler::Interlevel(cr.data(), wr.data(), m, cpr.data(), a.data(), n, 1.0f,
                                                          s1.data(), &cum, &diff)) -
                       ProposalSampler::Interlevel(cr.data(), wr.data(), m, cpr.data(), b.data(), n, 1.0f, s2.data(),
                                                   &cum, &diff)) /
                      (2 * h);
    EXPECT_NEAR(dr[k], fd, 2e-3 + 1e-2 * std::abs(fd)) << k;
    nonzero += dr[k] != 0.0f;
  }
  EXPECT_GT(nonzero, 0);
}

TEST(ProposalSamplerTest, ResampleFollowsTheWeightsAndStaysOrdered) {
  const int n = 8, m = 32;
  std::vector<float> s(n + 1), w(n, 0.0f), u(m + 1), out(m + 1);
  for (int i = 0; i <= n; ++i) s[i] = float(i);
  w[5] = 1.0f;  // All mass in [5, 6].
  for (int j = 0; j <= m; ++j) u[j] = (j + 0.5f) / (m + 1);
  ProposalSampler::Resample(s.data(), w.data(), n, 1.0f, 0.01f, u.data(), m, out.data());
  int inside = 0;
  for (int j = 0; j <= m; ++j) {
    EXPECT_GE(out[j], 0.0f);
    EXPECT_LE(out[j], 8.0f);
    if (j > 0) {
      EXPECT_GE(out[j], out[j - 1]);
    }
    inside += out[j] >= 5.0f && out[j] <= 6.0f;
  }
  EXPECT_GE(inside, 28);  // 1 / 1.08 of the mass.
  // Annealed to 0: every interval weighs the same (w^0 = 1 for w > 0... and
  // the padding for w = 0), so edges spread over the whole range.
  ProposalSampler::Resample(s.data(), w.data(), n, 0.0f, 0.01f, u.data(), m, out.data());
  EXPECT_LT(out[m / 4], 5.0f);
  // No weight at all: uniform.
  std::vector<float> zero(n, 0.0f);
  ProposalSampler::Resample(s.data(), zero.data(), n, 1.0f, 0.0f, u.data(), m, out.data());
  EXPECT_NEAR(out[m / 2], 4.0f, 0.2f);
}

TEST(ProposalSamplerTest, PlacementIsOrderedInsideTheRayAndDeterministic) {
  const NgpModel model = ProposalModel(1);
  const FieldEvaluator field(model);
  const ProposalSampler sampler(field);
  const int n = 9;
  std::vector<float> o(3 * n), d(3 * n);
  std::mt19937_64 rng(2);
  std::normal_distribution<float> g(0.0f, 1.0f);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3f oo = 1.5f * Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector3f dd = (0.2f * Eigen::Vector3f(g(rng), g(rng), g(rng)) - oo).normalized();
    std::copy_n(oo.data(), 3, &o[3 * i]);
    std::copy_n(dd.data(), 3, &d[3 * i]);
  }
  auto place = [&](uint64_t seed, std::vector<RaySample>* s, std::vector<int>* seg, std::vector<int>* ray) {
    ProposalContext ctx;
    seg->assign(1, 0);
    sampler.Place(o.data(), d.data(), n, seed, nullptr, 1.0f, &ctx, s, seg, ray);
  };
  std::vector<RaySample> a, b, c;
  std::vector<int> sa, sb, sc, ra, rb, rc;
  place(0, &a, &sa, &ra);
  place(0, &b, &sb, &rb);
  place(7, &c, &sc, &rc);
  ASSERT_EQ(int(ra.size()), n);
  ASSERT_EQ(a.size(), size_t(n) * 8);
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].t, b[i].t);
    EXPECT_EQ(a[i].dt, b[i].dt);
  }
  int moved = 0;
  for (size_t i = 0; i < a.size(); ++i) moved += a[i].t != c[i].t;
  EXPECT_GT(moved, int(a.size()) / 2);  // Jitter moves the samples.
  for (int k = 0; k < n; ++k) {
    float t0, t1;
    const Eigen::Map<const Eigen::Vector3f> oo(&o[3 * ra[k]]), dd(&d[3 * ra[k]]);
    ASSERT_TRUE(model.RayInterval(oo, dd, &t0, &t1));
    for (const auto* v : {&a, &c}) {
      for (int j = sa[k]; j < sa[k + 1]; ++j) {
        const RaySample& s = (*v)[j];
        EXPECT_GE(s.dt, 0.0f);
        EXPECT_GE(s.t - 0.5f * s.dt, t0 * (1 - 1e-5f));
        EXPECT_LE(s.t + 0.5f * s.dt, t1 * (1 + 1e-5f));
        if (j > sa[k]) {
          EXPECT_GE(s.t, (*v)[j - 1].t);
        }
      }
    }
  }
  // A ray that misses the box (pointing away from a far origin) gets none.
  std::vector<float> mo = {0.0f, 0.0f, 5000.0f}, md = {0.0f, 0.0f, 1.0f};
  std::vector<RaySample> ms;
  std::vector<int> mseg = {0}, mray;
  ProposalContext ctx;
  sampler.Place(mo.data(), md.data(), 1, 0, nullptr, 1.0f, &ctx, &ms, &mseg, &mray);
  EXPECT_TRUE(ms.empty());
  EXPECT_TRUE(mray.empty());
}

// The gradient training gives a proposal field: interlevel loss -> weights
// -> sigma -> MLP and hash grid, with the placement (all edges and the full
// field's weights) held fixed, against central differences.
TEST(ProposalSamplerTest, InterlevelGradientReachesTheFieldParameters) {
  NgpModel model = ProposalModel(4);
  std::mt19937_64 rng(6);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<float>& prm = model.mutable_params().proposal;
  for (int k = 0; k < 2; ++k) {
    const size_t off = model.proposal_offset(k);
    for (size_t i = 0; i < model.proposal_field(k).grid().num_params(); ++i) prm[off + i] = 1.2f * (u(rng) - 0.5f);
  }
  const FieldEvaluator field(model);
  const ProposalSampler sampler(field);
  const int n = 6;
  std::vector<float> o(3 * n), d(3 * n);
  std::normal_distribution<float> g(0.0f, 1.0f);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3f oo = 1.5f * Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector3f dd = (0.2f * Eigen::Vector3f(g(rng), g(rng), g(rng)) - oo).normalized();
    std::copy_n(oo.data(), 3, &o[3 * i]);
    std::copy_n(dd.data(), 3, &d[3 * i]);
  }
  ProposalContext ctx;
  std::vector<RaySample> samples;
  std::vector<int> seg = {0}, ray;
  sampler.Place(o.data(), d.data(), n, 3, nullptr, 1.0f, &ctx, &samples, &seg, &ray);
  const int nf = ctx.n_final;
  // Full-field weights: peaked, so part of them exceed the proposals' cover.
  std::vector<float> w(size_t(n) * nf);
  for (int r = 0; r < n; ++r) {
    for (int j = 0; j < nf; ++j) w[size_t(r) * nf + j] = j == (r % nf) ? 0.9f : 0.01f * u(rng);
  }
  std::vector<float> grad(prm.size(), 0.0f);
  ProposalGridStore store;
  ProposalContext work = ctx;
  const float base = sampler.InterlevelBackward(w.data(), 1.0f, &work, grad.data(), &store);
  ASSERT_GT(base, 0.0f);
  for (int k = 0; k < 2; ++k) {
    const HashGrid& pg = model.proposal_field(k).grid();
    for (int l = 0; l < pg.num_levels(); ++l) {
      pg.BackwardLevel(l, store.pos[k].data(), store.d_feat[k].data(), int(store.pos[k].size() / 3),
                       grad.data() + model.proposal_offset(k), nullptr, nullptr);
    }
  }
  // The loss with every edge fixed, recomputed from scratch.
  auto loss = [&](const std::vector<float>& p) {
    double total = 0;
    std::vector<float> cum, diff;
    for (int k = 0; k < 2; ++k) {
      const ProposalStage& st = ctx.stage[k];
      const ProposalField& pf = model.proposal_field(k);
      ProposalWorkspace ws;
      std::vector<float> sigma(size_t(n) * st.n), wp(size_t(n) * st.n), dummy(st.n);
      pf.Forward(p.data() + model.proposal_offset(k), st.pos.data(), n * st.n, &ws, sigma.data());
      for (int r = 0; r < n; ++r) {
        ProposalSampler::Weights(&sigma[size_t(r) * st.n], &st.t[size_t(r) * (st.n + 1)], st.n, &wp[size_t(r) * st.n]);
        total += ProposalSampler::Interlevel(&ctx.final_s[size_t(r) * (nf + 1)], &w[size_t(r) * nf], nf,
                                             &st.s[size_t(r) * (st.n + 1)], &wp[size_t(r) * st.n], st.n, 1.0f,
                                             dummy.data(), &cum, &diff);
      }
    }
    return total;
  };
  EXPECT_NEAR(loss(prm), base, 1e-4 * std::abs(base));
  int checked = 0, nonzero = 0;
  for (size_t i = 0; i < prm.size(); i += 3) {
    if (grad[i] == 0.0f && (i % 9) != 0) continue;  // Check every touched entry and a sample of the rest.
    std::vector<float> p = prm;
    const float h = 1e-3f;
    p[i] = prm[i] + h;
    const double up = loss(p);
    p[i] = prm[i] - h;
    const double fd = (up - loss(p)) / (2 * h);
    EXPECT_NEAR(grad[i], fd, 2e-3 + 3e-2 * std::abs(fd)) << "param " << i;
    ++checked;
    nonzero += grad[i] != 0.0f;
  }
  EXPECT_GT(nonzero, 50);
  EXPECT_GT(checked, nonzero);
}

}  // namespace
}  // namespace clnerf
