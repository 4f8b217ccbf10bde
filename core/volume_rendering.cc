#include "core/volume_rendering.h"

#include <cmath>

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

}  // namespace clnerf
