// DenseLayer: the forward product of one small fully connected layer over a
// batch of samples, y_j = act(W x_j + b_j), for the NGP model's tiny MLPs
// (widths of 16-128, a few thousand samples per call).
//
// A general GEMM (Eigen's) is built for large matrices: it zeroes the output,
// packs both operands into panels and runs a 48x4 micro-kernel, which on a
// 64 x 32 weight matrix spends much of its time packing (measured: the MLPs
// took ~40% of a fox_8 render, ~2x more cycles than their FMAs need). Here
// the weight columns are read in place (they stay in L1), each group of
// samples keeps its outputs in registers, and the bias and ReLU are applied
// before the one store.
//
// Layout (all column-major, one column per sample): W is rows x cols with
// leading dimension ldw (so a block of columns of a larger matrix works);
// x is cols x n with leading dimension ldx; y is rows x n with leading
// dimension ldy. bias[j] (may be null, or hold nulls) points at a rows-long
// bias column for sample j. Rows that are a multiple of 8 take the
// vectorised path; others (the 3 colour outputs) a per-sample dot product.
// Results equal the plain product up to float rounding (the summation order
// differs from Eigen's); they do not depend on the thread count.
//
// Pure functions; thread-safe.
#ifndef CLNERF_CORE_FIELD_DENSE_LAYER_H_
#define CLNERF_CORE_FIELD_DENSE_LAYER_H_

namespace clnerf {

enum class Activation { kNone = 0, kRelu = 1 };

void DenseForward(const float* W, int rows, int cols, int ldw, const float* x, int ldx, int n,
                  const float* const* bias, Activation act, float* y, int ldy);

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_DENSE_LAYER_H_
