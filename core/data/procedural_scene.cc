#include "core/data/procedural_scene.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <utility>

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "Eigen/Dense"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

constexpr float kPi = 3.14159265358979323846f;
constexpr float kInf = std::numeric_limits<float>::infinity();

// SplitMix64: a tiny generator whose output is fixed by its definition (unlike
// the standard distributions), so scenes are identical across platforms.
uint64_t SplitMix(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

uint64_t Mix(uint64_t a, uint64_t b) { return SplitMix(a ^ SplitMix(b + 0x632BE59BD9B4E019ull)); }
uint64_t Mix(uint64_t a, uint64_t b, uint64_t c) { return Mix(Mix(a, b), c); }

class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed) {}
  uint64_t Next() {
    state_ += 0x9E3779B97F4A7C15ull;
    uint64_t z = state_;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  float Uniform() { return float(Next() >> 40) * 0x1.0p-24f; }  // [0, 1)
  float Uniform(float lo, float hi) { return lo + (hi - lo) * Uniform(); }
  int Below(int n) { return int(Next() % uint64_t(n)); }

 private:
  uint64_t state_;
};

float HashToUnit(uint64_t h) { return float(h >> 40) * 0x1.0p-24f; }

Eigen::Vector3f HsvToRgb(float h, float s, float v) {
  h = h - std::floor(h);
  const float hh = h * 6.0f;
  const int i = std::min(int(hh), 5);
  const float f = hh - float(i);
  const float p = v * (1 - s), q = v * (1 - s * f), t = v * (1 - s * (1 - f));
  switch (i) {
    case 0: return {v, t, p};
    case 1: return {q, v, p};
    case 2: return {p, v, t};
    case 3: return {p, q, v};
    case 4: return {t, p, v};
    default: return {v, p, q};
  }
}

Eigen::Vector3f RandomColor(Rng& rng) {
  const float h = rng.Uniform(), s = rng.Uniform(0.45f, 0.85f), v = rng.Uniform(0.55f, 0.95f);
  return HsvToRgb(h, s, v);
}

float FootprintRadius(const ProceduralObject& o) {
  return o.shape == ProceduralObject::Shape::kSphere
             ? o.half_extent.x()
             : std::sqrt(o.half_extent.x() * o.half_extent.x() +
                         o.half_extent.y() * o.half_extent.y());
}

// A random object standing on (or, for some spheres, floating above) the
// floor, placed to avoid overlapping `existing` where possible.
ProceduralObject RandomObject(Rng& rng, const std::vector<ProceduralObject>& existing,
                              const ProceduralWorld& world, int id) {
  ProceduralObject o;
  o.id = id;
  if (rng.Uniform() < 0.5f) {
    o.shape = ProceduralObject::Shape::kSphere;
    o.half_extent = Eigen::Vector3f::Constant(rng.Uniform(0.18f, 0.35f));
  } else {
    o.shape = ProceduralObject::Shape::kBox;
    o.half_extent = Eigen::Vector3f(rng.Uniform(0.12f, 0.3f), rng.Uniform(0.12f, 0.3f),
                                    rng.Uniform(0.12f, 0.4f));
  }
  const float r = FootprintRadius(o);
  const float range = world.floor_half_size - 0.1f - r;
  for (int attempt = 0; attempt < 64; ++attempt) {
    o.center.x() = rng.Uniform(-range, range);
    o.center.y() = rng.Uniform(-range, range);
    bool clear = true;
    for (const ProceduralObject& e : existing) {
      const float d = (o.center.head<2>() - e.center.head<2>()).norm();
      if (d < r + FootprintRadius(e) + 0.05f) {
        clear = false;
        break;
      }
    }
    if (clear) break;
  }
  float lift = 0.0f;
  if (o.shape == ProceduralObject::Shape::kSphere && rng.Uniform() < 0.3f) {
    lift = rng.Uniform(0.1f, 0.4f);
  }
  o.center.z() = world.floor_z + o.half_extent.z() + lift;
  o.color = RandomColor(rng);
  return o;
}

Eigen::Vector3f DirectionFromAngles(float azimuth, float elevation) {
  return Eigen::Vector3f(std::cos(elevation) * std::cos(azimuth),
                         std::cos(elevation) * std::sin(azimuth), std::sin(elevation));
}

ProceduralLight LightAt(uint64_t seed, int time_step) {
  ProceduralLight light;
  if (time_step == 0) {
    light.direction = DirectionFromAngles(40.0f * kPi / 180, 55.0f * kPi / 180);
    return light;
  }
  Rng rng(Mix(seed, uint64_t(time_step), 0x11647ull));
  const float az = (40.0f + 100.0f * float(time_step) + rng.Uniform(-10.0f, 10.0f)) * kPi / 180;
  const float el = rng.Uniform(30.0f, 75.0f) * kPi / 180;
  light.direction = DirectionFromAngles(az, el);
  const Eigen::Vector3f warm(1.0f, 0.82f, 0.62f), cool(0.68f, 0.82f, 1.0f);
  const Eigen::Vector3f tint = (time_step % 2 == 1) ? warm : cool;
  light.color = tint + Eigen::Vector3f(rng.Uniform(-0.05f, 0.05f), rng.Uniform(-0.05f, 0.05f),
                                       rng.Uniform(-0.05f, 0.05f));
  light.color = light.color.cwiseMax(0.0f).cwiseMin(1.0f);
  light.intensity = rng.Uniform(0.6f, 1.1f);
  light.ambient = rng.Uniform(0.18f, 0.35f);
  return light;
}

