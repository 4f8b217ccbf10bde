#include "core/bake/fit_system.h"

#include <omp.h>

#include <algorithm>
#include <atomic>

namespace clnerf {
namespace {

// SolveDamped stops a channel once |A^T r - lambda delta|^2 is this fraction
// of its start (|A^T r0|^2): float arithmetic resolves no further.
constexpr double kSolvedResidualFraction = 1e-12;

// Per-channel dot products of two (n x 3) arrays.
Eigen::Array3d Dot3(const std::vector<float>& u, const std::vector<float>& v) {
  return OrderedSum<Eigen::Array3d>(int64_t(u.size() / 3), [&](int64_t i) {
    return Eigen::Array3d(double(u[3 * i]) * v[3 * i], double(u[3 * i + 1]) * v[3 * i + 1],
                          double(u[3 * i + 2]) * v[3 * i + 2]);
  });
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

// Marks the columns `rows` names in `used` (one int32 per lattice point,
// set to 0), in parallel.
void MarkUsed(const SparseRows& rows, std::vector<int32_t>* used) {
  const int64_t n = int64_t(rows.col.size());
#pragma omp parallel for schedule(static)
  for (int64_t k = 0; k < n; ++k) std::atomic_ref<int32_t>((*used)[rows.col[size_t(k)]]).store(0, std::memory_order_relaxed);
}

// Numbers the marked points in lattice order; renumbers the columns.
void Renumber(std::vector<int32_t>* used, SparseRows* rows, std::vector<uint32_t>* point) {
  point->clear();
  for (size_t p = 0; p < used->size(); ++p) {
    if ((*used)[p] < 0) continue;
    (*used)[p] = int32_t(point->size());
    point->push_back(uint32_t(p));
  }
  const int64_t n = int64_t(rows->col.size());
#pragma omp parallel for schedule(static)
  for (int64_t k = 0; k < n; ++k) rows->col[size_t(k)] = uint32_t((*used)[rows->col[size_t(k)]]);
}

// The columns of `rows` (`columns` of them), deterministically in parallel:
// each thread counts and then places the entries of its own range of rows,
// at offsets that keep every column in row order.
SparseColumns TransposeRows(const SparseRows& rows, size_t columns) {
  SparseColumns C;
  const int64_t m = int64_t(rows.start.size()) - 1;
  const int threads = std::max(1, omp_get_max_threads());
  std::vector<std::vector<int64_t>> at(size_t(threads), std::vector<int64_t>(columns, 0));
  C.row.resize(rows.col.size());
  C.val.resize(rows.col.size());
  C.start.assign(columns + 1, 0);
#pragma omp parallel num_threads(threads)
  {
    const int t = omp_get_thread_num(), nt = omp_get_num_threads();
    const int64_t r0 = m * t / nt, r1 = m * (t + 1) / nt;
    std::vector<int64_t>& mine = at[size_t(t)];
    for (int64_t k = rows.start[size_t(r0)]; k < rows.start[size_t(r1)]; ++k) ++mine[rows.col[size_t(k)]];
#pragma omp barrier
#pragma omp single
    {
      int64_t next = 0;
      for (size_t j = 0; j < columns; ++j) {
        C.start[j] = next;
        for (int p = 0; p < nt; ++p) {
          const int64_t count = at[size_t(p)][j];
          at[size_t(p)][j] = next;
          next += count;
        }
      }
      C.start[columns] = next;
    }
    for (int64_t r = r0; r < r1; ++r) {
      for (int64_t k = rows.start[size_t(r)]; k < rows.start[size_t(r) + 1]; ++k) {
        const int64_t to = mine[rows.col[size_t(k)]]++;
        C.row[size_t(to)] = uint32_t(r);
        C.val[size_t(to)] = rows.val[size_t(k)];
      }
    }
  }
  return C;
}

// Appends `part` to `all` at the given row and entry offsets (all sized).
void PlaceRows(const SparseRows& part, int64_t row_at, int64_t entry_at, SparseRows* all) {
  for (size_t i = 1; i < part.start.size(); ++i) all->start[size_t(row_at) + i] = entry_at + part.start[i];
  std::copy(part.col.begin(), part.col.end(), all->col.begin() + entry_at);
  std::copy(part.val.begin(), part.val.end(), all->val.begin() + entry_at);
}

}  // namespace

void SparseRows::Append(const std::vector<std::pair<uint32_t, float>>& row) {
  for (const auto& [c, v] : row) {
    col.push_back(c);
    val.push_back(v);
  }
  start.push_back(int64_t(col.size()));
}

void FitSystem::AppendRow(const std::vector<std::pair<uint32_t, float>>& diffuse_row,
                          const std::vector<std::pair<uint32_t, float>>& view_row, const float target_rgb[3],
                          const Eigen::Vector3f& direction) {
  diffuse.Append(diffuse_row);
  view.Append(view_row);
  target.insert(target.end(), target_rgb, target_rgb + 3);
  dir.insert(dir.end(), direction.data(), direction.data() + 3);
}

void FitSystem::DropViewEntries() {
  view.col.clear();
  view.val.clear();
  view.start.assign(diffuse.start.size(), 0);
  view_point.clear();
  view_cols = SparseColumns();
  if (!diffuse_cols.start.empty()) view_cols.start.assign(1, 0);  // Transposed already: no view columns.
}

void FitSystem::NumberUnknowns(size_t points) {
  std::vector<int32_t> used(points, -1);
  MarkUsed(diffuse, &used);
  Renumber(&used, &diffuse, &diffuse_point);
  used.assign(points, -1);
  MarkUsed(view, &used);
  Renumber(&used, &view, &view_point);
}

void FitSystem::Transpose() {
  diffuse_cols = TransposeRows(diffuse, num_diffuse());
  view_cols = TransposeRows(view, num_view());
}

void FitSystem::Multiply(const std::vector<float>& x, std::vector<float>* y) const {
  const int64_t m = rows();
  y->assign(size_t(3 * m), 0.0f);
  const float* xv = x.data() + 3 * num_diffuse();
#pragma omp parallel for schedule(static)
  for (int64_t r = 0; r < m; ++r) {
    float acc[3] = {0, 0, 0};
    for (int64_t k = diffuse.start[size_t(r)]; k < diffuse.start[size_t(r) + 1]; ++k) {
      const float* xc = x.data() + 3 * size_t(diffuse.col[size_t(k)]);
      const float v = diffuse.val[size_t(k)];
      for (int c = 0; c < 3; ++c) acc[c] += v * xc[c];
    }
    const float* d = dir.data() + 3 * size_t(r);
    for (int64_t k = view.start[size_t(r)]; k < view.start[size_t(r) + 1]; ++k) {
      const float* xc = xv + 9 * size_t(view.col[size_t(k)]);
      const float v = view.val[size_t(k)];
      for (int e = 0; e < 3; ++e) {
        for (int c = 0; c < 3; ++c) acc[c] += v * d[e] * xc[3 * e + c];
      }
    }
    for (int c = 0; c < 3; ++c) (*y)[3 * size_t(r) + c] = acc[c];
  }
}

void FitSystem::MultiplyTransposed(const std::vector<float>& y, std::vector<float>* z) const {
  z->assign(num_values(), 0.0f);
  const int64_t P = int64_t(num_diffuse()), V = int64_t(num_view());
  float* zv = z->data() + 3 * num_diffuse();
#pragma omp parallel
  {
#pragma omp for schedule(static, 4096)
    for (int64_t j = 0; j < P; ++j) {
      float acc[3] = {0, 0, 0};
      for (int64_t k = diffuse_cols.start[size_t(j)]; k < diffuse_cols.start[size_t(j) + 1]; ++k) {
        const float* yr = y.data() + 3 * size_t(diffuse_cols.row[size_t(k)]);
        const float v = diffuse_cols.val[size_t(k)];
        for (int c = 0; c < 3; ++c) acc[c] += v * yr[c];
      }
      std::copy(acc, acc + 3, z->data() + 3 * size_t(j));
    }
#pragma omp for schedule(static, 1024)
    for (int64_t j = 0; j < V; ++j) {
      float acc[9] = {0};
      for (int64_t k = view_cols.start[size_t(j)]; k < view_cols.start[size_t(j) + 1]; ++k) {
        const size_t r = view_cols.row[size_t(k)];
        const float* yr = y.data() + 3 * r;
        const float* d = dir.data() + 3 * r;
        const float v = view_cols.val[size_t(k)];
        for (int e = 0; e < 3; ++e) {
          for (int c = 0; c < 3; ++c) acc[3 * e + c] += v * d[e] * yr[c];
        }
      }
      std::copy(acc, acc + 9, zv + 9 * size_t(j));
    }
  }
}

double FitSystem::MeanDiffuseDiagonal() const {
  const int64_t P = int64_t(num_diffuse());
  if (P == 0) return 1.0;
  const double sum = OrderedSum<Eigen::Array<double, 1, 1>>(int64_t(diffuse_cols.val.size()), [&](int64_t k) {
    return Eigen::Array<double, 1, 1>(double(diffuse_cols.val[size_t(k)]) * diffuse_cols.val[size_t(k)]);
  })[0];
  return sum / double(P);
}

std::vector<float> FitSystem::SolveDamped(const std::vector<float>& r0, double lambda, int iterations) const {
  std::vector<float> delta(num_values(), 0.0f), r = r0, s, q;
  MultiplyTransposed(r, &s);
  std::vector<float> p = s;
  Eigen::Array3d gamma = Dot3(s, s);
  // A channel whose normal-equation residual |s|^2 has fallen to this
  // fraction of its start is solved to float precision: it stops, since
  // further steps divide rounding noise by rounding noise (beta) and grew
  // the error without bound (a 720-unknown system: 8e-7 relative after 100
  // steps, 1e32 after 1000).
  const Eigen::Array3d floor = kSolvedResidualFraction * gamma;
  for (int it = 0; it < iterations; ++it) {
    const Eigen::Array3d active = (gamma > floor).cast<double>();  // 1 per channel still solving.
    if ((active == 0).all()) break;
    Multiply(p, &q);
    const Eigen::Array3d denom = Dot3(q, q) + lambda * Dot3(p, p);
    Eigen::Array3d alpha;
    for (int c = 0; c < 3; ++c) alpha[c] = active[c] > 0 && denom[c] > 0 ? gamma[c] / denom[c] : 0.0;
    Axpy3(alpha, p, &delta);
    Axpy3(-alpha, q, &r);
    MultiplyTransposed(r, &s);
    Axpy3(Eigen::Array3d::Constant(-lambda), delta, &s);
    const Eigen::Array3d next = Dot3(s, s);
    Eigen::Array3d beta;
    for (int c = 0; c < 3; ++c) beta[c] = active[c] > 0 && gamma[c] > 0 ? next[c] / gamma[c] : 0.0;
    const int64_t n = int64_t(p.size() / 3);  // p = s + beta p.
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; ++i) {
      for (int c = 0; c < 3; ++c) p[3 * i + c] = s[3 * i + c] + float(beta[c]) * p[3 * i + c];
    }
    gamma = next;
  }
  return delta;
}

FitSystem JoinFitSystems(std::vector<FitSystem>* parts) {
  FitSystem all;
  int64_t rows = 0, d_entries = 0, v_entries = 0;
  std::vector<int64_t> row_at, d_at, v_at;
  for (const FitSystem& p : *parts) {
    row_at.push_back(rows);
    d_at.push_back(d_entries);
    v_at.push_back(v_entries);
    rows += p.rows();
    d_entries += int64_t(p.diffuse.col.size());
    v_entries += int64_t(p.view.col.size());
  }
  for (SparseRows* s : {&all.diffuse, &all.view}) s->start.assign(size_t(rows) + 1, 0);
  all.diffuse.col.resize(size_t(d_entries));
  all.diffuse.val.resize(size_t(d_entries));
  all.view.col.resize(size_t(v_entries));
  all.view.val.resize(size_t(v_entries));
  all.target.resize(3 * size_t(rows));
  all.dir.resize(3 * size_t(rows));
  const int n = int(parts->size());
#pragma omp parallel for schedule(static, 1)
  for (int i = 0; i < n; ++i) {
    FitSystem& p = (*parts)[size_t(i)];
    PlaceRows(p.diffuse, row_at[size_t(i)], d_at[size_t(i)], &all.diffuse);
    PlaceRows(p.view, row_at[size_t(i)], v_at[size_t(i)], &all.view);
    std::copy(p.target.begin(), p.target.end(), all.target.begin() + 3 * row_at[size_t(i)]);
    std::copy(p.dir.begin(), p.dir.end(), all.dir.begin() + 3 * row_at[size_t(i)]);
    p = FitSystem();
  }
  return all;
}

}  // namespace clnerf
