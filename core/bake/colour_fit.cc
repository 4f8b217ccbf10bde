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

// A's rows (compressed sparse rows) and each ray's target: the model's
// pixel minus what the asset's background contributes. Entries name
// lattice points (brick * 9^3 + local index) until FitBakedColours numbers
// the unknowns: the diffuse colours of P points are columns [0, P), the
// view-dependent terms of V points columns [P, P + V).
struct Rows {
  std::vector<int64_t> start = {0};
  std::vector<uint32_t> col;
  std::vector<float> val;
  std::vector<uint8_t> kind;  // Per entry: kDiffuseEntry or kViewEntry.
  std::vector<float> target;  // 3 per row.
  std::vector<float> dir;     // 3 per row: the ray's direction (model space).
};

// What an entry of A weighs: a point's diffuse colour c0, or its
// view-dependent term H (times the ray's direction).
constexpr uint8_t kDiffuseEntry = 1, kViewEntry = 2;

// The 8 corners the last sample blended: lattice ids, their trilinear
// weights times their density codes (in [0, 1]).
struct Corners {
  uint32_t id[8];
  float wa[8];
};

// Samples the density codes of `a` at u in block b, recording the corners.
bool SampleCodes(const BakedAsset& a, const Eigen::Vector3f& u, const int b[3], Corners* c, Eigen::Vector4f* rgba) {
  const int64_t brick = BlockBrick(a, b);
  if (brick < 0) return false;
  float l[3];
  LocalInBlock(u, b, l);
  const BrickCell cell = LocateInBrick(l);
  float A = 0.0f;
  for (int corner = 0; corner < 8; ++corner) {
    const int x = cell.x(corner), y = cell.y(corner), z = cell.z(corner);
    const float w = cell.weight(corner);
    const float code = float(a.atlas[4 * BrickTexel(a, uint32_t(brick), x, y, z) + 3]) / 255.0f;
    c->id[corner] = uint32_t(brick) * uint32_t(kLattice) + uint32_t(x + kBakeBrick * (y + kBakeBrick * z));
    c->wa[corner] = w * code;
    A += w * code;
  }
  *rgba = Eigen::Vector4f(0, 0, 0, A);
  return true;
}

// `view`: also the entries of the view-dependent term.
Rows BuildRows(const BakedAsset& a, const std::vector<float>& origins, const std::vector<float>& dirs,
               const std::vector<float>& model_rgb, bool view) {
  const int n = int(origins.size() / 3);
  const int threads = omp_get_max_threads();
  std::vector<Rows> part(static_cast<size_t>(threads));
#pragma omp parallel num_threads(threads)
  {
    Rows& mine = part[size_t(omp_get_thread_num())];
    std::vector<std::pair<uint32_t, float>> row, view_row;
#pragma omp for schedule(static)
    for (int r = 0; r < n; ++r) {
      const Eigen::Vector3f o(origins.data() + 3 * size_t(r)), d(dirs.data() + 3 * size_t(r));
      const float T = BakedRayWeights(a, o, d, &row, view ? &view_row : nullptr);
      if (row.empty()) continue;  // Nothing to fit: the ray sees only background.
      for (const auto& [id, v] : row) {
        mine.col.push_back(id);
        mine.val.push_back(v);
        mine.kind.push_back(kDiffuseEntry);
      }
      for (size_t k = 0; view && k < view_row.size(); ++k) {
        mine.col.push_back(view_row[k].first);
        mine.val.push_back(view_row[k].second);
        mine.kind.push_back(kViewEntry);
      }
      mine.start.push_back(int64_t(mine.col.size()));
      for (int c = 0; c < 3; ++c) mine.target.push_back(model_rgb[3 * size_t(r) + c] - T * a.background[c]);
      mine.dir.insert(mine.dir.end(), d.data(), d.data() + 3);
    }
  }
  Rows all;
  for (Rows& p : part) {  // Static schedule: thread order is ray order.
    const int64_t base = int64_t(all.col.size());
    for (size_t i = 1; i < p.start.size(); ++i) all.start.push_back(base + p.start[i]);
    all.col.insert(all.col.end(), p.col.begin(), p.col.end());
    all.val.insert(all.val.end(), p.val.begin(), p.val.end());
    all.kind.insert(all.kind.end(), p.kind.begin(), p.kind.end());
    all.target.insert(all.target.end(), p.target.begin(), p.target.end());
    all.dir.insert(all.dir.end(), p.dir.begin(), p.dir.end());
  }
  return all;
}