void ApplyGeometryChange(uint64_t seed, int time_step, ProceduralWorld* world) {
  Rng rng(Mix(seed, uint64_t(time_step), 0x6E0ull));
  std::vector<ProceduralObject>& objs = world->objects;
  int next_id = 0;
  for (const ProceduralObject& o : objs) next_id = std::max(next_id, o.id + 1);
  // Remove one object.
  if (!objs.empty()) objs.erase(objs.begin() + rng.Below(int(objs.size())));
  // Recolour one of the remaining objects with a clearly different colour.
  if (!objs.empty()) {
    ProceduralObject& o = objs[rng.Below(int(objs.size()))];
    Eigen::Vector3f c = RandomColor(rng);
    for (int attempt = 0; attempt < 16 && (c - o.color).cwiseAbs().sum() < 0.6f; ++attempt) {
      c = RandomColor(rng);
    }
    o.color = c;
  }
  // Add a new object.
  objs.push_back(RandomObject(rng, objs, *world, next_id));
}

// Thin rods (ProceduralSceneOptions::thin_structures), from their own random
// stream and the objects present now (time step 0): poles standing on the
// floor slab, bars lying across object tops and one arch.
void AddThinStructures(uint64_t seed, ProceduralWorld* world) {
  Rng rng(Mix(seed, 0x7410ull));
  const float lim = world->floor_half_size - 0.05f;
  auto rod = [&](const Eigen::Vector3f& center, const Eigen::Vector3f& half,
                 const Eigen::Vector3f& color) {
    ProceduralObject o;
    o.shape = ProceduralObject::Shape::kBox;
    o.center = center;
    o.half_extent = half;
    o.color = color;
    o.id = 1000 + int(world->rods.size());
    world->rods.push_back(o);
  };
  // Dark, saturated colours so that sub-pixel rods still show on the light
  // floor and the white background.
  auto color = [&] { return HsvToRgb(rng.Uniform(), rng.Uniform(0.5f, 0.9f), rng.Uniform(0.15f, 0.4f)); };
  auto width = [&] { return rng.Uniform(0.025f, 0.04f); };
  // Poles.
  const int poles = 2 + rng.Below(2);
  for (int i = 0; i < poles; ++i) {
    const float w = width(), h = rng.Uniform(0.6f, 1.1f);
    const Eigen::Vector3f c(rng.Uniform(-1.0f, 1.0f), rng.Uniform(-1.0f, 1.0f), world->floor_z + 0.5f * h);
    rod(c, Eigen::Vector3f(0.5f * w, 0.5f * w, 0.5f * h), color());
  }
  // Bars lying across the tops of objects, along x or y.
  const int bars = world->objects.empty() ? 0 : 1 + rng.Below(2);
  for (int i = 0; i < bars; ++i) {
    const ProceduralObject& obj = world->objects[rng.Below(int(world->objects.size()))];
    const float w = width(), len = rng.Uniform(0.8f, 1.2f);
    const int axis = rng.Below(2);
    Eigen::Vector3f half = Eigen::Vector3f::Constant(0.5f * w);
    half[axis] = 0.5f * len;
    Eigen::Vector3f c = obj.center;
    c[axis] = std::clamp(c[axis], -lim + half[axis], lim - half[axis]);
    c.z() = obj.center.z() + obj.half_extent.z() + 0.5f * w;
    rod(c, half, color());
  }
  // An arch: two posts and a lintel over them.
  {
    const float w = width(), span = rng.Uniform(0.6f, 1.0f), h = rng.Uniform(0.5f, 0.8f);
    const int axis = rng.Below(2);
    const Eigen::Vector3f col = color();
    Eigen::Vector3f c(rng.Uniform(-0.6f, 0.6f), rng.Uniform(-0.6f, 0.6f), world->floor_z + 0.5f * h);
    for (float side : {-0.5f, 0.5f}) {
      Eigen::Vector3f pc = c;
      pc[axis] += side * span;
      rod(pc, Eigen::Vector3f(0.5f * w, 0.5f * w, 0.5f * h), col);
    }
    Eigen::Vector3f half = Eigen::Vector3f::Constant(0.5f * w);
    half[axis] = 0.5f * (span + w);
    c.z() = world->floor_z + h + 0.5f * w;
    rod(c, half, col);
  }
}

// The backdrop (ProceduralSceneOptions::backdrop): ground plane at the floor
// slab's bottom, pillars outside the camera ring, and the backdrop sphere.
void AddBackdrop(const ProceduralSceneOptions& options, ProceduralWorld* world) {
  Rng rng(Mix(options.seed, 0xBAC4D0ull));
  const float rc = options.camera_radius;
  world->backdrop_radius = 5.0f * rc;
  world->ground_z = world->floor_z - world->floor_thickness;
  world->backdrop_phase = rng.Uniform(0.0f, 2 * kPi);
  world->backdrop_hue = rng.Uniform();
  constexpr int kPillars = 5;
  const float az0 = rng.Uniform(0.0f, 2 * kPi);
  for (int k = 0; k < kPillars; ++k) {
    ProceduralObject o;
    o.shape = ProceduralObject::Shape::kBox;
    o.id = 2000 + k;
    const float hx = rng.Uniform(0.25f, 0.45f), hy = rng.Uniform(0.25f, 0.45f);
    const float top = rng.Uniform(1.5f, 3.5f);
    const float footprint = std::sqrt(hx * hx + hy * hy);
    // Nearest point at least 1 unit outside the camera ring.
    const float dist = rng.Uniform(rc + 1.0f + footprint, 2.5f * rc - footprint);
    const float az = az0 + 2 * kPi * (float(k) + rng.Uniform(0.15f, 0.85f)) / kPillars;
    o.half_extent = Eigen::Vector3f(hx, hy, 0.5f * (top - world->ground_z));
    o.center = Eigen::Vector3f(dist * std::cos(az), dist * std::sin(az), 0.5f * (top + world->ground_z));
    o.color = RandomColor(rng);
    world->pillars.push_back(o);
  }
}

