// clnerf baked-asset renderer: draws a BakedAsset (core/bake/baked_asset.h)
// with WebGL2 on the visitor's own GPU. The fragment shader marches exactly
// the samples of the C++ reference renderer (core/bake/baked_renderer.h):
// same interval, same step lattice, same empty-space skips (the empty-space
// codes in the red channel of lattice points with no density, and the chessboard
// distance of each empty block to the nearest occupied one, computed here
// at load as ComputeBlockDistances does), same trilinear lattice,
// compositing and view-dependent term, so `clnerf render --model DIR` shows
// what this page shows.
//
// Usage: const r = new BakedRenderer(canvas); await r.load(baseUrl);
//        r.draw(camera)   // camera: {c2w: 12 numbers (3x4, OpenCV, world),
//                         //          fx, fy, cx, cy} for the canvas size.
// A page that moves the camera keeps its frames quick with a FrameScaler
// (below): fewer pixels while moving where frames are slow, all of them
// once the camera is still.
"use strict";

const BAKED_VS = `#version 300 es
in vec2 aPos;
void main() { gl_Position = vec4(aPos, 0.0, 1.0); }`;

// VIEW_MODE (defined when the program is built for an asset): 0 no view
// term, 1 at every sample (format 2), 2 once at the median sample (format 3).
// CONTRACTED: 1 for an unbounded scene. OUTSIDE: 0 when the camera is
// inside an unbounded scene's inner cube (no ray starts in the shell). They
// are #defines, not uniforms: software WebGL2 (SwiftShader) runs every
// instruction of a loop body on every step, branch taken or not, and every
// loop's body at least once (it tests its lanes at the end), so an
// object's shader must not carry the shell's code, nor a camera inside the
// cube the loop for rays that start outside it.
const BAKED_FS = `#version 300 es
#define VIEW_MODE 0
#define CONTRACTED 0
#define STEP_ONE 0
#define OUTSIDE 1
precision highp float;
precision highp int;
precision highp usampler3D;
precision highp sampler3D;
uniform usampler3D uIndex;
uniform sampler3D uAtlas;
uniform sampler3D uView0;  // View-dependent term (format 2): H's columns x, y, z.
uniform sampler3D uView1;
uniform sampler3D uView2;
uniform float uStepCells;  // The ray step in cells.
uniform mat3 uRot;        // Camera to model axes.
uniform vec3 uOrigin;     // Camera centre, model space.
uniform vec4 uIntr;       // fx, fy, cx, cy.
uniform float uHeight;
uniform float uHalf;      // B.
uniform float uRes;       // R.
uniform float uNear;
uniform vec3 uBg;
uniform vec3 uInvAtlasDims;  // 1 / the atlas's size in texels.
uniform ivec3 uOccLo;      // An object's box of occupied blocks (lo > hi: none).
uniform ivec3 uOccHi;
out vec4 outColor;

const int kBlock = 8;
const float kMinT = 1.0 / 255.0;
const float kMaxAlpha = 0.9999;
const float kTail2 = 0.5;  // kBakedTail2, 4, 8: longer steps where little light is left.
const float kTail4 = 0.2;
const float kTail8 = 0.05;
const int kMaxSteps = 4096;

float infNorm(vec3 x) { return max(abs(x.x), max(abs(x.y), abs(x.z))); }
vec3 contractP(vec3 x, float r) {  // r = infNorm(x), which the march has already.
  return r > 1.0 ? x * ((2.0 - 1.0 / r) / r) : x;
}
// The slab test as vector code (a loop over the axes, indexing vectors,
// cost software WebGL2 more than the rest of a pixel's setup: lego_100
// 20 -> 4 ms per frame with no march at all, session 77). An axis the ray
// runs along (|d| < 1e-12) is taken as 1e-12: its slab then bounds t to
// +-1e12 times the distance, all of it or none, as IntersectAabb skips it.
bool intersectAabb(vec3 o, vec3 d, vec3 lo, vec3 hi, out float ta, out float tb) {
  vec3 inv = 1.0 / mix(vec3(1e-12), d, greaterThanEqual(abs(d), vec3(1e-12)));
  vec3 u = (lo - o) * inv, v = (hi - o) * inv;
  vec3 near = min(u, v), far = max(u, v);
  ta = max(near.x, max(near.y, near.z));
  tb = min(far.x, min(far.y, far.z));
  return tb > ta;
}
bool intersectBox(vec3 o, vec3 d, float b, out float t0, out float t1) {  // [-b, b]^3, ahead of o.
  return intersectAabb(o, d, vec3(-b), vec3(b), t0, t1) && t1 > max(t0, 0.0);
}
// BakedExitT, as vector code; invD = 1 / d on the axes the ray moves along
// (|d| > 1e-12), else 0.
float exitT(vec3 o, vec3 d, vec3 invD, vec3 lo, vec3 hi) {
  vec3 e = mix(vec3(1e30), (mix(lo, hi, greaterThan(d, vec3(0.0))) - o) * invD, notEqual(invD, vec3(0.0)));
  return min(e.x, min(e.y, e.z));
}

// ShellEmptyRun (baked_march.h): how far the ray at x (beyond the inner
// cube, heading outwards) stays where every point contracts into [lo, hi],
// at most; 0 heading inwards. Branch-free vector code (SwiftShader runs it
// far better than loops over the axes).
float shellEmptyRun(vec3 x, vec3 d, vec3 lo, vec3 hi) {
  vec3 ax = abs(x);
  vec3 dom = ax.x >= ax.y && ax.x >= ax.z ? vec3(1, 0, 0) : (ax.y >= ax.z ? vec3(0, 1, 0) : vec3(0, 0, 1));
  float xm = dot(dom, x), s = xm < 0.0 ? -1.0 : 1.0, r = s * xm, r1 = s * dot(dom, d);
  if (r1 <= 0.0) return 0.0;
  bvec3 other = lessThan(dom, vec3(0.5));
  float rhoLo = 2.0 - 1.0 / r;
  vec3 q = x / r;
  // rho_hi: axis m's face, or sooner where x's own q_k would leave.
  vec3 capP = mix(vec3(2.0), hi / max(q, 1e-30), bvec3(vec3(other) * step(1e-30, q) * step(0.0, hi)));
  vec3 capN = mix(vec3(2.0), lo / min(q, -1e-30), bvec3(vec3(other) * step(1e-30, -q) * step(0.0, -lo)));
  vec3 caps = min(capP, capN);
  float rhoHi = min(min(2.0, s > 0.0 ? dot(dom, hi) : -dot(dom, lo)), min(caps.x, min(caps.y, caps.z)));
  float run = rhoHi >= 2.0 ? 1e30 : (1.0 / (2.0 - rhoHi) - r) / r1;
  vec3 qLo = max(vec3(-1.0), lo / mix(vec3(rhoLo), vec3(rhoHi), lessThanEqual(lo, vec3(0.0))));
  vec3 qHi = min(vec3(1.0), hi / mix(vec3(rhoLo), vec3(rhoHi), greaterThanEqual(hi, vec3(0.0))));
  vec3 f1 = d - qLo * r1, g1 = qHi * r1 - d;
  vec3 rf = mix(vec3(1e30), (x - qLo * r) / -min(f1, -1e-30), bvec3(vec3(other) * step(f1, vec3(-1e-30))));
  vec3 rg = mix(vec3(1e30), (qHi * r - x) / -min(g1, -1e-30), bvec3(vec3(other) * step(g1, vec3(-1e-30))));
  vec3 runs = min(rf, rg);
  return max(min(run, min(runs.x, min(runs.y, runs.z))), 0.0);
}

vec3 viewTerm(vec3 tc, vec3 d) {  // sum_k d_k (texel_k - 128) / 127, premultiplied like the colour.
  return d.x * (textureLod(uView0, tc, 0.0).rgb * 255.0 - 128.0) / 127.0 +
         d.y * (textureLod(uView1, tc, 0.0).rgb * 255.0 - 128.0) / 127.0 +
         d.z * (textureLod(uView2, tc, 0.0).rgb * 255.0 - 128.0) / 127.0;
}

// The march's state, shared by the step functions and main's loops.
vec3 o, d;                // The ray, model space (unit d).
float t, t1, T = 1.0;     // Its next sample, its end, its transmittance.
float stp, invStp, cell, toCells, blockSize;
vec3 invD;                // BakedExitT's reciprocals of d.
float skipScale;          // 1 / (uStepCells |d|_inf): cells of a code to steps along the ray.
float tCube = 1e30;       // Where the ray leaves an unbounded scene's inner cube.
int nb;
vec3 C = vec3(0.0);
vec3 tcMedian = vec3(-1.0);  // The median sample (format 3): where T first falls below 1/2.
float codeMedian = 0.0;

// The steps a sample at the ray's transmittance covers (BakedTailSteps).
float tailSteps() { return T < kTail8 ? 8.0 : (T < kTail4 ? 4.0 : (T < kTail2 ? 2.0 : 1.0)); }
// 1 / k for k = tailSteps(), exact.
float tailInverse(float k) { return k == 8.0 ? 0.125 : (k == 4.0 ? 0.25 : (k == 2.0 ? 0.5 : 1.0)); }

// Composites the sample at cell coordinates u of occupied block b (index
// entry e), dt long, and moves t past it; the sample covers k steps
// (tailSteps(): 2 below transmittance kTail2, 4 below kTail4, 8 below kTail8; kInv = 1 /
// k). cube: a step of
// the grid's own cells (dt = stp), whose opacity with STEP_ONE (one-cell
// steps) is the complement of the texel's own or its 2nd, 4th or 8th power,
// with no exp or log (a constant at each call).
void addSample(vec3 u, ivec3 b, uint e, float dt, bool cube, float k, float kInv) {
  ivec3 bo = ivec3(int(e & 1023u), int((e >> 10) & 1023u), int(e >> 20)) * 9;  // skipIndex packs it.
  vec3 l = clamp(u - vec3(b * kBlock), 0.0, 8.0);
  vec3 tc = (vec3(bo) + l + 0.5) * uInvAtlasDims;
  vec4 s = textureLod(uAtlas, tc, 0.0);
#if VIEW_MODE == 1
  s.rgb += viewTerm(tc, d);
#endif
  float a0 = min(s.a * s.a, kMaxAlpha);
  float run = k * dt;
#if STEP_ONE == 1
  float q = 1.0 - a0, q2 = q * q;
  float q4 = q2 * q2;
  float alpha = cube ? 1.0 - (k == 8.0 ? q4 * q4 : (k == 4.0 ? q4 : (k == 2.0 ? q2 : q))) : 1.0 - exp(log(q) * (run / cell));
#else
  float alpha = 1.0 - exp(log(1.0 - a0) * (run / cell));
#endif
  C += T * alpha * clamp(s.rgb / max(s.a, 1.0 / 255.0), vec3(0.0), vec3(1.0));  // Premultiplied by the code.
  float next = T * (1.0 - alpha);
  if (T >= 0.5 && next < 0.5) { tcMedian = tc; codeMedian = s.a; }
  if (cube) {
    // No density here: red is the empty-space code (BakedCodeSteps, skip_codes.h),
    // a jump by a multiple of k steps that passes only samples with none,
    // and stays in an unbounded scene's inner cube.
    float reach = (s.r * 255.0 - 2.0) * skipScale;
    float m = min(k * (floor(max(reach, 0.0) * kInv) + 1.0), k * max(1.0, ceil((tCube - t) * invStp * kInv)));
    run = s.a == 0.0 ? m * dt : run;
  }
  T = next;
  t += run;
}

// The block holding cell coordinates u, and its index entry.
ivec3 blockAt(vec3 u) { return clamp(ivec3(floor(u * (1.0 / float(kBlock)))), ivec3(0), ivec3(nb - 1)); }

// The cube of blocks (field units) that an empty block's entry e says is
// empty: every block within distance D - 1 of b.
void emptyCube(ivec3 b, uint e, out vec3 lo, out vec3 hi) {
  float D = float(e & 0xffu) - 1.0;
  lo = (vec3(b) - D) * blockSize - uHalf;
  hi = (vec3(b) + D + 1.0) * blockSize - uHalf;
}

// Past the empty block b (index entry e) and every block its entry says
// is empty too, by whole multiples of the k steps (kInv = 1 / k) the
// samples take, so that a code's jump over an empty block lands where this
// skip does.
void skipEmpty(ivec3 b, uint e, float k, float kInv) {
  vec3 lo, hi;
  emptyCube(b, e, lo, hi);
#if CONTRACTED == 1
  lo = max(lo, vec3(-1.0)); hi = min(hi, vec3(1.0));
#endif
  t += k * max(1.0, ceil((exitT(o, d, invD, lo, hi) - t) * invStp * kInv)) * stp;
}

// One step at x, uncontracted (an object's grid, or the inner cube of an
// unbounded scene's): a sample, or a skip past empty blocks by whole
// multiples of the tail's steps.
void cubeStep(vec3 x) {
  vec3 u = (x + uHalf) * toCells;
  ivec3 b = blockAt(u);
  uint e = texelFetch(uIndex, b, 0).r;
  float k = tailSteps(), kInv = tailInverse(k);
  if (e < 0x80000000u) {
    addSample(u, b, e, stp, true, k, kInv);
    return;
  }
  skipEmpty(b, e, k, kInv);
}

// The empty blocks before the ray's first occupied block in the cube (an
// object's grid), in a loop whose body reads only the index: the very
// skips cubeStep makes there, so the same samples follow, at about half
// the cost of its body (software WebGL2 runs a loop's whole body on every
// step, the atlas read included; session 79).
void skipToOccupied(inout int it) {
  for (; it < kMaxSteps; ++it) {
    if (!(t < t1)) break;
    vec3 x = o + t * d;
#if CONTRACTED == 1
    if (infNorm(x) > 1.0) break;
#endif
    ivec3 b = blockAt((x + uHalf) * toCells);
    uint e = texelFetch(uIndex, b, 0).r;
    if (e < 0x80000000u) break;
    float k = tailSteps();
    skipEmpty(b, e, k, tailInverse(k));
  }
}

#if CONTRACTED == 1
// One step at x in the contracted shell (r = |x|_inf > 1): steps grow as
// r^2; an empty cube of blocks is skipped past where the ray leaves it,
// the next sample half a step beyond. Its first lines repeat cubeStep's on
// purpose: one function for both, returning the empty cube through out
// parameters, drew 4-9 % slower in software WebGL2 (session 74).
void shellStep(vec3 x, float r) {
  float dt = stp * r * r;
  vec3 u = (contractP(x, r) + uHalf) * toCells;
  ivec3 b = blockAt(u);
  uint e = texelFetch(uIndex, b, 0).r;
  if (e < 0x80000000u) {
    addSample(u, b, e, dt, false, tailSteps(), 1.0);  // kInv is read by cube samples only.
    return;
  }
  vec3 lo, hi;
  emptyCube(b, e, lo, hi);
  float te = min(t + shellEmptyRun(x, d, lo, hi), t1);
  float re = infNorm(o + te * d);
  t = max(t + dt, te + 0.5 * stp * re * re);
}
#endif

void main() {
  vec2 px = vec2(gl_FragCoord.x, uHeight - gl_FragCoord.y);
  d = normalize(uRot * vec3((px.x - uIntr.z) / uIntr.x, (px.y - uIntr.w) / uIntr.y, 1.0));
  o = uOrigin;
  cell = 2.0 * uHalf / uRes; stp = uStepCells * cell; toCells = uRes / (2.0 * uHalf);
  invStp = 1.0 / stp;
  invD = mix(vec3(0.0), 1.0 / d, greaterThan(abs(d), vec3(1e-12)));
  blockSize = float(kBlock) / toCells;
  nb = int(uRes + 0.5) / kBlock;
  float t0;
  float box = CONTRACTED == 1 ? 2.0 / cell : uHalf;
  bool hit = intersectBox(o, d, box, t0, t1);
  skipScale = 1.0 / (uStepCells * infNorm(d));
#if CONTRACTED == 1
  float tc0;
  if (!intersectAabb(o, d, vec3(-1.0), vec3(1.0), tc0, tCube)) tCube = -1e30;
#endif
  t0 = max(t0, uNear);
  t = t0 + 0.5 * stp;
  if (hit && CONTRACTED == 0) {  // An object: march only across the box of occupied blocks.
    float ta, tb;
    vec3 lo = vec3(uOccLo) * blockSize - uHalf, hi = vec3(uOccHi + 1) * blockSize - uHalf;
    hit = uOccHi.x >= uOccLo.x && intersectAabb(o, d, lo, hi, ta, tb) && tb > t0 && ta < t1;
    if (hit) {
      t += max(0.0, floor((ta - t0) / stp - 0.5)) * stp;
      t1 = min(t1, tb + stp);
    }
  }
  int it = 0;
#if CONTRACTED == 1
  // The same samples as one loop that asks at each whether it is in the
  // inner cube, in three loops: the shell before the cube (a camera outside
  // it), the cube, the shell beyond (a line meets a cube in one interval).
  // Software WebGL2 runs every instruction of a loop body on every step, so
  // the cube's steps must not carry the shell's code.
#if OUTSIDE == 1
  for (; hit && it < kMaxSteps; ++it) {
    if (!(t < t1) || T <= kMinT) break;
    vec3 x = o + t * d;
    float r = infNorm(x);
    if (r <= 1.0) break;
    shellStep(x, r);
  }
#endif
  if (hit && T > kMinT) skipToOccupied(it);
  for (; hit && it < kMaxSteps; ++it) {
    if (!(t < t1) || T <= kMinT) break;
    vec3 x = o + t * d;
    if (infNorm(x) > 1.0) break;
    cubeStep(x);
  }
  for (; hit && it < kMaxSteps; ++it) {
    if (!(t < t1) || T <= kMinT) break;
    vec3 x = o + t * d;
    shellStep(x, infNorm(x));
  }
#else
  if (hit) skipToOccupied(it);
  for (; hit && it < kMaxSteps; ++it) {
    if (!(t < t1) || T <= kMinT) break;
    cubeStep(o + t * d);
  }
#endif
#if VIEW_MODE == 2
  if (tcMedian.x >= 0.0) C += (1.0 - T) * viewTerm(tcMedian, d) / max(codeMedian, 1.0 / 255.0);
#endif
  outColor = vec4(clamp(C + T * uBg, 0.0, 1.0), 1.0);
}`;