// Drops A's view entries (the fit is then diffuse).
void DropViewEntries(Rows* A) {
  Rows D;
  for (int64_t r = 0; r + 1 < int64_t(A->start.size()); ++r) {
    for (int64_t k = A->start[r]; k < A->start[r + 1]; ++k) {
      if (A->kind[k] != kDiffuseEntry) continue;
      D.col.push_back(A->col[k]);
      D.val.push_back(A->val[k]);
      D.kind.push_back(kDiffuseEntry);
    }
    D.start.push_back(int64_t(D.col.size()));
  }
  D.target = std::move(A->target);
  D.dir = std::move(A->dir);
  *A = std::move(D);
}

// The unknowns: P diffuse points (3 values each, channel fastest), then V
// view points (9 each: k = x, y, z, then channel). Column j's values start
// at Offset(j).
struct Unknowns {
  size_t diffuse = 0, view = 0;
  size_t Offset(uint32_t j) const { return j < diffuse ? 3 * size_t(j) : 3 * diffuse + 9 * (size_t(j) - diffuse); }
  size_t Values() const { return 3 * diffuse + 9 * view; }
  size_t Columns() const { return diffuse + view; }
};

// Renumbers A's columns from lattice ids (`points` of them) to unknowns:
// the diffuse colours of the points some ray blends, then the view terms
// of the points some ray's view entries name; *point and *view_point map
// them back to lattice ids.
Unknowns NumberUnknowns(size_t points, Rows* A, std::vector<uint32_t>* point, std::vector<uint32_t>* view_point) {
  std::vector<int32_t> compact(points, -1), compact_view(points, -1);
  for (size_t k = 0; k < A->col.size(); ++k) {
    const bool diffuse = A->kind[k] == kDiffuseEntry;
    std::vector<int32_t>& map = diffuse ? compact : compact_view;
    std::vector<uint32_t>& ids = diffuse ? *point : *view_point;
    if (map[A->col[k]] < 0) {
      map[A->col[k]] = int32_t(ids.size());
      ids.push_back(A->col[k]);
    }
    A->col[k] = uint32_t(map[A->col[k]]);
  }
  Unknowns u;
  u.diffuse = point->size();
  u.view = view_point->size();
  for (size_t k = 0; k < A->col.size(); ++k) {
    if (A->kind[k] == kViewEntry) A->col[k] += uint32_t(u.diffuse);
  }
  return u;
}

// y (rows x 3) = A x.
void MultiplyA(const Rows& A, const Unknowns& u, const std::vector<float>& x, std::vector<float>* y) {
  const int64_t m = int64_t(A.start.size()) - 1;
  y->assign(size_t(3 * m), 0.0f);
#pragma omp parallel for schedule(static)
  for (int64_t r = 0; r < m; ++r) {
    float acc[3] = {0, 0, 0};
    const float* d = A.dir.data() + 3 * size_t(r);
    for (int64_t k = A.start[r]; k < A.start[r + 1]; ++k) {
      const float* xc = x.data() + u.Offset(A.col[k]);
      const float v = A.val[k];
      if (A.kind[k] == kDiffuseEntry) {
        for (int c = 0; c < 3; ++c) acc[c] += v * xc[c];
      } else {
        for (int e = 0; e < 3; ++e) {
          for (int c = 0; c < 3; ++c) acc[c] += v * d[e] * xc[3 * e + c];
        }
      }
    }
    for (int c = 0; c < 3; ++c) (*y)[3 * size_t(r) + c] = acc[c];
  }
}

