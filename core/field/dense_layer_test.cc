#include "core/field/dense_layer.h"

#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

struct Shape {
  int rows, cols;
};

// Every path (16-row and 8-row column tiles in chunks of 1-4 blocks, the
// dot-product path), full sample groups and tails, strided operands, biases
// present / absent / per sample, ReLU or not: against a double-precision
// reference, to within float rounding of the sum of |terms|.
TEST(DenseLayerTest, MatchesReferenceOnEveryPathAndShape) {
  const Shape shapes[] = {{64, 32}, {16, 64}, {64, 16}, {3, 64}, {8, 5},  {24, 7},  {5, 3},
                          {1, 64},  {128, 48}, {48, 20}, {32, 9}, {80, 3}, {96, 33}, {7, 17}};
  const int counts[] = {0, 1, 5, 8, 13, 100};
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (const Shape& sh : shapes) {
    for (int n : counts) {
      for (int variant = 0; variant < 4; ++variant) {
        const int ldw = sh.rows + (variant & 1) * 3;  // A block of a wider matrix.
        const int ldx = sh.cols + (variant & 2);      // Strided inputs.
        const int ldy = sh.rows + (variant & 1);
        const bool relu = variant >= 2;
        std::vector<float> W(size_t(ldw) * sh.cols), x(size_t(ldx) * std::max(n, 1)),
            y(size_t(ldy) * std::max(n, 1), -99.0f);
        for (float& v : W) v = u(rng);
        for (float& v : x) v = u(rng);
        std::vector<std::vector<float>> bias_cols(3, std::vector<float>(sh.rows));
        for (auto& b : bias_cols) {
          for (float& v : b) v = u(rng);
        }
        std::vector<const float*> bias(std::max(n, 1));
        for (int j = 0; j < n; ++j) bias[j] = (j % 4 == 3) ? nullptr : bias_cols[j % 3].data();
        const bool with_bias = variant != 1;
        DenseForward(W.data(), sh.rows, sh.cols, ldw, x.data(), ldx, n, with_bias ? bias.data() : nullptr,
                     relu ? Activation::kRelu : Activation::kNone, y.data(), ldy);
        for (int j = 0; j < n; ++j) {
          for (int r = 0; r < sh.rows; ++r) {
            double ref = with_bias && bias[j] != nullptr ? bias[j][r] : 0.0;
            double mag = std::abs(ref);
            for (int i = 0; i < sh.cols; ++i) {
              const double t = double(W[size_t(i) * ldw + r]) * x[size_t(j) * ldx + i];
              ref += t;
              mag += std::abs(t);
            }
            if (relu) ref = std::max(ref, 0.0);
            // The standard bound of a float sum: (terms) * unit roundoff * sum |terms|.
            ASSERT_NEAR(y[size_t(j) * ldy + r], ref, (sh.cols + 2) * 6e-8 * (mag + 1.0))
                << sh.rows << "x" << sh.cols << " n=" << n << " variant " << variant << " sample " << j << " row " << r;
          }
          // Padding rows of y beyond `rows` are left alone.
          for (int r = sh.rows; r < ldy; ++r) ASSERT_EQ(y[size_t(j) * ldy + r], -99.0f);
        }
      }
    }
  }
}

TEST(DenseLayerTest, ReluClampsNegativesToZero) {
  const int rows = 16, cols = 2, n = 3;
  std::vector<float> W(rows * cols), x = {1, 0, -1, 0, 0, 0};
  for (int r = 0; r < rows; ++r) W[r] = r % 2 ? 1.0f : -1.0f;  // Column 0.
  std::vector<float> y(rows * n, 5.0f);
  DenseForward(W.data(), rows, cols, rows, x.data(), cols, n, nullptr, Activation::kRelu, y.data(), rows);
  for (int r = 0; r < rows; ++r) {
    EXPECT_EQ(y[r], r % 2 ? 1.0f : 0.0f);
    EXPECT_EQ(y[rows + r], r % 2 ? 0.0f : 1.0f);
    EXPECT_EQ(y[2 * rows + r], 0.0f);
  }
}

}  // namespace
}  // namespace clnerf
