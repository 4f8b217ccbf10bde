#include "core/bake/fit_system.h"

#include <omp.h>

#include <cmath>
#include <random>
#include <set>

#include "Eigen/Dense"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

using Row = std::vector<std::pair<uint32_t, float>>;

// A random system over `points` lattice points (only the even ones used, so
// numbering has gaps to close): `rows` rows of up to 12 diffuse entries and
// up to 3 view entries, built in `parts` per-thread pieces and joined.
FitSystem RandomSystem(int rows, int points, int parts, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> point(0, points / 2 - 1), count(0, 12);
  std::uniform_real_distribution<float> weight(0.01f, 1.0f), unit(-1.0f, 1.0f);
  std::vector<FitSystem> piece(static_cast<size_t>(parts));
  for (int r = 0; r < rows; ++r) {
    Row diffuse, view;  // Each point once per row, as BakedRayWeights merges repeats.
    const int n = count(rng);
    std::set<uint32_t> used, used_view;
    for (int k = 0; k < n; ++k) used.insert(uint32_t(2 * point(rng)));
    for (int k = 0; k < n / 4; ++k) used_view.insert(uint32_t(2 * point(rng)));
    for (uint32_t p : used) diffuse.emplace_back(p, weight(rng));
    for (uint32_t p : used_view) view.emplace_back(p, weight(rng));
    const float target[3] = {unit(rng), unit(rng), unit(rng)};
    piece[size_t(r * parts / rows)].AppendRow(diffuse, view, target,
                                              Eigen::Vector3f(unit(rng), unit(rng), unit(rng)).normalized());
  }
  FitSystem A = JoinFitSystems(&piece);
  A.NumberUnknowns(size_t(points));
  A.Transpose();
  return A;
}

// A as a dense matrix over the flattened unknowns, per channel c: pixel c
// of row r is row 3r + c.
Eigen::MatrixXd Dense(const FitSystem& A) {
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(3 * A.rows(), Eigen::Index(A.num_values()));
  const size_t P = A.num_diffuse();
  for (int64_t r = 0; r < A.rows(); ++r) {
    for (int64_t k = A.diffuse.start[size_t(r)]; k < A.diffuse.start[size_t(r) + 1]; ++k) {
      for (int c = 0; c < 3; ++c) M(3 * r + c, 3 * A.diffuse.col[size_t(k)] + c) += A.diffuse.val[size_t(k)];
    }
    for (int64_t k = A.view.start[size_t(r)]; k < A.view.start[size_t(r) + 1]; ++k) {
      for (int e = 0; e < 3; ++e) {
        for (int c = 0; c < 3; ++c) {
          M(3 * r + c, Eigen::Index(3 * P + 9 * A.view.col[size_t(k)] + 3 * e + c)) +=
              A.view.val[size_t(k)] * A.dir[3 * size_t(r) + size_t(e)];
        }
      }
    }
  }
  return M;
}

Eigen::VectorXd ToEigen(const std::vector<float>& v) {
  Eigen::VectorXd out(Eigen::Index(v.size()));
  for (size_t i = 0; i < v.size(); ++i) out[Eigen::Index(i)] = v[i];
  return out;
}

TEST(FitSystemTest, JoinedPiecesNumberEveryUsedPointOnceInLatticeOrder) {
  const FitSystem A = RandomSystem(300, 400, 3, 1);
  EXPECT_EQ(A.rows(), 300);
  ASSERT_GT(A.num_diffuse(), 50u);
  for (size_t j = 1; j < A.num_diffuse(); ++j) EXPECT_LT(A.diffuse_point[j - 1], A.diffuse_point[j]);
  for (uint32_t p : A.diffuse_point) EXPECT_EQ(p % 2, 0u);
  for (uint32_t c : A.diffuse.col) EXPECT_LT(c, A.num_diffuse());
  for (uint32_t c : A.view.col) EXPECT_LT(c, A.num_view());
  // The columns hold every entry once, each column's rows ascending.
  ASSERT_EQ(A.diffuse_cols.row.size(), A.diffuse.col.size());
  ASSERT_EQ(A.view_cols.row.size(), A.view.col.size());
  for (const SparseColumns* C : {&A.diffuse_cols, &A.view_cols}) {
    for (size_t j = 0; j + 1 < C->start.size(); ++j) {
      for (int64_t k = C->start[j] + 1; k < C->start[j + 1]; ++k) EXPECT_LT(C->row[size_t(k) - 1], C->row[size_t(k)]);
    }
  }
}

