// Bf16Mlp against the float network: the same function up to bfloat16
// rounding, on the tiles where the CPU has them and on the float fallback
// everywhere; bfloat16 rounding itself; the tile layout.
#include "core/field/bf16_mlp.h"

#include <cmath>
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

// The network's widths (and odd ones: a partial block, a partial chunk).
struct Bf16Shape {
  const char* name;
  int grid_dim, density_hidden, colour_hidden, colour_layers;
};

NetworkOptions Bf16OptionsOf(const Bf16Shape& s) {
  NetworkOptions o;
  o.density_hidden = s.density_hidden;
  o.colour_hidden = s.colour_hidden;
  o.colour_hidden_layers = s.colour_layers;
  return o;
}

// The float network's h and rgb for n samples in segments of 7 (per-ray
// biases from random SH directions and the embeddings of step 0), and the
// magnitude each output's error is bounded by: the network run on
// absolute values of weights, inputs and biases.
struct Bf16Reference {
  std::vector<float> feat, geo_cols, col_cols, h, rgb, h_mag, pre_mag;
  std::vector<const float*> geo_bias, col_bias;
};

Bf16Reference MakeBf16Reference(const Network& net, const std::vector<float>& mlp, int n, uint64_t seed);

TEST(Bf16MlpTest, MatchesTheFloatNetworkWithinBf16Rounding) {
  const Bf16Shape shapes[] = {{"default", 32, 64, 64, 2}, {"odd", 24, 40, 20, 1}, {"small", 8, 16, 16, 2}};
  for (const Bf16Shape& s : shapes) {
    const Network net(Bf16OptionsOf(s), s.grid_dim);
    std::vector<float> mlp(net.num_mlp_params());
    net.InitializeMlp(mlp.data(), 11);
    for (int n : {1, 31, 33, 200}) {
      const Bf16Reference ref = MakeBf16Reference(net, mlp, n, 5 + n);
      for (bool tiles : {false, true}) {
        if (tiles && !Bf16TilesAvailable()) continue;
        const Bf16Mlp bf(net, mlp.data(), tiles);
        ASSERT_EQ(bf.tiles(), tiles);
        const int dout = net.options().density_out;
        std::vector<float> h(size_t(dout) * n), rgb(3 * size_t(n));
        bf.Density(ref.feat.data(), n, ref.geo_bias.data(), h.data());
        bf.Colour(ref.h.data(), n, ref.col_bias.data(), rgb.data());
        // Weights and inputs each within 2^-9 of their floats, hidden
        // activations too: three layers' worth, bounded by 2^-6 of the
        // magnitude (a mislaid weight is off by the magnitude itself).
        for (size_t i = 0; i < h.size(); ++i) {
          ASSERT_NEAR(h[i], ref.h[i], std::ldexp(1.0f, -6) * ref.h_mag[i] + 1e-6f)
              << s.name << " n=" << n << " tiles=" << tiles << " h " << i;
        }
        for (size_t i = 0; i < rgb.size(); ++i) {
          ASSERT_NEAR(rgb[i], ref.rgb[i], 0.25f * std::ldexp(1.0f, -6) * ref.pre_mag[i] + 1e-6f)
              << s.name << " n=" << n << " tiles=" << tiles << " rgb " << i;
        }
      }
    }
  }
}

// With tiles, the two paths compute the same rounded function: they differ
// only in summation order, and where that moves a hidden activation across
// a rounding boundary (one bfloat16 step, 2^-8).
TEST(Bf16MlpTest, TilesAndTheFallbackAgree) {
  if (!Bf16TilesAvailable()) GTEST_SKIP() << "no AMX tiles on this CPU (the fallback is checked above)";
  const Bf16Shape s = {"default", 32, 64, 64, 2};
  const Network net(Bf16OptionsOf(s), s.grid_dim);
  std::vector<float> mlp(net.num_mlp_params());
  net.InitializeMlp(mlp.data(), 12);
  const int n = 300;
  const Bf16Reference ref = MakeBf16Reference(net, mlp, n, 9);
  const Bf16Mlp tiles(net, mlp.data(), true), fallback(net, mlp.data(), false);
  std::vector<float> h1(16 * n), h2(16 * n), c1(3 * n), c2(3 * n);
  tiles.Density(ref.feat.data(), n, ref.geo_bias.data(), h1.data());
  fallback.Density(ref.feat.data(), n, ref.geo_bias.data(), h2.data());
  tiles.Colour(ref.h.data(), n, ref.col_bias.data(), c1.data());
  fallback.Colour(ref.h.data(), n, ref.col_bias.data(), c2.data());
  for (size_t i = 0; i < h1.size(); ++i) ASSERT_NEAR(h1[i], h2[i], std::ldexp(1.0f, -7) * ref.h_mag[i] + 1e-6f);
  for (size_t i = 0; i < c1.size(); ++i) ASSERT_NEAR(c1[i], c2[i], std::ldexp(1.0f, -8) * ref.pre_mag[i] + 1e-6f);
}

