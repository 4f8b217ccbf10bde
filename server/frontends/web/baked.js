// clnerf baked-asset renderer: draws a BakedAsset (core/bake/baked_asset.h)
// with WebGL2 on the visitor's own GPU. The fragment shader marches exactly
// the samples of the C++ reference renderer (core/bake/baked_renderer.h):
// same interval, same half-cell lattice, same empty-block skips, same
// trilinear lattice and compositing, so `clnerf render --model DIR` shows
// what this page shows.
//
// Usage: const r = new BakedRenderer(canvas); await r.load(baseUrl);
//        r.draw(camera)   // camera: {c2w: 12 numbers (3x4, OpenCV, world),
//                         //          fx, fy, cx, cy} for the canvas size.
"use strict";

const BAKED_VS = `#version 300 es
in vec2 aPos;
void main() { gl_Position = vec4(aPos, 0.0, 1.0); }`;

const BAKED_FS = `#version 300 es
precision highp float;
precision highp int;
precision highp usampler3D;
precision highp sampler3D;
uniform usampler3D uIndex;
uniform sampler3D uAtlas;
uniform sampler3D uView0;  // View-dependent term (format 2): H's columns x, y, z.
uniform sampler3D uView1;
uniform sampler3D uView2;
uniform int uViewDep;
uniform mat3 uRot;        // Camera to model axes.
uniform vec3 uOrigin;     // Camera centre, model space.
uniform vec4 uIntr;       // fx, fy, cx, cy.
uniform float uHeight;
uniform float uHalf;      // B.
uniform float uRes;       // R.
uniform int uContracted;
uniform float uNear;
uniform vec3 uBg;
uniform ivec3 uBricks;
uniform vec3 uAtlasDims;
out vec4 outColor;

const int kBlock = 8;
const float kMinT = 1.0 / 255.0;
const float kMaxAlpha = 0.9999;
const int kMaxSteps = 4096;

float infNorm(vec3 x) { return max(abs(x.x), max(abs(x.y), abs(x.z))); }
vec3 contractP(vec3 x) {
  float r = infNorm(x);
  return r > 1.0 ? x * ((2.0 - 1.0 / r) / r) : x;
}
bool intersectBox(vec3 o, vec3 d, float b, out float t0, out float t1) {
  float lo = -1e30, hi = 1e30;
  for (int a = 0; a < 3; ++a) {
    if (abs(d[a]) < 1e-12) {
      if (o[a] < -b || o[a] > b) return false;
      continue;
    }
    float inv = 1.0 / d[a];
    float ta = (-b - o[a]) * inv, tb = (b - o[a]) * inv;
    lo = max(lo, min(ta, tb));
    hi = min(hi, max(ta, tb));
  }
  t0 = lo; t1 = hi;
  return hi > max(lo, 0.0);
}
float exitT(vec3 o, vec3 d, vec3 lo, vec3 hi) {
  float t = 1e30;
  for (int k = 0; k < 3; ++k) {
    if (d[k] > 1e-12) t = min(t, (hi[k] - o[k]) / d[k]);
    if (d[k] < -1e-12) t = min(t, (lo[k] - o[k]) / d[k]);
  }
  return t;
}

void main() {
  vec2 px = vec2(gl_FragCoord.x, uHeight - gl_FragCoord.y);
  vec3 d = normalize(uRot * vec3((px.x - uIntr.z) / uIntr.x, (px.y - uIntr.w) / uIntr.y, 1.0));
  vec3 o = uOrigin;
  float cell = 2.0 * uHalf / uRes, stp = 0.5 * cell, toCells = uRes / (2.0 * uHalf);
  float blockSize = float(kBlock) / toCells;
  int nb = int(uRes + 0.5) / kBlock;
  float T = 1.0;
  vec3 C = vec3(0.0);
  float t0, t1;
  float box = uContracted == 1 ? 2.0 / cell : uHalf;
  if (intersectBox(o, d, box, t0, t1)) {
    t0 = max(t0, uNear);
    float t = t0 + 0.5 * stp;
    for (int it = 0; it < kMaxSteps; ++it) {
      if (!(t < t1) || T <= kMinT) break;
      vec3 x = o + t * d;
      float r = infNorm(x);
      float dt = (uContracted == 1 && r > 1.0) ? stp * r * r : stp;
      vec3 u = ((uContracted == 1 ? contractP(x) : x) + uHalf) * toCells;
      ivec3 b = clamp(ivec3(floor(u / float(kBlock))), ivec3(0), ivec3(nb - 1));
      uint e = texelFetch(uIndex, b, 0).r;
      if (e == 0u) {
        vec3 lo = vec3(b) * blockSize - uHalf, hi = lo + blockSize;
        if (uContracted == 0 || (infNorm(lo) <= 1.0 && infNorm(hi) <= 1.0)) {
          t += max(1.0, ceil((exitT(o, d, lo, hi) - t) / stp)) * stp;
        } else {
          t += dt;
        }
        continue;
      }
      int brick = int(e - 1u);
      ivec3 bo = ivec3(brick % uBricks.x, (brick / uBricks.x) % uBricks.y, brick / (uBricks.x * uBricks.y)) * 9;
      vec3 l = clamp(u - vec3(b * kBlock), 0.0, 8.0);
      vec3 tc = (vec3(bo) + l + 0.5) / uAtlasDims;
      vec4 s = texture(uAtlas, tc);
      if (uViewDep == 1) {  // c(d) = c0 + H d, premultiplied like c0; codes 128 + 127 v.
        s.rgb += d.x * (texture(uView0, tc).rgb * 255.0 - 128.0) / 127.0 +
                 d.y * (texture(uView1, tc).rgb * 255.0 - 128.0) / 127.0 +
                 d.z * (texture(uView2, tc).rgb * 255.0 - 128.0) / 127.0;
      }
      float a0 = min(s.a * s.a, kMaxAlpha);
      float alpha = 1.0 - exp(log(1.0 - a0) * (dt / cell));
      C += T * alpha * clamp(s.rgb / max(s.a, 1.0 / 255.0), vec3(0.0), vec3(1.0));  // Premultiplied by the code.
      T *= 1.0 - alpha;
      t += dt;
    }
  }
  outColor = vec4(C + T * uBg, 1.0);
}`;