// A's columns (compressed sparse columns): for each unknown, the rows that
// blend it and their weights, so that A^T y is a gather per unknown
// (parallel, no per-thread copies of the result to add up).
struct Columns {
  std::vector<int64_t> start;
  std::vector<uint32_t> row;
  std::vector<float> val;
};

Columns Transpose(const Rows& A, size_t columns) {
  Columns C;
  C.start.assign(columns + 1, 0);
  for (uint32_t c : A.col) ++C.start[c + 1];
  for (size_t j = 0; j < columns; ++j) C.start[j + 1] += C.start[j];
  C.row.resize(A.col.size());
  C.val.resize(A.col.size());
  std::vector<int64_t> fill(C.start.begin(), C.start.end() - 1);
  const int64_t m = int64_t(A.start.size()) - 1;
  for (int64_t r = 0; r < m; ++r) {
    for (int64_t k = A.start[r]; k < A.start[r + 1]; ++k) {
      const int64_t at = fill[A.col[k]]++;
      C.row[at] = uint32_t(r);
      C.val[at] = A.val[k];
    }
  }
  return C;
}

// z = A^T y (the adjoint of MultiplyA).
void MultiplyAt(const Rows& A, const Columns& C, const Unknowns& u, const std::vector<float>& y,
                std::vector<float>* z) {
  z->assign(u.Values(), 0.0f);
  const int64_t columns = int64_t(u.Columns());
#pragma omp parallel for schedule(dynamic, 1024)
  for (int64_t j = 0; j < columns; ++j) {
    float acc[9] = {0};
    const bool view = size_t(j) >= u.diffuse;
    for (int64_t k = C.start[j]; k < C.start[j + 1]; ++k) {
      const size_t r = C.row[k];
      const float* yr = y.data() + 3 * r;
      if (!view) {
        for (int c = 0; c < 3; ++c) acc[c] += C.val[k] * yr[c];
        continue;
      }
      const float* d = A.dir.data() + 3 * r;
      for (int e = 0; e < 3; ++e) {
        for (int c = 0; c < 3; ++c) acc[3 * e + c] += C.val[k] * d[e] * yr[c];
      }
    }
    std::copy(acc, acc + (view ? 9 : 3), z->data() + u.Offset(uint32_t(j)));
  }
}

// Per-channel dot products of two (n x 3) arrays.
Eigen::Array3d Dot3(const std::vector<float>& u, const std::vector<float>& v) {
  const int64_t n = int64_t(u.size() / 3);
  double s0 = 0, s1 = 0, s2 = 0;
#pragma omp parallel for schedule(static) reduction(+ : s0, s1, s2)
  for (int64_t i = 0; i < n; ++i) {
    s0 += double(u[3 * i]) * v[3 * i];
    s1 += double(u[3 * i + 1]) * v[3 * i + 1];
    s2 += double(u[3 * i + 2]) * v[3 * i + 2];
  }
  return Eigen::Array3d(s0, s1, s2);
}

// y += a (per channel) * x over (n x 3) arrays.
void Axpy3(const Eigen::Array3d& a, const std::vector<float>& x, std::vector<float>* y) {
  const int64_t n = int64_t(x.size() / 3);
  const float a0 = float(a[0]), a1 = float(a[1]), a2 = float(a[2]);
  float* yd = y->data();
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < n; ++i) {
    yd[3 * i] += a0 * x[3 * i];
    yd[3 * i + 1] += a1 * x[3 * i + 1];
    yd[3 * i + 2] += a2 * x[3 * i + 2];
  }
}

