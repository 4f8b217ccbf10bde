// Numerical-correctness tests of the two MLPs: the per-ray bias trick against
// a brute-force per-sample evaluation, and Backward + BackwardBiases against
// central finite differences (of an independent double-precision reference
// and of the library's own float forward).
#include "core/field/network.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "Eigen/Dense"
#include "core/field/sh_encoding.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

constexpr int kGridDim = 8;
constexpr int kSteps = 3;

struct Config {
  const char* name;
  int density_layers;
  int colour_layers;
  bool embeddings;
};
// Readable parameter names in test listings (instead of raw bytes).
void PrintTo(const Config& c, std::ostream* os) { *os << c.name; }

NetworkOptions MakeOptions(const Config& c) {
  NetworkOptions o;
  o.density_hidden = 16;
  o.density_hidden_layers = c.density_layers;
  o.density_out = 16;
  o.colour_hidden = 16;
  o.colour_hidden_layers = c.colour_layers;
  o.appearance_dim = 8;
  o.geometry_dim = 4;
  o.use_embeddings = c.embeddings;
  return o;
}

// A fixed problem: 4 rays (one of them empty) over 9 samples, random
// features, directions, time steps, and loss weights
//   L = sum_j a_j . rgb_j + sum_j b_j h0_j.
struct Problem {
  std::vector<int> seg = {0, 3, 3, 5, 9};
  std::vector<int> steps = {2, 0, 1, 2};
  int nrays() const { return int(seg.size()) - 1; }
  int n() const { return seg.back(); }
  std::vector<float> mlp, emb, feat, dirs, sh, a, b;
};

Problem MakeProblem(const Network& net, uint64_t seed) {
  Problem p;
  std::mt19937_64 rng(seed);
  p.mlp.resize(net.num_mlp_params());
  net.InitializeMlp(p.mlp.data(), seed + 1);
  p.emb.resize(size_t(kSteps) * net.embedding_row_size());
  net.InitializeEmbeddings(p.emb.data(), kSteps, seed + 2);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  p.feat.resize(size_t(p.n()) * kGridDim);
  for (float& v : p.feat) v = u(rng);
  p.sh.resize(size_t(kShDim) * p.nrays());
  for (int r = 0; r < p.nrays(); ++r) {
    Eigen::Vector3f d(u(rng), u(rng), u(rng));
    d.normalize();
    p.dirs.insert(p.dirs.end(), d.data(), d.data() + 3);
    ShEncode(d.x(), d.y(), d.z(), &p.sh[size_t(kShDim) * r]);
  }
  p.a.resize(3 * size_t(p.n()));
  for (float& v : p.a) v = u(rng);
  p.b.resize(p.n());
  for (float& v : p.b) v = u(rng);
  return p;
}

// The library forward exactly as the trainer drives it (per-ray biases).
struct Forward {
  NetworkWorkspace ws;
  std::vector<float> geo_bias, colour_bias;
};

void RunForward(const Network& net, const Problem& p, const float* mlp, const float* emb, const float* feat,
                Forward* f) {
  const int Hd = net.options().density_hidden, Hc = net.options().colour_hidden;
  Eigen::MatrixXf geo, app;
  net.StepBiases(mlp, emb, kSteps, &geo, &app);
  f->ws.Reserve(p.n(), net.options(), kGridDim);
  f->geo_bias.assign(size_t(Hd) * p.nrays(), 0.0f);
  f->colour_bias.assign(size_t(Hc) * p.nrays(), 0.0f);
  for (int r = 0; r < p.nrays(); ++r) {
    std::copy(geo.col(p.steps[r]).data(), geo.col(p.steps[r]).data() + Hd, &f->geo_bias[size_t(Hd) * r]);
    net.RayColourBias(mlp, &p.sh[size_t(kShDim) * r], app.col(p.steps[r]).data(), &f->colour_bias[size_t(Hc) * r]);
  }
  net.DensityForward(mlp, feat, p.n(), p.seg.data(), p.nrays(), f->geo_bias.data(), &f->ws);
  net.ColourForward(mlp, p.n(), p.seg.data(), p.nrays(), f->colour_bias.data(), &f->ws);
}