// Threads share one Bf16Mlp; each gets the single-threaded result.
TEST(Bf16MlpTest, ThreadsShareOneMlp) {
  const Network net(NetworkOptions{}, 32);
  std::vector<float> mlp(net.num_mlp_params());
  net.InitializeMlp(mlp.data(), 13);
  const int n = 257;
  const Bf16Reference ref = MakeBf16Reference(net, mlp, n, 4);
  const Bf16Mlp bf(net, mlp.data());
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
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  r.feat.resize(size_t(Dg) * n);
  for (float& v : r.feat) v = u(rng);
  std::vector<float> emb(net.embedding_row_size());
  net.InitializeEmbeddings(emb.data(), 1, seed + 1);
  Eigen::MatrixXf geo, app;
  net.StepBiases(mlp.data(), emb.data(), 1, &geo, &app);
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
    std::copy(geo.data(), geo.data() + Hd, r.geo_cols.data() + size_t(Hd) * k);
    net.RayColourBias(mlp.data(), sh, app.data(), r.col_cols.data() + size_t(Hc) * k);
  }
  for (int k = 0; k < nrays; ++k) {
    for (int j = seg[k]; j < seg[k + 1]; ++j) {
      r.geo_bias.push_back(r.geo_cols.data() + size_t(Hd) * k);
      r.col_bias.push_back(r.col_cols.data() + size_t(Hc) * k);
    }
  }
  NetworkWorkspace ws;
  ws.Reserve(n, o, Dg);
  net.DensityForward(mlp.data(), r.feat.data(), n, seg.data(), nrays, r.geo_cols.data(), &ws);
  r.h.assign(ws.h.data(), ws.h.data() + size_t(dout) * n);
  net.ColourForward(mlp.data(), n, seg.data(), nrays, r.col_cols.data(), &ws);
  r.rgb.assign(ws.rgb.data(), ws.rgb.data() + 3 * size_t(n));
  // Magnitudes: the same network on |weights|, |inputs| and |biases|.
  std::vector<float> abs_mlp(mlp.size()), abs_feat(r.feat.size()), abs_geo(r.geo_cols.size()),
      abs_col(r.col_cols.size());
  auto absolute = [](const std::vector<float>& a, std::vector<float>* b) {
    for (size_t i = 0; i < a.size(); ++i) (*b)[i] = std::abs(a[i]);
  };
  absolute(mlp, &abs_mlp);
  absolute(r.feat, &abs_feat);
  absolute(r.geo_cols, &abs_geo);
  absolute(r.col_cols, &abs_col);
  net.DensityForward(abs_mlp.data(), abs_feat.data(), n, seg.data(), nrays, abs_geo.data(), &ws);
  r.h_mag.assign(ws.h.data(), ws.h.data() + size_t(dout) * n);
  for (size_t i = 0; i < r.h.size(); ++i) ws.h.data()[i] = std::abs(r.h[i]);
  net.ColourForward(abs_mlp.data(), n, seg.data(), nrays, abs_col.data(), &ws);
  r.pre_mag.resize(3 * size_t(n));  // ColourForward's sigmoid undone: the magnitude before it.
  for (size_t i = 0; i < r.pre_mag.size(); ++i) {
    const float s = std::clamp(ws.rgb.data()[i], 1e-7f, 1.0f - 1e-7f);
    r.pre_mag[i] = std::log(s / (1.0f - s));
  }
  return r;
}

}  // namespace
}  // namespace clnerf
