#include "core/bake/colour_fit.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>

#include "absl/strings/str_format.h"
#include "core/bake/baked_march.h"
#include "core/bake/fit_system.h"
#include "core/render/renderer.h"

namespace clnerf {
namespace {


double Since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

uint32_t HashCell(uint32_t a, uint32_t b, uint32_t c) {
  uint32_t h = a * 0x9E3779B1u ^ b * 0x85EBCA77u ^ c * 0xC2B2AE3Du;
  h ^= h >> 15;
  h *= 0x2C1B3C6Du;
  h ^= h >> 12;
  return h;
}

// The fit's rays in model space, about `rays` of them: one per stride x
// stride pixel cell of every camera (the largest stride that leaves at
// least `rays` cells, then a hashed share of the cells), at a hashed
// position inside the cell (so that they are not the visibility pass's cell
// centres, and cover the cell over cameras).
void FitRays(const BakedAsset& a, const std::vector<Camera>& cameras, int rays, std::vector<float>* origins,
             std::vector<float>* dirs) {
  double pixels = 0;
  for (const Camera& c : cameras) pixels += double(c.intrinsics.width) * c.intrinsics.height;
  const int stride = std::max(1, int(std::floor(std::sqrt(pixels / double(rays)))));
  const double share = std::min(1.0, double(rays) * stride * stride / pixels);
  const uint32_t keep_below = share >= 1.0 ? 0xFFFFFFFFu : uint32_t(share * 4294967296.0);
  for (size_t ci = 0; ci < cameras.size(); ++ci) {
    const Camera cam = BakedModelCamera(a, cameras[ci]);
    for (int gy = 0; gy * stride < cam.intrinsics.height; ++gy) {
      for (int gx = 0; gx * stride < cam.intrinsics.width; ++gx) {
        const uint32_t h = HashCell(uint32_t(ci), uint32_t(gx), uint32_t(gy));
        if (share < 1.0 && HashCell(h, 0x27D4EB2Fu, 1u) >= keep_below) continue;
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
    c->id[corner] = LatticeId(uint32_t(brick), cell, corner);
    c->wa[corner] = w * code;
    A += w * code;
  }
  *rgba = Eigen::Vector4f(0, 0, 0, A);
  return true;
}

// Entries of a ray's row that weigh less than this are not unknowns of that
// ray: their share is taken at the first-guess colour and moved to the
// target. They are 37-58 % of the entries (fox_8, lego_100, beer_2; under
// 1e-4: 13-32 %), so more rays fit in the entry budget: fox_8's test views
// +0.06 dB, flower_4 +0.05 against 1e-4 (docs/baking.md).
constexpr float kMinEntryWeight = 1e-3f;

// Removes the entries below kMinEntryWeight from `row`, returning what they
// add to the pixel at the colours `rgb` (3 per lattice point; null: not
// summed).
Eigen::Vector3f DropFaintEntries(const std::vector<float>* rgb, std::vector<std::pair<uint32_t, float>>* row) {
  Eigen::Vector3f faint = Eigen::Vector3f::Zero();
  size_t out = 0;
  for (const auto& [id, w] : *row) {
    if (w >= kMinEntryWeight) {
      (*row)[out++] = {id, w};
    } else if (rgb != nullptr) {
      faint += w * Eigen::Vector3f((*rgb)[3 * size_t(id)], (*rgb)[3 * size_t(id) + 1], (*rgb)[3 * size_t(id) + 2]);
    }
  }
  row->resize(out);
  return faint;
}

// A ray's rows of A (BakedRayWeights) without their faint entries; *faint
// gets what those add to the pixel at the colours `rgb` (null: not summed).
// Format 2's view row is the diffuse row's copy: its faint entries go too
// (H's first guess is 0, so nothing is folded). Returns T.
float FitRayRows(const BakedAsset& a, const Eigen::Vector3f& o, const Eigen::Vector3f& d, bool view,
                 const std::vector<float>* rgb, std::vector<std::pair<uint32_t, float>>* row,
                 std::vector<std::pair<uint32_t, float>>* view_row, Eigen::Vector3f* faint) {
  const float T = BakedRayWeights(a, o, d, row, view ? view_row : nullptr);
  *faint = DropFaintEntries(rgb, row);
  if (!view) {
    view_row->clear();
  } else if (a.view_term == BakedViewTerm::kPerSample) {
    DropFaintEntries(nullptr, view_row);
  }
  return T;
}

// A's rows, one per ray that meets the grid, with each ray's target: the
// model's pixel minus what the asset's background contributes. `view`:
// also the entries of the view-dependent term. Each thread appends its own
// share of the rays (about `entries` in all, reserved up front), joined in
// ray order.
FitSystem BuildRows(const BakedAsset& a, const std::vector<float>& origins, const std::vector<float>& dirs,
                    const std::vector<float>& model_rgb, const std::vector<float>& rgb, bool view, int64_t entries) {
  const int n = int(origins.size() / 3);
  const int threads = omp_get_max_threads();
  std::vector<FitSystem> part(static_cast<size_t>(threads));
#pragma omp parallel num_threads(threads)
  {
    FitSystem& mine = part[size_t(omp_get_thread_num())];
    mine.diffuse.col.reserve(size_t(1.1 * double(entries) / threads));
    mine.diffuse.val.reserve(mine.diffuse.col.capacity());
    std::vector<std::pair<uint32_t, float>> row, view_row;
#pragma omp for schedule(static)
    for (int r = 0; r < n; ++r) {
      const Eigen::Vector3f o(origins.data() + 3 * size_t(r)), d(dirs.data() + 3 * size_t(r));
      Eigen::Vector3f faint;
      const float T = FitRayRows(a, o, d, view, &rgb, &row, &view_row, &faint);
      if (row.empty()) continue;  // Nothing to fit: the ray sees only background.
      float target[3];
      for (int c = 0; c < 3; ++c) target[c] = model_rgb[3 * size_t(r) + c] - T * a.background[c] - faint[c];
      mine.AppendRow(row, view_row, target, d);
    }
  }
  return JoinFitSystems(&part);  // Static schedule: thread order is ray order.
}

// What the fit's rays will cost, estimated from a pilot of 4096 rays spread
// over the list: A's entries, and the model's samples for the targets.
struct FitWork {
  double entries = 0, model_samples = 0;
};

FitWork EstimateWork(const NgpModel& model, int time_step, const BakedAsset& a, bool view,
                     const std::vector<float>& origins, const std::vector<float>& dirs) {
  const int64_t n = int64_t(origins.size() / 3);
  if (n == 0) return {};
  const int64_t pilot = std::min<int64_t>(n, 4096), every = n / pilot;
  std::vector<float> po(3 * size_t(pilot)), pd(3 * size_t(pilot)), rgb(3 * size_t(pilot));
  for (int64_t k = 0; k < pilot; ++k) {
    std::copy_n(origins.data() + 3 * size_t(k * every), 3, po.data() + 3 * k);
    std::copy_n(dirs.data() + 3 * size_t(k * every), 3, pd.data() + 3 * k);
  }
  int64_t entries = 0;
#pragma omp parallel reduction(+ : entries)
  {
    std::vector<std::pair<uint32_t, float>> row, view_row;
#pragma omp for schedule(static)
    for (int64_t k = 0; k < pilot; ++k) {
      Eigen::Vector3f faint;
      FitRayRows(a, Eigen::Vector3f(po.data() + 3 * k), Eigen::Vector3f(pd.data() + 3 * k), view, nullptr, &row,
                 &view_row, &faint);
      entries += int64_t(row.size() + view_row.size());
    }
  }
  RenderOptions ro;
  ro.time_step = time_step;
  const long long samples = RenderRays(model, po.data(), pd.data(), int(pilot), time_step, ro, rgb.data(), nullptr, nullptr);
  const double scale = double(n) / double(pilot);
  return {double(entries) * scale, double(std::max(samples, 0LL)) * scale};
}

// Keeps the fit within its work budget (options.max_nonzeros,
// max_model_samples): a hashed share of the rays is kept.
void ThinToBudget(const FitWork& work, const ColourFitOptions& o, std::vector<float>* origins,
                  std::vector<float>* dirs) {
  double share = 1.0;
  if (o.max_nonzeros > 0 && work.entries > 0) share = std::min(share, double(o.max_nonzeros) / work.entries);
  if (o.max_model_samples > 0 && work.model_samples > 0) {
    share = std::min(share, double(o.max_model_samples) / work.model_samples);
  }
  if (share >= 1.0) return;
  const uint32_t keep_below = uint32_t(share * 4294967296.0);
  const int64_t n = int64_t(origins->size() / 3);
  size_t out = 0;
  for (int64_t r = 0; r < n; ++r) {
    if (HashCell(uint32_t(r), 0x165667B1u, 7u) >= keep_below) continue;
    for (int c = 0; c < 3; ++c) {
      (*origins)[3 * out + c] = (*origins)[3 * size_t(r) + c];
      (*dirs)[3 * out + c] = (*dirs)[3 * size_t(r) + c];
    }
    ++out;
  }
  origins->resize(3 * out);
  dirs->resize(3 * out);
}

// target - A x.
std::vector<float> Residual(const FitSystem& A, const std::vector<float>& x) {
  std::vector<float> r;
  A.Multiply(x, &r);
  for (size_t i = 0; i < r.size(); ++i) r[i] = A.target[i] - r[i];
  return r;
}

double Rms(const std::vector<float>& r) {
  double s = 0;
  for (float v : r) s += double(v) * v;
  return r.empty() ? 0.0 : std::sqrt(s / double(r.size()));
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
      [&](int, float weight, float, const Eigen::Vector4f& rgba, float) {
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
  if (max_nonzeros < 0 || max_model_samples < 0) {
    return absl::InvalidArgumentError("bake: the fit's max_nonzeros and max_model_samples must be >= 0");
  }
  if (!(prior > 0.0f && std::isfinite(prior))) return absl::InvalidArgumentError("bake: fit prior must be positive");
  return absl::OkStatus();
}

namespace {

absl::Status CheckColourArrays(const BakedAsset& asset, const std::vector<float>& rgb, const std::vector<float>* view) {
  if (rgb.size() != size_t(3 * kBrickLattice) * size_t(asset.num_bricks()) ||
      (view != nullptr && view->size() != 3 * rgb.size())) {
    return absl::InvalidArgumentError("bake: colour array does not match the atlas");
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status MakeFitTargets(const NgpModel& model, int time_step, const std::vector<Camera>& cameras,
                            const BakedAsset& asset, const ColourFitOptions& options, bool view, FitTargets* targets,
                            ColourFitReport* report) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  *targets = FitTargets();
  *report = ColourFitReport();
  if (options.rays == 0 || options.iterations == 0 || cameras.empty() || asset.num_bricks() == 0) {
    return absl::OkStatus();
  }
  const auto t0 = std::chrono::steady_clock::now();
  FitRays(asset, cameras, options.rays, &targets->origins, &targets->dirs);
  report->candidate_rays = targets->size();
  const FitWork work = EstimateWork(model, time_step, asset, view, targets->origins, targets->dirs);
  report->estimated_nonzeros = targets->estimated_nonzeros = int64_t(work.entries);
  report->estimated_model_samples = int64_t(work.model_samples);
  ThinToBudget(work, options, &targets->origins, &targets->dirs);
  const int n = targets->size();
  RenderOptions ro;
  ro.time_step = time_step;
  // The targets are the pixels the model itself serves (RenderView's defaults).
  targets->rgb.assign(3 * size_t(n), 0.0f);
  RenderRays(model, targets->origins.data(), targets->dirs.data(), n, time_step, ro, targets->rgb.data(), nullptr,
             nullptr);
  report->target_seconds = Since(t0);
  return absl::OkStatus();
}

absl::Status FitBakedColours(const NgpModel& model, int time_step, const std::vector<Camera>& cameras,
                             const BakedAsset& asset, const ColourFitOptions& options, std::vector<float>* rgb,
                             std::vector<float>* view, ColourFitReport* report) {
  if (absl::Status s = CheckColourArrays(asset, *rgb, view); !s.ok()) return s;
  ColourFitReport rep;
  FitTargets targets;
  if (absl::Status s = MakeFitTargets(model, time_step, cameras, asset, options, view != nullptr, &targets, &rep);
      !s.ok()) {
    return s;
  }
  if (absl::Status s = FitBakedColoursTo(targets, asset, options, rgb, view, &rep); !s.ok()) return s;
  if (report != nullptr) *report = rep;
  return absl::OkStatus();
}

absl::Status FitBakedColoursTo(const FitTargets& targets, const BakedAsset& asset, const ColourFitOptions& options,
                               std::vector<float>* rgb, std::vector<float>* view, ColourFitReport* report) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (absl::Status s = CheckColourArrays(asset, *rgb, view); !s.ok()) return s;
  ColourFitReport unused;
  ColourFitReport& rep = report != nullptr ? *report : unused;
  if (targets.size() == 0 || options.iterations == 0) return absl::OkStatus();
  auto t0 = std::chrono::steady_clock::now();
  FitSystem A = BuildRows(asset, targets.origins, targets.dirs, targets.rgb, *rgb, view != nullptr,
                          std::min<int64_t>(targets.estimated_nonzeros,
                                            options.max_nonzeros > 0 ? options.max_nonzeros : INT64_MAX));
  if (view != nullptr && int64_t(A.view.col.size()) > options.max_view_nonzeros) {
    view->clear();
    view = nullptr;
    A.DropViewEntries();
  }
  rep.view_dependent = view != nullptr;
  A.NumberUnknowns(rgb->size() / 3);
  A.Transpose();
  std::vector<float> x0(A.num_values(), 0.0f);  // The field's colours; no view dependence.
  for (size_t j = 0; j < A.num_diffuse(); ++j) {
    for (int c = 0; c < 3; ++c) x0[3 * j + c] = (*rgb)[3 * size_t(A.diffuse_point[j]) + c];
  }
  const std::vector<float> r0 = Residual(A, x0);
  rep.rows_seconds = Since(t0);
  t0 = std::chrono::steady_clock::now();
  const std::vector<float> delta = A.SolveDamped(r0, options.prior * A.MeanDiffuseDiagonal(), options.iterations);
  // Clamped to what the atlases store: colour in [0, 1], H in [-1, 1].
  std::vector<float> fitted(A.num_values());
  for (size_t i = 0; i < fitted.size(); ++i) {
    fitted[i] = std::clamp(x0[i] + delta[i], i < 3 * A.num_diffuse() ? 0.0f : -1.0f, 1.0f);
  }
  for (size_t j = 0; j < A.num_diffuse(); ++j) {
    for (int c = 0; c < 3; ++c) (*rgb)[3 * size_t(A.diffuse_point[j]) + c] = fitted[3 * j + c];
  }
  for (size_t j = 0; view != nullptr && j < A.num_view(); ++j) {
    for (int e = 0; e < 9; ++e) (*view)[9 * size_t(A.view_point[j]) + e] = fitted[3 * A.num_diffuse() + 9 * j + e];
  }
  rep.solve_seconds = Since(t0);
  rep.rays = A.rows();
  rep.unknowns = int64_t(A.num_diffuse() + A.num_view());
  rep.nonzeros = A.entries();
  rep.rms_before = Rms(r0);
  rep.rms_after = Rms(Residual(A, fitted));
  return absl::OkStatus();
}

}  // namespace clnerf
