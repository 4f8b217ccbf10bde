// FitSystem: the colour fit's sparse linear system (colour_fit.h). Each row
// is one ray: its pixel, per colour channel, is a weighted sum of the
// diffuse colours c0 of the lattice points it blends plus, for its "view"
// entries, the points' view-dependent terms H times the ray's direction d
// (c = c0 + H d, H a 3x3 per point). Rows are appended per thread, then
// joined; the columns name lattice points until NumberUnknowns numbers the
// unknowns (the points some entry names, in lattice order); then
// Transpose builds the columns, and SolveDamped runs CGLS on
//
//   min_delta |A delta - r0|^2 + lambda |delta|^2   (each channel its own system).
//
// Unknown vectors hold 3 values per diffuse point, then 9 per view point
// (H column-major: k = x, y, z, then channel).
//
// A FitSystem is a plain value: build it on one thread (its functions use
// the calling context's OpenMP threads), then the const functions may run
// concurrently.
#ifndef CLNERF_CORE_BAKE_FIT_SYSTEM_H_
#define CLNERF_CORE_BAKE_FIT_SYSTEM_H_

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "core/bake/huge_pages.h"

namespace clnerf {

// One half of A in compressed sparse rows: row r's entries are
// [start[r], start[r + 1]).
struct SparseRows {
  HugeVector<int64_t> start = {0};
  HugeVector<uint32_t> col;
  HugeVector<float> val;
  // Appends a row of (column, weight) pairs.
  void Append(const std::vector<std::pair<uint32_t, float>>& row);
};

// The same entries by column: column j's rows are [start[j], start[j + 1]),
// in row order.
struct SparseColumns {
  HugeVector<int64_t> start;
  HugeVector<uint32_t> row;
  HugeVector<float> val;
};

struct FitSystem {
  SparseRows diffuse, view;   // Entries on c0, on H.
  std::vector<float> target;  // 3 per row: what the row should sum to.
  std::vector<float> dir;     // 3 per row: the ray's direction.
  // After NumberUnknowns: the points behind the unknowns (lattice ids).
  std::vector<uint32_t> diffuse_point, view_point;
  // After Transpose.
  SparseColumns diffuse_cols, view_cols;

  int64_t rows() const { return int64_t(diffuse.start.size()) - 1; }
  int64_t entries() const { return int64_t(diffuse.col.size() + view.col.size()); }
  size_t num_diffuse() const { return diffuse_point.size(); }
  size_t num_view() const { return view_point.size(); }
  size_t num_values() const { return 3 * num_diffuse() + 9 * num_view(); }

  // Adds one row (the two halves given, either may be empty).
  void AppendRow(const std::vector<std::pair<uint32_t, float>>& diffuse_row,
                 const std::vector<std::pair<uint32_t, float>>& view_row, const float target_rgb[3],
                 const Eigen::Vector3f& direction);
  // Empties every row's view entries and unknowns (the fit is then diffuse).
  void DropViewEntries();
  // Renumbers the columns from lattice ids in [0, points) to unknowns.
  void NumberUnknowns(size_t points);
  // Builds diffuse_cols and view_cols (after NumberUnknowns).
  void Transpose();

  // y (rows x 3) = A x.
  void Multiply(const std::vector<float>& x, std::vector<float>* y) const;
  // z = A^T y (after Transpose).
  void MultiplyTransposed(const std::vector<float>& y, std::vector<float>* z) const;
  // Sum over each diffuse unknown's entries of the squared weights, averaged
  // over the diffuse unknowns (after Transpose; 1 when there are none).
  double MeanDiffuseDiagonal() const;
  // CGLS from zero for min |A delta - r0|^2 + lambda |delta|^2 (after
  // Transpose); returns delta.
  std::vector<float> SolveDamped(const std::vector<float>& r0, double lambda, int iterations) const;
};

// Sums f(i) over [0, n) in fixed chunks, in parallel, then the chunks in
// order: the same bits at any thread count and on every run (an OpenMP
// reduction adds the threads' shares in whatever order they finish). T is
// an Eigen array (T::Zero()).
template <class T, class F>
T OrderedSum(int64_t n, F f) {
  constexpr int64_t kChunk = 1 << 14;
  const int64_t chunks = (n + kChunk - 1) / kChunk;
  std::vector<T> part(size_t(std::max<int64_t>(chunks, 0)), T::Zero());
#pragma omp parallel for schedule(static)
  for (int64_t c = 0; c < chunks; ++c) {
    T acc = T::Zero();
    for (int64_t i = c * kChunk; i < std::min(n, (c + 1) * kChunk); ++i) acc += f(i);
    part[size_t(c)] = acc;
  }
  T sum = T::Zero();
  for (const T& p : part) sum += p;
  return sum;
}

// Sorts (lattice id, value) pairs by id and merges repeated ids (adding
// their values).
template <class V>
void MergeRepeats(std::vector<std::pair<uint32_t, V>>* row) {
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

// Joins per-thread systems (before numbering), rows in the order given.
// The parts are emptied.
FitSystem JoinFitSystems(std::vector<FitSystem>* parts);

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_FIT_SYSTEM_H_