// The room shell (ProceduralLayout::kRoom) around the rug and its objects.
void AddRoom(const ProceduralSceneOptions& options, ProceduralWorld* world) {
  Rng rng(Mix(options.seed, 0x200Dull));
  const float rc = options.camera_radius;
  world->room_half = Eigen::Vector2f(0.9f * rc, 0.8f * rc);
  world->room_floor_z = world->floor_z - world->floor_thickness;
  world->room_ceiling_z = world->room_floor_z + 2.5f;
  const float hy = world->room_half.y(), hx = world->room_half.x();
  // Door on the wall x = -hx: 0.9 wide, 2.0 tall, somewhere along y.
  const float dy = rng.Uniform(-hy + 0.3f, hy - 1.2f);
  world->door = Eigen::Vector4f(dy, world->room_floor_z, dy + 0.9f, world->room_floor_z + 2.0f);
  // Picture on the wall y = +hy: 1.0 x 0.7, at eye height, along x.
  const float px = rng.Uniform(-hx + 0.3f, hx - 1.3f);
  world->picture = Eigen::Vector4f(px, world->room_floor_z + 1.2f, px + 1.0f, world->room_floor_z + 1.9f);
  world->room_phase = rng.Uniform(0.0f, 1.0f);
}

// --- Ray casting ---------------------------------------------------------------

struct Hit {
  float t = kInf;
  Eigen::Vector3f normal = Eigen::Vector3f::Zero();
  Eigen::Vector3f albedo = Eigen::Vector3f::Zero();
  bool emissive = false;  // The backdrop sphere: `albedo` is the radiance, unlit.
};

float SmoothStep(float e0, float e1, float x) {
  const float t = std::clamp((x - e0) / (e1 - e0), 0.0f, 1.0f);
  return t * t * (3.0f - 2.0f * t);
}

Eigen::Vector3f Lerp(const Eigen::Vector3f& a, const Eigen::Vector3f& b, float t) {
  return a + t * (b - a);
}

// The backdrop's radiance in direction `u` (unit) from the origin: a sky
// gradient (warm horizon, blue zenith) under soft lat-long stripes, 12
// sectors in azimuth by bands of ~20 degrees in elevation, whose edges are
// tanh-smoothed so the pattern is band-limited (learnable) but clearly
// textured.
Eigen::Vector3f BackdropColor(const ProceduralWorld& world, const Eigen::Vector3f& u) {
  const float el = std::asin(std::clamp(u.z(), -1.0f, 1.0f));
  const float az = std::atan2(u.y(), u.x());
  const Eigen::Vector3f horizon(0.92f, 0.84f, 0.7f), zenith(0.3f, 0.5f, 0.85f);
  const Eigen::Vector3f sky = Lerp(horizon, zenith, SmoothStep(-0.1f, 1.2f, el));
  const float wave =
      std::sin(6.0f * az + world.backdrop_phase) * std::sin(9.0f * el + 0.5f * world.backdrop_phase + 0.8f);
  const float m = 0.5f + 0.5f * std::tanh(2.5f * wave);
  const Eigen::Vector3f band = HsvToRgb(world.backdrop_hue + 0.06f * std::sin(az), 0.65f, 0.45f);
  return Lerp(sky, band, 0.75f * m).cwiseMax(0.0f).cwiseMin(1.0f);
}

// Albedo of the ground plane at `p`: a soft checker of 1-unit cells (grass
// and sand) fading into haze between 1.5 and 4.5 camera radii (a quarter and
// nine tenths of the backdrop radius), so the far ground is smooth.
Eigen::Vector3f GroundAlbedo(const ProceduralWorld& world, const Eigen::Vector3f& p) {
  constexpr float kCell = 1.0f;
  const float wave = std::sin(kPi * p.x() / kCell) * std::sin(kPi * p.y() / kCell);
  const float m = 0.5f + 0.5f * std::tanh(3.0f * wave);
  const Eigen::Vector3f grass(0.32f, 0.46f, 0.28f), sand(0.74f, 0.67f, 0.5f), haze(0.62f, 0.66f, 0.7f);
  const float r = p.head<2>().norm();
  const float fade = SmoothStep(0.3f * world.backdrop_radius, 0.9f * world.backdrop_radius, r);
  return Lerp(Lerp(grass, sand, m), haze, fade);
}

// Value noise at `p`: hashed lattice values in [0, 1], trilinear.
float ValueNoise(uint64_t seed, const Eigen::Vector3f& p) {
  const Eigen::Vector3f f = p.array().floor();
  const Eigen::Vector3f t = p - f;
  const int64_t x = int64_t(f.x()), y = int64_t(f.y()), z = int64_t(f.z());
  auto at = [&](int64_t i, int64_t j, int64_t k) {
    return HashToUnit(Mix(seed, uint64_t(i) * 73856093ull ^ uint64_t(j) * 19349663ull ^ uint64_t(k) * 83492791ull));
  };
  float v = 0;
  for (int c = 0; c < 8; ++c) {
    const int dx = c & 1, dy = (c >> 1) & 1, dz = c >> 2;
    const float w = (dx ? t.x() : 1 - t.x()) * (dy ? t.y() : 1 - t.y()) * (dz ? t.z() : 1 - t.z());
    v += w * at(x + dx, y + dy, z + dz);
  }
  return v;
}

