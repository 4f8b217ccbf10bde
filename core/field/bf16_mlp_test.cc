// Bf16Mlp against the float network: the same function up to bfloat16
// rounding, on the tiles where the CPU has them and on the float fallback
// everywhere; bfloat16 rounding itself; the tile layout.
#include "core/field/bf16_mlp.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <limits>
#include <random>
#include <thread>
#include <vector>

#include "core/field/sh_encoding.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(Bf16Test, RoundsToNearestEven) {
  EXPECT_EQ(ToBf16(1.0f), 0x3f80);
  EXPECT_EQ(ToBf16(-2.0f), 0xc000);
  EXPECT_EQ(ToBf16(1.0f + std::ldexp(1.0f, -8)), 0x3f80);      // Halfway: to the even 1.0.
  EXPECT_EQ(ToBf16(1.0f + 3 * std::ldexp(1.0f, -8)), 0x3f82);  // Halfway: to the even neighbour above.
  EXPECT_EQ(ToBf16(1.0f + 0.6f * std::ldexp(1.0f, -7)), 0x3f81);
  EXPECT_EQ(ToBf16(std::numeric_limits<float>::infinity()), 0x7f80);
  EXPECT_TRUE(std::isnan(FromBf16(ToBf16(std::numeric_limits<float>::quiet_NaN()))));
  EXPECT_FLOAT_EQ(FromBf16(ToBf16(0.15625f)), 0.15625f);  // Exact in 8 bits.
}

TEST(Bf16WeightsTest, TilesHoldInputPairsPerOutput) {
  const int rows = 20, cols = 40, ldw = 23;  // Two blocks (one partial), two chunks (one partial).
  std::vector<float> W(size_t(ldw) * cols);
  for (int c = 0; c < cols; ++c) {
    for (int r = 0; r < ldw; ++r) W[size_t(c) * ldw + r] = std::ldexp(float(2 * r + 1), c - 20);  // Exact in bfloat16, one per (r, c).
  }
  const Bf16Weights p(W.data(), rows, cols, ldw);
  ASSERT_EQ(p.row_blocks(), 2);
  ASSERT_EQ(p.col_chunks(), 2);
  for (int b = 0; b < 2; ++b) {
    for (int ch = 0; ch < 2; ++ch) {
      for (int k = 0; k < 16; ++k) {
        for (int o = 0; o < 16; ++o) {
          for (int q = 0; q < 2; ++q) {
            const int r = b * 16 + o, c = ch * 32 + 2 * k + q;
            const float want = r < rows && c < cols ? W[size_t(c) * ldw + r] : 0.0f;
            ASSERT_EQ(FromBf16(p.tile(b, ch)[k * 32 + 2 * o + q]), want) << b << " " << ch << " " << k << " " << o;
          }
        }
      }
    }
  }
  EXPECT_EQ(p.rounded()[size_t(7) * rows + 3], W[size_t(7) * ldw + 3]);
}

// The network's widths and odd ones: partial blocks and chunks, a deeper
// density MLP, no embeddings (no density bias).
struct Bf16Shape {
  const char* name;
  int grid_dim, density_hidden, density_layers, colour_hidden, colour_layers;
  bool embeddings;
};

NetworkOptions Bf16OptionsOf(const Bf16Shape& s) {
  NetworkOptions o;
  o.density_hidden = s.density_hidden;
  o.density_hidden_layers = s.density_layers;
  o.colour_hidden = s.colour_hidden;
  o.colour_hidden_layers = s.colour_layers;
  o.use_embeddings = s.embeddings;
  return o;
}

const Bf16Shape kShapes[] = {{"default", 32, 64, 1, 64, 2, true},
                             {"odd", 24, 40, 1, 20, 1, true},
                             {"deep", 32, 48, 2, 64, 2, true},
                             {"no-embed", 16, 16, 1, 16, 2, false}};

// One layer of an MLP as the network lays it out (column-major, leading
// dimension ld).
struct LayerRef {
  const float* W;
  int rows, cols, ld;
};

// What an MLP's outputs should be, per sample (rows x n, column per sample):
// `emulated`, the function Bf16Mlp computes (weights and layer inputs
// rounded to bfloat16, sums in double, hidden activations through the ReLU
// and rounded to bfloat16); `last_mag`, the last layer on the absolute
// values of its rounded weights and inputs (how far one bfloat16 step in
// every input moves an output, times 2^8); `abs_mag`, the whole MLP on
// absolute values of its weights, inputs and biases (bounds the error
// against float).
struct MlpRef {
  std::vector<double> emulated, last_mag, abs_mag;
};