async function fetchGunzip(url) {
  const res = await fetch(url);
  if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
  if (typeof DecompressionStream === "undefined") throw new Error("this browser has no DecompressionStream");
  const stream = res.body.pipeThrough(new DecompressionStream("gzip"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

// The index with each empty block's entry replaced by 0x80000000 | D, D
// its chessboard distance in blocks to the nearest occupied block (at most
// 255): ComputeBlockDistances (core/bake/baked_asset.h), two raster passes
// over the 26-neighbourhood.
function skipIndex(index, nb, bricks) {
  const n = nb * nb * nb, dist = new Uint8Array(n);
  for (let i = 0; i < n; ++i) dist[i] = index[i] === 0 ? 255 : 0;
  for (let pass = 0; pass < 2; ++pass) {
    for (let s = 0; s < n; ++s) {
      const i = pass === 0 ? s : n - 1 - s;
      if (dist[i] === 0) continue;
      const x = i % nb, y = Math.floor(i / nb) % nb, z = Math.floor(i / (nb * nb));
      let best = dist[i];
      for (let dz = Math.max(z - 1, 0); dz <= Math.min(z + 1, nb - 1); ++dz) {
        for (let dy = Math.max(y - 1, 0); dy <= Math.min(y + 1, nb - 1); ++dy) {
          for (let dx = Math.max(x - 1, 0); dx <= Math.min(x + 1, nb - 1); ++dx) {
            best = Math.min(best, dist[dx + nb * (dy + nb * dz)] + 1);
          }
        }
      }
      dist[i] = Math.min(best, 255);
    }
  }
  // An occupied block's entry becomes its brick's atlas position, x | y << 10
  // | z << 20 in bricks, so the shader decodes it with shifts (integer
  // division is slow in software WebGL, which runs every instruction of the
  // march's loop on every step).
  const out = new Uint32Array(n), bx = bricks[0], by = bricks[1];
  for (let i = 0; i < n; ++i) {
    const b = index[i] - 1;
    out[i] = index[i] !== 0 ? ((b % bx) | ((Math.floor(b / bx) % by) << 10) | (Math.floor(b / (bx * by)) << 20)) >>> 0
                            : (0x80000000 | dist[i]) >>> 0;
  }
  return out;
}

// The box of occupied blocks, {lo, hi} in block coordinates (lo > hi when
// none is): ComputeBlockDistances's occupied_lo / occupied_hi.
function occupiedBox(index, nb) {
  const lo = [nb, nb, nb], hi = [-1, -1, -1];
  for (let i = 0; i < index.length; ++i) {
    if (index[i] === 0) continue;
    const b = [i % nb, Math.floor(i / nb) % nb, Math.floor(i / (nb * nb))];
    for (let k = 0; k < 3; ++k) {
      lo[k] = Math.min(lo[k], b[k]);
      hi[k] = Math.max(hi[k], b[k]);
    }
  }
  return {lo, hi};
}

// The ray step in cells a manifest gives (as LoadBakedAsset reads it).
function stepCells(m) {
  if (m.step === undefined) return 0.5;
  const ratio = m.step * m.resolution / (2 * m.half_size);
  const snapped = Math.round(32 * ratio) / 32;  // Exact in binary, as LoadBakedAsset snaps it.
  if (Math.abs(ratio - snapped) < 1e-3 && snapped >= 0.5 && snapped <= 2) return snapped;
  throw new Error(`baked asset step of ${ratio} cells is not supported`);
}

class BakedRenderer {
  constructor(canvas) {
    this.canvas = canvas;
    this.gl = canvas.getContext("webgl2", {preserveDrawingBuffer: true, antialias: false});
    if (!this.gl) throw new Error("WebGL2 is not available");
    this.manifest = null;
  }

  static supported() {
    try {
      return !!document.createElement("canvas").getContext("webgl2");
    } catch (e) {
      return false;
    }
  }

  compile(type, src) {
    const gl = this.gl, s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(s));
    return s;
  }

  // The program for a view mode, kind, step and camera side (built once
  // each; all are #defines, so the shader carries no branch for them), with
  // its uniform locations. `outside` matters for unbounded scenes only.
  program(viewMode, contracted, stepOne, outside = true) {
    const key = `${viewMode}/${contracted ? 1 : 0}/${stepOne ? 1 : 0}/${outside ? 1 : 0}`;
    if (this.programs[key]) return this.programs[key];
    const gl = this.gl, p = gl.createProgram();
    gl.attachShader(p, this.compile(gl.VERTEX_SHADER, BAKED_VS));
    gl.attachShader(p, this.compile(gl.FRAGMENT_SHADER,
                                    BAKED_FS.replace("#define VIEW_MODE 0", `#define VIEW_MODE ${viewMode}`)
                                        .replace("#define CONTRACTED 0", `#define CONTRACTED ${contracted ? 1 : 0}`)
                                        .replace("#define STEP_ONE 0", `#define STEP_ONE ${stepOne ? 1 : 0}`)
                                        .replace("#define OUTSIDE 1", `#define OUTSIDE ${outside ? 1 : 0}`)));
    gl.bindAttribLocation(p, 0, "aPos");
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error("link: " + gl.getProgramInfoLog(p));
    return (this.programs[key] = {p, uniforms: {}});
  }

  // Loads manifest.json and its arrays from `base` (a URL ending in "/", or
  // a function mapping a file name to its URL).
  async load(base) {
    const url = typeof base === "function" ? base : (name) => base + name;
    const res = await fetch(url("manifest.json"));
    if (!res.ok) throw new Error(`manifest.json: HTTP ${res.status}`);
    const m = await res.json();
    if (m.format !== 1 && m.format !== 2 && m.format !== 3) {
      throw new Error(`baked asset format ${m.format} is not supported`);
    }
    const viewDep = m.format !== 1;
    const steps = stepCells(m);
    const [index, atlas, view] = await Promise.all([fetchGunzip(url(m.files.index)), fetchGunzip(url(m.files.atlas)),
                                                    viewDep ? fetchGunzip(url(m.files.view)) : null]);
    const gl = this.gl, nb = m.resolution / m.block;
    const dims = m.bricks.map((b) => b * m.brick);
    if (index.byteLength !== nb * nb * nb * 4 || atlas.byteLength !== dims[0] * dims[1] * dims[2] * 4 ||
        (view && view.byteLength !== 3 * atlas.byteLength)) {
      throw new Error("baked asset arrays do not match the manifest");
    }
    const max3d = gl.getParameter(gl.MAX_3D_TEXTURE_SIZE);
    if (Math.max(...dims, nb) > max3d) throw new Error(`atlas ${dims} exceeds this GPU's 3-D textures (${max3d})`);
    if (!this.vao) {
      const buf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, buf);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 3, -1, -1, 3]), gl.STATIC_DRAW);
      this.vao = gl.createVertexArray();
      gl.bindVertexArray(this.vao);
      gl.enableVertexAttribArray(0);
      gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
      this.programs = {};
    }
    const viewMode = !view ? 0 : m.format === 2 ? 1 : 2;
    // Built now, so a shader error fails the load and no frame waits for one.
    this.program(viewMode, m.kind === "unbounded", steps === 1);
    if (m.kind === "unbounded") this.program(viewMode, true, steps === 1, false);
    for (const t of [this.indexTex, this.atlasTex, ...(this.viewTex || [])]) if (t) gl.deleteTexture(t);
    this.viewTex = [];
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    this.indexTex = gl.createTexture();
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_3D, this.indexTex);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.R32UI, nb, nb, nb, 0, gl.RED_INTEGER, gl.UNSIGNED_INT,
                  skipIndex(new Uint32Array(index.buffer, index.byteOffset, index.byteLength / 4), nb, m.bricks));
    for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.NEAREST], [gl.TEXTURE_MAG_FILTER, gl.NEAREST]]) {
      gl.texParameteri(gl.TEXTURE_3D, k, v);
    }
    this.atlasTex = gl.createTexture();
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_3D, this.atlasTex);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGBA8, dims[0], dims[1], dims[2], 0, gl.RGBA, gl.UNSIGNED_BYTE, atlas);
    for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
                          [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE],
                          [gl.TEXTURE_WRAP_R, gl.CLAMP_TO_EDGE]]) {
      gl.texParameteri(gl.TEXTURE_3D, k, v);
    }
    const linear = () => {
      for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
                            [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE],
                            [gl.TEXTURE_WRAP_R, gl.CLAMP_TO_EDGE]]) {
        gl.texParameteri(gl.TEXTURE_3D, k, v);
      }
    };
    for (let k = 0; view && k < 3; ++k) {
      const t = gl.createTexture();
      gl.activeTexture(gl.TEXTURE2 + k);
      gl.bindTexture(gl.TEXTURE_3D, t);
      gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGBA8, dims[0], dims[1], dims[2], 0, gl.RGBA, gl.UNSIGNED_BYTE,
                    view.subarray(k * atlas.byteLength, (k + 1) * atlas.byteLength));
      linear();
      this.viewTex.push(t);
    }
    this.occ = occupiedBox(new Uint32Array(index.buffer, index.byteOffset, index.byteLength / 4), nb);
    this.viewMode = viewMode;
    this.stepCells = steps;
    this.manifest = m;
    this.dims = dims;
    this.bytes = index.byteLength + atlas.byteLength + (view ? view.byteLength : 0);
    return m;
  }

  // Model-space camera (BakedModelCamera): rotation and centre.
  modelCamera(c2w) {
    const m = this.manifest, R = m.rotation, s = m.scale, ctr = m.center;
    const rot = new Float32Array(9);  // Column-major mat3 of R_norm * R_c2w.
    for (let r = 0; r < 3; ++r) {
      for (let c = 0; c < 3; ++c) {
        let v = 0;
        for (let k = 0; k < 3; ++k) v += R[3 * r + k] * c2w[4 * k + c];
        rot[3 * c + r] = v;
      }
    }
    const p = [c2w[3] - ctr[0], c2w[7] - ctr[1], c2w[11] - ctr[2]];
    const o = [0, 1, 2].map((r) => s * (R[3 * r] * p[0] + R[3 * r + 1] * p[1] + R[3 * r + 2] * p[2]));
    return {rot, o};
  }

  draw(cam) {
    const gl = this.gl, m = this.manifest, stepOne = this.stepCells === 1;
    const W = this.canvas.width, H = this.canvas.height;
    const {rot, o} = this.modelCamera(cam.c2w);
    // From a camera inside the inner cube every ray is in the cube, then in
    // the shell (a line meets a cube in one interval), never in the shell
    // first: that loop can go (0.999: clear of rounding at the faces).
    const unbounded = m.kind === "unbounded";
    const inside = unbounded && Math.max(Math.abs(o[0]), Math.abs(o[1]), Math.abs(o[2])) < 0.999;
    const prog = this.program(this.viewMode, unbounded, stepOne, !inside), p = prog.p;
    gl.viewport(0, 0, W, H);
    gl.useProgram(p);
    gl.bindVertexArray(this.vao);
    const cache = prog.uniforms;  // Looked up once per program, not per frame.
    const u = (n) => cache[n] !== undefined ? cache[n] : (cache[n] = gl.getUniformLocation(p, n));
    gl.uniform1i(u("uIndex"), 0);
    gl.uniform1i(u("uAtlas"), 1);
    gl.uniform1i(u("uView0"), 2);
    gl.uniform1i(u("uView1"), 3);
    gl.uniform1i(u("uView2"), 4);
    gl.uniform1f(u("uStepCells"), this.stepCells);
    gl.uniformMatrix3fv(u("uRot"), false, rot);
    gl.uniform3fv(u("uOrigin"), o);
    gl.uniform4f(u("uIntr"), cam.fx, cam.fy, cam.cx, cam.cy);
    gl.uniform1f(u("uHeight"), H);
    gl.uniform1f(u("uHalf"), m.half_size);
    gl.uniform1f(u("uRes"), m.resolution);
    gl.uniform1f(u("uNear"), m.near);
    gl.uniform3fv(u("uBg"), m.background);
    gl.uniform3fv(u("uInvAtlasDims"), this.dims.map((v) => 1 / v));
    gl.uniform3iv(u("uOccLo"), this.occ.lo);
    gl.uniform3iv(u("uOccHi"), this.occ.hi);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  // Draws `cam` and waits until the frame is done (a one-pixel read, so
  // the GPU's work is counted): its milliseconds.
  drawTimed(cam) {
    const gl = this.gl, px = new Uint8Array(4), t0 = performance.now();
    this.draw(cam);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    return performance.now() - t0;
  }

  // Milliseconds per frame over `n` timed draws of `cam`, after one more.
  timeFrames(cam, n) {
    this.drawTimed(cam);
    let ms = 0;
    for (let i = 0; i < n; ++i) ms += this.drawTimed(cam);
    return ms / n;
  }

  // The canvas as RGBA bytes, top row first.
  pixels() {
    const gl = this.gl, W = this.canvas.width, H = this.canvas.height;
    const buf = new Uint8Array(W * H * 4), out = new Uint8Array(W * H * 4);
    gl.readPixels(0, 0, W, H, gl.RGBA, gl.UNSIGNED_BYTE, buf);
    for (let y = 0; y < H; ++y) out.set(buf.subarray((H - 1 - y) * W * 4, (H - y) * W * 4), y * W * 4);
    return out;
  }
}

