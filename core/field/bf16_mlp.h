// Bf16Mlp: the network's two MLPs (network.h) for inference in bfloat16:
// weights and each layer's inputs rounded to bfloat16 (8-bit mantissa,
// round to nearest even), products summed in float, hidden activations
// kept in bfloat16, outputs (h, rgb) in float. tiny-cuda-nn runs its NeRF
// MLPs in half precision the same way. The point is speed on a CPU with
// Intel's AMX tile unit, which multiplies a 16 x 32 by a 32 x 16 bfloat16
// matrix in one instruction (on a 2-core Xeon, 1,040 G products/s against
// 86 G for float AVX-512 FMAs): samples go through the layers in slabs of
// 128, their activations never leaving the L1 cache.
//
// Only for inference (the renderer's field, RenderOptions::bf16_mlp):
// training's forward and backward passes stay in float, so the gradients
// are those of the function trained. Renders of the four shared models
// move by less than 0.01 dB (docs/render_cost.md, session 76).
//
// Without the tile unit (AMD CPUs, a build that does not target AMX, a
// kernel that refuses the tile state, valgrind, whose CPU has none, or
// CLNERF_NO_AMX=1 in the environment) the same rounded function is
// computed with float kernels, up to summation order (slower than plain
// float: FieldEvaluator then keeps float), so the tests check the function
// on every machine and the tile kernel where the CPU has it.
//
// Thread-safety: immutable after construction; Density and Colour may run
// on many threads at once (each keeps its own tile state and scratch).
// Bf16TilesAvailable asks the CPU and the kernel once per process.
#ifndef CLNERF_CORE_FIELD_BF16_MLP_H_
#define CLNERF_CORE_FIELD_BF16_MLP_H_

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/field/network.h"

namespace clnerf {

// Whether Bf16Mlp runs on AMX tiles in this process.
bool Bf16TilesAvailable();

// float -> bfloat16 (round to nearest even; NaN stays NaN) and back.
uint16_t ToBf16(float f);
float FromBf16(uint16_t h);

// A rows x cols weight matrix (column-major, leading dimension ldw) in the
// tile layout: 16-output blocks by 32-input chunks, each a 16 x 32
// bfloat16 tile in pair-interleaved (VNNI) order, zero-padded.
class Bf16Weights {
 public:
  Bf16Weights(const float* W, int rows, int cols, int ldw);

  int rows() const { return rows_; }
  int cols() const { return cols_; }
  int row_blocks() const { return (rows_ + 15) / 16; }
  int col_chunks() const { return (cols_ + 31) / 32; }
  // Tile (block, chunk): 16 rows of 32 bfloat16.
  const uint16_t* tile(int block, int chunk) const {
    return tiles_.data() + (size_t(block) * col_chunks() + chunk) * 512;
  }
  // W rounded to bfloat16 and back, rows x cols (the float fallback's).
  const float* rounded() const { return rounded_.data(); }

 private:
  int rows_, cols_;
  std::vector<uint16_t> tiles_;
  std::vector<float> rounded_;
};

class Bf16Mlp {
 public:
  // Packs net's layers from its flat weights (copied: `mlp` may change or
  // go away afterwards). tiles: run on AMX tiles where available (false:
  // the float fallback, for tests).
  Bf16Mlp(const Network& net, const float* mlp, bool tiles = true);

  // Whether Density and Colour run on AMX tiles (else the float fallback).
  bool tiles() const { return tiles_; }

  // h (density_out x n, column per sample) = the density MLP of feat
  // (grid_dim x n); bias[j]: sample j's first-layer bias (density_hidden
  // values: the geometry embedding's product), or null.
  void Density(const float* feat, int n, const float* const* bias, float* h) const;
  // rgb (3 x n) = the colour MLP of h (density_out x n), through the
  // sigmoid; bias[j]: sample j's first-layer bias (colour_hidden values:
  // the view direction's and appearance embedding's products), or null.
  void Colour(const float* h, int n, const float* const* bias, float* rgb) const;

 private:
  // Layers in order, ReLU after each but the last.
  void Run(const std::vector<Bf16Weights>& chain, const float* in, int n, const float* const* bias, float* out) const;

  bool tiles_;
  std::vector<Bf16Weights> density_, colour_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_BF16_MLP_H_