// The albedo factor of ProceduralSceneOptions::textured at `p`.
float TextureAt(const ProceduralWorld& world, const Eigen::Vector3f& p) {
  const float n = 0.5f * ValueNoise(world.texture_seed, 3.0f * p) + 0.3f * ValueNoise(world.texture_seed + 1, 7.0f * p) +
                  0.2f * ValueNoise(world.texture_seed + 2, 17.0f * p);
  return 0.4f + 1.2f * n;
}

bool InRect(const Eigen::Vector4f& r, float u, float v) { return u >= r[0] && u <= r[2] && v >= r[1] && v <= r[3]; }

// Albedo of the room shell at `p` on the face with (inward or outward) normal
// `n`: nearly white walls and ceiling, a skirting board, a plank floor, the
// door and the picture.
Eigen::Vector3f RoomAlbedo(const ProceduralWorld& world, const Eigen::Vector3f& p, const Eigen::Vector3f& n) {
  if (std::abs(n.z()) > 0.5f) {
    if (p.z() > 0.5f * (world.room_floor_z + world.room_ceiling_z)) return Eigen::Vector3f(0.93f, 0.93f, 0.92f);
    // Planks 0.25 wide along x, each its own shade, with a dark seam.
    const float u = p.y() / 0.25f + world.room_phase;
    const int plank = int(std::floor(u));
    const float f = u - float(plank);
    const float shade = 0.08f * (HashToUnit(SplitMix(uint64_t(int64_t(plank) + 4096))) - 0.5f);
    const float seam = (f < 0.04f || f > 0.96f) ? -0.18f : 0.0f;
    const float grain = 0.02f * std::sin(23.0f * p.x() + 3.0f * float(plank));
    return (Eigen::Vector3f(0.63f, 0.47f, 0.32f) + Eigen::Vector3f::Constant(shade + seam + grain))
        .cwiseMax(0.0f)
        .cwiseMin(1.0f);
  }
  const float z = p.z();
  if (z < world.room_floor_z + 0.1f) return Eigen::Vector3f(0.55f, 0.53f, 0.5f);  // Skirting board.
  if (std::abs(n.x()) > 0.5f && p.x() < 0 && InRect(world.door, p.y(), z)) {
    const float inset = std::min({p.y() - world.door[0], world.door[2] - p.y(), world.door[3] - z});
    return inset < 0.06f ? Eigen::Vector3f(0.35f, 0.26f, 0.18f) : Eigen::Vector3f(0.58f, 0.42f, 0.29f);
  }
  if (std::abs(n.y()) > 0.5f && p.y() > 0 && InRect(world.picture, p.x(), z)) {
    const Eigen::Vector4f& r = world.picture;
    const float u = (p.x() - r[0]) / (r[2] - r[0]), v = (z - r[1]) / (r[3] - r[1]);
    if (u < 0.05f || u > 0.95f || v < 0.07f || v > 0.93f) return Eigen::Vector3f(0.15f, 0.12f, 0.1f);
    const float m = 0.5f + 0.5f * std::sin(14.0f * u + 5.0f * std::sin(6.0f * v));
    return Lerp(Eigen::Vector3f(0.2f, 0.35f, 0.6f), Eigen::Vector3f(0.9f, 0.7f, 0.3f), m);
  }
  // Paint: white with a barely visible low-frequency variation.
  const float wobble = 0.01f * std::sin(0.7f * (p.x() + p.y()) + 0.9f * z);
  return Eigen::Vector3f(0.9f, 0.89f, 0.86f) + Eigen::Vector3f::Constant(wobble);
}

// Nearest t > t_min where the ray enters the sphere (or leaves it, if the
// origin is inside).
bool IntersectSphere(const Eigen::Vector3f& o, const Eigen::Vector3f& d, const Eigen::Vector3f& c,
                     float r, float t_min, float* t_out, Eigen::Vector3f* n_out) {
  const Eigen::Vector3f oc = o - c;
  const float b = oc.dot(d);
  const float cc = oc.squaredNorm() - r * r;
  const float disc = b * b - cc;
  if (disc < 0) return false;
  const float s = std::sqrt(disc);
  float t = -b - s;
  if (t <= t_min) t = -b + s;
  if (t <= t_min) return false;
  *t_out = t;
  *n_out = (o + t * d - c) / r;
  return true;
}

bool IntersectBox(const Eigen::Vector3f& o, const Eigen::Vector3f& d, const Eigen::Vector3f& lo,
                  const Eigen::Vector3f& hi, float t_min, float* t_out, Eigen::Vector3f* n_out) {
  float t0 = -kInf, t1 = kInf;
  int axis0 = 0, axis1 = 0;
  float sign0 = 0, sign1 = 0;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0.0f) {
      if (o[a] < lo[a] || o[a] > hi[a]) return false;
      continue;
    }
    const float inv = 1.0f / d[a];
    float ta = (lo[a] - o[a]) * inv, tb = (hi[a] - o[a]) * inv;
    // Entering through the face at `ta` whose outward normal is -sign(d).
    const float s = d[a] > 0 ? -1.0f : 1.0f;
    if (ta > tb) std::swap(ta, tb);
    if (ta > t0) {
      t0 = ta;
      axis0 = a;
      sign0 = s;
    }
    if (tb < t1) {
      t1 = tb;
      axis1 = a;
      sign1 = -s;
    }
  }
  if (t0 > t1) return false;
  Eigen::Vector3f n = Eigen::Vector3f::Zero();
  if (t0 > t_min) {
    *t_out = t0;
    n[axis0] = sign0;
  } else if (t1 > t_min) {
    *t_out = t1;
    n[axis1] = sign1;
  } else {
    return false;
  }
  *n_out = n;
  return true;
}

