// Baker: bakes one time step of a trained NgpModel into a BakedAsset (the
// block-sparse voxel grid the browser renders itself; baked_asset.h), using
// only point queries of the field, in four stages:
//
//  1. Candidate blocks: the 8^3-cell blocks that overlap occupied cells of
//     the model's occupancy grid.
//  2. Density at the 9^3 lattice points of every candidate block that a
//     ray of stage 3 reaches (computed as the first one does).
//  3. Visibility: rays from the training cameras and from cameras halfway
//     between neighbouring ones (a strided subset of their pixels) march
//     the baked densities exactly as the renderer will; a
//     block is kept when some ray deposits at least `min_block_weight` of
//     its weight in it, and the rays' weighted mean direction in the block
//     is recorded.
//  4. Colour at the kept blocks' lattice points, from the full field seen
//     along that mean direction (the colour the photos showed there).
//  5. Density fit (density_fit.h), then colour fit (colour_fit.h): the
//     density codes, then the colours, that make the asset's renders of
//     training-camera rays match the model's (damped Gauss-Newton steps on
//     the codes with stage 4's colours; damped least squares from stage 4's
//     colours).
//  6. Quantised to RGBA8 and packed into the atlas.
//
// Thread-safe for concurrent calls on the same (const) model; each call runs
// its stages over the OpenMP threads of the calling context.
#ifndef CLNERF_CORE_BAKE_BAKER_H_
#define CLNERF_CORE_BAKE_BAKER_H_

#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/bake/baked_asset.h"
#include "core/bake/colour_fit.h"
#include "core/bake/density_fit.h"
#include "core/data/camera.h"
#include "core/field/ngp_model.h"