MlpRef EmulateMlp(const std::vector<LayerRef>& layers, const float* in, int n, const float* const* bias) {
  MlpRef r;
  const int out_rows = layers.back().rows;
  for (int j = 0; j < n; ++j) {
    std::vector<double> x(in + size_t(j) * layers[0].cols, in + size_t(j + 1) * layers[0].cols), ax(x);
    for (double& v : x) v = FromBf16(ToBf16(float(v)));
    for (double& v : ax) v = std::abs(v);
    for (size_t l = 0; l < layers.size(); ++l) {
      const LayerRef& L = layers[l];
      const bool last = l + 1 == layers.size();
      std::vector<double> y(L.rows), ay(L.rows), my(L.rows);
      for (int o = 0; o < L.rows; ++o) {
        const float b = l == 0 && bias != nullptr && bias[j] != nullptr ? bias[j][o] : 0.0f;
        double sum = b, abs_sum = std::abs(b), mag = std::abs(b);
        for (int c = 0; c < L.cols; ++c) {
          const double w = FromBf16(ToBf16(L.W[size_t(c) * L.ld + o]));
          sum += w * x[c];
          mag += std::abs(w * x[c]);
          abs_sum += std::abs(L.W[size_t(c) * L.ld + o]) * ax[c];
        }
        y[o] = last ? sum : FromBf16(ToBf16(float(std::max(sum, 0.0))));
        ay[o] = abs_sum;
        my[o] = mag;
      }
      x.swap(y);
      ax.swap(ay);
      if (last) r.last_mag.insert(r.last_mag.end(), my.begin(), my.end());
    }
    r.emulated.insert(r.emulated.end(), x.begin(), x.end());
    r.abs_mag.insert(r.abs_mag.end(), ax.begin(), ax.end());
  }
  EXPECT_EQ(r.emulated.size(), size_t(out_rows) * n);
  return r;
}

// n samples in rays of 7 over three time steps: random features, view
// directions and embeddings (so every ray has its own first-layer biases),
// the float network's h and rgb, and each MLP emulated.
struct Bf16Reference {
  std::vector<float> feat, geo_cols, col_cols, h, rgb;
  std::vector<const float*> geo_bias, col_bias;  // Per sample; geo_bias empty without embeddings.
  MlpRef density, colour;  // The colour MLP's are before the sigmoid, from the float h.
};

Bf16Reference MakeBf16Reference(const Network& net, const std::vector<float>& mlp, int n, uint64_t seed);

double Sigmoid(double x) { return 1.0 / (1.0 + std::exp(-x)); }

// Against the function it computes: every output within a bfloat16 step of
// its last layer's inputs (2^-7 of last_mag: sums in float round a hidden
// value to the neighbouring bfloat16 now and then), and on average within
// 2^-12 of it (a kernel that drops one input column of 64 is off by ~2^-6).
void ExpectEmulated(const float* got, const MlpRef& ref, bool sigmoid, const std::string& what) {
  double diff = 0.0, mag = 0.0;
  for (size_t i = 0; i < ref.emulated.size(); ++i) {
    const double want = sigmoid ? Sigmoid(ref.emulated[i]) : ref.emulated[i];
    const double d = std::abs(got[i] - want) / (sigmoid ? 0.25 : 1.0);  // The sigmoid's slope is at most 1/4.
    ASSERT_LE(d, std::ldexp(1.0, -7) * ref.last_mag[i] + 1e-6) << what << " output " << i;
    diff += d;
    mag += ref.last_mag[i];
  }
  EXPECT_LE(diff, std::ldexp(1.0, -12) * mag) << what;
}

TEST(Bf16MlpTest, ComputesTheRoundedFunctionCloseToTheFloatNetwork) {
  for (const Bf16Shape& s : kShapes) {
    const Network net(Bf16OptionsOf(s), s.grid_dim);
    std::vector<float> mlp(net.num_mlp_params());
    net.InitializeMlp(mlp.data(), 11);
    for (int n : {1, 31, 33, 200}) {
      const Bf16Reference ref = MakeBf16Reference(net, mlp, n, 5 + n);
      for (bool tiles : {false, true}) {
        if (tiles && !Bf16TilesAvailable()) continue;
        const std::string what = std::string(s.name) + " n=" + std::to_string(n) + (tiles ? " tiles" : " fallback");
        const Bf16Mlp bf(net, mlp.data(), tiles);
        ASSERT_EQ(bf.tiles(), tiles);
        std::vector<float> h(size_t(net.options().density_out) * n), rgb(3 * size_t(n));
        bf.Density(ref.feat.data(), n, ref.geo_bias.empty() ? nullptr : ref.geo_bias.data(), h.data());
        bf.Colour(ref.h.data(), n, ref.col_bias.data(), rgb.data());
        ExpectEmulated(h.data(), ref.density, false, what + " h");
        ExpectEmulated(rgb.data(), ref.colour, true, what + " rgb");
        // Against float: each weight and input within 2^-9 of its float,
        // hidden activations too, over at most four layers: within 2^-6 of
        // the absolute network's output.
        for (size_t i = 0; i < h.size(); ++i) {
          ASSERT_NEAR(h[i], ref.h[i], std::ldexp(1.0, -6) * ref.density.abs_mag[i] + 1e-6) << what << " h " << i;
        }
        for (size_t i = 0; i < rgb.size(); ++i) {
          ASSERT_NEAR(rgb[i], ref.rgb[i], 0.25 * std::ldexp(1.0, -6) * ref.colour.abs_mag[i] + 1e-6)
              << what << " rgb " << i;
        }
      }
    }
  }
}