// CGLS for min |A delta - r0|^2 + lambda |delta|^2, each channel its own
// system over the same A. Returns delta.
// CGLS for min |A delta - r0|^2 + lambda |delta|^2, each channel its own
// system over the same A. Returns delta.
std::vector<float> SolveDamped(const Rows& A, const Unknowns& u, const std::vector<float>& r0, double lambda,
                               int iterations) {
  const Columns C = Transpose(A, u.Columns());
  std::vector<float> delta(u.Values(), 0.0f), r = r0, s, q;
  MultiplyAt(A, C, u, r, &s);
  std::vector<float> p = s;
  Eigen::Array3d gamma = Dot3(s, s);
  for (int it = 0; it < iterations; ++it) {
    MultiplyA(A, u, p, &q);
    const Eigen::Array3d denom = Dot3(q, q) + lambda * Dot3(p, p);
    Eigen::Array3d alpha;
    for (int c = 0; c < 3; ++c) alpha[c] = denom[c] > 0 ? gamma[c] / denom[c] : 0.0;
    Axpy3(alpha, p, &delta);
    Axpy3(-alpha, q, &r);
    MultiplyAt(A, C, u, r, &s);
    Axpy3(Eigen::Array3d::Constant(-lambda), delta, &s);
    const Eigen::Array3d next = Dot3(s, s);
    Eigen::Array3d beta;
    for (int c = 0; c < 3; ++c) beta[c] = gamma[c] > 0 ? next[c] / gamma[c] : 0.0;
    // p = s + beta p.
    const int64_t n = int64_t(p.size() / 3);
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; ++i) {
      for (int c = 0; c < 3; ++c) p[3 * i + c] = s[3 * i + c] + float(beta[c]) * p[3 * i + c];
    }
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

namespace {

// Sorts (id, weight) pairs by id and merges repeated ids.
void MergeRepeats(std::vector<std::pair<uint32_t, float>>* row) {
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
}

}  // namespace

// One ray's row: march the asset, collect each corner's share of the pixel
// (sample weight * trilinear weight * code / blended code), merge repeats;
// for the view term at the median, the median sample's corners times the
// ray's opacity. Returns the final transmittance.
float BakedRayWeights(const BakedAsset& a, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
                      std::vector<std::pair<uint32_t, float>>* row,
                      std::vector<std::pair<uint32_t, float>>* view_row) {
  row->clear();
  Corners c, median;
  BakedMedian median_sample;
  const float T = MarchBaked(
      a, o, d, [&](int, const Eigen::Vector3f& u, const int b[3], Eigen::Vector4f* rgba) {
        return SampleCodes(a, u, b, &c, rgba);
      },
      [&](int, float weight, float, const Eigen::Vector4f& rgba) {
        const float s = weight / std::max(rgba[3], 1.0f / 255.0f);
        for (int k = 0; k < 8; ++k) {
          if (c.wa[k] > 0.0f) row->emplace_back(c.id[k], s * c.wa[k]);
        }
        if (median_sample.Step(weight)) {
          median = c;
          for (float& v : median.wa) v /= std::max(rgba[3], 1.0f / 255.0f);
        }
      });
  MergeRepeats(row);
  if (view_row != nullptr) {
    if (a.view_term == BakedViewTerm::kPerSample) {
      *view_row = *row;
    } else {
      view_row->clear();
      for (int k = 0; median_sample.found() && k < 8; ++k) {
        if (median.wa[k] > 0.0f) view_row->emplace_back(median.id[k], (1.0f - T) * median.wa[k]);
      }
      MergeRepeats(view_row);
    }
  }
  return T;
}

absl::Status ColourFitOptions::Validate() const {
  if (rays < 0) return absl::InvalidArgumentError("bake: the colour fit's rays must be >= 0");
  if (iterations < 0 || iterations > 1000) return absl::InvalidArgumentError("bake: fit iterations must be in [0, 1000]");
  if (max_view_nonzeros < 0) return absl::InvalidArgumentError("bake: max_view_nonzeros must be >= 0");
  if (!(prior > 0.0f && std::isfinite(prior))) return absl::InvalidArgumentError("bake: fit prior must be positive");
  return absl::OkStatus();
}

absl::Status FitBakedColours(const NgpModel& model, int time_step, const std::vector<Camera>& cameras,
                             const BakedAsset& asset, const ColourFitOptions& options, std::vector<float>* rgb,
                             std::vector<float>* view, ColourFitReport* report) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (rgb->size() != size_t(3 * kLattice) * size_t(asset.num_bricks()) ||
      (view != nullptr && view->size() != 3 * rgb->size())) {
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
  // The targets are the pixels the model itself serves (RenderView's defaults).
  std::vector<float> model_rgb(3 * size_t(n));
  RenderRays(model, origins.data(), dirs.data(), n, time_step, ro, model_rgb.data(), nullptr, nullptr);
  rep.target_seconds = Since(t0);
  t0 = std::chrono::steady_clock::now();
  const bool want_view = view != nullptr;
  Rows A = BuildRows(asset, origins, dirs, model_rgb, want_view);
  int64_t view_entries = 0;  // Entries that weigh H (format 2: one per diffuse entry).
  for (uint8_t k : A.kind) view_entries += k == kViewEntry;
  if (view != nullptr && view_entries > options.max_view_nonzeros) {
    view->clear();
    view = nullptr;
    DropViewEntries(&A);
  }
  rep.view_dependent = view != nullptr;
  std::vector<uint32_t> point, view_point;  // Compact -> lattice id.
  const Unknowns u = NumberUnknowns(rgb->size() / 3, &A, &point, &view_point);
  std::vector<float> x0(u.Values(), 0.0f);  // The field's colours; no view dependence.
  for (size_t j = 0; j < u.diffuse; ++j) {
    for (int c = 0; c < 3; ++c) x0[3 * j + c] = (*rgb)[3 * size_t(point[j]) + c];
  }
  std::vector<float> r0;
  MultiplyA(A, u, x0, &r0);
  for (size_t i = 0; i < r0.size(); ++i) r0[i] = A.target[i] - r0[i];
  std::vector<double> diag(u.diffuse, 0.0);
  for (size_t k = 0; k < A.col.size(); ++k) {
    if (A.kind[k] == kDiffuseEntry) diag[A.col[k]] += double(A.val[k]) * A.val[k];
  }
  double mean_diag = 0;
  for (double v : diag) mean_diag += v;
  mean_diag = u.diffuse > 0 ? mean_diag / double(u.diffuse) : 1.0;
  rep.rows_seconds = Since(t0);
  t0 = std::chrono::steady_clock::now();
  const std::vector<float> delta = SolveDamped(A, u, r0, options.prior * mean_diag, options.iterations);
  // Clamped to what the atlases store: colour in [0, 1], H in [-1, 1].
  std::vector<float> fitted(u.Values());
  for (size_t i = 0; i < fitted.size(); ++i) {
    fitted[i] = std::clamp(x0[i] + delta[i], i < 3 * u.diffuse ? 0.0f : -1.0f, 1.0f);
  }
  for (size_t j = 0; j < u.diffuse; ++j) {
    for (int c = 0; c < 3; ++c) (*rgb)[3 * size_t(point[j]) + c] = fitted[3 * j + c];
  }
  for (size_t j = 0; view != nullptr && j < u.view; ++j) {
    for (int e = 0; e < 9; ++e) (*view)[9 * size_t(view_point[j]) + e] = fitted[3 * u.diffuse + 9 * j + e];
  }
  std::vector<float> r1;
  MultiplyA(A, u, fitted, &r1);
  for (size_t i = 0; i < r1.size(); ++i) r1[i] = A.target[i] - r1[i];
  rep.solve_seconds = Since(t0);
  rep.rays = int64_t(A.start.size()) - 1;
  rep.unknowns = int64_t(u.diffuse + u.view);
  rep.nonzeros = int64_t(A.col.size());
  rep.rms_before = Rms(r0);
  rep.rms_after = Rms(r1);
  if (report != nullptr) *report = rep;
  return absl::OkStatus();
}

}  // namespace clnerf
