#include "core/bake/density_fit.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "core/bake/baked_march.h"
#include "core/bake/fit_system.h"

namespace clnerf {
namespace {


// Derivatives smaller than this (in every channel) are left out of J.
constexpr float kMinDerivative = 1e-5f;

double Since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// One composited sample: its 8 corners (lattice ids, trilinear weights),
// blended code A, raw colour P / max(A, 1/255) before clamping, exponent
// s = dt / cell, opacity and the transmittance before it.
struct Sample {
  uint32_t id[8];
  float w[8];
  float A, s, alpha, T;
  Eigen::Vector3f raw;
};

// Marches the asset's grid with float codes and colours, recording every
// composited sample; returns the pixel (unclamped, no view term).
Eigen::Vector3f MarchSamples(const BakedAsset& a, const float* codes, const float* rgb, const Eigen::Vector3f& o,
                             const Eigen::Vector3f& d, std::vector<Sample>* samples, float* T_end) {
  samples->clear();
  Sample cur;
  const float cell = a.cell();
  Eigen::Vector3f pixel = Eigen::Vector3f::Zero();
  float T = 1.0f;
  const float Tf = MarchBaked(
      a, o, d,
      [&](int, const Eigen::Vector3f& u, const int b[3], Eigen::Vector4f* rgba) {
        const int64_t brick = BlockBrick(a, b);
        if (brick < 0) return false;
        float l[3];
        LocalInBlock(u, b, l);
        const BrickCell bc = LocateInBrick(l);
        float A = 0.0f;
        Eigen::Vector3f P = Eigen::Vector3f::Zero();
        for (int k = 0; k < 8; ++k) {
          const uint32_t id = LatticeId(uint32_t(brick), bc, k);
          const float w = bc.weight(k);
          cur.id[k] = id;
          cur.w[k] = w;
          A += w * codes[id];
          P += (w * codes[id]) * Eigen::Vector3f(rgb + 3 * size_t(id));
        }
        cur.A = A;
        cur.raw = P / std::max(A, 1.0f / 255.0f);
        *rgba << P, A;
        return true;
      },
      [&](int, float weight, float, const Eigen::Vector4f&, float run) {
        cur.s = run / cell;
        cur.T = T;
        cur.alpha = T > 0.0f ? weight / T : 0.0f;
        pixel += weight * cur.raw.cwiseMax(0.0f).cwiseMin(1.0f);
        T -= weight;
        samples->push_back(cur);
      });
  *T_end = Tf;
  return pixel + Tf * a.background;
}

// The pixel's derivatives by the codes of `samples` (back to front):
// through each sample's opacity (and so every later sample's
// transmittance) and through its colour's blend weights.
void Backward(const std::vector<Sample>& samples, const float* rgb, const Eigen::Vector3f& tail,
              std::vector<std::pair<uint32_t, Eigen::Vector3f>>* jacobian) {
  jacobian->clear();
  Eigen::Vector3f R = tail;  // What the samples after i (and the background) add.
  for (size_t i = samples.size(); i-- > 0;) {
    const Sample& s = samples[i];
    const Eigen::Vector3f c = s.raw.cwiseMax(0.0f).cwiseMin(1.0f);
    const Eigen::Vector3f dC_dalpha = s.T * c - R / (1.0f - s.alpha);
    R += s.T * s.alpha * c;
    const float A2 = s.A * s.A;
    // alpha = 1 - (1 - A^2)^s while A^2 is below the cap.
    const float dalpha_dA = A2 < kBakedMaxAlpha ? s.s * 2.0f * s.A * (1.0f - s.alpha) / (1.0f - A2) : 0.0f;
    const Eigen::Vector3f through_alpha = dalpha_dA * dC_dalpha;
    // raw = P / max(A, 1/255); clamped channels do not move.
    const bool divides = s.A >= 1.0f / 255.0f;
    const float inv = 1.0f / std::max(s.A, 1.0f / 255.0f), weight = s.T * s.alpha;
    Eigen::Vector3f open;
    for (int c3 = 0; c3 < 3; ++c3) open[c3] = s.raw[c3] > 0.0f && s.raw[c3] < 1.0f ? 1.0f : 0.0f;
    for (int k = 0; k < 8; ++k) {
      if (s.w[k] == 0.0f) continue;
      const Eigen::Vector3f ck(rgb + 3 * size_t(s.id[k]));
      const Eigen::Vector3f dcol = (ck - (divides ? s.raw : Eigen::Vector3f::Zero())) * inv;
      jacobian->emplace_back(s.id[k], s.w[k] * (through_alpha + weight * dcol.cwiseProduct(open)));
    }
  }
  MergeRepeats(jacobian);
}

uint32_t Hash(uint32_t a) {
  a ^= a >> 16;
  a *= 0x7FEB352Du;
  a ^= a >> 15;
  a *= 0x846CA68Bu;
  a ^= a >> 16;
  return a;
}

struct Entry {
  uint32_t col;
  Eigen::Vector3f j;
};

// The linearised system: per ray, its residual (model - asset pixel) and
// its entries; by unknown (after Transpose), the same entries' rows.
struct DensitySystem {
  std::vector<int64_t> start = {0};
  std::vector<Entry> entries;
  std::vector<float> residual;  // 3 per row.
  std::vector<uint32_t> point;  // Lattice id of each unknown.
  std::vector<int64_t> col_start;
  std::vector<Entry> by_col;  // .col holds the row.