double LibraryLoss(const Network& net, const Problem& p, const float* mlp, const float* emb, const float* feat) {
  Forward f;
  RunForward(net, p, mlp, emb, feat, &f);
  double l = 0;
  for (int j = 0; j < p.n(); ++j) {
    for (int k = 0; k < 3; ++k) l += double(p.a[3 * j + k]) * f.ws.rgb(k, j);
    l += double(p.b[j]) * f.ws.h(0, j);
  }
  return l;
}

// Brute-force reference in double: every sample sees its full input vectors
// [feat; e_g] and [SH(d); h; e_a]; no per-ray bias trick.
struct Reference {
  std::vector<Eigen::MatrixXd> density_act;  // per layer, hidden x n (post-ReLU)
  Eigen::MatrixXd h, rgb;
};

Eigen::MatrixXd Weight(const std::vector<double>& mlp, const Network::Layer& l) {
  return Eigen::Map<const Eigen::MatrixXd>(mlp.data() + l.offset, l.rows, l.cols);
}

Reference RunReference(const Network& net, const Problem& p, const std::vector<double>& mlp,
                       const std::vector<double>& emb, const std::vector<double>& feat) {
  const NetworkOptions& o = net.options();
  const int A = o.app_dim(), G = o.geo_dim(), row = net.embedding_row_size();
  const auto& dl = net.density_layers();
  const auto& cl = net.colour_layers();
  Reference ref;
  const int n = p.n();
  ref.density_act.assign(dl.size() - 1, Eigen::MatrixXd(o.density_hidden, n));
  ref.h.resize(o.density_out, n);
  ref.rgb.resize(3, n);
  for (int r = 0; r < p.nrays(); ++r) {
    const int t = p.steps[r];
    for (int j = p.seg[r]; j < p.seg[r + 1]; ++j) {
      Eigen::VectorXd x(kGridDim + G);
      for (int k = 0; k < kGridDim; ++k) x[k] = feat[size_t(j) * kGridDim + k];
      for (int k = 0; k < G; ++k) x[kGridDim + k] = emb[size_t(t) * row + A + k];
      for (size_t k = 0; k + 1 < dl.size(); ++k) {
        x = (Weight(mlp, dl[k]) * x).cwiseMax(0.0);
        ref.density_act[k].col(j) = x;
      }
      const Eigen::VectorXd h = Weight(mlp, dl.back()) * x;
      ref.h.col(j) = h;
      Eigen::VectorXd y(kShDim + o.density_out + A);
      for (int k = 0; k < kShDim; ++k) y[k] = p.sh[size_t(kShDim) * r + k];
      y.segment(kShDim, o.density_out) = h;
      for (int k = 0; k < A; ++k) y[kShDim + o.density_out + k] = emb[size_t(t) * row + k];
      for (size_t k = 0; k + 1 < cl.size(); ++k) y = (Weight(mlp, cl[k]) * y).cwiseMax(0.0);
      const Eigen::VectorXd z = Weight(mlp, cl.back()) * y;
      for (int k = 0; k < 3; ++k) ref.rgb(k, j) = 1.0 / (1.0 + std::exp(-z[k]));
    }
  }
  return ref;
}

double ReferenceLoss(const Network& net, const Problem& p, const std::vector<double>& mlp,
                     const std::vector<double>& emb, const std::vector<double>& feat) {
  const Reference ref = RunReference(net, p, mlp, emb, feat);
  double l = 0;
  for (int j = 0; j < p.n(); ++j) {
    for (int k = 0; k < 3; ++k) l += p.a[3 * j + k] * ref.rgb(k, j);
    l += p.b[j] * ref.h(0, j);
  }
  return l;
}

std::vector<double> ToDouble(const std::vector<float>& v) { return std::vector<double>(v.begin(), v.end()); }

struct Grads {
  std::vector<float> mlp, emb, feat;
};