// The share of a canvas's width and height to draw while the camera moves,
// so that moving frames take about targetMs: a frame's time goes with its
// pixels, so each timed moving frame at scale s that took ms moves the
// scale halfway towards s * sqrt(targetMs / ms), in steps of 1/16, within
// [minScale, 1]. A still camera is drawn whole (scale 1). Software WebGL2
// (a laptop whose GPU the browser does not use) draws fox_8's 400x300 in
// ~150 ms on 2 cores: moving frames there are drawn at about half size
// and shown stretched; a GPU's stay whole. Not thread-safe (one page).
class FrameScaler {
  constructor(targetMs = 50, minScale = 0.25) {
    this.targetMs = targetMs;
    this.minScale = minScale;
    this.scale = 1;
  }

  // The scale of the next frame.
  next(moving) { return moving ? this.scale : 1; }

  // A moving frame drawn at scale s took ms milliseconds.
  report(s, ms) {
    const want = s * Math.sqrt(this.targetMs / Math.max(ms, 0.1));
    const next = Math.round(16 * 0.5 * (this.scale + want)) / 16;
    this.scale = Math.min(1, Math.max(this.minScale, next));
  }
}

// An OpenGL-convention camera-to-world (12 or 16 numbers, row-major, as
// `clnerf render --pose` takes) as the OpenCV 3x4 the renderer uses.
function openGlToOpenCv(gl12) {
  const c = gl12.slice(0, 12);
  for (let r = 0; r < 3; ++r) {
    c[4 * r + 1] = -c[4 * r + 1];
    c[4 * r + 2] = -c[4 * r + 2];
  }
  return c;
}
