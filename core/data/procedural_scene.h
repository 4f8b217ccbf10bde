// ProceduralScene: an analytic scene generator for tests and continual-
// learning benchmarks (core/data/blender_writer.h stores any Scene, these
// included, in the NeRF-synthetic "Blender" format).
//
// The world is a set of spheres and axis-aligned boxes standing on a finite,
// thin, checkerboard floor slab ([-1.2, 1.2]^2, top face at z = -0.5), lit by
// one directional light (diffuse + ambient, hard shadows), with z up. All
// content lies inside [-1.5, 1.5]^3 world units, the NeRF-synthetic convention,
// so the Blender normalisation (scale 1/3) maps it into [-0.5, 0.5]^3. Images
// are rendered by analytic ray casting with n x n stratified, jittered
// subsamples per pixel; alpha is the fraction of subsamples that hit anything,
// and colours are composited onto a white background.
//
// Options add what object scenes like lego lack: `thin_structures` (rods
// about a pixel thick) and `backdrop` (an unbounded scene with a ground plane,
// pillars and an environment sphere far outside the NeRF-synthetic box, so
// content lies at many depths; see ProceduralSceneOptions).
//
// Time steps: at each step t > 0 the world changes deterministically from the
// world at t - 1: with `change_lighting` the light's direction, colour and
// intensity change; with `change_geometry` one object is removed, one new
// object is added and one existing object is recoloured. Every time step gets
// its own train and test cameras (the camera ring is rotated per step) with
// camera.time_step = t. Everything is a pure function of the options (seed
// included): the same options give bit-identical images.
//
// Cameras sit on an upper-hemisphere spiral at `camera_radius` looking at the
// origin. They are built as Blender/OpenGL camera-to-world matrices and stored
// in the OpenCV convention via ConvertPose(..., kOpenGL), like every loader.
//
// Alpha: Scene/View has no alpha channel, so GenerateProceduralDataset returns
// the Scene together with per-view alpha (ViewAlphas). The Blender writers take
// an optional ViewAlphas; without it they write alpha = 1 everywhere.
//
// Thread safety: all functions are pure (they share no state) and may be
// called concurrently. Generation renders views in parallel with OpenMP when
// the library is built with it.
#ifndef CLNERF_CORE_DATA_PROCEDURAL_SCENE_H_
#define CLNERF_CORE_DATA_PROCEDURAL_SCENE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/blender_writer.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/data/scene.h"
#include "Eigen/Core"

