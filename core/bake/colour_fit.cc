#include "core/bake/colour_fit.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>

#include "absl/strings/str_format.h"
#include "core/bake/baked_march.h"
#include "core/render/renderer.h"

namespace clnerf {
namespace {

constexpr int kLattice = kBakeBrick * kBakeBrick * kBakeBrick;

double Since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The fit's rays in model space: one per stride x stride pixel cell of every
// camera, at a hashed position inside the cell (so that they are not the
// visibility pass's cell centres, and cover the cell over cameras).
void FitRays(const BakedAsset& a, const std::vector<Camera>& cameras, int rays, std::vector<float>* origins,
             std::vector<float>* dirs) {
  double pixels = 0;
  for (const Camera& c : cameras) pixels += double(c.intrinsics.width) * c.intrinsics.height;
  const int stride = std::max(1, int(std::ceil(std::sqrt(pixels / double(rays)))));
  for (size_t ci = 0; ci < cameras.size(); ++ci) {
    const Camera cam = BakedModelCamera(a, cameras[ci]);
    for (int gy = 0; gy * stride < cam.intrinsics.height; ++gy) {
      for (int gx = 0; gx * stride < cam.intrinsics.width; ++gx) {
        uint32_t h = uint32_t(ci) * 0x9E3779B1u ^ uint32_t(gx) * 0x85EBCA77u ^ uint32_t(gy) * 0xC2B2AE3Du;
        h ^= h >> 15;
        h *= 0x2C1B3C6Du;
        h ^= h >> 12;
        const int x = std::min(gx * stride + int(h % uint32_t(stride)), cam.intrinsics.width - 1);
        const int y = std::min(gy * stride + int((h >> 16) % uint32_t(stride)), cam.intrinsics.height - 1);
        Eigen::Vector3f o, d;
        cam.Ray(float(x) + 0.5f, float(y) + 0.5f, &o, &d);
        origins->insert(origins->end(), o.data(), o.data() + 3);
        dirs->insert(dirs->end(), d.data(), d.data() + 3);
      }
    }
  }
}

// A's rows (compressed sparse rows over lattice points, brick * 9^3 +
// local index) and each ray's target: the model's pixel minus what the
// asset's background contributes.
struct Rows {
  std::vector<int64_t> start = {0};
  std::vector<uint32_t> col;
  std::vector<float> val;
  std::vector<float> target;  // 3 per row.
};

// The 8 corners the last sample blended: lattice ids, their trilinear
// weights times their density codes (in [0, 1]).
struct Corners {
  uint32_t id[8];
  float wa[8];
};

// Samples the density codes of `a` at u in block b, recording the corners.
bool SampleCodes(const BakedAsset& a, const Eigen::Vector3f& u, const int b[3], Corners* c, Eigen::Vector4f* rgba) {
  const int nb = a.blocks_per_axis();
  const uint32_t e = a.index[size_t(b[0]) + size_t(nb) * (size_t(b[1]) + size_t(nb) * size_t(b[2]))];
  if (e == 0) return false;
  const uint32_t brick = e - 1, bx = uint32_t(a.bricks[0]), by = uint32_t(a.bricks[1]);
  const size_t ox = size_t(brick % bx) * kBakeBrick, oy = size_t((brick / bx) % by) * kBakeBrick,
               oz = size_t(brick / (bx * by)) * kBakeBrick;
  const std::array<int, 3> dims = a.atlas_texels();
  int i0[3];
  float f[3];
  for (int k = 0; k < 3; ++k) {
    const float l = std::clamp(u[k] - float(kBakeBlock * b[k]), 0.0f, float(kBakeBlock));
    i0[k] = std::min(int(l), kBakeBlock - 1);
    f[k] = l - float(i0[k]);
  }
  float A = 0.0f;
  for (int corner = 0; corner < 8; ++corner) {
    const int dx = corner & 1, dy = (corner >> 1) & 1, dz = corner >> 2;
    const int x = i0[0] + dx, y = i0[1] + dy, z = i0[2] + dz;
    const float w = (dx ? f[0] : 1.0f - f[0]) * (dy ? f[1] : 1.0f - f[1]) * (dz ? f[2] : 1.0f - f[2]);
    const size_t texel = (ox + size_t(x)) + size_t(dims[0]) * ((oy + size_t(y)) + size_t(dims[1]) * (oz + size_t(z)));
    const float code = float(a.atlas[4 * texel + 3]) / 255.0f;
    c->id[corner] = brick * uint32_t(kLattice) + uint32_t(x + kBakeBrick * (y + kBakeBrick * z));
    c->wa[corner] = w * code;
    A += w * code;
  }
  *rgba = Eigen::Vector4f(0, 0, 0, A);
  return true;
}

// One ray's row: march the asset, collect each corner's share of the pixel
// (sample weight * trilinear weight * code / blended code), merge repeats.
// Returns the final transmittance.
float RayRow(const BakedAsset& a, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
             std::vector<std::pair<uint32_t, float>>* row) {
  row->clear();
  Corners c;
  const float T = MarchBaked(
      a, o, d, [&](int, const Eigen::Vector3f& u, const int b[3], Eigen::Vector4f* rgba) {
        return SampleCodes(a, u, b, &c, rgba);
      },
      [&](int, float weight, float, const Eigen::Vector4f& rgba) {
        const float s = weight / std::max(rgba[3], 1.0f / 255.0f);
        for (int k = 0; k < 8; ++k) {
          if (c.wa[k] > 0.0f) row->emplace_back(c.id[k], s * c.wa[k]);
        }
      });
  std::sort(row->begin(), row->end(), [](const auto& x, const auto& y) { return x.first < y.first; });
  size_t out = 0;
  for (size_t i = 0; i < row->size(); ++i) {
    if (out > 0 && (*row)[out - 1].first == (*row)[i].first) {
      (*row)[out - 1].second += (*row)[i].second;
    } else {
      (*row)[out++] = (*row)[i];
    }
  }
  row->resize(out);
  return T;
}

Rows BuildRows(const BakedAsset& a, const std::vector<float>& origins, const std::vector<float>& dirs,
               const std::vector<float>& model_rgb) {
  const int n = int(origins.size() / 3);
  const int threads = omp_get_max_threads();
  std::vector<Rows> part(static_cast<size_t>(threads));
#pragma omp parallel num_threads(threads)
  {
    Rows& mine = part[size_t(omp_get_thread_num())];
    std::vector<std::pair<uint32_t, float>> row;
#pragma omp for schedule(static)
    for (int r = 0; r < n; ++r) {
      const Eigen::Vector3f o(origins.data() + 3 * size_t(r)), d(dirs.data() + 3 * size_t(r));
      const float T = RayRow(a, o, d, &row);
      if (row.empty()) continue;  // Nothing to fit: the ray sees only background.
      for (const auto& [id, v] : row) {
        mine.col.push_back(id);
        mine.val.push_back(v);
      }
      mine.start.push_back(int64_t(mine.col.size()));
      for (int c = 0; c < 3; ++c) mine.target.push_back(model_rgb[3 * size_t(r) + c] - T * a.background[c]);
    }
  }
  Rows all;
  for (Rows& p : part) {  // Static schedule: thread order is ray order.
    const int64_t base = int64_t(all.col.size());
    for (size_t i = 1; i < p.start.size(); ++i) all.start.push_back(base + p.start[i]);
    all.col.insert(all.col.end(), p.col.begin(), p.col.end());
    all.val.insert(all.val.end(), p.val.begin(), p.val.end());
    all.target.insert(all.target.end(), p.target.begin(), p.target.end());
  }
  return all;
}

// y (rows x 3) = A x (unknowns x 3).
void MultiplyA(const Rows& A, const std::vector<float>& x, std::vector<float>* y) {
  const int64_t m = int64_t(A.start.size()) - 1;
  y->assign(size_t(3 * m), 0.0f);
#pragma omp parallel for schedule(static)
  for (int64_t r = 0; r < m; ++r) {
    float acc[3] = {0, 0, 0};
    for (int64_t k = A.start[r]; k < A.start[r + 1]; ++k) {
      const float v = A.val[k];
      const float* xc = x.data() + 3 * size_t(A.col[k]);
      for (int c = 0; c < 3; ++c) acc[c] += v * xc[c];
    }
    for (int c = 0; c < 3; ++c) (*y)[3 * size_t(r) + c] = acc[c];
  }
}

// z (unknowns x 3) = A^T y (rows x 3), per-thread partial sums added up.
void MultiplyAt(const Rows& A, const std::vector<float>& y, size_t unknowns, std::vector<std::vector<float>>* scratch,
                std::vector<float>* z) {
  const int64_t m = int64_t(A.start.size()) - 1;
  const int threads = int(scratch->size());
#pragma omp parallel num_threads(threads)
  {
    std::vector<float>& mine = (*scratch)[size_t(omp_get_thread_num())];
    mine.assign(3 * unknowns, 0.0f);
#pragma omp for schedule(static)
    for (int64_t r = 0; r < m; ++r) {
      const float* yr = y.data() + 3 * size_t(r);
      for (int64_t k = A.start[r]; k < A.start[r + 1]; ++k) {
        float* zc = mine.data() + 3 * size_t(A.col[k]);
        for (int c = 0; c < 3; ++c) zc[c] += A.val[k] * yr[c];
      }
    }
  }
  z->assign(3 * unknowns, 0.0f);
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < int64_t(3 * unknowns); ++i) {
    float s = 0.0f;
    for (const std::vector<float>& p : *scratch) s += p[size_t(i)];
    (*z)[size_t(i)] = s;
  }
}

// Per-channel dot products of two (n x 3) arrays.
Eigen::Array3d Dot3(const std::vector<float>& u, const std::vector<float>& v) {
  Eigen::Array3d s = Eigen::Array3d::Zero();
  for (size_t i = 0; i < u.size(); ++i) s[i % 3] += double(u[i]) * double(v[i]);
  return s;
}

// CGLS for min |A delta - r0|^2 + lambda |delta|^2, each channel its own
// system over the same A. Returns delta.
std::vector<float> SolveDamped(const Rows& A, const std::vector<float>& r0, size_t unknowns, double lambda,
                               int iterations) {
  std::vector<std::vector<float>> scratch(static_cast<size_t>(omp_get_max_threads()));
  std::vector<float> delta(3 * unknowns, 0.0f), r = r0, s, q;
  MultiplyAt(A, r, unknowns, &scratch, &s);
  std::vector<float> p = s;
  Eigen::Array3d gamma = Dot3(s, s);
  for (int it = 0; it < iterations; ++it) {
    MultiplyA(A, p, &q);
    const Eigen::Array3d denom = Dot3(q, q) + lambda * Dot3(p, p);
    Eigen::Array3d alpha;
    for (int c = 0; c < 3; ++c) alpha[c] = denom[c] > 0 ? gamma[c] / denom[c] : 0.0;
    for (size_t i = 0; i < delta.size(); ++i) delta[i] += float(alpha[i % 3]) * p[i];
    for (size_t i = 0; i < r.size(); ++i) r[i] -= float(alpha[i % 3]) * q[i];
    MultiplyAt(A, r, unknowns, &scratch, &s);
    for (size_t i = 0; i < s.size(); ++i) s[i] -= float(lambda) * delta[i];
    const Eigen::Array3d next = Dot3(s, s);
    for (size_t i = 0; i < p.size(); ++i) p[i] = s[i] + float(gamma[i % 3] > 0 ? next[i % 3] / gamma[i % 3] : 0.0) * p[i];
    gamma = next;
  }
  return delta;
}

double Rms(const std::vector<float>& r) {
  double s = 0;
  for (float v : r) s += double(v) * v;
  return r.empty() ? 0.0 : std::sqrt(s / double(r.size()));
}

}  // namespace

