// DensityFit: refits a baked asset's density codes to its model, as the
// colour fit (colour_fit.h) refits its colours. The baker's codes are the
// field's density sampled at the lattice points; a ray through the asset
// blends 8 of them trilinearly at a few samples, so a thin surface between
// two lattice points is seen fainter or smeared (flower_4's leaves: 0.4 dB
// from the lattice alone, docs/baking.md). This stage instead chooses the
// codes that make the asset's own renders of training-camera rays match the
// model's renders of the same rays (the shared FitTargets; no photos).
//
// A pixel is nonlinear in the codes, so the fit takes a few damped
// Gauss-Newton (Levenberg-Marquardt) steps: at the current codes each ray's
// pixel is linearised (BakedRayDensityJacobian, checked against central
// differences), the damped linear system
//
//   min_delta sum_rays |J delta - (model pixel - asset pixel)|^2 + lambda |delta|^2
//
// is solved by CGLS (lambda = `prior` times the mean squared derivative a
// code gets, so codes few rays see stay near the field's own), the codes
// move by delta (clamped to [0, 1]), and the step is kept only if the rays'
// residual falls. Colours stay fixed (the first guess); the colour fit runs
// afterwards on the new codes. Sample positions do not depend on the codes
// (the lattice's steps), so the linearisation is exact but for rays'
// early stops.
//
// Thread-safe for concurrent calls; each runs over the OpenMP threads of the
// calling context, and its result does not depend on their number.
#ifndef CLNERF_CORE_BAKE_DENSITY_FIT_H_
#define CLNERF_CORE_BAKE_DENSITY_FIT_H_

#include <cstdint>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "core/bake/baked_asset.h"
#include "core/bake/colour_fit.h"

namespace clnerf {

struct DensityFitOptions {
  // Rays of the colour fit's targets the density fit uses (a hashed share;
  // all when there are fewer). 0 = no density fit, the default: it lowers
  // the training rays' residual but hardly moves the test views (flower_4 at
  // 1024^3 with 2^18 rays: +0.09 dB at prior 100 and 1 step, -0.19 dB at
  // prior 10 and 2 steps; fox_8 +0.04 dB) for 7-17 s more per bake
  // (docs/baking.md, session 73).
  int rays = 0;
  // Gauss-Newton steps (each one pass over the rays to linearise, and one
  // more to check the step).
  int steps = 1;
  // CGLS iterations per step.
  int iterations = 16;
  // Damping towards the current codes, relative to the mean squared
  // derivative of the pixels by a code (10 overfits the training rays:
  // flower_4's test views lost 0.28 dB against 100).
  float prior = 100.0f;
  absl::Status Validate() const;
};

struct DensityFitReport {
  long long rays = 0;       // Rays in the fit (those that meet an occupied block).
  long long unknowns = 0;   // Codes some ray's pixel depends on (last step).
  long long nonzeros = 0;   // Entries of J (last step).
  int accepted_steps = 0;   // Steps that lowered the residual.
  double rms_before = 0, rms_after = 0;  // Residual on the rays (colour units).
  double seconds = 0;
};

// One ray's pixel before clamping and without the view term, for float
// density `codes` (one per lattice point, brick-major as colour_fit.h's
// `rgb`, in [0, 1]) and colours `rgb` (3 per point, not premultiplied),
// marching `asset`'s grid as the reference renderer does. With `jacobian`,
// also the pixel's derivative by each code it depends on: (lattice id,
// dpixel/dcode), sorted by id. *T (optional) gets the final transmittance.
Eigen::Vector3f BakedRayDensityJacobian(const BakedAsset& asset, const float* codes, const float* rgb,
                                        const Eigen::Vector3f& o, const Eigen::Vector3f& d,
                                        std::vector<std::pair<uint32_t, Eigen::Vector3f>>* jacobian,
                                        float* T = nullptr);

// Fits the density codes of `asset` (the atlas's alpha; its colour channels
// are not read) to `targets`, with the colours `rgb` (3 floats per lattice
// point, as colour_fit.h's) held fixed, and writes the fitted codes back to
// the atlas's alpha. No-op when options.rays is 0 or there are no targets.
absl::Status FitBakedDensities(const FitTargets& targets, const DensityFitOptions& options,
                               const std::vector<float>& rgb, BakedAsset* asset, DensityFitReport* report = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_DENSITY_FIT_H_
