#include "core/train/occupancy_prune.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "core/render/metrics.h"
#include "core/render/renderer.h"
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

struct Calibration {
  std::vector<float> origin, dir, target;
  std::vector<int> time_step;
};

// Renders the calibration rays (grouped by time step); returns the PSNR
// against their targets and the mean samples per ray.
void Score(const NgpModel& model, const Calibration& cal, double* psnr, double* samples) {
  const int n = int(cal.time_step.size());
  std::vector<float> rgb(3 * size_t(n));
  long long total = 0;
  for (int t = 0; t < model.num_time_steps(); ++t) {
    std::vector<int> idx;
    for (int i = 0; i < n; ++i) {
      if (cal.time_step[i] == t) idx.push_back(i);
    }
    if (idx.empty()) continue;
    std::vector<float> o(3 * idx.size()), d(3 * idx.size()), c(3 * idx.size());
    for (size_t k = 0; k < idx.size(); ++k) {
      std::copy_n(&cal.origin[3 * size_t(idx[k])], 3, &o[3 * k]);
      std::copy_n(&cal.dir[3 * size_t(idx[k])], 3, &d[3 * k]);
    }
    RenderOptions ro;
    total += RenderRays(model, o.data(), d.data(), int(idx.size()), t, ro, c.data(), nullptr, nullptr);
    for (size_t k = 0; k < idx.size(); ++k) std::copy_n(&c[3 * k], 3, &rgb[3 * size_t(idx[k])]);
  }
  double se = 0;
  for (size_t i = 0; i < rgb.size(); ++i) se += double(rgb[i] - cal.target[i]) * (rgb[i] - cal.target[i]);
  *psnr = PsnrFromMse(se / double(std::max<size_t>(rgb.size(), 1)));
  *samples = n > 0 ? double(total) / n : 0.0;
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

  // Calibration pixels: uniform over views, then pixels (unmasked ones).
  Calibration cal;
  const int n = options.calibration_rays;
  cal.origin.resize(3 * size_t(n));
  cal.dir.resize(3 * size_t(n));
  cal.target.resize(3 * size_t(n));
  cal.time_step.resize(n);
  std::vector<Camera> cams;
  for (const View* v : usable) cams.push_back(model->ToModelCamera(v->camera));
  for (int i = 0; i < n; ++i) {
    const size_t v = rng() % usable.size();
    const View& view = *usable[v];
    uint32_t pixel = uint32_t(rng() % view.image.num_pixels());
    for (int tries = 0; tries < 16 && !view.mask.empty() && !view.mask.keep[pixel]; ++tries) {
      pixel = uint32_t(rng() % view.image.num_pixels());
    }
    PixelRay(cams[v], pixel, &cal.origin[3 * size_t(i)], &cal.dir[3 * size_t(i)]);
    std::copy_n(&view.image.rgb[3 * size_t(pixel)], 3, &cal.target[3 * size_t(i)]);
    cal.time_step[i] = view.camera.time_step;
  }

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

  Score(*model, cal, &report.psnr_before, &report.samples_before);
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
    Score(*model, cal, &psnr, &samples);
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
