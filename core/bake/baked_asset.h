// BakedAsset: one time step of a trained model, baked into the block-sparse
// voxel grid that the browser renders itself (issue 41; after SNeRG's
// design). It is the asset's in-memory form and its file format.
//
// The grid covers the model's field space, the cube [-B, B]^3 (B = the
// model box's half size for objects, 2 for unbounded scenes, whose far
// surroundings are contracted into the shell 1 < |q|_inf < 2 exactly as the
// model's field is, see contraction.h). It has R^3 cells in (R/8)^3 blocks
// of 8^3 cells. `index` holds one entry per block: 0 = empty (no density),
// otherwise 1 + the block's brick in `atlas`. A brick holds the 9^3 lattice
// points of its block's cells (its own copy of the faces it shares with the
// neighbouring blocks, so trilinear interpolation never leaves a brick), as
// RGBA8: a density code a = round(255 sqrt(alpha0)), where alpha0 = 1 -
// exp(-sigma * cell) is the opacity of one cell's length of the field (model
// units, inner cube), and the diffuse colour premultiplied by a / 255, so
// that interpolation weighs each corner's colour by its density (renderers
// divide by the interpolated a). Bricks are laid out in an atlas of
// bricks_x x bricks_y x bricks_z bricks (texels: 9 bricks_x wide, x fastest),
// which is also the 3-D texture the page uploads.
//
// View-dependent colour (optional): c(d) = c0 + H d for the ray's
// model-space direction d, H a 3x3 matrix per lattice point, stored as three
// more atlases of the same shape (k = x, y, z), RGB = 128 + round(127 * (a /
// 255) * H[c][k]) (premultiplied like the colour, so it interpolates the
// same way), A = 0. Two ways to apply it:
//   format 2 (per sample): every sample adds sum_k d_k * (texel - 128) / 127
//     to its blended colour before dividing by the blended code;
//   format 3 (at the median, the default): the term is read once per ray, at
//     the first sample after which the transmittance is below 1/2 (none if
//     it never is): the pixel gains (1 - T) * sum_k d_k * (texel - 128) /
//     127 / (blended code there), T the ray's final transmittance. Three
//     texture reads per pixel instead of three per sample.
//
// Rays step `step_cells` cells, a multiple of 1/32 in [0.5, 2] (1 for
// assets baked now, at any resolution; R/512 on the finer grids of a
// derived resolution in sessions 49-73, so that a step stayed one 512th
// of the box long; 0.5 for assets before format 3), as the manifest's
// "step" says.
//
// Files (a folder; SaveBakedAsset / LoadBakedAsset): manifest.json (the
// fields below; format 1 diffuse, 2 or 3 with the view term), index.bin.gz
// (uint32 little-endian, (R/8)^3, x fastest), atlas.bin.gz (RGBA8) and,
// formats 2 and 3, view.bin.gz (the three atlases back to back), gzip
// streams which the page decodes with DecompressionStream.
//
// Renderers skip empty space by `block_distance` (derived, not stored): for
// each block the chessboard distance, in blocks, to the nearest occupied
// one, so a ray in an empty block with distance D jumps past the (2D - 1)^3
// blocks around it, which are all empty. Inside occupied blocks, a lattice
// point with no density (a = 0, so no colour) may carry in its red channel
// its chessboard distance in cells to the nearest point with density
// (skip_codes.h; assets baked since session 78), by which renderers jump
// over samples with none; red 0 there means no code.
//
// A value type without locking: concurrent const use is safe.
#ifndef CLNERF_CORE_BAKE_BAKED_ASSET_H_
#define CLNERF_CORE_BAKE_BAKED_ASSET_H_

#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/scene.h"
#include "Eigen/Core"