Grads RunBackward(const Network& net, const Problem& p) {
  Forward f;
  RunForward(net, p, p.mlp.data(), p.emb.data(), p.feat.data(), &f);
  const int Hd = net.options().density_hidden, Hc = net.options().colour_hidden;
  Grads g;
  g.mlp.assign(p.mlp.size(), 0.0f);
  g.emb.assign(p.emb.size(), 0.0f);
  g.feat.assign(p.feat.size(), 0.0f);
  std::vector<float> d_geo(size_t(Hd) * p.nrays(), 0.0f), d_col(size_t(Hc) * p.nrays(), 0.0f);
  net.Backward(p.mlp.data(), p.feat.data(), p.n(), p.seg.data(), p.nrays(), p.a.data(), p.b.data(), &f.ws,
               g.mlp.data(), g.feat.data(), d_geo.data(), d_col.data());
  net.BackwardBiases(p.mlp.data(), p.emb.data(), p.nrays(), p.steps.data(), p.sh.data(), d_geo.data(),
                     d_col.data(), g.mlp.data(), g.emb.data());
  return g;
}

// Central difference of `loss` in parameter `x[i]` (double), with a kink
// check: returns false when the one-sided differences disagree by more than
// `kink_tol` (the interval straddles a ReLU kink).
template <typename T, typename F>
bool CentralDifference(std::vector<T>* x, size_t i, T h, double base, F&& loss, double kink_tol, double* fd) {
  const T x0 = (*x)[i];
  (*x)[i] = x0 + h;
  const T hi = (*x)[i];
  const double lp = loss();
  (*x)[i] = x0 - h;
  const T lo = (*x)[i];
  const double lm = loss();
  (*x)[i] = x0;
  const double up = (lp - base) / (double(hi) - double(x0));
  const double down = (base - lm) / (double(x0) - double(lo));
  *fd = (lp - lm) / (double(hi) - double(lo));
  return std::abs(up - down) <= kink_tol;
}

class NetworkGradientTest : public testing::TestWithParam<Config> {};

// The per-ray bias trick (embedding and SH products computed once per ray)
// is the same function as feeding [feat; e_g] and [SH; h; e_a] per sample.
TEST_P(NetworkGradientTest, BiasTrickMatchesBruteForce) {
  const Network net(MakeOptions(GetParam()), kGridDim);
  const Problem p = MakeProblem(net, 11);
  Forward f;
  RunForward(net, p, p.mlp.data(), p.emb.data(), p.feat.data(), &f);
  const Reference ref = RunReference(net, p, ToDouble(p.mlp), ToDouble(p.emb), ToDouble(p.feat));
  for (size_t k = 0; k < ref.density_act.size(); ++k) {
    const double err = (f.ws.density_act[k].leftCols(p.n()).cast<double>() - ref.density_act[k]).cwiseAbs().maxCoeff();
    EXPECT_LT(err, 1e-5) << "density layer " << k;
  }
  EXPECT_LT((f.ws.h.leftCols(p.n()).cast<double>() - ref.h).cwiseAbs().maxCoeff(), 1e-5);
  EXPECT_LT((f.ws.rgb.leftCols(p.n()).cast<double>() - ref.rgb).cwiseAbs().maxCoeff(), 1e-6);
  // The geometry code matters when embeddings are on (so this comparison
  // would catch a dropped or misplaced bias).
  if (GetParam().embeddings) {
    EXPECT_GT(ref.h.cwiseAbs().maxCoeff(), 0.1);
    std::vector<double> zero_emb(p.emb.size(), 0.0);
    const Reference no_emb = RunReference(net, p, ToDouble(p.mlp), zero_emb, ToDouble(p.feat));
    EXPECT_GT((no_emb.h - ref.h).cwiseAbs().maxCoeff(), 1e-2);
  }
  // DensityOnly gives the same h[0].
  std::vector<float> h0(p.n());
  NetworkWorkspace ws2;
  ws2.Reserve(p.n(), net.options(), kGridDim);
  net.DensityOnly(p.mlp.data(), p.feat.data(), p.n(), p.seg.data(), p.nrays(), f.geo_bias.data(), &ws2, h0.data());
  for (int j = 0; j < p.n(); ++j) EXPECT_NEAR(h0[j], ref.h(0, j), 1e-5) << j;
}