// Casts a ray against the world. With `any_hit`, returns on the first hit
// (shadow rays) without filling in normal/albedo.
bool CastRay(const ProceduralWorld& world, const Eigen::Vector3f& o, const Eigen::Vector3f& d,
             bool any_hit, Hit* hit) {
  constexpr float kTMin = 1e-4f;
  float best = kInf;
  const ProceduralObject* best_obj = nullptr;
  Eigen::Vector3f best_n = Eigen::Vector3f::Zero();
  bool floor_hit = false;
  bool ground_hit = false;
  float t;
  Eigen::Vector3f n;
  for (const std::vector<ProceduralObject>* list : {&world.objects, &world.rods, &world.pillars}) {
    for (const ProceduralObject& obj : *list) {
      bool h;
      if (obj.shape == ProceduralObject::Shape::kSphere) {
        h = IntersectSphere(o, d, obj.center, obj.half_extent.x(), kTMin, &t, &n);
      } else {
        h = IntersectBox(o, d, obj.center - obj.half_extent, obj.center + obj.half_extent, kTMin,
                         &t, &n);
      }
      if (h && t < best) {
        if (any_hit) return true;
        best = t;
        best_obj = &obj;
        best_n = n;
      }
    }
  }
  const Eigen::Vector3f flo(-world.floor_half_size, -world.floor_half_size,
                            world.floor_z - world.floor_thickness);
  const Eigen::Vector3f fhi(world.floor_half_size, world.floor_half_size, world.floor_z);
  if (IntersectBox(o, d, flo, fhi, kTMin, &t, &n) && t < best) {
    if (any_hit) return true;
    best = t;
    best_obj = nullptr;
    best_n = n;
    floor_hit = true;
  }
  if (world.backdrop_radius > 0) {
    // The ground plane, a disc out to the backdrop sphere.
    if (d.z() != 0.0f) {
      t = (world.ground_z - o.z()) / d.z();
      if (t > kTMin && t < best && (o + t * d).norm() < world.backdrop_radius) {
        if (any_hit) return true;
        best = t;
        best_obj = nullptr;
        best_n = Eigen::Vector3f::UnitZ();
        floor_hit = false;
        ground_hit = true;
      }
    }
    // The emissive backdrop sphere encloses everything else and casts no
    // shadows, so it only matters for camera rays that hit nothing else.
    if (best == kInf && !any_hit &&
        IntersectSphere(o, d, Eigen::Vector3f::Zero(), world.backdrop_radius, kTMin, &t, &n)) {
      hit->t = t;
      hit->normal = -n;
      hit->albedo = BackdropColor(world, n);
      hit->emissive = true;
      return true;
    }
  }
  bool room_hit = false;
  if (world.room_half.x() > 0 && !any_hit) {
    // The shell, seen from inside; it casts no shadows (the light is inside).
    const Eigen::Vector3f lo(-world.room_half.x(), -world.room_half.y(), world.room_floor_z);
    const Eigen::Vector3f hi(world.room_half.x(), world.room_half.y(), world.room_ceiling_z);
    if (IntersectBox(o, d, lo, hi, kTMin, &t, &n) && t < best) {
      best = t;
      best_obj = nullptr;
      best_n = n;
      floor_hit = ground_hit = false;
      room_hit = true;
    }
  }
  if (best == kInf) return false;
  hit->t = best;
  hit->normal = best_n;
  if (room_hit) {
    hit->albedo = RoomAlbedo(world, o + best * d, best_n);
  } else if (ground_hit) {
    hit->albedo = GroundAlbedo(world, o + best * d);
  } else if (floor_hit) {
    if (best_n.z() > 0.5f) {
      const Eigen::Vector3f p = o + best * d;
      const int cx = int(std::floor(p.x() / world.checker_size));
      const int cy = int(std::floor(p.y() / world.checker_size));
      hit->albedo = ((cx + cy) & 1) ? Eigen::Vector3f(0.85f, 0.84f, 0.78f)
                                    : Eigen::Vector3f(0.3f, 0.36f, 0.42f);
    } else {
      hit->albedo = Eigen::Vector3f(0.45f, 0.42f, 0.4f);
    }
  } else {
    hit->albedo = best_obj->color;
  }
  if (world.textured) hit->albedo = (hit->albedo * TextureAt(world, o + best * d)).cwiseMin(1.0f);
  return true;
}

Eigen::Vector3f Shade(const ProceduralWorld& world, const Eigen::Vector3f& o,
                      const Eigen::Vector3f& d, const Hit& hit) {
  if (hit.emissive) return hit.albedo;
  Eigen::Vector3f n = hit.normal;
  if (n.dot(d) > 0) n = -n;
  const ProceduralLight& light = world.light;
  const float ndl = n.dot(light.direction);
  float direct = 0.0f;
  if (ndl > 0) {
    const Eigen::Vector3f p = o + hit.t * d + 1e-3f * n;
    Hit unused;
    if (!CastRay(world, p, light.direction, /*any_hit=*/true, &unused)) direct = ndl;
  }
  const Eigen::Vector3f lit =
      Eigen::Vector3f::Constant(light.ambient) + light.intensity * direct * light.color;
  return hit.albedo.cwiseProduct(lit).cwiseMin(1.0f).cwiseMax(0.0f);
}