namespace clnerf {

// Where the cameras are and what surrounds the objects.
enum class ProceduralLayout {
  // Cameras on an upper-hemisphere spiral looking at the origin (an object
  // capture, like NeRF-synthetic); `backdrop` optional.
  kOrbit,
  // An LLFF-style forward-facing rig: cameras on a small plane (a grid
  // 0.3 camera_radius wide, 0.2 tall) at camera_radius from the origin, their
  // optical axes parallel within a few degrees, all looking across the
  // objects at the backdrop (implied), so content lies at 2 to 20 camera
  // baselines. Test cameras sit between the train ones.
  kForwardFacing,
  // A room walkthrough: the objects on their rug inside a closed room (walls
  // 0.9 x 0.8 camera_radius from the centre, floor, ceiling 2.5 units above
  // the floor) with nearly white, textureless walls and ceiling, a plank
  // floor, a door and one picture. Cameras walk a loop of radius 0.5
  // camera_radius at eye height, looking around (outwards, sideways and at
  // the objects), never at one point. The shell casts no shadows (the light
  // is inside). Unbounded, black background; every ray hits the shell.
  kRoom,
};

// "orbit", "forward" or "room"; Parse returns INVALID_ARGUMENT for others.
const char* ProceduralLayoutName(ProceduralLayout layout);
absl::Status ParseProceduralLayout(const std::string& name, ProceduralLayout* layout);

struct ProceduralSceneOptions {
  // Scene name stored in Scene::name.
  std::string name = "procedural";
  // Seed for object layout, colours, camera jitter and anti-aliasing jitter.
  uint64_t seed = 0;
  // Image size in pixels (both in [1, 4096]).
  int width = 64;
  int height = 64;
  // Horizontal field of view in radians (NeRF-synthetic uses 0.6911112).
  float camera_angle_x = 0.6911112f;
  // Views per time step for each split (train >= 1, test >= 0).
  int num_train_views = 50;
  int num_test_views = 10;
  // Number of time steps (>= 1) and what changes between consecutive steps.
  int num_time_steps = 1;
  bool change_lighting = true;
  bool change_geometry = true;
  // Number of objects in the world at every time step (1..16).
  int num_objects = 5;
  // Camera distance from the origin (> 2.2 so cameras stay outside the
  // content) and elevation range above the floor plane, in degrees
  // (0 < min <= max < 89).
  float camera_radius = 4.0f;
  float min_elevation_deg = 15.0f;
  float max_elevation_deg = 60.0f;
  // Anti-aliasing: samples_per_axis^2 stratified jittered rays per pixel
  // (1..8; 1 means a single ray through the pixel centre).
  int samples_per_axis = 2;
  // Unbounded scene: besides the objects on the floor slab, content at many
  // depths all around: an extended ground plane (the slab's bottom plane,
  // z = floor_z - floor_thickness, with a soft large checker that fades into
  // haze with distance) out to the backdrop; a few tall box pillars standing
  // at horizontal distances in [camera_radius + 1, 2.5 * camera_radius]
  // (outside the camera ring); and an emissive (unlit, never in shadow)
  // inward-facing sphere of radius 5 * camera_radius centred on the origin
  // whose colour is a smooth lat-long pattern of the viewing direction (soft
  // stripes over a sky gradient). Every ray hits something, so alpha = 1
  // everywhere, and the Scene is kUnbounded with a black background and no
  // normalisation hints (ComputeNormalization centres it on the cameras'
  // look-at point, the origin). Needs camera_radius <= 20.
  bool backdrop = false;
  // Thin structures: a few axis-aligned rods with a square cross-section of
  // 0.025-0.04 world units (about 0.6-0.9 pixel at 64 px and the default
  // field of view and camera radius) and lengths around 1 unit: 2-3 poles
  // standing on the floor slab, 1-2 bars lying across the tops of objects and
  // one arch (two posts and a lintel). Placed from the seed and the objects
  // at time step 0, and the same at every time step.
  bool thin_structures = false;
  // Every surface but the sky carries a fine, non-repeating texture (value
  // noise of the world position, three octaves, albedo x 0.4-1.6), as real
  // floors, walls and objects do; without it the flat colours and repeating
  // checkers give feature matching (core/pose) little to hold on to.
  bool textured = false;
  // Camera rig and surroundings (see ProceduralLayout). kForwardFacing and
  // kRoom scenes are kUnbounded with a black background and no hints.
  ProceduralLayout layout = ProceduralLayout::kOrbit;
  // Both flags false and kOrbit reproduce the original scenes bit for bit.

  absl::Status Validate() const;
};

// --- The analytic world -------------------------------------------------------

struct ProceduralObject {
  enum class Shape { kSphere, kBox };
  Shape shape = Shape::kSphere;
  Eigen::Vector3f center = Eigen::Vector3f::Zero();
  // Sphere: radius in x (all components equal). Box: half side lengths.
  Eigen::Vector3f half_extent = Eigen::Vector3f::Constant(0.25f);
  Eigen::Vector3f color = Eigen::Vector3f::Constant(0.5f);  // Albedo in [0, 1].
  int id = 0;  // Unique within a world's history (added objects get new ids).
};

struct ProceduralLight {
  Eigen::Vector3f direction = Eigen::Vector3f(0, 0, 1);  // Unit, towards the light.
  Eigen::Vector3f color = Eigen::Vector3f::Ones();
  float intensity = 0.85f;
  float ambient = 0.3f;
};

struct ProceduralWorld {
  std::vector<ProceduralObject> objects;
  ProceduralLight light;
  // Floor slab: [-floor_half_size, floor_half_size]^2 x
  // [floor_z - floor_thickness, floor_z].
  float floor_half_size = 1.2f;
  float floor_z = -0.5f;
  float floor_thickness = 0.04f;
  float checker_size = 0.3f;
  // Thin rods (ProceduralSceneOptions::thin_structures), boxes with albedo.
  std::vector<ProceduralObject> rods;
  // Backdrop (ProceduralSceneOptions::backdrop): pillars (boxes standing on
  // the ground plane), the ground plane z = ground_z (a disc of radius
  // backdrop_radius) and the emissive backdrop sphere of that radius around
  // the origin. backdrop_radius == 0 means no backdrop, ground or pillars.
  std::vector<ProceduralObject> pillars;
  float backdrop_radius = 0.0f;
  float ground_z = 0.0f;
  float backdrop_phase = 0.0f;  // Seeded offsets of the backdrop pattern.
  float backdrop_hue = 0.0f;
  // Room shell (ProceduralLayout::kRoom): the inside of the box
  // [-room_half.x, room_half.x] x [-room_half.y, room_half.y] x
  // [room_floor_z, room_ceiling_z]; room_half.x == 0 means no room. The door
  // and the picture are rectangles on the walls (x = -room_half.x and
  // y = room_half.y), given as (u0, v0, u1, v1) in the wall's (along, z).
  Eigen::Vector2f room_half = Eigen::Vector2f::Zero();
  float room_floor_z = 0.0f;
  float room_ceiling_z = 0.0f;
  Eigen::Vector4f door = Eigen::Vector4f::Zero();
  Eigen::Vector4f picture = Eigen::Vector4f::Zero();
  float room_phase = 0.0f;  // Seeded offset of the plank pattern.
  bool textured = false;    // ProceduralSceneOptions::textured.
  uint64_t texture_seed = 0;

