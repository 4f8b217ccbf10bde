#include "core/field/hash_grid.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#if defined(__AVX512F__)
#include <immintrin.h>
#endif

#include "absl/strings/str_format.h"

namespace clnerf {

absl::Status HashGridOptions::Validate() const {
  if (levels < 1 || levels > 32) return absl::InvalidArgumentError("hash grid: levels must be in [1, 32]");
  if (features_per_level != 2) {
    return absl::InvalidArgumentError("hash grid: only features_per_level = 2 is supported");
  }
  if (log2_table_size < 10 || log2_table_size > 24) {
    return absl::InvalidArgumentError("hash grid: log2_table_size must be in [10, 24]");
  }
  if (base_resolution < 2) return absl::InvalidArgumentError("hash grid: base_resolution must be >= 2");
  if (finest_resolution < base_resolution) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "hash grid: finest_resolution (%d) < base_resolution (%d)", finest_resolution, base_resolution));
  }
  return absl::OkStatus();
}

HashGrid::HashGrid(const HashGridOptions& options) : options_(options) {
  const int L = options.levels;
  const double growth =
      L > 1 ? std::exp(std::log(double(options.finest_resolution) / options.base_resolution) / (L - 1))
            : 1.0;
  const size_t max_size = size_t(1) << options.log2_table_size;
  size_t offset = 0;
  for (int l = 0; l < L; ++l) {
    // Upstream: scale = 2^(l*log2 b) * base - 1, resolution = ceil(scale) + 1.
    const double scale = std::exp2(l * std::log2(growth)) * options.base_resolution - 1.0;
    const uint32_t res = uint32_t(std::ceil(scale)) + 1;
    // Dense levels use stride res + 1 so that the upper corner of a point at
    // the box face (x = scale + 0.5 rounds down to res - 1) stays in range
    // without tiny-cuda-nn's trailing modulo.
    const size_t stride = size_t(res) + 1;
    const size_t dense_size = (stride * stride * stride + 7) / 8 * 8;
    const bool dense = dense_size <= max_size;
    scales_.push_back(float(scale));
    resolutions_.push_back(res);
    strides_.push_back(uint32_t(stride));
    dense_.push_back(dense);
    sizes_.push_back(dense ? dense_size : max_size);
    offsets_.push_back(offset);
    offset += sizes_.back();
  }
  total_entries_ = offset;
}

void HashGrid::Initialize(float* params, uint64_t seed) const {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1e-4f, 1e-4f);
  for (size_t i = 0; i < num_params(); ++i) params[i] = u(rng);
}

namespace {

struct Corners {
  uint32_t base[3];
  float frac[3];
};

inline Corners Locate(float scale, const float* p) {
  Corners c;
  for (int d = 0; d < 3; ++d) {
    const float x = p[d] * scale + 0.5f;
    const float f = std::floor(x);
    c.base[d] = uint32_t(int(f));
    c.frac[d] = x - f;
  }
  return c;
}

}  // namespace

