#include "core/field/bf16_mlp.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <utility>

#include "Eigen/Core"
#include "core/field/dense_layer.h"
#include "core/field/sh_encoding.h"

// GCC spells the AMX macros __AMX_TILE__, Clang 14 __AMXTILE__.
#if (defined(__AMX_TILE__) || defined(__AMXTILE__)) && (defined(__AMX_BF16__) || defined(__AMXBF16__)) && \
    defined(__AVX512BF16__) && defined(__linux__)
#define CLNERF_AMX 1
#include <cpuid.h>
#include <immintrin.h>
#include <sys/syscall.h>
#include <unistd.h>
#else
#define CLNERF_AMX 0
#endif

namespace clnerf {

uint16_t ToBf16(float f) {
  uint32_t u;
  std::memcpy(&u, &f, sizeof u);
  if (std::isnan(f)) return uint16_t((u >> 16) | 0x40);  // Quiet NaN, sign kept.
  u += 0x7fffu + ((u >> 16) & 1u);                       // Round to nearest even.
  return uint16_t(u >> 16);
}

float FromBf16(uint16_t h) {
  const uint32_t u = uint32_t(h) << 16;
  float f;
  std::memcpy(&f, &u, sizeof f);
  return f;
}

Bf16Weights::Bf16Weights(const float* W, int rows, int cols, int ldw) : rows_(rows), cols_(cols) {
  tiles_.assign(size_t(row_blocks()) * col_chunks() * 512, 0);
  rounded_.resize(size_t(rows) * cols);
  for (int c = 0; c < cols; ++c) {
    for (int r = 0; r < rows; ++r) {
      const uint16_t h = ToBf16(W[size_t(c) * ldw + r]);
      rounded_[size_t(c) * rows + r] = FromBf16(h);
      // Tile (r / 16, c / 32): its row (c % 32) / 2 holds, for each of the
      // block's 16 outputs, the pair of inputs 2k, 2k + 1.
      const int kk = (c % 32) / 2, o = r % 16, p = c % 2;
      tiles_[(size_t(r / 16) * col_chunks() + c / 32) * 512 + kk * 32 + 2 * o + p] = h;
    }
  }
}

namespace {

bool RequestTiles() {
#if CLNERF_AMX
  const char* off = std::getenv("CLNERF_NO_AMX");
  if (off != nullptr && *off != '\0' && std::strcmp(off, "0") != 0) return false;
  unsigned a, b, c, d;
  if (!__get_cpuid_count(7, 0, &a, &b, &c, &d)) return false;
  if (!(d & (1u << 22)) || !(d & (1u << 24))) return false;  // AMX-BF16, AMX-TILE.
  if (!__get_cpuid_count(7, 1, &a, &b, &c, &d) || !(a & (1u << 5))) return false;  // AVX512-BF16.
  // Linux keeps the 8 KB tile state off until a process asks for it
  // (ARCH_REQ_XCOMP_PERM for XFEATURE_XTILEDATA); the grant is process-wide.
  constexpr long kArchReqXcompPerm = 0x1023, kXfeatureXtiledata = 18;
  return syscall(SYS_arch_prctl, kArchReqXcompPerm, kXfeatureXtiledata) == 0;
#else
  return false;
#endif
}

// The fallback: the same rounded operands through DenseForward, layer by
// layer, hidden activations rounded to bfloat16.
void FloatChain(const std::vector<Bf16Weights>& chain, const float* in, int n, const float* const* bias, float* out) {
  thread_local std::vector<float> a, b;
  const int in_dim = chain.front().cols();
  a.resize(size_t(in_dim) * n);
  for (size_t i = 0; i < a.size(); ++i) a[i] = FromBf16(ToBf16(in[i]));
  for (size_t l = 0; l < chain.size(); ++l) {
    const Bf16Weights& W = chain[l];
    const bool last = l + 1 == chain.size();
    float* y = last ? out : (b.resize(size_t(W.rows()) * n), b.data());
    DenseForward(W.rounded(), W.rows(), W.cols(), W.rows(), a.data(), W.cols(), n, l == 0 ? bias : nullptr,
                 last ? Activation::kNone : Activation::kRelu, y, W.rows());
    if (last) break;
    for (float& v : b) v = FromBf16(ToBf16(v));
    std::swap(a, b);
  }
}

#if CLNERF_AMX
// Eight tiles of 16 rows x 64 bytes: 0-1 two groups of 16 samples' inputs
// (a 32-value chunk each), 2-3 two 16-output blocks' weights for that
// chunk, 4-7 the four accumulators.
struct alignas(64) TileConfig {
  uint8_t palette = 1;
  uint8_t start_row = 0;
  uint8_t reserved[14] = {};
  uint16_t colsb[16] = {};
  uint8_t rows[16] = {};
};

constexpr int kGroup = 32;  // Samples per pass through the layers.

// Samples in[0..g) (dim floats each) as bfloat16 rows of `width` values
// (zero beyond dim).
void ConvertInputs(const float* in, int dim, int g, int width, uint16_t* rows) {
  for (int s = 0; s < g; ++s) {
    const float* src = in + size_t(s) * dim;
    for (int c = 0; c < width; c += 32) {
      const int lo_n = std::clamp(dim - c, 0, 16), hi_n = std::clamp(dim - c - 16, 0, 16);
      const __m512 lo = _mm512_maskz_loadu_ps(__mmask16((1u << lo_n) - 1u), src + c);
      const __m512 hi = _mm512_maskz_loadu_ps(__mmask16((1u << hi_n) - 1u), src + c + 16);
      _mm512_storeu_si512(rows + size_t(s) * width + c, (__m512i)_mm512_cvtne2ps_pbh(hi, lo));
    }
  }
}

// Where a layer's outputs for a group of samples go: the next layer's
// bfloat16 rows (through the ReLU), or the float output (no activation).
struct Sink {
  uint16_t* next = nullptr;  // Rows of next_width values, or null for the output.
  int next_width = 0;
  float* out = nullptr;  // out_rows values per sample.
  int out_rows = 0;
};

__mmask16 FirstLanes(int count) { return __mmask16(count >= 16 ? 0xffffu : count <= 0 ? 0u : (1u << count) - 1u); }

// Blocks b0 and b0 + 1 (acc: group 0's and group 1's tiles of block b0,
// then of b0 + 1; rows past the layer's outputs are 0, their weights
// being 0) of g samples: plus bias, then into the next layer's rows as
// bfloat16 through the ReLU (32 values, a missing second block as 0s), or
// into the float output as they are.
void Epilogue(float (*acc)[256], int g, int r0, int rows, const float* const* bias, const Sink& sink) {
  const __mmask16 m0 = FirstLanes(rows - r0), m1 = FirstLanes(rows - r0 - 16);
  for (int s = 0; s < g; ++s) {
    const int row = 16 * (s % 16), grp = s / 16;
    __m512 v0 = _mm512_load_ps(acc[grp] + row);
    __m512 v1 = m1 ? _mm512_load_ps(acc[2 + grp] + row) : _mm512_setzero_ps();
    const float* b = bias != nullptr ? bias[s] : nullptr;
    if (b != nullptr) {
      v0 = _mm512_add_ps(v0, _mm512_maskz_loadu_ps(m0, b + r0));
      v1 = _mm512_add_ps(v1, _mm512_maskz_loadu_ps(m1, b + r0 + 16));
    }
    if (sink.next != nullptr) {
      // ReLU on the bfloat16 bits: a negative value's sign bit makes it a negative int16.
      const __m512i h = _mm512_max_epi16((__m512i)_mm512_cvtne2ps_pbh(v1, v0), _mm512_setzero_si512());
      _mm512_storeu_si512(sink.next + size_t(s) * sink.next_width + r0, h);
    } else {
      float* o = sink.out + size_t(s) * sink.out_rows + r0;
      _mm512_mask_storeu_ps(o, m0, v0);
      if (m1) _mm512_mask_storeu_ps(o + 16, m1, v1);
    }
  }
}

// One layer on one group of 32 samples (rows of `width` bfloat16 in `in`).
void TileLayer(const Bf16Weights& W, const uint16_t* in, int width, int g, const float* const* bias,
               const Sink& sink) {
  alignas(64) float acc[4][256];
  const size_t stride = size_t(width) * sizeof(uint16_t);
  const uint16_t* in1 = in + size_t(16) * width;
  const int blocks = W.row_blocks(), chunks = W.col_chunks();
  if (chunks == 1) {  // The inputs stay in tiles 0-1 for every block.
    _tile_loadd(0, in, stride);
    _tile_loadd(1, in1, stride);
  }
  for (int b0 = 0; b0 < blocks; b0 += 2) {
    const bool two = b0 + 1 < blocks;
    _tile_zero(4);
    _tile_zero(5);
    _tile_zero(6);
    _tile_zero(7);
    for (int c = 0; c < chunks; ++c) {
      if (chunks > 1) {
        _tile_loadd(0, in + c * 32, stride);
        _tile_loadd(1, in1 + c * 32, stride);
      }
      _tile_loadd(2, W.tile(b0, c), 64);
      _tile_dpbf16ps(4, 0, 2);
      _tile_dpbf16ps(5, 1, 2);
      if (!two) continue;
      _tile_loadd(3, W.tile(b0 + 1, c), 64);
      _tile_dpbf16ps(6, 0, 3);
      _tile_dpbf16ps(7, 1, 3);
    }
    _tile_stored(4, acc[0], 64);
    _tile_stored(5, acc[1], 64);
    _tile_stored(6, acc[2], 64);
    _tile_stored(7, acc[3], 64);
    Epilogue(acc, g, b0 * 16, W.rows(), bias, sink);
  }
}

// The chain over n samples in slabs of kSlab: each layer runs over the
// whole slab before the next starts, so a tile load of a layer's inputs
// does not wait on the stores that just wrote them (a slab's activations,
// 2 x 128 x 64 bfloat16, stay in L1).
void TileChain(const std::vector<Bf16Weights>& chain, const float* in, int n, const float* const* bias, float* out) {
  constexpr int kSlab = 128;
  int width = 0;
  for (const Bf16Weights& W : chain) width = std::max(width, W.col_chunks() * 32);
  thread_local std::vector<uint16_t> buf;
  buf.assign(size_t(2) * kSlab * width, 0);  // Rows past the samples stay 0.
  TileConfig cfg;
  for (int t = 0; t < 8; ++t) {
    cfg.rows[t] = 16;
    cfg.colsb[t] = 64;
  }
  _tile_loadconfig(&cfg);
  const int in_dim = chain.front().cols(), out_rows = chain.back().rows();
  for (int j0 = 0; j0 < n; j0 += kSlab) {
    const int slab = std::min(kSlab, n - j0);
    uint16_t* cur = buf.data();
    uint16_t* nxt = cur + size_t(kSlab) * width;
    ConvertInputs(in + size_t(j0) * in_dim, in_dim, slab, width, cur);
    for (size_t l = 0; l < chain.size(); ++l) {
      const bool last = l + 1 == chain.size();
      for (int g0 = 0; g0 < slab; g0 += kGroup) {
        Sink sink;
        if (!last) {
          sink.next = nxt + size_t(g0) * width;
          sink.next_width = width;
        } else {
          sink.out = out + size_t(j0 + g0) * out_rows;
          sink.out_rows = out_rows;
        }
        const float* const* b = l == 0 && bias != nullptr ? bias + j0 + g0 : nullptr;
        TileLayer(chain[l], cur + size_t(g0) * width, width, std::min(kGroup, slab - g0), b, sink);
      }
      std::swap(cur, nxt);
    }
  }
  _tile_release();
}
#endif  // CLNERF_AMX

}  // namespace

bool Bf16TilesAvailable() {
  static const bool ok = RequestTiles();
  return ok;
}

Bf16Mlp::Bf16Mlp(const Network& net, const float* mlp, bool tiles) : tiles_(tiles && Bf16TilesAvailable()) {
  const auto& d = net.density_layers();
  const auto& c = net.colour_layers();
  // First layers: only the per-sample inputs' columns (hash features; h);
  // the embeddings' and SH's products come as the per-sample bias.
  density_.emplace_back(mlp + d[0].offset, d[0].rows, net.grid_dim(), d[0].rows);
  for (size_t k = 1; k < d.size(); ++k) density_.emplace_back(mlp + d[k].offset, d[k].rows, d[k].cols, d[k].rows);
  colour_.emplace_back(mlp + c[0].offset + size_t(kShDim) * c[0].rows, c[0].rows, net.options().density_out,
                       c[0].rows);
  for (size_t k = 1; k < c.size(); ++k) colour_.emplace_back(mlp + c[k].offset, c[k].rows, c[k].cols, c[k].rows);
}

void Bf16Mlp::Run(const std::vector<Bf16Weights>& chain, const float* in, int n, const float* const* bias,
                  float* out) const {
  if (n <= 0) return;
#if CLNERF_AMX
  if (tiles_) {
    TileChain(chain, in, n, bias, out);
    return;
  }
#endif
  FloatChain(chain, in, n, bias, out);
}

void Bf16Mlp::Density(const float* feat, int n, const float* const* bias, float* h) const {
  Run(density_, feat, n, bias, h);
}

void Bf16Mlp::Colour(const float* h, int n, const float* const* bias, float* rgb) const {
  Run(colour_, h, n, bias, rgb);
  Eigen::Map<Eigen::ArrayXf> a(rgb, 3 * Eigen::Index(n));
  a = (1.0f + (-a).exp()).inverse();  // Vectorised, as ColourForward's.
}

}  // namespace clnerf