absl::Status ColourFitOptions::Validate() const {
  if (rays < 0) return absl::InvalidArgumentError("bake: the colour fit's rays must be >= 0");
  if (iterations < 0 || iterations > 1000) return absl::InvalidArgumentError("bake: fit iterations must be in [0, 1000]");
  if (!(prior > 0.0f && std::isfinite(prior))) return absl::InvalidArgumentError("bake: fit prior must be positive");
  return absl::OkStatus();
}

absl::Status FitBakedColours(const NgpModel& model, int time_step, const std::vector<Camera>& cameras,
                             const BakedAsset& asset, const ColourFitOptions& options, std::vector<float>* rgb,
                             ColourFitReport* report) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (rgb->size() != size_t(3 * kLattice) * size_t(asset.num_bricks())) {
    return absl::InvalidArgumentError("bake: colour array does not match the atlas");
  }
  ColourFitReport rep;
  if (options.rays == 0 || options.iterations == 0 || cameras.empty() || asset.num_bricks() == 0) {
    if (report != nullptr) *report = rep;
    return absl::OkStatus();
  }
  auto t0 = std::chrono::steady_clock::now();
  std::vector<float> origins, dirs;
  FitRays(asset, cameras, options.rays, &origins, &dirs);
  const int n = int(origins.size() / 3);
  RenderOptions ro;
  ro.time_step = time_step;
  ro.min_weight = 0.0f;  // Every sample coloured: the targets are the model's exact pixels.
  std::vector<float> model_rgb(3 * size_t(n));
  RenderRays(model, origins.data(), dirs.data(), n, time_step, ro, model_rgb.data(), nullptr, nullptr);
  rep.target_seconds = Since(t0);
  t0 = std::chrono::steady_clock::now();
  Rows A = BuildRows(asset, origins, dirs, model_rgb);
  // Columns renumbered to the lattice points some ray blends.
  std::vector<int32_t> compact(rgb->size() / 3, -1);
  std::vector<uint32_t> point;  // Compact -> lattice id.
  for (uint32_t& c : A.col) {
    if (compact[c] < 0) {
      compact[c] = int32_t(point.size());
      point.push_back(c);
    }
    c = uint32_t(compact[c]);
  }
  const size_t unknowns = point.size();
  std::vector<float> x0(3 * unknowns);
  for (size_t j = 0; j < unknowns; ++j) {
    for (int c = 0; c < 3; ++c) x0[3 * j + c] = (*rgb)[3 * size_t(point[j]) + c];
  }
  std::vector<float> r0;
  MultiplyA(A, x0, &r0);
  for (size_t i = 0; i < r0.size(); ++i) r0[i] = A.target[i] - r0[i];
  std::vector<double> diag(unknowns, 0.0);
  for (size_t k = 0; k < A.col.size(); ++k) diag[A.col[k]] += double(A.val[k]) * A.val[k];
  double mean_diag = 0;
  for (double v : diag) mean_diag += v;
  mean_diag = unknowns > 0 ? mean_diag / double(unknowns) : 1.0;
  rep.rows_seconds = Since(t0);
  t0 = std::chrono::steady_clock::now();
  const std::vector<float> delta = SolveDamped(A, r0, unknowns, options.prior * mean_diag, options.iterations);
  for (size_t j = 0; j < unknowns; ++j) {
    for (int c = 0; c < 3; ++c) {
      (*rgb)[3 * size_t(point[j]) + c] = std::clamp(x0[3 * j + c] + delta[3 * j + c], 0.0f, 1.0f);
    }
  }
  std::vector<float> fitted(3 * unknowns), r1;
  for (size_t j = 0; j < unknowns; ++j) {
    for (int c = 0; c < 3; ++c) fitted[3 * j + c] = (*rgb)[3 * size_t(point[j]) + c];
  }
  MultiplyA(A, fitted, &r1);
  for (size_t i = 0; i < r1.size(); ++i) r1[i] = A.target[i] - r1[i];
  rep.solve_seconds = Since(t0);
  rep.rays = int64_t(A.start.size()) - 1;
  rep.unknowns = int64_t(unknowns);
  rep.nonzeros = int64_t(A.col.size());
  rep.rms_before = Rms(r0);
  rep.rms_after = Rms(r1);
  if (report != nullptr) *report = rep;
  return absl::OkStatus();
}

}  // namespace clnerf