// The same rows joined and transposed at 1 and at 2 threads give the same
// arrays: the parallel steps place every entry where the serial ones do.
TEST(FitSystemTest, TheSystemDoesNotDependOnTheThreadCount) {
  const int saved = omp_get_max_threads();
  omp_set_num_threads(1);
  const FitSystem one = RandomSystem(300, 400, 3, 6);
  omp_set_num_threads(2);
  const FitSystem two = RandomSystem(300, 400, 3, 6);
  omp_set_num_threads(saved);
  EXPECT_EQ(one.diffuse.start, two.diffuse.start);
  EXPECT_EQ(one.diffuse.col, two.diffuse.col);
  EXPECT_EQ(one.view.col, two.view.col);
  EXPECT_EQ(one.diffuse_point, two.diffuse_point);
  EXPECT_EQ(one.diffuse_cols.start, two.diffuse_cols.start);
  EXPECT_EQ(one.diffuse_cols.row, two.diffuse_cols.row);
  EXPECT_EQ(one.diffuse_cols.val, two.diffuse_cols.val);
  EXPECT_EQ(one.view_cols.row, two.view_cols.row);
  EXPECT_EQ(one.target, two.target);
}

TEST(FitSystemTest, ProductsMatchTheDenseMatrixAndEachOther) {
  const int saved = omp_get_max_threads();
  for (int threads : {1, 2}) {
    omp_set_num_threads(threads);
    const FitSystem A = RandomSystem(250, 300, threads, 2);
    const Eigen::MatrixXd M = Dense(A);
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
    std::vector<float> x(A.num_values()), y(3 * size_t(A.rows())), Ax, Aty;
    for (float& v : x) v = unit(rng);
    for (float& v : y) v = unit(rng);
    A.Multiply(x, &Ax);
    A.MultiplyTransposed(y, &Aty);
    EXPECT_LT((ToEigen(Ax) - M * ToEigen(x)).cwiseAbs().maxCoeff(), 1e-4);
    EXPECT_LT((ToEigen(Aty) - M.transpose() * ToEigen(y)).cwiseAbs().maxCoeff(), 1e-4);
    // <A x, y> = <x, A^T y>: the two products are adjoint.
    EXPECT_NEAR(ToEigen(Ax).dot(ToEigen(y)), ToEigen(x).dot(ToEigen(Aty)), 1e-3);
    // The mean diagonal is the diffuse columns' squared weights per unknown.
    double diag = 0;
    for (Eigen::Index j = 0; j < Eigen::Index(3 * A.num_diffuse()); j += 3) diag += M.col(j).squaredNorm();
    EXPECT_NEAR(A.MeanDiffuseDiagonal(), diag / double(A.num_diffuse()), 1e-4 * diag / double(A.num_diffuse()));
  }
  omp_set_num_threads(saved);
}

TEST(FitSystemTest, DampedSolveApproachesTheNormalEquationsSolution) {
  const FitSystem A = RandomSystem(400, 120, 2, 4);
  const Eigen::MatrixXd M = Dense(A);
  const double lambda = 0.5;
  // Per channel the systems are separate, but the dense normal equations
  // over all channels have the same solution.
  const Eigen::VectorXd b = ToEigen(A.target);
  const Eigen::MatrixXd N = M.transpose() * M + lambda * Eigen::MatrixXd::Identity(M.cols(), M.cols());
  const Eigen::VectorXd exact = N.ldlt().solve(M.transpose() * b);
  const Eigen::VectorXd few = ToEigen(A.SolveDamped(A.target, lambda, 4));
  const Eigen::VectorXd many = ToEigen(A.SolveDamped(A.target, lambda, 200));
  EXPECT_LT((many - exact).norm(), 1e-3 * exact.norm());
  EXPECT_GT((few - exact).norm(), (many - exact).norm());  // Iterations matter: a real solve.
  // Solved channels stop: more steps past convergence divided rounding noise
  // by rounding noise and blew up (relative error 0.014 at 200 steps, 1e32
  // at 1000, on an Intel Xeon build).
  const Eigen::VectorXd long_run = ToEigen(A.SolveDamped(A.target, lambda, 1000));
  EXPECT_LT((long_run - exact).norm(), 1e-3 * exact.norm());
  // The objective falls from zero to the solution.
  auto cost = [&](const Eigen::VectorXd& x) { return (M * x - b).squaredNorm() + lambda * x.squaredNorm(); };
  EXPECT_LT(cost(few), cost(Eigen::VectorXd::Zero(M.cols())));
  EXPECT_LE(cost(many), cost(few) + 1e-9);
}

TEST(FitSystemTest, DroppingViewEntriesKeepsTheDiffuseRows) {
  FitSystem A = RandomSystem(100, 200, 1, 5);
  const auto diffuse = A.diffuse.col;
  ASSERT_GT(A.num_view(), 0u);
  A.DropViewEntries();
  EXPECT_TRUE(A.view.col.empty());
  EXPECT_EQ(A.view.start.size(), A.diffuse.start.size());
  EXPECT_EQ(A.diffuse.col, diffuse);
  EXPECT_EQ(A.num_view(), 0u);  // No view unknowns left: the products still agree.
  std::vector<float> x(A.num_values(), 0.5f), y(3 * size_t(A.rows()), 0.25f), Ax, Aty;
  A.Multiply(x, &Ax);
  A.MultiplyTransposed(y, &Aty);
  EXPECT_EQ(Aty.size(), A.num_values());
  EXPECT_NEAR(ToEigen(Ax).dot(ToEigen(y)), ToEigen(x).dot(ToEigen(Aty)), 1e-3);
}

}  // namespace
}  // namespace clnerf