// Threads share one Bf16Mlp; each gets the single-threaded result.
TEST(Bf16MlpTest, ThreadsShareOneMlp) {
  const Network net(NetworkOptions{}, 32);
  std::vector<float> mlp(net.num_mlp_params());
  net.InitializeMlp(mlp.data(), 13);
  const int n = 257;
  const Bf16Reference ref = MakeBf16Reference(net, mlp, n, 4);
  const Bf16Mlp bf(net, mlp.data());
  RecordProperty("amx_tiles", bf.tiles() ? "yes" : "no");
  std::vector<float> want(16 * n);
  bf.Density(ref.feat.data(), n, ref.geo_bias.data(), want.data());
  std::vector<std::vector<float>> got(4, std::vector<float>(16 * n));
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int k = 0; k < 10; ++k) bf.Density(ref.feat.data(), n, ref.geo_bias.data(), got[t].data());
    });
  }
  for (auto& t : threads) t.join();
  for (int t = 0; t < 4; ++t) {
    for (size_t i = 0; i < want.size(); ++i) ASSERT_NEAR(got[t][i], want[i], 1e-5f * (1.0f + std::abs(want[i])));
  }
}

Bf16Reference MakeBf16Reference(const Network& net, const std::vector<float>& mlp, int n, uint64_t seed) {
  Bf16Reference r;
  const NetworkOptions& o = net.options();
  const int Dg = net.grid_dim(), Hd = o.density_hidden, Hc = o.colour_hidden, dout = o.density_out;
  constexpr int kSteps = 3;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  r.feat.resize(size_t(Dg) * n);
  for (float& v : r.feat) v = u(rng);
  std::vector<float> emb(size_t(kSteps) * net.embedding_row_size());
  net.InitializeEmbeddings(emb.data(), kSteps, seed + 1);
  Eigen::MatrixXf geo, app;
  net.StepBiases(mlp.data(), emb.data(), kSteps, &geo, &app);
  std::vector<int> seg = {0};
  while (seg.back() < n) seg.push_back(std::min(n, seg.back() + 7));
  const int nrays = int(seg.size()) - 1;
  r.geo_cols.resize(size_t(Hd) * nrays);
  r.col_cols.resize(size_t(Hc) * nrays);
  for (int k = 0; k < nrays; ++k) {
    Eigen::Vector3f d(u(rng), u(rng), u(rng));
    d.normalize();
    float sh[kShDim];
    ShEncode(d.x(), d.y(), d.z(), sh);
    std::copy(geo.col(k % kSteps).data(), geo.col(k % kSteps).data() + Hd, r.geo_cols.data() + size_t(Hd) * k);
    net.RayColourBias(mlp.data(), sh, app.col(k % kSteps).data(), r.col_cols.data() + size_t(Hc) * k);
  }
  for (int k = 0; k < nrays; ++k) {
    for (int j = seg[k]; j < seg[k + 1]; ++j) {
      if (o.geo_dim() > 0) r.geo_bias.push_back(r.geo_cols.data() + size_t(Hd) * k);
      r.col_bias.push_back(r.col_cols.data() + size_t(Hc) * k);
    }
  }
  NetworkWorkspace ws;
  ws.Reserve(n, o, Dg);
  net.DensityForward(mlp.data(), r.feat.data(), n, seg.data(), nrays, r.geo_cols.data(), &ws);
  r.h.assign(ws.h.data(), ws.h.data() + size_t(dout) * n);
  net.ColourForward(mlp.data(), n, seg.data(), nrays, r.col_cols.data(), &ws);
  r.rgb.assign(ws.rgb.data(), ws.rgb.data() + 3 * size_t(n));
  // The two MLPs layer by layer, as Bf16Mlp packs them (first layers: the
  // per-sample inputs' columns only; the rest comes as the bias).
  const auto& dl = net.density_layers();
  const auto& cl = net.colour_layers();
  std::vector<LayerRef> density = {{mlp.data() + dl[0].offset, dl[0].rows, Dg, dl[0].rows}};
  for (size_t k = 1; k < dl.size(); ++k) density.push_back({mlp.data() + dl[k].offset, dl[k].rows, dl[k].cols, dl[k].rows});
  std::vector<LayerRef> colour = {{mlp.data() + cl[0].offset + size_t(kShDim) * cl[0].rows, cl[0].rows, dout, cl[0].rows}};
  for (size_t k = 1; k < cl.size(); ++k) colour.push_back({mlp.data() + cl[k].offset, cl[k].rows, cl[k].cols, cl[k].rows});
  r.density = EmulateMlp(density, r.feat.data(), n, r.geo_bias.empty() ? nullptr : r.geo_bias.data());
  r.colour = EmulateMlp(colour, r.h.data(), n, r.col_bias.data());
  return r;
}

}  // namespace
}  // namespace clnerf
