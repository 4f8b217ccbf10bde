// ViewColour: per-view affine colour transforms that absorb a photo's own
// exposure and white balance during training (item 3 of issue 19; the role
// nerfacto's per-image appearance embedding plays, in the closed form
// multinerf's colour-corrected evaluation fits after the fact).
//
// Each training photo i gets 12 parameters p_i = [M_i (3x3, row-major), b_i],
// and the colour a ray of that photo is compared with is
//     c' = M_i c + b_i,
// where c is the composited colour (background included). The field is left
// to model what all photos share; M_i, b_i start at the identity and a prior
//     weight / V * sum_i (||M_i - I||^2 + ||b_i||^2)
// (V = number of views) holds them there unless the photos disagree. It also
// fixes the gauge: without it the field could drift to any global colour
// transform S and every M_i to M_i S^-1, and test views, which have no
// transform of their own, would render in S's colours.
//
// Protocol for views without a transform (test views, replay labels): the
// identity, i.e. the field's own colour, for every method alike.
//
// Free functions on plain arrays; thread-safe.
#ifndef CLNERF_CORE_TRAIN_VIEW_COLOUR_H_
#define CLNERF_CORE_TRAIN_VIEW_COLOUR_H_

#include <cstddef>
#include <vector>

namespace clnerf {

constexpr int kViewColourParams = 12;

// n identity transforms (12 floats each).
std::vector<float> IdentityViewColours(int n);

// out = M c + b.
inline void ApplyViewColour(const float* p, const float* c, float* out) {
  for (int r = 0; r < 3; ++r) out[r] = p[3 * r] * c[0] + p[3 * r + 1] * c[1] + p[3 * r + 2] * c[2] + p[9 + r];
}

// Backward of ApplyViewColour: dc = M^T dout; dp += dout c^T (and dout for b).
inline void ViewColourBackward(const float* p, const float* c, const float* dout, float* dc, float* dp) {
  for (int k = 0; k < 3; ++k) dc[k] = p[k] * dout[0] + p[3 + k] * dout[1] + p[6 + k] * dout[2];
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) dp[3 * r + k] += dout[r] * c[k];
    dp[9 + r] += dout[r];
  }
}

// The identity prior over all transforms in `p` (12 per view): returns
// weight / V * sum ||p_i - identity||^2 and adds its gradient to `grad`.
float ViewColourPrior(const std::vector<float>& p, float weight, float* grad);

}  // namespace clnerf

#endif  // CLNERF_CORE_TRAIN_VIEW_COLOUR_H_
