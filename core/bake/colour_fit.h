// ColourFit: distils a baked asset's colours from its model. Evaluating the
// field's colour at each lattice point (the baker's first guess) ignores how
// the asset is rendered: trilinear blending of 8 corners, half-cell steps,
// quantised densities, one viewing direction per block. This stage instead
// chooses the colours that make the asset's own renders of training-camera
// rays match the model's renders of the same rays.
//
// With the densities fixed, a baked pixel is linear in the lattice colours
// (the atlas stores colour premultiplied by the density code, and the
// renderer divides the blend by the blended code), so the fit is a damped
// linear least-squares problem, solved with CGLS from the first guess:
//
//   min_x  sum_rays |A x - (model pixel - T background)|^2 + lambda |x - x0|^2
//
// where each row of A holds a ray's weights on the lattice points it
// blends, and lambda = `prior` times the mean diagonal of A^T A keeps points
// few rays see near the field's own colour.
//
// Thread-safe for concurrent calls; each runs over the OpenMP threads of the
// calling context.
#ifndef CLNERF_CORE_BAKE_COLOUR_FIT_H_
#define CLNERF_CORE_BAKE_COLOUR_FIT_H_

#include <cstdint>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "core/bake/baked_asset.h"
#include "core/data/camera.h"
#include "core/field/ngp_model.h"

namespace clnerf {

struct ColourFitOptions {
  // Training-camera rays the fit may use (one per pixel cell of a stride that
  // gives about this many, jittered within the cell; all pixels when the
  // cameras have fewer). 0 = no fit.
  int rays = 1 << 21;
  // ... thinned so that A has at most about this many entries (0 = no
  // limit): A's size sets the fit's time (~0.2 s per million entries on 2
  // cores) and memory (~20 bytes per entry; fox_8's bake peaks at 2.1 GB). More rays fit better: fox_8's
  // test views 27.70 dB from 209 K rays (19 M entries) and 28.04 from 473 K
  // (43 M); at 640^3 40 M -> 80 M entries +0.24 dB (476 K -> 952 K rays),
  // flower_4 +0.14 dB (docs/baking.md).
  int64_t max_nonzeros = 80'000'000;
  // ... and so that the model's renders of their targets take at most about
  // this many field samples (0 = no limit): a hazy capture marches ~500 per
  // ray (beer_2: 360 K rays took 12.8 s to render, for no gain over 245 K).
  int64_t max_model_samples = 50'000'000;
  // CGLS iterations.
  int iterations = 16;
  // Damping towards the field's own colours, relative to the mean squared
  // weight a lattice point gets from the rays. Weak damping overfits the
  // training rays: on fox_8's test views prior 0.1 lost 0.46 dB against no
  // fit, 1 gained 0.36, 10 gained 0.57, 30 0.49, 100 0.35 (docs/baking.md).
  // The view-dependent term is damped by the same lambda (towards none):
  // damped relative to its own, larger weights it loses its gain (fox_8
  // test views 27.70 -> 27.04 dB at 10, 26.03 at 100; docs/baking.md).
  float prior = 10.0f;
  // The view-dependent term (4x the unknowns) is fitted only while A has at
  // most this many entries that weigh it; above it the fit is diffuse.
  // Format 2 applied the term at every sample, so every entry weighed it
  // (fox_8 19.4 M entries 4.5 s, beer_2's haze 44.5 M entries 19.4 s, for
  // +0.02 dB there); format 3 applies it once per ray, at most 8 entries.
  int64_t max_view_nonzeros = 30'000'000;
  absl::Status Validate() const;
};

struct ColourFitReport {
  long long candidate_rays = 0;       // Rays sampled from the cameras (options.rays or the pixels).
  long long estimated_nonzeros = 0;   // Their entries of A, estimated from a pilot of 4096.
  long long estimated_model_samples = 0;  // The model's samples to render their targets, likewise.
  long long rays = 0;           // Rays in the fit (within the entry budget, not background only).
  long long unknowns = 0;       // Lattice points some ray blends.
  long long nonzeros = 0;       // Entries of A.
  bool view_dependent = false;  // The view-dependent term was fitted.
  double rms_before = 0, rms_after = 0;  // Residual on the rays (colour units).
  double target_seconds = 0, rows_seconds = 0, solve_seconds = 0;
};

// One ray's pixel as a linear function of the lattice colours (a row of the
// fit's A): pixel = sum_j w_j c0_j + sum_j v_j H_j d + T background over
// lattice points j = brick * 9^3 + local index, with c0_j the colour before
// premultiplication. Fills (j, w_j) sorted by j and returns T. `view_row`
// (optional) gets (j, v_j): for format 3 (asset.view_term kAtMedian) the
// median sample's corners times (1 - T), for format 2 the same as the
// w_j. Marches as the reference renderer does (only the atlas's density
// codes are read).
float BakedRayWeights(const BakedAsset& asset, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
                      std::vector<std::pair<uint32_t, float>>* weights,
                      std::vector<std::pair<uint32_t, float>>* view_row = nullptr);

// The fit's rays (model space, 3 floats each, unit directions) and the
// model's pixels for them (3 floats each): the teacher's answers, which the
// density fit (density_fit.h) and the colour fit share.
struct FitTargets {
  std::vector<float> origins, dirs, rgb;
  // The colour fit's entries these rays are estimated to make (what its
  // rows reserve).
  long long estimated_nonzeros = 0;
  int size() const { return int(origins.size() / 3); }
};

// Chooses the fit's rays from `cameras` (options.rays, thinned to the work
// budget that `asset`'s rows would cost; `view`: with the view term's
// entries) and renders the model's pixel for each. Fills the report's ray
// counts, estimates and target_seconds.
absl::Status MakeFitTargets(const NgpModel& model, int time_step, const std::vector<Camera>& cameras,
                            const BakedAsset& asset, const ColourFitOptions& options, bool view, FitTargets* targets,
                            ColourFitReport* report);

// The colour fit to given targets (FitBakedColours below, after its
// targets are made). Fills the report's fit fields and keeps its target
// fields; `report` may be null.
absl::Status FitBakedColoursTo(const FitTargets& targets, const BakedAsset& asset, const ColourFitOptions& options,
                               std::vector<float>* rgb, std::vector<float>* view, ColourFitReport* report);

// `asset` holds the grid: index, and the density codes in the atlas's alpha
// (its colour channels are not read). `rgb` holds 3 floats per lattice point
// of every brick (brick-major, 9^3 points x fastest, as the atlas's bricks):
// the first guess on entry, the fitted colours (clamped to [0, 1]) on return.
// `cameras` are world-space training cameras; `time_step` the model's.
// `view` (optional): 9 floats per lattice point, the view-dependent term H
// of c(d) = c0 + H d (d the ray's model-space direction; H column-major,
// k = x, y, z then channel), applied as asset.view_term says, fitted with
// c0 from zero, clamped to [-1, 1];
// null = diffuse colours only. Cleared when A is too large for it
// (max_view_nonzeros): the fit is then diffuse.
absl::Status FitBakedColours(const NgpModel& model, int time_step, const std::vector<Camera>& cameras,
                             const BakedAsset& asset, const ColourFitOptions& options, std::vector<float>* rgb,
                             std::vector<float>* view = nullptr, ColourFitReport* report = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_COLOUR_FIT_H_