  int64_t rows() const { return int64_t(start.size()) - 1; }
  size_t unknowns() const { return point.size(); }
  void Number(size_t points);
  void Transpose();
  void Multiply(const std::vector<float>& x, std::vector<float>* y) const;
  void MultiplyTransposed(const std::vector<float>& y, std::vector<float>* z) const;
  std::vector<float> SolveDamped(double lambda, int iterations) const;
};

// Columns from lattice ids to unknowns numbered in lattice order.
void DensitySystem::Number(size_t points) {
  std::vector<int32_t> unknown(points, -1);
  for (const Entry& e : entries) unknown[e.col] = 0;
  point.clear();
  for (size_t i = 0; i < points; ++i) {
    if (unknown[i] == 0) {
      unknown[i] = int32_t(point.size());
      point.push_back(uint32_t(i));
    }
  }
  for (Entry& e : entries) e.col = uint32_t(unknown[e.col]);
}

void DensitySystem::Transpose() {
  col_start.assign(unknowns() + 1, 0);
  for (const Entry& e : entries) ++col_start[e.col + 1];
  for (size_t j = 0; j < unknowns(); ++j) col_start[j + 1] += col_start[j];
  by_col.resize(entries.size());
  std::vector<int64_t> at(col_start.begin(), col_start.end() - 1);
  for (int64_t r = 0; r < rows(); ++r) {
    for (int64_t e = start[size_t(r)]; e < start[size_t(r) + 1]; ++e) {
      by_col[size_t(at[entries[size_t(e)].col]++)] = {uint32_t(r), entries[size_t(e)].j};
    }
  }
}

void DensitySystem::Multiply(const std::vector<float>& x, std::vector<float>* y) const {
  y->assign(3 * size_t(rows()), 0.0f);
#pragma omp parallel for schedule(static)
  for (int64_t r = 0; r < rows(); ++r) {
    Eigen::Vector3f acc = Eigen::Vector3f::Zero();
    for (int64_t e = start[size_t(r)]; e < start[size_t(r) + 1]; ++e) acc += x[entries[size_t(e)].col] * entries[size_t(e)].j;
    for (int c = 0; c < 3; ++c) (*y)[3 * size_t(r) + c] = acc[c];
  }
}

void DensitySystem::MultiplyTransposed(const std::vector<float>& y, std::vector<float>* z) const {
  z->assign(unknowns(), 0.0f);
  const int64_t n = int64_t(unknowns());
#pragma omp parallel for schedule(static)
  for (int64_t j = 0; j < n; ++j) {
    float acc = 0.0f;
    for (int64_t e = col_start[size_t(j)]; e < col_start[size_t(j) + 1]; ++e) {
      const Entry& en = by_col[size_t(e)];
      acc += en.j.dot(Eigen::Vector3f(y.data() + 3 * size_t(en.col)));
    }
    (*z)[size_t(j)] = acc;
  }
}

double Dot(const std::vector<float>& u, const std::vector<float>& v) {
  return OrderedSum<Eigen::Array<double, 1, 1>>(int64_t(u.size()), [&](int64_t i) {
    return Eigen::Array<double, 1, 1>(double(u[size_t(i)]) * v[size_t(i)]);
  })[0];
}

// CGLS from zero for min |J delta - residual|^2 + lambda |delta|^2.
std::vector<float> DensitySystem::SolveDamped(double lambda, int iterations) const {
  std::vector<float> delta(unknowns(), 0.0f), r = residual, s, q;
  MultiplyTransposed(r, &s);
  std::vector<float> p = s;
  double gamma = Dot(s, s);
  const double floor = 1e-12 * gamma;
  for (int it = 0; it < iterations && gamma > floor; ++it) {
    Multiply(p, &q);
    const double denom = Dot(q, q) + lambda * Dot(p, p);
    if (!(denom > 0.0)) break;
    const float alpha = float(gamma / denom);
    for (size_t i = 0; i < delta.size(); ++i) delta[i] += alpha * p[i];
    for (size_t i = 0; i < r.size(); ++i) r[i] -= alpha * q[i];
    MultiplyTransposed(r, &s);
    for (size_t i = 0; i < s.size(); ++i) s[i] -= float(lambda) * delta[i];
    const double next = Dot(s, s);
    const float beta = float(next / gamma);
    for (size_t i = 0; i < p.size(); ++i) p[i] = s[i] + beta * p[i];
    gamma = next;
  }
  return delta;
}

// The rays of `targets` the fit uses: a hashed share of about `rays`.
std::vector<int> ChooseRays(const FitTargets& targets, int rays) {
  const int n = targets.size();
  const double share = std::min(1.0, double(rays) / std::max(1, n));
  const uint32_t keep_below = share >= 1.0 ? 0xFFFFFFFFu : uint32_t(share * 4294967296.0);
  std::vector<int> chosen;
  for (int r = 0; r < n; ++r) {
    if (share >= 1.0 || Hash(uint32_t(r) ^ 0x5BD1E995u) < keep_below) chosen.push_back(r);
  }
  return chosen;
}

// The rms of per-ray squared residuals (3 channels each), summed in ray
// order.
double RmsOf(const std::vector<double>& sq) {
  double sum = 0.0;
  for (double v : sq) sum += v;
  return sq.empty() ? 0.0 : std::sqrt(sum / (3.0 * double(sq.size())));
}

// Linearises the chosen rays' pixels at `codes`: the rows of J (rays that
// meet no occupied block have none and are left out) and their residuals;
// *rms gets the residual of every chosen ray (RaysRms at `codes`). Each
// thread builds a contiguous share; joined in ray order.
DensitySystem BuildSystem(const BakedAsset& a, const FitTargets& targets, const std::vector<int>& rays,
                          const std::vector<float>& codes, const std::vector<float>& rgb, double* rms) {
  const int threads = omp_get_max_threads();
  std::vector<DensitySystem> part(static_cast<size_t>(threads));
  std::vector<double> sq(rays.size());
#pragma omp parallel num_threads(threads)
  {
    DensitySystem& mine = part[size_t(omp_get_thread_num())];
    std::vector<std::pair<uint32_t, Eigen::Vector3f>> jac;
#pragma omp for schedule(static)
    for (size_t k = 0; k < rays.size(); ++k) {
      const size_t r = size_t(rays[k]);
      const Eigen::Vector3f o(targets.origins.data() + 3 * r), d(targets.dirs.data() + 3 * r);
      const Eigen::Vector3f px = BakedRayDensityJacobian(a, codes.data(), rgb.data(), o, d, &jac);
      sq[k] = (Eigen::Vector3f(targets.rgb.data() + 3 * r) - px).cast<double>().squaredNorm();
      if (jac.empty()) continue;
      for (const auto& [id, j] : jac) {
        if (j.cwiseAbs().maxCoeff() >= kMinDerivative) mine.entries.push_back({id, j});
      }
      mine.start.push_back(int64_t(mine.entries.size()));
      for (int c = 0; c < 3; ++c) mine.residual.push_back(targets.rgb[3 * r + size_t(c)] - px[c]);
    }
  }
  DensitySystem all;
  for (DensitySystem& p : part) {
    const int64_t base = int64_t(all.entries.size());
    for (size_t i = 1; i < p.start.size(); ++i) all.start.push_back(base + p.start[i]);
    all.entries.insert(all.entries.end(), p.entries.begin(), p.entries.end());
    all.residual.insert(all.residual.end(), p.residual.begin(), p.residual.end());
    p = DensitySystem();
  }
  *rms = RmsOf(sq);
  return all;
}

// The rms residual of the chosen rays' pixels at `codes` (every ray, those
// that meet no block included: they add their constant share).
double RaysRms(const BakedAsset& a, const FitTargets& targets, const std::vector<int>& rays,
               const std::vector<float>& codes, const std::vector<float>& rgb) {
  std::vector<double> sq(rays.size());
#pragma omp parallel for schedule(static)
  for (size_t k = 0; k < rays.size(); ++k) {
    const size_t r = size_t(rays[k]);
    const Eigen::Vector3f o(targets.origins.data() + 3 * r), d(targets.dirs.data() + 3 * r);
    const Eigen::Vector3f px = BakedRayDensityJacobian(a, codes.data(), rgb.data(), o, d, nullptr);
    sq[k] = (Eigen::Vector3f(targets.rgb.data() + 3 * r) - px).cast<double>().squaredNorm();
  }
  return RmsOf(sq);
}

}  // namespace

Eigen::Vector3f BakedRayDensityJacobian(const BakedAsset& asset, const float* codes, const float* rgb,
                                        const Eigen::Vector3f& o, const Eigen::Vector3f& d,
                                        std::vector<std::pair<uint32_t, Eigen::Vector3f>>* jacobian, float* T) {
  thread_local std::vector<Sample> samples;
  float T_end = 1.0f;
  const Eigen::Vector3f pixel = MarchSamples(asset, codes, rgb, o, d, &samples, &T_end);
  if (T != nullptr) *T = T_end;
  if (jacobian != nullptr) Backward(samples, rgb, T_end * asset.background, jacobian);
  return pixel;
}

absl::Status DensityFitOptions::Validate() const {
  if (rays < 0) return absl::InvalidArgumentError("bake: the density fit's rays must be >= 0");
  if (steps < 0 || steps > 100) return absl::InvalidArgumentError("bake: density-fit steps must be in [0, 100]");
  if (iterations < 1 || iterations > 1000) {
    return absl::InvalidArgumentError("bake: density-fit iterations must be in [1, 1000]");
  }
  if (!(prior > 0.0f && std::isfinite(prior))) {
    return absl::InvalidArgumentError("bake: density-fit prior must be positive");
  }
  return absl::OkStatus();
}

absl::Status FitBakedDensities(const FitTargets& targets, const DensityFitOptions& options,
                               const std::vector<float>& rgb, BakedAsset* asset, DensityFitReport* report) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  const size_t points = size_t(kBrickLattice) * size_t(asset->num_bricks());
  if (rgb.size() != 3 * points) return absl::InvalidArgumentError("bake: colour array does not match the atlas");
  DensityFitReport rep;
  const auto t0 = std::chrono::steady_clock::now();
  if (options.rays == 0 || options.steps == 0 || targets.size() == 0 || points == 0) {
    if (report != nullptr) *report = rep;
    return absl::OkStatus();
  }
  std::vector<float> codes(points);
  for (size_t i = 0; i < points; ++i) {
    codes[i] = float(asset->atlas[4 * LatticeTexel(*asset, uint32_t(i)) + 3]) / 255.0f;
  }
  const std::vector<int> rays = ChooseRays(targets, options.rays);
  double rms = 0.0;
  DensitySystem J = BuildSystem(*asset, targets, rays, codes, rgb, &rms);
  rep.rms_before = rms;
  for (int step = 0; step < options.steps; ++step) {
    if (step > 0) {
      double same = 0.0;  // The accepted codes' rms, already known.
      J = BuildSystem(*asset, targets, rays, codes, rgb, &same);
    }
    J.Number(points);
    J.Transpose();
    rep.rays = J.rows();
    rep.unknowns = int64_t(J.unknowns());
    rep.nonzeros = int64_t(J.entries.size());
    if (J.unknowns() == 0) break;
    const double diag = OrderedSum<Eigen::Array<double, 1, 1>>(int64_t(J.entries.size()), [&](int64_t e) {
                          return Eigen::Array<double, 1, 1>(double(J.entries[size_t(e)].j.squaredNorm()));
                        })[0] / double(J.unknowns());
    const std::vector<float> delta = J.SolveDamped(options.prior * diag, options.iterations);
    std::vector<float> next = codes;
    for (size_t u = 0; u < J.unknowns(); ++u) next[J.point[u]] = std::clamp(codes[J.point[u]] + delta[u], 0.0f, 1.0f);
    const double next_rms = RaysRms(*asset, targets, rays, next, rgb);
    if (!(next_rms < rms)) break;  // The linearisation no longer holds: keep the codes.
    codes.swap(next);
    rms = next_rms;
    ++rep.accepted_steps;
  }
  rep.rms_after = rms;
  for (size_t i = 0; i < points; ++i) {
    asset->atlas[4 * LatticeTexel(*asset, uint32_t(i)) + 3] = uint8_t(std::lround(255.0f * codes[i]));
  }
  rep.seconds = Since(t0);
  if (report != nullptr) *report = rep;
  return absl::OkStatus();
}

}  // namespace clnerf
