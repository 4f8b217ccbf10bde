// Volume rendering of one ray, forward and backward, exactly as CLNeRF eq. (1):
//   C = sum_i w_i c_i + T_n * bg,  w_i = T_i (1 - exp(-sigma_i dt_i)),
//   T_i = exp(-sum_{j<i} sigma_j dt_j).
// Compositing stops after the first sample that drives T to or below
// `min_transmittance` (early termination); samples after it are dropped and
// contribute nothing to the colour or the gradients. Pure functions on
// caller-owned arrays; thread-safe.
#ifndef CLNERF_CORE_RENDER_VOLUME_RENDERING_H_
#define CLNERF_CORE_RENDER_VOLUME_RENDERING_H_

namespace clnerf {

inline constexpr float kMinTransmittance = 1e-4f;

// Computes weights w[i] for the first `used` samples and returns `used`
// (<= n). *t_final receives the transmittance after the last used sample.
int CompositeWeights(const float* sigma, const float* dt, int n, float min_transmittance,
                     float* weights, float* t_final);

// Composites colours (rgb: 3 per sample) with the given weights over `used`
// samples, plus t_final * background. out: rgb[3].
void CompositeColour(const float* weights, const float* rgb, int used, float t_final,
                     const float* background, float* out);

// Backward of CompositeColour∘CompositeWeights for one ray.
//   d_out:     dL/dC (3 values).
//   d_opacity: dL/d(1 - t_final).
// Writes d_rgb (3 per used sample) and d_sigma (per used sample).
void CompositeBackward(const float* sigma, const float* dt, const float* rgb, const float* weights,
                       int used, float t_final, const float* background, const float* d_out,
                       float d_opacity, float* d_rgb, float* d_sigma);

// Distortion loss of one ray (mip-NeRF 360, eq. 15):
//   L = sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 s_i,
// with m_i the midpoint and s_i the width of sample i's interval in a
// normalised ray distance (ascending m). It pulls each ray's weights into one
// compact surface, removing fog and floaters. Returns L and adds
// scale * dL/dsigma_i to d_sigma (through the weights of CompositeWeights;
// used = number of composited samples).
float DistortionLoss(const float* dt, const float* weights, const float* mid, const float* width, int used,
                     float scale, float* d_sigma);

// Sparse-depth loss of one ray with a known surface at ray distance `depth`
// (DS-NeRF's ray-distribution loss, in nerfstudio depth-nerfacto's form):
//   L = sum_i -log(w_i + eps) exp(-(m_i - depth)^2 / (2 s^2)) dt_i,
// with m_i each sample's ray distance and s = sigma * max(1, depth) (sample
// spacing grows with distance in contracted space). It rewards weight near
// the known depth and nothing else. eps = kSparseDepthEps. Returns L and adds
// scale * dL/dsigma_i to d_sigma.
inline constexpr float kSparseDepthEps = 1e-4f;
float SparseDepthLoss(const float* dt, const float* weights, const float* mid, int used, float depth, float sigma,
                      float scale, float* d_sigma);

// Adds scale * sum_i g_i dw_i/dsigma_k to d_sigma[k] for the weights of
// CompositeWeights (g_i = dL/dw_i): the shared last step of every loss on a
// ray's weights.
void WeightsToSigmaGradient(const float* dt, const float* weights, const float* g, int used, float scale,
                            float* d_sigma);

}  // namespace clnerf

#endif  // CLNERF_CORE_RENDER_VOLUME_RENDERING_H_
