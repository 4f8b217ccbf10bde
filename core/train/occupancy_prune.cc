#include "core/train/occupancy_prune.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>

#include "core/render/metrics.h"
#include "core/train/ray_sampler.h"

namespace clnerf {

absl::Status PruneOptions::Validate() const {
  if (probes_per_cell < 1 || calibration_rays < 1) {
    return absl::InvalidArgumentError("prune: probes_per_cell and calibration_rays must be >= 1");
  }
  if (!(max_psnr_drop >= 0) || !std::isfinite(max_psnr_drop)) {
    return absl::InvalidArgumentError("prune: max_psnr_drop must be finite and >= 0");
  }
  for (size_t i = 0; i < ladder.size(); ++i) {
    if (!(ladder[i] > 0) || !std::isfinite(ladder[i]) || (i > 0 && !(ladder[i] > ladder[i - 1]))) {
      return absl::InvalidArgumentError("prune: ladder must be positive, finite and increasing");
    }
  }
  return absl::OkStatus();
}

namespace {

// Renders the calibration rays; returns their PSNR against the batch's
// targets and the mean samples per ray.
void Score(const NgpModel& model, const RayBatch& cal, const std::vector<int>& all, double* psnr, double* samples) {
  std::vector<float> rgb;
  const long long total = RenderBatchRays(model, cal, all, &rgb);
  double se = 0;
  for (size_t i = 0; i < rgb.size(); ++i) se += double(rgb[i] - cal.target[i]) * (rgb[i] - cal.target[i]);
  *psnr = PsnrFromMse(se / double(std::max<size_t>(rgb.size(), 1)));
  *samples = cal.size() > 0 ? double(total) / cal.size() : 0.0;
}

}  // namespace

absl::StatusOr<PruneReport> PruneOccupancy(NgpModel* model, const std::vector<const View*>& views,
                                           const PruneOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  PruneReport report;
  if (model->uses_proposals()) return report;
  std::vector<const View*> usable;
  for (const View* v : views) {
    if (v != nullptr && !v->image.empty() && v->camera.time_step >= 0 &&
        v->camera.time_step < model->num_time_steps()) {
      usable.push_back(v);
    }
  }
  if (usable.empty()) return absl::InvalidArgumentError("prune: no training view with an image");
  OccupancyGrid& grid = model->mutable_occupancy();
  std::mt19937_64 rng(options.seed);

  // Calibration pixels: training rays as the trainer draws them (uniform
  // over views, then over unmasked pixels).
  absl::StatusOr<std::unique_ptr<ImageRaySampler>> sampler = ImageRaySampler::Create(usable, *model);
  if (!sampler.ok()) return sampler.status();
  RayBatch cal;
  (*sampler)->Sample(options.calibration_rays, &rng, &cal);
  std::vector<int> all(cal.size());
  for (int i = 0; i < cal.size(); ++i) all[i] = i;

  // Density probes of every occupied cell: the maximum over jittered points
  // and time steps.
  std::vector<uint32_t> cells;
  for (uint32_t c = 0; c < uint32_t(grid.num_cells()); ++c) {
    if (grid.OccupiedCell(c)) cells.push_back(c);
  }
  report.cells_before = report.cells_after = cells.size();
  std::vector<float> peak(cells.size(), 0.0f);
  std::uniform_real_distribution<float> u(-0.5f, 0.5f);
  std::vector<float> pts(3 * cells.size()), sigma(cells.size());
  for (int p = 0; p < options.probes_per_cell; ++p) {
    for (size_t k = 0; k < cells.size(); ++k) {
      const Eigen::Vector3f q = grid.CellPosition(cells[k], Eigen::Vector3f(u(rng), u(rng), u(rng)));
      pts[3 * k] = q.x();
      pts[3 * k + 1] = q.y();
      pts[3 * k + 2] = q.z();
    }
    for (int t = 0; t < model->num_time_steps(); ++t) {
      model->Density(pts.data(), int(cells.size()), t, sigma.data());
      for (size_t k = 0; k < cells.size(); ++k) {
        if (std::isfinite(sigma[k])) peak[k] = std::max(peak[k], sigma[k]);
      }
    }
  }

  Score(*model, cal, all, &report.psnr_before, &report.samples_before);
  report.psnr_after = report.psnr_before;
  report.samples_after = report.samples_before;
  const std::vector<float> density = grid.density();
  const std::vector<uint8_t> visible = grid.visible();
  const std::vector<uint64_t> original = grid.bits();
  const float base = grid.threshold();
  auto bits_at = [&](float thr, size_t* count) {
    std::vector<uint64_t> bits(original.size(), 0);
    *count = 0;
    for (size_t k = 0; k < cells.size(); ++k) {
      if (peak[k] > thr) {
        bits[cells[k] >> 6] |= uint64_t(1) << (cells[k] & 63);
        ++*count;
      }
    }
    return bits;
  };
  std::vector<uint64_t> best = original;
  for (float f : options.ladder) {
    const float thr = f * base;
    size_t count = 0;
    std::vector<uint64_t> bits = bits_at(thr, &count);
    grid.Restore(density, visible, bits, base);
    double psnr = 0, samples = 0;
    Score(*model, cal, all, &psnr, &samples);
    if (!(psnr >= report.psnr_before - options.max_psnr_drop)) break;
    best = std::move(bits);
    report.threshold = thr;
    report.cells_after = count;
    report.psnr_after = psnr;
    report.samples_after = samples;
  }
  // Pruned cells also lose their density EMA (a warm start rebuilds it).
  std::vector<float> kept = density;
  for (size_t c = 0; c < kept.size(); ++c) {
    if (!((best[c >> 6] >> (c & 63)) & 1)) kept[c] = 0.0f;
  }
  grid.Restore(std::move(kept), visible, std::move(best), base);
  return report;
}

}  // namespace clnerf