  // True if world point `p` is inside an object, a rod, a pillar, the floor
  // slab or (with a backdrop) below the ground plane inside the backdrop
  // sphere, or (with a room) outside the room's inner box: the ground-truth
  // occupancy, e.g. for occupancy-grid tests. The backdrop sphere itself is a
  // surface and occupies nothing.
  bool Occupied(const Eigen::Vector3f& p) const;
};

// The world at `time_step` >= 0 (it need not be < options.num_time_steps).
// Precondition: options.Validate() is OK.
ProceduralWorld ProceduralWorldAt(const ProceduralSceneOptions& options, int time_step);

// The cameras of one split at one time step (deterministic from the options).
// `test_split` selects the test ring instead of the train spiral.
std::vector<Camera> ProceduralCameras(const ProceduralSceneOptions& options, int time_step,
                                      bool test_split);

struct ProceduralRender {
  Image image;               // Composited onto white.
  std::vector<float> alpha;  // Per pixel coverage in [0, 1].
};

// Renders `world` through `camera` (which must have no distortion) with
// samples_per_axis^2 jittered subsamples per pixel. The jitter depends only on
// `seed` and the pixel, so two worlds rendered from one camera differ exactly
// where the worlds differ.
ProceduralRender RenderProceduralView(const ProceduralWorld& world, const Camera& camera,
                                      int samples_per_axis, uint64_t seed);

// --- Datasets -----------------------------------------------------------------

// Distance along each pixel centre's unit ray to the first surface (world
// units), +inf where the ray hits nothing; row-major, width * height. A
// ground-truth depth map for tests of what renders depth (registration).
std::vector<float> RenderProceduralDistance(const ProceduralWorld& world, const Camera& camera);

struct ProceduralDataset {
  Scene scene;
  ViewAlphas alpha;
};

// Generates the scene: for each time step t, num_train_views train views and
// num_test_views test views with camera.time_step = t, appended to
// scene.train / scene.test in time-step order (scene.val stays empty). View
// names are "train/r_<i>" / "test/r_<i>" with i the index within the split.
// scene.kind = kBounded, background white, world_scale_hint = 1/3,
// world_offset_hint = 0; with options.backdrop, kind = kUnbounded, background
// black, world_scale_hint = 0. Returns INVALID_ARGUMENT for bad options.
absl::StatusOr<ProceduralDataset> GenerateProceduralDataset(const ProceduralSceneOptions& options);
// As above, without the alpha channels.
absl::StatusOr<Scene> GenerateProceduralScene(const ProceduralSceneOptions& options);

// The NeRF-synthetic writers (core/data/blender_writer.h) for a generated dataset,
// with its alpha channels.
absl::Status WriteBlenderDataset(const ProceduralDataset& dataset, const std::string& dir);
absl::Status WriteScanFolders(const ProceduralDataset& dataset, const std::string& dir);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_PROCEDURAL_SCENE_H_
