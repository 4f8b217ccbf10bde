#include "core/train/view_colour.h"

namespace clnerf {
using std::size_t;
namespace {
float IdentityAt(int k) { return (k == 0 || k == 4 || k == 8) ? 1.0f : 0.0f; }
}  // namespace

std::vector<float> IdentityViewColours(int n) {
  std::vector<float> p(size_t(n) * kViewColourParams);
  for (size_t i = 0; i < p.size(); ++i) p[i] = IdentityAt(int(i % kViewColourParams));
  return p;
}

float ViewColourPrior(const std::vector<float>& p, float weight, float* grad) {
  const size_t views = p.size() / kViewColourParams;
  if (views == 0 || weight == 0.0f) return 0.0f;
  const float s = weight / float(views);
  double loss = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    const float d = p[i] - IdentityAt(int(i % kViewColourParams));
    loss += double(s) * d * d;
    grad[i] += 2.0f * s * d;
  }
  return float(loss);
}

}  // namespace clnerf
