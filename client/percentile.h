// Latency helpers the benchmarks share. Percentile: the q-quantile (0..1) of
// a sample by linear interpolation between order statistics, as the
// benchmarks report p50/p99 (empty: 0). Ms: a steady-clock duration in
// milliseconds. Thread-safe (pure functions).
#ifndef CLNERF_CLIENT_PERCENTILE_H_
#define CLNERF_CLIENT_PERCENTILE_H_

#include <algorithm>
#include <chrono>
#include <vector>

namespace clnerf {

inline double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = q * double(v.size() - 1);
  const size_t lo = size_t(pos);
  const size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (pos - double(lo)) * (v[hi] - v[lo]);
}

inline double Ms(std::chrono::steady_clock::duration d) {
  return std::chrono::duration<double, std::milli>(d).count();
}

}  // namespace clnerf

#endif  // CLNERF_CLIENT_PERCENTILE_H_