bool BoxContains(const Eigen::Vector3f& p, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
  return (p.array() >= lo.array()).all() && (p.array() <= hi.array()).all();
}

// A camera at `pos` looking along `forward` (unit) with the world's z up.
Camera CameraLookingAlong(const ProceduralSceneOptions& opt, const Eigen::Vector3f& pos,
                          const Eigen::Vector3f& forward, int time_step) {
  Camera cam;
  cam.intrinsics.width = opt.width;
  cam.intrinsics.height = opt.height;
  cam.intrinsics.fx = 0.5f * float(opt.width) / std::tan(0.5f * opt.camera_angle_x);
  cam.intrinsics.fy = cam.intrinsics.fx;
  cam.intrinsics.cx = 0.5f * float(opt.width);
  cam.intrinsics.cy = 0.5f * float(opt.height);
  const Eigen::Vector3f right = forward.cross(Eigen::Vector3f::UnitZ()).normalized();
  const Eigen::Vector3f up = right.cross(forward);
  Pose gl;  // Blender/OpenGL: x right, y up, looks along -z.
  gl.col(0) = right;
  gl.col(1) = up;
  gl.col(2) = -forward;
  gl.col(3) = pos;
  cam.c2w = ConvertPose(gl, PoseConvention::kOpenGL);
  cam.time_step = time_step;
  return cam;
}

Camera LookAtCamera(const ProceduralSceneOptions& opt, float azimuth, float elevation,
                    int time_step) {
  const Eigen::Vector3f pos = opt.camera_radius * DirectionFromAngles(azimuth, elevation);
  return CameraLookingAlong(opt, pos, (-pos).normalized(), time_step);
}

}  // namespace

const char* ProceduralLayoutName(ProceduralLayout layout) {
  switch (layout) {
    case ProceduralLayout::kOrbit: return "orbit";
    case ProceduralLayout::kForwardFacing: return "forward";
    case ProceduralLayout::kRoom: return "room";
  }
  return "unknown";
}

absl::Status ParseProceduralLayout(const std::string& name, ProceduralLayout* layout) {
  for (ProceduralLayout l : {ProceduralLayout::kOrbit, ProceduralLayout::kForwardFacing, ProceduralLayout::kRoom}) {
    if (name == ProceduralLayoutName(l)) {
      *layout = l;
      return absl::OkStatus();
    }
  }
  return absl::InvalidArgumentError(absl::StrCat("unknown procedural layout '", name, "' (orbit, forward or room)"));
}

absl::Status ProceduralSceneOptions::Validate() const {
  if (width < 1 || width > 4096 || height < 1 || height > 4096) {
    return absl::InvalidArgumentError(
        absl::StrFormat("image size must be in [1, 4096], got %dx%d", width, height));
  }
  if (!(camera_angle_x > 0.01f && camera_angle_x < 3.0f)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("camera_angle_x must be in (0.01, 3) radians, got %g", camera_angle_x));
  }
  if (num_train_views < 1 || num_test_views < 0) {
    return absl::InvalidArgumentError("need >= 1 train view and >= 0 test views per time step");
  }
  if (num_time_steps < 1 || num_time_steps > 1000) {
    return absl::InvalidArgumentError("num_time_steps must be in [1, 1000]");
  }
  if (num_objects < 1 || num_objects > 16) {
    return absl::InvalidArgumentError("num_objects must be in [1, 16]");
  }
  if (!(camera_radius > 2.2f && camera_radius < 100.0f)) {
    return absl::InvalidArgumentError("camera_radius must be in (2.2, 100)");
  }
  if (!(min_elevation_deg > 0.0f && min_elevation_deg <= max_elevation_deg &&
        max_elevation_deg < 89.0f)) {
    return absl::InvalidArgumentError(
        "elevations must satisfy 0 < min_elevation_deg <= max_elevation_deg < 89");
  }
  if (samples_per_axis < 1 || samples_per_axis > 8) {
    return absl::InvalidArgumentError("samples_per_axis must be in [1, 8]");
  }
  if ((backdrop || layout != ProceduralLayout::kOrbit) && camera_radius > 20.0f) {
    return absl::InvalidArgumentError("backdrop, forward and room scenes need camera_radius <= 20");
  }
  return absl::OkStatus();
}

bool ProceduralWorld::Occupied(const Eigen::Vector3f& p) const {
  if (BoxContains(p, Eigen::Vector3f(-floor_half_size, -floor_half_size, floor_z - floor_thickness),
                  Eigen::Vector3f(floor_half_size, floor_half_size, floor_z))) {
    return true;
  }
  for (const std::vector<ProceduralObject>* list : {&objects, &rods, &pillars}) {
    for (const ProceduralObject& o : *list) {
      if (o.shape == ProceduralObject::Shape::kSphere) {
        if ((p - o.center).squaredNorm() <= o.half_extent.x() * o.half_extent.x()) return true;
      } else if (BoxContains(p, o.center - o.half_extent, o.center + o.half_extent)) {
        return true;
      }
    }
  }
  if (room_half.x() > 0 && (std::abs(p.x()) > room_half.x() || std::abs(p.y()) > room_half.y() ||
                            p.z() < room_floor_z || p.z() > room_ceiling_z)) {
    return true;
  }
  return backdrop_radius > 0 && p.z() <= ground_z && p.norm() < backdrop_radius;
}