// Backward vs central differences of the double-precision reference: the
// reference is smooth except at ReLU kinks, so h = 1e-6 gives an FD error of
// ~1e-9; the float backward is accurate to ~1e-6 relative. Tolerance
// 5e-6 absolute + 5e-5 relative (observed errors are < 3% of it).
TEST_P(NetworkGradientTest, GradientsMatchDoubleReference) {
  const Network net(MakeOptions(GetParam()), kGridDim);
  const Problem p = MakeProblem(net, 21);
  const Grads g = RunBackward(net, p);
  std::vector<double> mlp = ToDouble(p.mlp), emb = ToDouble(p.emb), feat = ToDouble(p.feat);
  auto loss = [&]() { return ReferenceLoss(net, p, mlp, emb, feat); };
  const double base = loss();
  constexpr double kH = 1e-6, kAtol = 5e-6, kRtol = 5e-5;
  int skipped = 0, checked = 0;
  auto check = [&](std::vector<double>* x, const std::vector<float>& grad, const char* what) {
    double max_abs = 0;
    for (size_t i = 0; i < x->size(); ++i) {
      double fd;
      if (!CentralDifference(x, i, kH, base, loss, kAtol, &fd)) {
        ++skipped;
        continue;
      }
      ++checked;
      EXPECT_NEAR(grad[i], fd, kAtol + kRtol * std::abs(fd)) << what << "[" << i << "]";
      max_abs = std::max(max_abs, std::abs(fd));
    }
    EXPECT_GT(max_abs, 1e-3) << what;  // The block does influence the loss.
  };
  check(&mlp, g.mlp, "mlp");
  if (GetParam().embeddings) {
    check(&emb, g.emb, "emb");
  } else {
    EXPECT_TRUE(p.emb.empty());
  }
  check(&feat, g.feat, "feat");
  EXPECT_LE(skipped, checked / 50) << "too many parameters straddle a ReLU kink";
}

// Backward vs central differences of the library's own float forward (so
// forward and backward are consistent as implemented). A random sample of
// 200 MLP weights, every embedding value and every feature; h = 1e-3. The
// loss is a sum of ~40 float outputs of O(1), rounding noise ~3e-7, so FD
// noise ~3e-4; the second-order term is ~h^2 = 1e-6. Tolerance 5e-4
// absolute + 2e-3 relative; intervals whose one-sided differences disagree
// by more than that straddle a ReLU kink and are skipped.
TEST_P(NetworkGradientTest, GradientsMatchFloatForward) {
  const Network net(MakeOptions(GetParam()), kGridDim);
  Problem p = MakeProblem(net, 31);
  const Grads g = RunBackward(net, p);
  auto loss = [&]() { return LibraryLoss(net, p, p.mlp.data(), p.emb.data(), p.feat.data()); };
  const double base = loss();
  constexpr float kH = 1e-3f;
  constexpr double kAtol = 5e-4, kRtol = 2e-3;
  int skipped = 0, checked = 0;
  auto check_one = [&](std::vector<float>* x, size_t i, const std::vector<float>& grad, const char* what) {
    double fd;
    if (!CentralDifference(x, i, kH, base, loss, 2 * kAtol, &fd)) {
      ++skipped;
      return;
    }
    ++checked;
    EXPECT_NEAR(grad[i], fd, kAtol + kRtol * std::abs(fd)) << what << "[" << i << "]";
  };
  std::mt19937_64 rng(32);
  std::uniform_int_distribution<size_t> pick(0, p.mlp.size() - 1);
  for (int k = 0; k < 200; ++k) check_one(&p.mlp, pick(rng), g.mlp, "mlp");
  for (size_t i = 0; i < p.emb.size(); ++i) check_one(&p.emb, i, g.emb, "emb");
  for (size_t i = 0; i < p.feat.size(); ++i) check_one(&p.feat, i, g.feat, "feat");
  EXPECT_LE(skipped, checked / 10) << "too many parameters straddle a ReLU kink";
}

