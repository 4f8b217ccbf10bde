#include "core/ngp_model.h"

#include <omp.h>

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace clnerf {

absl::Status ModelOptions::Validate() const {
  for (const absl::Status& s : {grid.Validate(), network.Validate(), occupancy.Validate(), march.Validate()}) {
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

NgpModel::NgpModel(const ModelOptions& options, const Normalization& norm, SceneKind kind,
                   const Eigen::Vector3f& background, int num_time_steps)
    : options_(options),
      norm_(norm),
      kind_(kind),
      background_(background),
      grid_(options.grid),
      network_(options.network, grid_.output_dim()),
      occupancy_(options.occupancy, norm.bound, options.march.min_step()),
      num_time_steps_(num_time_steps) {}

absl::StatusOr<NgpModel> NgpModel::Create(const ModelOptions& options, const Normalization& norm,
                                          SceneKind kind, const Eigen::Vector3f& background,
                                          int num_time_steps, uint64_t seed) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (num_time_steps < 1) return absl::InvalidArgumentError("model needs at least one time step");
  if (!(norm.bound > 0) || !(norm.scale > 0)) return absl::InvalidArgumentError("invalid normalisation");
  NgpModel m(options, norm, kind, background, num_time_steps);
  m.Reinitialize(seed);
  return m;
}

absl::StatusOr<NgpModel> NgpModel::FromParts(const ModelOptions& options, const Normalization& norm,
                                             SceneKind kind, const Eigen::Vector3f& background,
                                             int num_time_steps, ModelParams params) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  NgpModel m(options, norm, kind, background, num_time_steps);
  if (params.grid.size() != m.grid_.num_params() || params.mlp.size() != m.network_.num_mlp_params() ||
      params.emb.size() != size_t(num_time_steps) * m.network_.embedding_row_size()) {
    return absl::InvalidArgumentError("parameter block sizes do not match the model options");
  }
  m.params_ = std::move(params);
  return m;
}

void NgpModel::Reinitialize(uint64_t seed) {
  params_.grid.assign(grid_.num_params(), 0.0f);
  params_.mlp.assign(network_.num_mlp_params(), 0.0f);
  params_.emb.assign(size_t(num_time_steps_) * network_.embedding_row_size(), 0.0f);
  grid_.Initialize(params_.grid.data(), seed * 3 + 1);
  network_.InitializeMlp(params_.mlp.data(), seed * 3 + 2);
  network_.InitializeEmbeddings(params_.emb.data(), num_time_steps_, seed * 3 + 3);
  occupancy_ = OccupancyGrid(options_.occupancy, norm_.bound, options_.march.min_step());
}

void NgpModel::AddTimeStep(uint64_t seed) {
  const int row = network_.embedding_row_size();
  std::vector<float> fresh(row);
  network_.InitializeEmbeddings(fresh.data(), 1, seed);
  params_.emb.insert(params_.emb.end(), fresh.begin(), fresh.end());
  ++num_time_steps_;
}

size_t NgpModel::num_params() const { return params_.grid.size() + params_.mlp.size() + params_.emb.size(); }

size_t NgpModel::num_bytes() const {
  return num_params() * sizeof(float) + occupancy_.bits().size() * sizeof(uint64_t);
}

bool NgpModel::AllFinite() const {
  for (const auto* v : {&params_.grid, &params_.mlp, &params_.emb}) {
    for (float x : *v) {
      if (!std::isfinite(x)) return false;
    }
  }
  return true;
}

Camera NgpModel::ToModelCamera(const Camera& world) const {
  Camera c = world;
  c.c2w.col(3) = norm_.ToModel(world.c2w.col(3));
  return c;
}

void NgpModel::Density(const float* points, int n, int time_step, float* sigma) const {
  const int t = std::clamp(time_step, 0, num_time_steps_ - 1);
  Eigen::MatrixXf geo, app;
  network_.StepBiases(params_.mlp.data(), params_.emb.data(), num_time_steps_, &geo, &app);
  const Eigen::VectorXf geo_t = geo.col(t);
  constexpr int kChunk = 2048;
  const int nchunks = (n + kChunk - 1) / kChunk;
#pragma omp parallel
  {
    NetworkWorkspace ws;
    ws.Reserve(kChunk, network_.options(), grid_.output_dim());
    std::vector<float> pos(3 * kChunk), feat(size_t(kChunk) * grid_.output_dim()), h0(kChunk);
#pragma omp for schedule(dynamic)
    for (int ci = 0; ci < nchunks; ++ci) {
      const int begin = ci * kChunk, m = std::min(kChunk, n - begin);
      for (int i = 0; i < m; ++i) {
        const Eigen::Vector3f g = ToGridInput(Eigen::Map<const Eigen::Vector3f>(points + 3 * (begin + i)));
        pos[3 * i] = g.x();
        pos[3 * i + 1] = g.y();
        pos[3 * i + 2] = g.z();
      }
      grid_.Encode(params_.grid.data(), pos.data(), m, feat.data());
      const int seg[2] = {0, m};
      network_.DensityOnly(params_.mlp.data(), feat.data(), m, seg, 1, geo_t.data(), &ws, h0.data());
      for (int i = 0; i < m; ++i) sigma[begin + i] = TruncExp(h0[i]);
    }
  }
}

void NgpModel::UpdateOccupancy(int iteration, std::mt19937_64* rng) {
  std::vector<uint32_t> cells = occupancy_.CellsToUpdate(iteration, rng);
  std::uniform_real_distribution<float> u(-0.5f, 0.5f);
  std::vector<float> pts(3 * cells.size());
  for (size_t i = 0; i < cells.size(); ++i) {
    const Eigen::Vector3f p = occupancy_.CellPosition(cells[i], Eigen::Vector3f(u(*rng), u(*rng), u(*rng)));
    pts[3 * i] = std::clamp(p.x(), -bound(), bound());
    pts[3 * i + 1] = std::clamp(p.y(), -bound(), bound());
    pts[3 * i + 2] = std::clamp(p.z(), -bound(), bound());
  }
  std::uniform_int_distribution<int> step(0, num_time_steps_ - 1);
  std::vector<float> sigma(cells.size());
  Density(pts.data(), int(cells.size()), step(*rng), sigma.data());
  occupancy_.ApplyUpdate(cells, sigma);
}

}  // namespace clnerf