async function fetchGunzip(url) {
  const res = await fetch(url);
  if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
  if (typeof DecompressionStream === "undefined") throw new Error("this browser has no DecompressionStream");
  const stream = res.body.pipeThrough(new DecompressionStream("gzip"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
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

  // Loads manifest.json and its arrays from `base` (a URL ending in "/", or
  // a function mapping a file name to its URL).
  async load(base) {
    const url = typeof base === "function" ? base : (name) => base + name;
    const res = await fetch(url("manifest.json"));
    if (!res.ok) throw new Error(`manifest.json: HTTP ${res.status}`);
    const m = await res.json();
    if (m.format !== 1 && m.format !== 2) throw new Error(`baked asset format ${m.format} is not supported`);
    const viewDep = m.format === 2;
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
    if (!this.program) {
      const p = gl.createProgram();
      gl.attachShader(p, this.compile(gl.VERTEX_SHADER, BAKED_VS));
      gl.attachShader(p, this.compile(gl.FRAGMENT_SHADER, BAKED_FS));
      gl.linkProgram(p);
      if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error("link: " + gl.getProgramInfoLog(p));
      this.program = p;
      const buf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, buf);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 3, -1, -1, 3]), gl.STATIC_DRAW);
      this.vao = gl.createVertexArray();
      gl.bindVertexArray(this.vao);
      const loc = gl.getAttribLocation(p, "aPos");
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, 2, gl.FLOAT, false, 0, 0);
    }
    for (const t of [this.indexTex, this.atlasTex, ...(this.viewTex || [])]) if (t) gl.deleteTexture(t);
    this.viewTex = [];
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    this.indexTex = gl.createTexture();
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_3D, this.indexTex);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.R32UI, nb, nb, nb, 0, gl.RED_INTEGER, gl.UNSIGNED_INT,
                  new Uint32Array(index.buffer, index.byteOffset, index.byteLength / 4));
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
    this.viewDep = !!view;
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
    const gl = this.gl, m = this.manifest, p = this.program;
    const W = this.canvas.width, H = this.canvas.height;
    const {rot, o} = this.modelCamera(cam.c2w);
    gl.viewport(0, 0, W, H);
    gl.useProgram(p);
    gl.bindVertexArray(this.vao);
    if (!this.uniforms) this.uniforms = {};  // Looked up once per program, not per frame.
    const u = (n) => this.uniforms[n] !== undefined ? this.uniforms[n] : (this.uniforms[n] = gl.getUniformLocation(p, n));
    gl.uniform1i(u("uIndex"), 0);
    gl.uniform1i(u("uAtlas"), 1);
    gl.uniform1i(u("uView0"), 2);
    gl.uniform1i(u("uView1"), 3);
    gl.uniform1i(u("uView2"), 4);
    gl.uniform1i(u("uViewDep"), this.viewDep ? 1 : 0);
    gl.uniformMatrix3fv(u("uRot"), false, rot);
    gl.uniform3fv(u("uOrigin"), o);
    gl.uniform4f(u("uIntr"), cam.fx, cam.fy, cam.cx, cam.cy);
    gl.uniform1f(u("uHeight"), H);
    gl.uniform1f(u("uHalf"), m.half_size);
    gl.uniform1f(u("uRes"), m.resolution);
    gl.uniform1i(u("uContracted"), m.kind === "unbounded" ? 1 : 0);
    gl.uniform1f(u("uNear"), m.near);
    gl.uniform3fv(u("uBg"), m.background);
    gl.uniform3iv(u("uBricks"), m.bricks);
    gl.uniform3fv(u("uAtlasDims"), this.dims);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  // Milliseconds per frame over `n` draws of `cam` (each finished with a
  // one-pixel read, so the GPU's work is counted).
  timeFrames(cam, n) {
    const gl = this.gl, px = new Uint8Array(4);
    this.draw(cam);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    const t0 = performance.now();
    for (let i = 0; i < n; ++i) {
      this.draw(cam);
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    }
    return (performance.now() - t0) / n;
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