ProceduralWorld ProceduralWorldAt(const ProceduralSceneOptions& options, int time_step) {
  ProceduralWorld world;
  Rng rng(Mix(options.seed, 0x5CE4Eull));
  for (int i = 0; i < options.num_objects; ++i) {
    world.objects.push_back(RandomObject(rng, world.objects, world, i));
  }
  world.light = LightAt(options.seed, 0);
  if (options.thin_structures) AddThinStructures(options.seed, &world);
  world.textured = options.textured;
  world.texture_seed = Mix(options.seed, 0x7E47ull);
  if (options.layout == ProceduralLayout::kRoom) {
    AddRoom(options, &world);
  } else if (options.backdrop || options.layout == ProceduralLayout::kForwardFacing) {
    AddBackdrop(options, &world);
  }
  for (int s = 1; s <= time_step; ++s) {
    if (options.change_geometry) ApplyGeometryChange(options.seed, s, &world);
  }
  if (options.change_lighting) world.light = LightAt(options.seed, time_step);
  return world;
}

std::vector<Camera> ProceduralCameras(const ProceduralSceneOptions& options, int time_step,
                                      bool test_split) {
  const int n = test_split ? options.num_test_views : options.num_train_views;
  std::vector<Camera> cams;
  cams.reserve(std::max(n, 0));
  Rng rng(Mix(options.seed, uint64_t(time_step), test_split ? 0x7E57ull : 0x7A1Eull));
  if (options.layout == ProceduralLayout::kForwardFacing) {
    // A jittered grid on the plane x = -R (test cameras offset by half a
    // cell), looking along +x, pitched 8 degrees down, within 3 degrees.
    const float R = options.camera_radius;
    const int cols = std::max(1, int(std::ceil(std::sqrt(1.5f * float(std::max(n, 1))))));
    const int rows = std::max(1, (n + cols - 1) / cols);
    for (int i = 0; i < n; ++i) {
      const float off = test_split ? 0.5f : 0.0f;
      const float u = (float(i % cols) + off + 0.5f) / float(cols) - 0.5f;
      const float v = (float(i / cols) + off + 0.5f) / float(rows) - 0.5f;
      const float jitter = test_split ? 0.0f : 0.2f;
      const Eigen::Vector3f pos(-R, 0.3f * R * (u + jitter * rng.Uniform(-0.5f, 0.5f) / cols),
                                0.3f + 0.2f * R * (v + jitter * rng.Uniform(-0.5f, 0.5f) / rows));
      const float yaw = rng.Uniform(-3.0f, 3.0f) * kPi / 180;
      const float pitch = (-8.0f + rng.Uniform(-3.0f, 3.0f)) * kPi / 180;
      cams.push_back(CameraLookingAlong(options, pos, DirectionFromAngles(yaw, pitch), time_step));
    }
    return cams;
  }
  if (options.layout == ProceduralLayout::kRoom) {
    // One loop around the rug at eye height, looking around: along the path,
    // outwards at the walls, across at the objects, and the other way.
    const float R = options.camera_radius, floor_z = -0.5f - 0.04f;
    const float phase = 2.39996323f * float(time_step) + (test_split ? kPi / std::max(n, 1) + 0.4f : 0.0f);
    for (int i = 0; i < n; ++i) {
      const float a = phase + 2 * kPi * (float(i) + 0.5f) / float(std::max(n, 1));
      const Eigen::Vector3f pos(0.5f * R * std::cos(a), 0.45f * R * std::sin(a),
                                floor_z + 1.4f + rng.Uniform(-0.1f, 0.1f));
      static const float kLook[4] = {0.5f * kPi, 0.0f, kPi, -0.5f * kPi};
      const float yaw = a + kLook[(i + (test_split ? 1 : 0)) % 4] + rng.Uniform(-0.35f, 0.35f);
      const float pitch = rng.Uniform(-22.0f, 2.0f) * kPi / 180;
      cams.push_back(CameraLookingAlong(options, pos, DirectionFromAngles(yaw, pitch), time_step));
    }
    return cams;
  }
  const float min_el = options.min_elevation_deg * kPi / 180;
  const float max_el = options.max_elevation_deg * kPi / 180;
  // Rotate the ring per time step (golden angle) so every step sees new poses.
  const float phase = 2.39996323f * float(time_step);
  for (int i = 0; i < n; ++i) {
    const float frac = (float(i) + 0.5f) / float(n);
    float az, el;
    if (!test_split) {
      // Three-turn spiral rising from min to max elevation, lightly jittered.
      const float turns = 3.0f;
      const float step = 2 * kPi * turns / float(n);
      az = phase + 2 * kPi * turns * frac + rng.Uniform(-0.25f, 0.25f) * step;
      el = min_el + (max_el - min_el) * std::clamp(frac + rng.Uniform(-0.5f, 0.5f) / n, 0.0f, 1.0f);
    } else {
      // One descending turn, offset from the train spiral.
      az = phase + 2 * kPi * frac + kPi / std::max(options.num_train_views, 1) + 0.3f;
      el = max_el - (max_el - min_el) * frac;
    }
    cams.push_back(LookAtCamera(options, az, el, time_step));
  }
  return cams;
}

