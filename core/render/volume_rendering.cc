#include "core/render/volume_rendering.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace clnerf {

int CompositeWeights(const float* sigma, const float* dt, int n, float min_transmittance,
                     float* weights, float* t_final) {
  float T = 1.0f;
  int i = 0;
  while (i < n) {
    const float alpha = 1.0f - std::exp(-sigma[i] * dt[i]);
    weights[i] = T * alpha;
    T *= 1.0f - alpha;
    ++i;
    if (T <= min_transmittance) break;
  }
  *t_final = T;
  return i;
}

void CompositeColour(const float* weights, const float* rgb, int used, float t_final,
                     const float* background, float* out) {
  float r = 0, g = 0, b = 0;
  for (int i = 0; i < used; ++i) {
    r += weights[i] * rgb[3 * i + 0];
    g += weights[i] * rgb[3 * i + 1];
    b += weights[i] * rgb[3 * i + 2];
  }
  out[0] = r + t_final * background[0];
  out[1] = g + t_final * background[1];
  out[2] = b + t_final * background[2];
}

void CompositeBackward(const float* sigma, const float* dt, const float* rgb, const float* weights,
                       int used, float t_final, const float* background, const float* d_out,
                       float d_opacity, float* d_rgb, float* d_sigma) {
  // R = colour still to come after sample i (including the background term),
  // dotted with d_out. Start from the total and peel samples off.
  float rest = t_final * (background[0] * d_out[0] + background[1] * d_out[1] + background[2] * d_out[2]);
  for (int i = 0; i < used; ++i) {
    rest += weights[i] * (rgb[3 * i] * d_out[0] + rgb[3 * i + 1] * d_out[1] + rgb[3 * i + 2] * d_out[2]);
  }
  float T = 1.0f;
  for (int i = 0; i < used; ++i) {
    const float cg = rgb[3 * i] * d_out[0] + rgb[3 * i + 1] * d_out[1] + rgb[3 * i + 2] * d_out[2];
    rest -= weights[i] * cg;
    const float t_next = T - weights[i];  // T_{i+1} = T_i (1 - alpha_i).
    // dC/dsigma_i = dt_i (T_{i+1} c_i - R_i); d(1-T_n)/dsigma_i = dt_i T_n.
    d_sigma[i] = dt[i] * (t_next * cg - rest + d_opacity * t_final);
    d_rgb[3 * i + 0] = weights[i] * d_out[0];
    d_rgb[3 * i + 1] = weights[i] * d_out[1];
    d_rgb[3 * i + 2] = weights[i] * d_out[2];
    T = t_next;
  }
}

float DistortionLoss(const float* dt, const float* weights, const float* mid, const float* width, int used,
                     float scale, float* d_sigma) {
  if (used <= 0) return 0.0f;
  double W = 0, WM = 0;
  for (int i = 0; i < used; ++i) {
    W += weights[i];
    WM += double(weights[i]) * mid[i];
  }
  // g_i = dL/dw_i = 2 sum_j w_j |m_i - m_j| + 2/3 w_i s_i, with the sum split
  // at i using prefix sums (m ascending).
  thread_local std::vector<float> g;
  g.resize(used);
  double loss = 0, Wl = 0, WMl = 0;
  for (int i = 0; i < used; ++i) {
    const double wi = weights[i], mi = mid[i];
    const double below = mi * Wl - WMl;
    const double above = (WM - WMl - wi * mi) - mi * (W - Wl - wi);
    const double spread = below + above;
    loss += wi * spread + wi * wi * width[i] / 3.0;
    g[i] = float(2.0 * spread + 2.0 / 3.0 * wi * width[i]);
    Wl += wi;
    WMl += wi * mi;
  }
  WeightsToSigmaGradient(dt, weights, g.data(), used, scale, d_sigma);
  return float(loss);
}

void WeightsToSigmaGradient(const float* dt, const float* weights, const float* g, int used, float scale,
                            float* d_sigma) {
  // dw_i/dsigma_k = dt_k (T_{k+1} [i == k] - w_i [i > k]), T_{k+1} = T_k - w_k.
  double suffix = 0;  // sum_{i > k} g_i w_i
  // Transmittances front to back.
  thread_local std::vector<double> T;
  T.resize(used + 1);
  T[0] = 1.0;
  for (int i = 0; i < used; ++i) T[i + 1] = T[i] - weights[i];
  for (int k = used - 1; k >= 0; --k) {
    d_sigma[k] += scale * float(dt[k] * (g[k] * T[k + 1] - suffix));
    suffix += double(g[k]) * weights[k];
  }
}

float SparseDepthLoss(const float* dt, const float* weights, const float* mid, int used, float depth, float sigma,
                      float scale, float* d_sigma) {
  if (used <= 0 || !(depth > 0.0f)) return 0.0f;
  const float s = sigma * std::max(1.0f, depth);
  const float inv2s2 = 0.5f / (s * s);
  thread_local std::vector<float> g;
  g.resize(used);
  double loss = 0;
  for (int i = 0; i < used; ++i) {
    const float e = mid[i] - depth;
    const float k = std::exp(-e * e * inv2s2) * dt[i];
    const float w = weights[i] + kSparseDepthEps;
    loss += -double(std::log(w)) * k;
    g[i] = -k / w;
  }
  WeightsToSigmaGradient(dt, weights, g.data(), used, scale, d_sigma);
  return float(loss);
}

}  // namespace clnerf
