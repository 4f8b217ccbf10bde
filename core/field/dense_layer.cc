#include "core/field/dense_layer.h"

#include <algorithm>
#include <cstring>

#include "Eigen/Core"

namespace clnerf {
namespace {

// GCC/Clang vector extensions: lowered to AVX-512, AVX2 or SSE by -march.
// (A typedef per width: an alias template would drop the attribute.)
typedef float Vec16 __attribute__((vector_size(16 * sizeof(float))));
typedef float Vec8 __attribute__((vector_size(8 * sizeof(float))));
template <int L>
struct VecOf;
template <>
struct VecOf<16> {
  using type = Vec16;
};
template <>
struct VecOf<8> {
  using type = Vec8;
};
template <int L>
using Vec = typename VecOf<L>::type;
static_assert(sizeof(Vec<16>) == 64 && sizeof(Vec<8>) == 32, "vector extension types");

// The register file the build targets (-march): vector bytes and count.
// Tiles are sized so that their accumulators, the weight column and the
// broadcast sample fit it; a build without AVX-512 (e.g. an AVX2-only
// EPYC) must not pin a 64-byte vector in one register.
#if defined(__AVX512F__)
constexpr int kRegBytes = 64;
constexpr int kRegs = 32;
#elif defined(__AVX__)
constexpr int kRegBytes = 32;
constexpr int kRegs = 16;
#else
constexpr int kRegBytes = 16;
constexpr int kRegs = 16;
#endif

template <int L>
inline Vec<L> Load(const float* p) {
  Vec<L> v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <int L>
inline void Store(float* p, const Vec<L>& v) {
  std::memcpy(p, &v, sizeof v);
}

// NS samples starting at j0 times RB row blocks of L rows starting at row r0:
// RB * NS accumulators in registers, one pass over the columns of W.
template <int L, int RB, int NS>
inline void Tile(const float* W, int r0, int cols, int ldw, const float* x, int ldx, int j0,
                 const float* const* bias, bool relu, float* y, int ldy) {
  Vec<L> acc[NS][RB];
  for (int s = 0; s < NS; ++s) {
    const float* b = bias != nullptr ? bias[j0 + s] : nullptr;
    for (int r = 0; r < RB; ++r) acc[s][r] = b != nullptr ? Load<L>(b + r0 + r * L) : Vec<L>{};
  }
  const float* xs[NS];
  for (int s = 0; s < NS; ++s) xs[s] = x + size_t(j0 + s) * ldx;
  const float* wc = W + r0;
  for (int i = 0; i < cols; ++i, wc += ldw) {
    Vec<L> w[RB];
    for (int r = 0; r < RB; ++r) {
      w[r] = Load<L>(wc + r * L);
#if defined(__x86_64__) || defined(__i386__)
      // Keeps the column in registers: folded into each FMA as a memory
      // operand, it costs RB * NS loads per column instead of RB (measured
      // 65 vs 112 GFLOP/s on a 64 x 32 layer, one Zen 5 core). Only for a
      // vector that fits one register of the target.
      if constexpr (sizeof(Vec<L>) <= kRegBytes) asm("" : "+v"(w[r]));
#endif
    }
    for (int s = 0; s < NS; ++s) {
      const float xv = xs[s][i];
      for (int r = 0; r < RB; ++r) acc[s][r] += w[r] * xv;
    }
  }
  for (int s = 0; s < NS; ++s) {
    float* ys = y + size_t(j0 + s) * ldy + r0;
    for (int r = 0; r < RB; ++r) {
      Vec<L> v = acc[s][r];
      if (relu) v = v > Vec<L>{} ? v : Vec<L>{};
      Store<L>(ys + r * L, v);
    }
  }
}

// All n samples for RB row blocks from r0: groups of NS, then single samples.
template <int L, int RB, int NS>
void RowChunk(const float* W, int r0, int cols, int ldw, const float* x, int ldx, int n, const float* const* bias,
              bool relu, float* y, int ldy) {
  int j = 0;
  for (; j + NS <= n; j += NS) Tile<L, RB, NS>(W, r0, cols, ldw, x, ldx, j, bias, relu, y, ldy);
  for (; j < n; ++j) Tile<L, RB, 1>(W, r0, cols, ldw, x, ldx, j, bias, relu, y, ldy);
}

// Rows a multiple of L: chunks of up to 4 row blocks. With 32 registers
// (AVX-512) a 4 x 4 tile's 16 accumulators and 4 weight vectors fit; with 16
// (AVX2, SSE) the tiles keep at most 12 accumulators plus the weights.
template <int L>
void ColumnPath(const float* W, int rows, int cols, int ldw, const float* x, int ldx, int n,
                const float* const* bias, bool relu, float* y, int ldy) {
  constexpr bool kWide = kRegs >= 32;
  for (int r0 = 0; r0 < rows;) {
    switch (std::min((rows - r0) / L, kWide ? 4 : 3)) {
      case 4:  // Only reached with kWide.
        if constexpr (kWide) RowChunk<L, 4, 4>(W, r0, cols, ldw, x, ldx, n, bias, relu, y, ldy);
        r0 += 4 * L;
        break;
      case 3:
        RowChunk<L, 3, kWide ? 4 : 3>(W, r0, cols, ldw, x, ldx, n, bias, relu, y, ldy);
        r0 += 3 * L;
        break;
      case 2:
        RowChunk<L, 2, kWide ? 6 : 5>(W, r0, cols, ldw, x, ldx, n, bias, relu, y, ldy);
        r0 += 2 * L;
        break;
      default:
        RowChunk<L, 1, 8>(W, r0, cols, ldw, x, ldx, n, bias, relu, y, ldy);
        r0 += L;
        break;
    }
  }
}

// Other row counts (the 3 colour outputs, sigma's single row): Eigen's
// product, which for so few rows beats a dot-product kernel (measured 14 vs
// 17 ns per sample for 3 x 64), then the bias and activation.
void GeneralPath(const float* W, int rows, int cols, int ldw, const float* x, int ldx, int n,
                 const float* const* bias, bool relu, float* y, int ldy) {
  using Strided = Eigen::Map<const Eigen::MatrixXf, 0, Eigen::OuterStride<>>;
  Eigen::Map<Eigen::MatrixXf, 0, Eigen::OuterStride<>> out(y, rows, n, Eigen::OuterStride<>(ldy));
  if (ldw == rows && ldx == cols && ldy == rows) {  // Contiguous: Eigen's faster unstrided kernel.
    Eigen::Map<Eigen::MatrixXf>(y, rows, n).noalias() =
        Eigen::Map<const Eigen::MatrixXf>(W, rows, cols) * Eigen::Map<const Eigen::MatrixXf>(x, cols, n);
  } else {
    out.noalias() = Strided(W, rows, cols, Eigen::OuterStride<>(ldw)) * Strided(x, cols, n, Eigen::OuterStride<>(ldx));
  }
  for (int j = 0; j < n; ++j) {
    if (bias != nullptr && bias[j] != nullptr) out.col(j) += Eigen::Map<const Eigen::VectorXf>(bias[j], rows);
    if (relu) out.col(j) = out.col(j).cwiseMax(0.0f);
  }
}

}  // namespace

void DenseForward(const float* W, int rows, int cols, int ldw, const float* x, int ldx, int n,
                  const float* const* bias, Activation act, float* y, int ldy) {
  if (n <= 0 || rows <= 0) return;
  const bool relu = act == Activation::kRelu;
  // 16-float vectors only where a register holds them (AVX-512).
  if (kRegBytes >= 64 && rows % 16 == 0) {
    ColumnPath<16>(W, rows, cols, ldw, x, ldx, n, bias, relu, y, ldy);
  } else if (rows % 8 == 0) {
    ColumnPath<8>(W, rows, cols, ldw, x, ldx, n, bias, relu, y, ldy);
  } else {
    GeneralPath(W, rows, cols, ldw, x, ldx, n, bias, relu, y, ldy);
  }
}

}  // namespace clnerf