namespace {

// Corner indices and trilinear weights of one sample at one level. Dense and
// hashed levels are separate instantiations so the inner loop has no branch.
template <bool kDense>
inline void CornerSetup(float scale, uint32_t stride, uint32_t mask, const float* p, uint32_t* idx,
                        float* w) {
  float fr[3];
  uint32_t b[3];
  for (int d = 0; d < 3; ++d) {
    const float x = p[d] * scale + 0.5f;
    const float f = std::floor(x);
    b[d] = uint32_t(int(f));
    fr[d] = x - f;
  }
  uint32_t ix[2], iy[2], iz[2];
  if constexpr (kDense) {
    ix[0] = b[0];
    ix[1] = b[0] + 1;
    iy[0] = b[1] * stride;
    iy[1] = iy[0] + stride;
    iz[0] = b[2] * stride * stride;
    iz[1] = iz[0] + stride * stride;
  } else {
    ix[0] = b[0];
    ix[1] = b[0] + 1;
    iy[0] = b[1] * 2654435761u;
    iy[1] = iy[0] + 2654435761u;
    iz[0] = b[2] * 805459861u;
    iz[1] = iz[0] + 805459861u;
  }
  const float wx[2] = {1.0f - fr[0], fr[0]}, wy[2] = {1.0f - fr[1], fr[1]}, wz[2] = {1.0f - fr[2], fr[2]};
  for (int k = 0; k < 8; ++k) {
    const int a = k & 1, bb = (k >> 1) & 1, c = (k >> 2) & 1;
    if constexpr (kDense) {
      idx[k] = ix[a] + iy[bb] + iz[c];
    } else {
      idx[k] = (ix[a] ^ iy[bb] ^ iz[c]) & mask;
    }
    w[k] = wx[a] * wy[bb] * wz[c];
  }
}

// Samples are processed in small batches: corner indices of the whole batch
// are computed (and their cache lines prefetched) before any table entry is
// read, so the random table reads of one batch overlap in the memory system.
constexpr int kBatch = 16;

template <bool kDense>
void EncodeLevel(const float* table, float scale, uint32_t stride, uint32_t mask, const float* pos, int n,
                 int out_stride, float* out) {
  uint32_t idx[kBatch][8];
  float w[kBatch][8];
  for (int i0 = 0; i0 < n; i0 += kBatch) {
    const int m = std::min(kBatch, n - i0);
    for (int b = 0; b < m; ++b) {
      CornerSetup<kDense>(scale, stride, mask, pos + 3 * (i0 + b), idx[b], w[b]);
      if constexpr (!kDense) {
        for (int k = 0; k < 8; ++k) __builtin_prefetch(table + 2 * size_t(idx[b][k]));
      }
    }
    for (int b = 0; b < m; ++b) {
      float f0 = 0, f1 = 0;
      for (int k = 0; k < 8; ++k) {
        const float* e = table + 2 * size_t(idx[b][k]);
        f0 += w[b][k] * e[0];
        f1 += w[b][k] * e[1];
      }
      out[size_t(i0 + b) * out_stride] = f0;
      out[size_t(i0 + b) * out_stride + 1] = f1;
    }
  }
}

#if defined(__AVX512F__)
// 16 samples at a time (positions as three coordinate arrays): the corner
// indices and weights in vector registers, each corner's entries fetched by
// two 8-lane 64-bit gathers (an entry is a pair of floats), and the sums kept
// in (feature 0, feature 1) pair order, which is the output order. Measured
// on 4096 ray-ordered samples with 2^16-entry levels: 5.0 vs 10.1 ns per
// sample and level for the scalar loop (whose time goes mostly into the
// per-corner index and weight arithmetic); about 1.5x inside a fox_8 render,
// where more of the table reads miss the caches.
template <bool kDense>
void EncodeLevel16(const float* table, float scale, uint32_t stride, uint32_t mask, const float* px,
                   const float* py, const float* pz, int n, int out_stride, float* out) {
  const __m512 vscale = _mm512_set1_ps(scale), half = _mm512_set1_ps(0.5f), one = _mm512_set1_ps(1.0f);
  const __m512i ky = _mm512_set1_epi32(int(kDense ? stride : 2654435761u));
  const __m512i kz = _mm512_set1_epi32(int(kDense ? stride * stride : 805459861u));
  const __m512i vmask = _mm512_set1_epi32(int(mask)), vone = _mm512_set1_epi32(1);
  // Lane 2s and 2s+1 of a pair-ordered vector belong to sample s (low half)
  // or sample 8+s (high half).
  const __m512i pairs_lo = _mm512_set_epi32(7, 7, 6, 6, 5, 5, 4, 4, 3, 3, 2, 2, 1, 1, 0, 0);
  const __m512i pairs_hi = _mm512_add_epi32(pairs_lo, _mm512_set1_epi32(8));
  const double* entries = reinterpret_cast<const double*>(table);
  alignas(64) double lo_out[8], hi_out[8];
  for (int i0 = 0; i0 + 16 <= n; i0 += 16) {
    __m512 frac[3];
    __m512i base[3];
    const float* p[3] = {px + i0, py + i0, pz + i0};
    for (int d = 0; d < 3; ++d) {
      const __m512 x = _mm512_fmadd_ps(_mm512_loadu_ps(p[d]), vscale, half);
      const __m512 f = _mm512_roundscale_ps(x, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
      base[d] = _mm512_cvttps_epi32(f);
      frac[d] = _mm512_sub_ps(x, f);
    }
    const __m512i ix[2] = {base[0], _mm512_add_epi32(base[0], vone)};
    const __m512i iy0 = _mm512_mullo_epi32(base[1], ky), iz0 = _mm512_mullo_epi32(base[2], kz);
    const __m512i iy[2] = {iy0, _mm512_add_epi32(iy0, ky)};
    const __m512i iz[2] = {iz0, _mm512_add_epi32(iz0, kz)};
    const __m512 wx[2] = {_mm512_sub_ps(one, frac[0]), frac[0]};
    const __m512 wy[2] = {_mm512_sub_ps(one, frac[1]), frac[1]};
    const __m512 wz[2] = {_mm512_sub_ps(one, frac[2]), frac[2]};
    __m512 acc_lo = _mm512_setzero_ps(), acc_hi = _mm512_setzero_ps();
    for (int k = 0; k < 8; ++k) {
      const int a = k & 1, b = (k >> 1) & 1, c = (k >> 2) & 1;
      __m512i idx;
      if constexpr (kDense) {
        idx = _mm512_add_epi32(_mm512_add_epi32(ix[a], iy[b]), iz[c]);
      } else {
        idx = _mm512_and_si512(_mm512_xor_si512(_mm512_xor_si512(ix[a], iy[b]), iz[c]), vmask);
      }
      const __m512 w = _mm512_mul_ps(_mm512_mul_ps(wx[a], wy[b]), wz[c]);
      const __m512 e_lo = _mm512_castpd_ps(_mm512_i32gather_pd(_mm512_castsi512_si256(idx), entries, 8));
      const __m512 e_hi = _mm512_castpd_ps(_mm512_i32gather_pd(_mm512_extracti64x4_epi64(idx, 1), entries, 8));
      acc_lo = _mm512_fmadd_ps(_mm512_permutexvar_ps(pairs_lo, w), e_lo, acc_lo);
      acc_hi = _mm512_fmadd_ps(_mm512_permutexvar_ps(pairs_hi, w), e_hi, acc_hi);
    }
    _mm512_store_pd(lo_out, _mm512_castps_pd(acc_lo));
    _mm512_store_pd(hi_out, _mm512_castps_pd(acc_hi));
    for (int s = 0; s < 8; ++s) {
      std::memcpy(out + size_t(i0 + s) * out_stride, &lo_out[s], sizeof(double));
      std::memcpy(out + size_t(i0 + 8 + s) * out_stride, &hi_out[s], sizeof(double));
    }
  }
}
#endif  // __AVX512F__

template <bool kDense>
void BackwardLevelImpl(float* gtable, float scale, uint32_t stride, uint32_t mask, const float* pos,
                       const float* dout, int n, int in_stride, size_t offset, uint8_t* touched,
                       std::vector<uint32_t>* touched_list) {
  uint32_t idx[kBatch][8];
  float w[kBatch][8];
  float g[kBatch][2];
  for (int i0 = 0; i0 < n; i0 += kBatch) {
    const int m = std::min(kBatch, n - i0);
    int cnt = 0;
    for (int b = 0; b < m; ++b) {
      const float g0 = dout[size_t(i0 + b) * in_stride], g1 = dout[size_t(i0 + b) * in_stride + 1];
      if (g0 == 0.0f && g1 == 0.0f) continue;
      g[cnt][0] = g0;
      g[cnt][1] = g1;
      CornerSetup<kDense>(scale, stride, mask, pos + 3 * (i0 + b), idx[cnt], w[cnt]);
      if constexpr (!kDense) {
        for (int k = 0; k < 8; ++k) __builtin_prefetch(gtable + 2 * size_t(idx[cnt][k]), 1);
      }
      ++cnt;
    }
    for (int b = 0; b < cnt; ++b) {
      for (int k = 0; k < 8; ++k) {
        float* e = gtable + 2 * size_t(idx[b][k]);
        e[0] += w[b][k] * g[b][0];
        e[1] += w[b][k] * g[b][1];
      }
      if (touched != nullptr) {
        for (int k = 0; k < 8; ++k) {
          const size_t global = offset + idx[b][k];
          if (!touched[global]) {
            touched[global] = 1;
            touched_list->push_back(uint32_t(global));
          }
        }
      }
    }
  }
}

}  // namespace

void HashGrid::Encode(const float* params, const float* pos, int n, float* out) const {
  if (n == 0) return;  // `out` may be null for an empty batch.
  const int D = output_dim();
  int done = 0;  // Samples encoded by the vector path.
#if defined(__AVX512F__)
  done = n / 16 * 16;
  if (done > 0) {
    thread_local std::vector<float> soa;
    soa.resize(3 * size_t(done));
    float* px = soa.data();
    float* py = px + done;
    float* pz = py + done;
    for (int i = 0; i < done; ++i) {
      px[i] = pos[3 * i];
      py[i] = pos[3 * i + 1];
      pz[i] = pos[3 * i + 2];
    }
    for (int l = 0; l < options_.levels; ++l) {
      const float* table = params + offsets_[l] * kFeatures;
      const uint32_t mask = uint32_t(sizes_[l]) - 1u;
      if (dense_[l]) {
        EncodeLevel16<true>(table, scales_[l], strides_[l], mask, px, py, pz, done, D, out + l * kFeatures);
      } else {
        EncodeLevel16<false>(table, scales_[l], strides_[l], mask, px, py, pz, done, D, out + l * kFeatures);
      }
    }
  }
#endif
  if (done == n) return;
  const float* rest = pos + 3 * size_t(done);
  float* rest_out = out + size_t(done) * D;
  for (int l = 0; l < options_.levels; ++l) {
    const float* table = params + offsets_[l] * kFeatures;
    const uint32_t mask = uint32_t(sizes_[l]) - 1u;
    if (dense_[l]) {
      EncodeLevel<true>(table, scales_[l], strides_[l], mask, rest, n - done, D, rest_out + l * kFeatures);
    } else {
      EncodeLevel<false>(table, scales_[l], strides_[l], mask, rest, n - done, D, rest_out + l * kFeatures);
    }
  }
}

void HashGrid::BackwardLevel(int l, const float* pos, const float* dout, int n, float* grad,
                             uint8_t* touched, std::vector<uint32_t>* touched_list) const {
  if (n == 0) return;  // `dout` may be null for an empty batch.
  const int D = output_dim();
  float* gtable = grad + offsets_[l] * kFeatures;
  const uint32_t mask = uint32_t(sizes_[l]) - 1u;
  if (dense_[l]) {
    BackwardLevelImpl<true>(gtable, scales_[l], strides_[l], mask, pos, dout + l * kFeatures, n, D, offsets_[l],
                            touched, touched_list);
  } else {
    BackwardLevelImpl<false>(gtable, scales_[l], strides_[l], mask, pos, dout + l * kFeatures, n, D, offsets_[l],
                             touched, touched_list);
  }
}

void HashGrid::BackwardPosition(const float* params, const float* pos, const float* dout, int n,
                                float* dpos) const {
  const int L = options_.levels;
  const int D = output_dim();
  for (int i = 0; i < n; ++i) {
    float g[3] = {0, 0, 0};
    for (int l = 0; l < L; ++l) {
      const float scale = scales_[l];
      const float* table = params + offsets_[l] * kFeatures;
      const Corners c = Locate(scale, pos + 3 * i);
      const float g0 = dout[size_t(i) * D + l * kFeatures + 0];
      const float g1 = dout[size_t(i) * D + l * kFeatures + 1];
      for (int k = 0; k < 8; ++k) {
        const int b[3] = {k & 1, (k >> 1) & 1, (k >> 2) & 1};
        const float* e = table + size_t(Index(l, c.base[0] + b[0], c.base[1] + b[1], c.base[2] + b[2])) * kFeatures;
        const float v = g0 * e[0] + g1 * e[1];
        for (int d = 0; d < 3; ++d) {
          float dw = b[d] ? 1.0f : -1.0f;
          for (int o = 0; o < 3; ++o) {
            if (o != d) dw *= b[o] ? c.frac[o] : 1 - c.frac[o];
          }
          g[d] += v * dw * scale;
        }
      }
    }
    for (int d = 0; d < 3; ++d) dpos[3 * i + d] = g[d];
  }
}

}  // namespace clnerf