// Backward accumulates into d_mlp (the trainer sums per-thread chunks).
TEST_P(NetworkGradientTest, BackwardAccumulates) {
  const Network net(MakeOptions(GetParam()), kGridDim);
  const Problem p = MakeProblem(net, 41);
  const Grads g = RunBackward(net, p);
  Forward f;
  RunForward(net, p, p.mlp.data(), p.emb.data(), p.feat.data(), &f);
  const int Hd = net.options().density_hidden, Hc = net.options().colour_hidden;
  std::vector<float> d_mlp = g.mlp, d_emb = g.emb, d_feat(p.feat.size());
  std::vector<float> d_geo(size_t(Hd) * p.nrays(), 0.0f), d_col(size_t(Hc) * p.nrays(), 0.0f);
  net.Backward(p.mlp.data(), p.feat.data(), p.n(), p.seg.data(), p.nrays(), p.a.data(), p.b.data(), &f.ws,
               d_mlp.data(), d_feat.data(), d_geo.data(), d_col.data());
  net.BackwardBiases(p.mlp.data(), p.emb.data(), p.nrays(), p.steps.data(), p.sh.data(), d_geo.data(),
                     d_col.data(), d_mlp.data(), d_emb.data());
  for (size_t i = 0; i < d_mlp.size(); ++i) ASSERT_NEAR(d_mlp[i], 2 * g.mlp[i], 1e-6 + 1e-5 * std::abs(g.mlp[i]));
  for (size_t i = 0; i < d_emb.size(); ++i) ASSERT_NEAR(d_emb[i], 2 * g.emb[i], 1e-6 + 1e-5 * std::abs(g.emb[i]));
  EXPECT_EQ(d_feat, g.feat);  // Written, not accumulated.
}

INSTANTIATE_TEST_SUITE_P(Configs, NetworkGradientTest,
                         testing::Values(Config{"OneDensityLayerEmbeddings", 1, 2, true},
                                         Config{"TwoDensityLayersEmbeddings", 2, 2, true},
                                         Config{"NoEmbeddings", 1, 2, false},
                                         Config{"TwoDensityLayersNoEmbeddingsOneColourLayer", 2, 1, false}),
                         [](const testing::TestParamInfo<Config>& info) { return std::string(info.param.name); });

TEST(NetworkLayoutTest, LayerShapes) {
  NetworkOptions o = MakeOptions({"", 2, 2, true});
  const Network net(o, kGridDim);
  ASSERT_EQ(net.density_layers().size(), 3u);
  ASSERT_EQ(net.colour_layers().size(), 3u);
  EXPECT_EQ(net.density_layers()[0].rows, 16);
  EXPECT_EQ(net.density_layers()[0].cols, kGridDim + 4);
  EXPECT_EQ(net.density_layers()[2].rows, 16);
  EXPECT_EQ(net.colour_layers()[0].cols, kShDim + 16 + 8);
  EXPECT_EQ(net.colour_layers()[2].rows, 3);
  size_t total = 0;
  for (const auto* ls : {&net.density_layers(), &net.colour_layers()}) {
    for (const auto& l : *ls) {
      EXPECT_EQ(l.offset, total);
      total += size_t(l.rows) * l.cols;
    }
  }
  EXPECT_EQ(net.num_mlp_params(), total);
  EXPECT_EQ(net.embedding_row_size(), 12);
  o.use_embeddings = false;
  const Network plain(o, kGridDim);
  EXPECT_EQ(plain.embedding_row_size(), 0);
  EXPECT_EQ(plain.density_layers()[0].cols, kGridDim);
  EXPECT_EQ(plain.colour_layers()[0].cols, kShDim + 16);
}

}  // namespace
}  // namespace clnerf