ProceduralRender RenderProceduralView(const ProceduralWorld& world, const Camera& camera,
                                      int samples_per_axis, uint64_t seed) {
  const int w = camera.intrinsics.width, h = camera.intrinsics.height;
  const int n = std::max(samples_per_axis, 1);
  const float inv_n = 1.0f / float(n);
  const float inv_count = 1.0f / float(n * n);
  ProceduralRender out;
  out.image = Image(w, h);
  out.alpha.assign(size_t(w) * h, 0.0f);
  const uint64_t jitter_seed = Mix(seed, 0x4A177E5ull);
  for (int py = 0; py < h; ++py) {
    for (int px = 0; px < w; ++px) {
      Eigen::Vector3f sum = Eigen::Vector3f::Zero();
      int hits = 0;
      for (int sy = 0; sy < n; ++sy) {
        for (int sx = 0; sx < n; ++sx) {
          float jx = 0.5f, jy = 0.5f;
          if (n > 1) {
            const uint64_t hsh =
                Mix(jitter_seed, (uint64_t(uint32_t(py)) << 32) | uint32_t(px),
                    uint64_t(sy * n + sx));
            jx = HashToUnit(hsh);
            jy = HashToUnit(SplitMix(hsh));
          }
          const float u = float(px) + (float(sx) + jx) * inv_n;
          const float v = float(py) + (float(sy) + jy) * inv_n;
          Eigen::Vector3f o, d;
          camera.Ray(u, v, &o, &d);
          Hit hit;
          if (CastRay(world, o, d, /*any_hit=*/false, &hit)) {
            sum += Shade(world, o, d, hit);
            ++hits;
          } else {
            sum += Eigen::Vector3f::Ones();  // White background.
          }
        }
      }
      float* p = out.image.pixel(px, py);
      p[0] = sum.x() * inv_count;
      p[1] = sum.y() * inv_count;
      p[2] = sum.z() * inv_count;
      out.alpha[size_t(py) * w + px] = float(hits) * inv_count;
    }
  }
  return out;
}

std::vector<float> RenderProceduralDistance(const ProceduralWorld& world, const Camera& camera) {
  const int w = camera.intrinsics.width, h = camera.intrinsics.height;
  std::vector<float> out(size_t(w) * h, kInf);
  for (int py = 0; py < h; ++py) {
    for (int px = 0; px < w; ++px) {
      Eigen::Vector3f o, d;
      camera.Ray(float(px) + 0.5f, float(py) + 0.5f, &o, &d);
      Hit hit;
      if (CastRay(world, o, d, /*any_hit=*/false, &hit)) out[size_t(py) * w + px] = hit.t;
    }
  }
  return out;
}

absl::StatusOr<ProceduralDataset> GenerateProceduralDataset(
    const ProceduralSceneOptions& options) {
  absl::Status s = options.Validate();
  if (!s.ok()) return s;

  struct Job {
    bool test;
    int index;  // Within the split.
    Camera camera;
    const ProceduralWorld* world;
  };
  std::vector<ProceduralWorld> worlds;
  worlds.reserve(options.num_time_steps);
  for (int t = 0; t < options.num_time_steps; ++t) worlds.push_back(ProceduralWorldAt(options, t));
  std::vector<Job> jobs;
  int n_train = 0, n_test = 0;
  for (int t = 0; t < options.num_time_steps; ++t) {
    for (const Camera& c : ProceduralCameras(options, t, /*test_split=*/false)) {
      jobs.push_back({false, n_train++, c, &worlds[t]});
    }
    for (const Camera& c : ProceduralCameras(options, t, /*test_split=*/true)) {
      jobs.push_back({true, n_test++, c, &worlds[t]});
    }
  }

  ProceduralDataset ds;
  Scene& scene = ds.scene;
  scene.name = options.name;
  scene.kind = SceneKind::kBounded;
  scene.background = Eigen::Vector3f::Ones();
  scene.world_scale_hint = 1.0f / 3.0f;
  scene.world_offset_hint = Eigen::Vector3f::Zero();
  if (options.backdrop || options.layout != ProceduralLayout::kOrbit) {
    // Every ray hits the backdrop or the room (alpha = 1); the content reaches far
    // beyond any box, so the scene is a real-capture-like unbounded one.
    scene.kind = SceneKind::kUnbounded;
    scene.background = Eigen::Vector3f::Zero();
    scene.world_scale_hint = 0.0f;
  }
  scene.train.resize(n_train);
  scene.test.resize(n_test);
  ds.alpha.train.resize(n_train);
  ds.alpha.test.resize(n_test);

  const long num_jobs = long(jobs.size());
#pragma omp parallel for schedule(dynamic)
  for (long k = 0; k < num_jobs; ++k) {
    const Job& job = jobs[k];
    ProceduralRender r =
        RenderProceduralView(*job.world, job.camera, options.samples_per_axis, options.seed);
    View& v = job.test ? scene.test[job.index] : scene.train[job.index];
    v.name = absl::StrCat(job.test ? "test" : "train", "/r_", job.index);
    v.camera = job.camera;
    v.image = std::move(r.image);
    (job.test ? ds.alpha.test : ds.alpha.train)[job.index] = std::move(r.alpha);
  }
  return ds;
}

absl::StatusOr<Scene> GenerateProceduralScene(const ProceduralSceneOptions& options) {
  absl::StatusOr<ProceduralDataset> ds = GenerateProceduralDataset(options);
  if (!ds.ok()) return ds.status();
  return std::move(ds->scene);
}

absl::Status WriteBlenderDataset(const ProceduralDataset& dataset, const std::string& dir) {
  return WriteBlenderDataset(dataset.scene, dir, &dataset.alpha);
}

absl::Status WriteScanFolders(const ProceduralDataset& dataset, const std::string& dir) {
  return WriteScanFolders(dataset.scene, dir, &dataset.alpha);
}

}  // namespace clnerf
