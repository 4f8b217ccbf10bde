// Spherical-harmonics direction encoding of degree 4 (16 coefficients), with
// the real SH basis constants used by tiny-cuda-nn. Upstream maps a unit
// direction d to (d+1)/2 and tiny-cuda-nn maps it back to 2x-1, so the basis is
// evaluated on the unit direction itself, as here. Pure functions; thread-safe.
#ifndef CLNERF_CORE_FIELD_SH_ENCODING_H_
#define CLNERF_CORE_FIELD_SH_ENCODING_H_

namespace clnerf {

inline constexpr int kShDim = 16;

// out[16] = Y_lm(d) for l = 0..3, d = (x, y, z) a unit vector.
void ShEncode(float x, float y, float z, float* out);

// jac[16][3]: d out[k] / d (x, y, z). Directions are not trained; this exists
// for gradient checks and future pose refinement.
void ShJacobian(float x, float y, float z, float* jac);

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_SH_ENCODING_H_