namespace clnerf {

struct BakeOptions {
  // Cells per axis of the grid over the field space (a multiple of 32);
  // 0 = derived: 256 for objects; for unbounded scenes (whose inner cube,
  // where the cameras are, gets half of them) 512, or finer where the
  // download budget leaves room: baked at 512 first, the finest grid (up to
  // 1024) whose download, scaled by the surface area (R^2), stays within
  // 70 % of max_asset_bytes is baked instead, stepping one base cell
  // (fox_8, 5.1 MB estimated at 512 in session 49, -> 640: +0.18 dB; 5.6 MB
  // with session 50's visibility pass, -> 608; flower_4 -> 768:
  // +0.48 dB; beer_2, over the budget at 512, stays). The cap was 768 while
  // the models were blurrier (session 49: flower_4 at 960 and 1024 below
  // 768); on session 73's model flower_4 at 1024 is +0.61 dB over 768.
  // Where the download at the default (512, or 256 for objects) is over the
  // budget, the coarser grid (down to half of it) whose scaled download
  // stays within 70 % of it, rather than drop blocks (a procedural room:
  // 15.8 MB at 512 -> 352, 32.08 -> 34.06 dB; lego_100 with a 2 MB budget:
  // 256 -> 160 instead of dropping blocks, 17.03 -> 31.00 dB).
  int resolution = 0;
  // Training-camera rays marched for visibility: pixels on a stride that
  // gives about this many over the training cameras, plus every border pixel of
  // each photo (lego_100: 280 K rays in all, beer_2: 347 K).
  int visibility_rays = 1 << 18;
  // The visibility rays also come from one camera halfway between each
  // training camera and its nearest neighbour (centre and rotation), what a
  // viewer sees moving along the capture: where the model's geometry
  // differs between neighbouring views (a textureless wall drawn at two
  // depths), blocks no training ray reaches but such a viewer does are
  // kept. A procedural room: 30.78 -> 32.08 dB (bake 30.8 -> 23.4 s); a
  // procedural forward-facing scene and the four shared captures within
  // 0.07 dB (docs/baking.md, session 74). They march on the training
  // cameras' stride: visibility_rays counts the training cameras' rays,
  // and these add about as many.
  bool in_between_views = true;
  // A block is kept when some training ray deposits at least this much of
  // its weight in it. 0.1 against 0.01: assets 8-46 % smaller for at most
  // 0.06 dB on lego_100, fox_8 and flower_4, 0.55 dB on beer_2's haze
  // (docs/baking.md). On a grid finer than the kind's default D (256
  // objects, 512 unbounded) the threshold shrinks with the block: x D/R
  // (flower_4 at 768: +0.09 dB).
  float min_block_weight = 0.1f;
  int threads = 0;  // OpenMP threads; 0 = all available.
  ColourFitOptions fit;  // Stage 5; fit.rays = 0 skips it (and the density fit).
  // Stage 5a, before the colour fit: the density codes refitted to the
  // same targets (density_fit.h); density_fit.rays = 0 skips it.
  DensityFitOptions density_fit;
  // Stage 5 also fits a view-dependent term per lattice point (c0 + H d;
  // format 2, baked_asset.h; skipped above fit.max_view_nonzeros). Test
  // views: fox_8 25.96 -> 27.74 dB, lego_100 30.04 -> 30.64, flower_4
  // 25.58 -> 25.83 (docs/baking.md); assets 11-23 % larger.
  bool view_dependent = true;
  // Where rays apply that term: once, at the median sample (format 3), or
  // at every sample (format 2). See docs/baking.md for what each costs.
  BakedViewTerm view_term = BakedViewTerm::kAtMedian;
  // The ray step in cells of the baked grid: a multiple of 1/32 in [0.5, 2]
  // (0.5: every asset before format 3). A derived finer grid steps its own
  // cells too (until session 73 it kept the base grid's step, R/512 of its
  // cells: flower_4 at 1024^3 27.95 dB with 2-cell steps, 28.41 with one,
  // for 30 -> 51 steps per ray; docs/baking.md, session 74).
  float step_cells = 1.0f;
  // Download budget in bytes for an unbounded scene (0 = none). A derived
  // grid over it is baked coarser (`resolution`); then, before the
  // colour fit, while the kept blocks' first-guess colours compress (gzip
  // level 1, ~10 % above the stored level 6, about what the fit adds) to
  // more than this, the blocks the training rays weigh least are dropped;
  // after it, only when the asset would store more than this are the
  // view-dependent codes within one step of none written as none (fox_8:
  // 9.51 -> 9.91 MB without, +0.13 dB; lego_100 4.33 -> 3.92 MB with,
  // 0.11 dB).
  int64_t max_asset_bytes = 12'000'000;
  // The same for a bounded (object) scene: objects are small (lego_100's
  // asset: 3.3 MB at 256^3). A derived object grid over it is baked coarser
  // (down to 128^3); an explicit finer one (`resolution`) needs it raised,
  // or its least-seen blocks are dropped to fit.
  int64_t max_object_asset_bytes = 4'000'000;
  absl::Status Validate() const;
};

struct BakeReport {
  int resolution = 0;
  int candidate_blocks = 0;  // Blocks overlapping occupied cells.
  int evaluated_blocks = 0;  // Candidates some training ray reached (their densities computed).
  int visible_blocks = 0;    // Blocks the training rays see.
  int kept_blocks = 0;       // Of those, kept within the download budget.
  long long visibility_rays = 0;
  // The first guess's estimated download at the base resolution (512 for
  // unbounded scenes), which a derived resolution is chosen from.
  long long base_resolution_bytes = 0;
  // The stored asset's estimated bytes before and after the view term's
  // dead zone (0 = not estimated: no budget), and whether it applied; the
  // second is measured exactly when the estimate is within 10 % of the
  // budget.
  long long estimated_bytes = 0;
  long long stored_bytes = 0;
  bool view_dead_zone = false;
  // How often the fitted asset was over the budget and stages 4-6 ran again
  // with fewer blocks (at most 3).
  int over_budget_rebakes = 0;
  ColourFitReport fit;
  DensityFitReport density_fit;
  // candidate_seconds: stage 1; visibility_seconds: stages 2 and 3 (densities
  // are computed as rays reach candidates). With a derived finer grid the
  // seconds add up both grids' passes; the counts describe the final grid.
  double candidate_seconds = 0, visibility_seconds = 0, colour_seconds = 0, fit_seconds = 0, total_seconds = 0;
};

// One camera halfway between each of `cameras` and its nearest neighbour
// (BakeOptions::in_between_views): centre midway, rotation halfway
// (slerp), that camera's intrinsics and time step. A camera with no
// distinct neighbour, or either rotation improper, gives none. Pure
// function.
std::vector<Camera> InBetweenCameras(const std::vector<Camera>& cameras);

// The derived grid (BakeOptions::resolution = 0) from the estimated
// download `bytes` of the grid at `resolution` (the kind's default): the
// finest multiple of 32 whose download, scaled by the surface area (R^2),
// stays within 70 % of `budget`, up to `finest` (1024 for unbounded
// scenes, `resolution` for objects), and never coarser than `resolution`
// unless `bytes` is over the budget (then down to half of it). `bytes` or
// `budget` 0: `resolution`. Pure function.
int DerivedResolution(int resolution, uint64_t bytes, int64_t budget, int finest);

// Bakes `time_step` (-1 = the latest) of `model`. `cameras` are the training
// cameras in world space (visibility); INVALID_ARGUMENT when there are none
// or the options are bad.
absl::StatusOr<BakedAsset> BakeModel(const NgpModel& model, int time_step, const std::vector<Camera>& cameras,
                                     const BakeOptions& options, BakeReport* report = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_BAKER_H_
