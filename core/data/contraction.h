// Scene contraction for unbounded real captures (mip-NeRF 360, with the L-inf
// norm as instant-ngp's and nerfstudio's NGP models use, so the contracted
// space fills a cube that the hash grid and the occupancy grid tile fully):
//
//   contract(x) = x                              if |x|_inf <= 1
//               = (2 - 1/|x|_inf) * x / |x|_inf  otherwise,
//
// mapping all of R^3 into (-2, 2)^3. The inner cube [-1, 1]^3 (cameras and the
// main subject, after ComputeNormalization) keeps its metric; everything
// farther away is squeezed into the shell 1 < |q|_inf < 2 with resolution
// falling off as 1/r^2 (disparity-like), so the far background costs a thin
// shell of the model's capacity, samples and time instead of a huge box.
//
// Pure inline functions; thread-safe.
#ifndef CLNERF_CORE_DATA_CONTRACTION_H_
#define CLNERF_CORE_DATA_CONTRACTION_H_

#include <cmath>

#include "Eigen/Core"

namespace clnerf {

// Half-size of the contracted cube (-2, 2)^3.
inline constexpr float kContractedBound = 2.0f;

inline float InfNorm(const Eigen::Vector3f& x) {
  return std::max(std::abs(x.x()), std::max(std::abs(x.y()), std::abs(x.z())));
}

inline Eigen::Vector3f Contract(const Eigen::Vector3f& x) {
  const float r = InfNorm(x);
  if (!(r > 1.0f)) return x;
  return x * ((2.0f - 1.0f / r) / r);
}

// Inverse of Contract on (-2, 2)^3: for |q|_inf = s in (1, 2), r = 1 / (2 - s)
// and x = q * r / s. Points on or beyond the outer face map to a large but
// finite distance.
inline Eigen::Vector3f Uncontract(const Eigen::Vector3f& q) {
  const float s = InfNorm(q);
  if (!(s > 1.0f)) return q;
  const float r = 1.0f / std::max(2.0f - s, 1e-6f);
  return q * (r / s);
}

// Jacobian dq/dx of Contract at x (3x3, row = output component).
Eigen::Matrix3f ContractJacobian(const Eigen::Vector3f& x);

// Derivative of the contracted point along a ray, d/dt contract(o + t d) at
// x = o + t d, i.e. J(x) d, without forming J.
Eigen::Vector3f ContractDirectional(const Eigen::Vector3f& x, const Eigen::Vector3f& d);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_CONTRACTION_H_
