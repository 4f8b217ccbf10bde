#include "core/data/contraction.h"

namespace clnerf {

namespace {
// Index of the dominant (largest |x_k|) axis.
int DominantAxis(const Eigen::Vector3f& x) {
  const Eigen::Vector3f a = x.cwiseAbs();
  return a.x() >= a.y() ? (a.x() >= a.z() ? 0 : 2) : (a.y() >= a.z() ? 1 : 2);
}
}  // namespace

// For r = |x_k| > 1 on the dominant axis k, with g(r) = (2 - 1/r) / r =
// (2r - 1) / r^2 and g'(r) = 2 (1 - r) / r^3:
//   q_i = g(r) x_i  =>  dq_i/dx_j = g(r) delta_ij + x_i g'(r) sign(x_k) delta_jk.
Eigen::Matrix3f ContractJacobian(const Eigen::Vector3f& x) {
  const float r = InfNorm(x);
  if (!(r > 1.0f)) return Eigen::Matrix3f::Identity();
  const int k = DominantAxis(x);
  const float g = (2.0f * r - 1.0f) / (r * r);
  const float gp = 2.0f * (1.0f - r) / (r * r * r);
  const float sk = x[k] < 0 ? -1.0f : 1.0f;
  Eigen::Matrix3f j = g * Eigen::Matrix3f::Identity();
  j.col(k) += x * (gp * sk);
  return j;
}

Eigen::Vector3f ContractDirectional(const Eigen::Vector3f& x, const Eigen::Vector3f& d) {
  const float r = InfNorm(x);
  if (!(r > 1.0f)) return d;
  const int k = DominantAxis(x);
  const float g = (2.0f * r - 1.0f) / (r * r);
  const float gp = 2.0f * (1.0f - r) / (r * r * r);
  const float sk = x[k] < 0 ? -1.0f : 1.0f;
  return g * d + x * (gp * sk * d[k]);
}

}  // namespace clnerf