namespace clnerf {

inline constexpr int kBakeFormat = 1;                 // Diffuse colour.
inline constexpr int kBakeFormatViewDependent = 2;    // Plus the view-dependent term, per sample.
inline constexpr int kBakeFormatViewAtMedian = 3;     // Plus the view-dependent term, once per ray.
// A ray step in cells rounded to the nearest 1/32 (exact in binary, so the
// C++ and WebGL renderers march the same samples), and whether a step is
// one: a multiple of 1/32 in [0.5, 2].
inline float RoundBakedStep(float cells) { return std::round(32.0f * cells) / 32.0f; }
inline bool IsBakedStep(float cells) { return cells >= 0.5f && cells <= 2.0f && RoundBakedStep(cells) == cells; }

inline constexpr int kBakeBlock = 8;   // Cells per block side.
inline constexpr int kBakeBrick = 9;   // Lattice points per brick side.

// Where a ray applies the view-dependent term (formats 2 and 3).
enum class BakedViewTerm { kPerSample, kAtMedian };

struct BakedAsset {
  bool contracted = false;      // Unbounded scene: the field space is contracted.
  float half_size = 1.0f;       // B: the grid covers [-B, B]^3 of field space.
  int resolution = 0;           // R cells per axis, a multiple of kBakeBlock.
  float near = 0.0f;            // Rays start this far from the camera (model units).
  Normalization normalization;  // World -> model, as the model's.
  Eigen::Vector3f background = Eigen::Vector3f::Ones();
  int time_step = 0;            // The model's time step this is.
  std::array<int, 3> bricks = {0, 0, 0};  // Atlas size in bricks.
  // A few of the training cameras (world space), where a viewer starts.
  std::vector<Camera> views;
  std::vector<uint32_t> index;  // (R/8)^3 entries, x fastest.
  std::vector<uint8_t> atlas;   // RGBA8 texels, 9 bricks x (x fastest) ...
  std::vector<uint8_t> view;    // Empty, or 3 atlases: the view-dependent term.
  BakedViewTerm view_term = BakedViewTerm::kAtMedian;
  float step_cells = 1.0f;      // The ray step in cells (above).
  // Derived from `index` by ComputeBlockDistances (LoadBakedAsset and
  // BakeModel call it): (R/8)^3 chessboard distances in blocks to the
  // nearest occupied block (0 = occupied, capped at 255). Empty = not
  // computed: renderers then skip one empty block at a time.
  std::vector<uint8_t> block_distance;
  // Also derived there, for an object (bounded) asset: the box of blocks
  // that holds every occupied one, [occupied_lo, occupied_hi] (block
  // coordinates; lo > hi when none is). Rays march only where they cross
  // it (from the lattice point before they enter to one step past).
  std::array<int, 3> occupied_lo = {0, 0, 0}, occupied_hi = {-1, -1, -1};

  int blocks_per_axis() const { return resolution / kBakeBlock; }
  float cell() const { return 2.0f * half_size / float(resolution); }
  // The model-space step along a ray inside the inner cube.
  float step() const { return step_cells * cell(); }
  int num_bricks() const;
  std::array<int, 3> atlas_texels() const {
    return {kBakeBrick * bricks[0], kBakeBrick * bricks[1], kBakeBrick * bricks[2]};
  }
  // Bytes of the raw (uncompressed) arrays.
  size_t raw_bytes() const { return index.size() * 4 + atlas.size() + view.size(); }
  bool view_dependent() const { return !view.empty(); }
  // Sizes and ranges consistent (every index entry names a brick).
  absl::Status Validate() const;
};

// The asset's files, name -> bytes (manifest.json, index.bin.gz,
// atlas.bin.gz, and view.bin.gz for formats 2 and 3), e.g. for
// WriteDirectoryAtomically.
absl::StatusOr<std::vector<std::pair<std::string, std::string>>> SerializeBakedAsset(const BakedAsset& asset);
// Writes them into `dir` (created if needed; files replaced atomically).
absl::Status SaveBakedAsset(const BakedAsset& asset, const std::string& dir);
// Reads a folder SaveBakedAsset wrote. NOT_FOUND without a manifest;
// INVALID_ARGUMENT / DATA_LOSS for a corrupt or inconsistent one.
absl::StatusOr<BakedAsset> LoadBakedAsset(const std::string& dir);
// Bytes of the asset's files in `dir` (what a browser downloads; other
// files beside them, such as a copied viewer page, are not counted).
absl::StatusOr<uint64_t> BakedAssetBytes(const std::string& dir);
// The names of the files an asset may have (for servers that hand them out).
bool IsBakedAssetFileName(const std::string& name);
// True when `dir` holds a baked asset's manifest.
bool IsBakedAssetDir(const std::string& dir);

// Fills asset->block_distance from its index (two raster passes over the
// 26-neighbourhood; exact for the chessboard distance), and the occupied
// blocks' box.
void ComputeBlockDistances(BakedAsset* asset);

// The model-space camera of a world-space one (as NgpModel::ToModelCamera).
Camera BakedModelCamera(const BakedAsset& asset, const Camera& world);

}  // namespace clnerf

#endif  // CLNERF_CORE_BAKE_BAKED_ASSET_H_
