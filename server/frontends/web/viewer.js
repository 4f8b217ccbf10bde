// clnerf viewer: looks around a place through clnerf-server's HTTP API
// (GET /api/scene, /api/render, /api/jobs). Plain JS on a 2D canvas, no
// build step, nothing fetched from anywhere but this server.
//
// Rendering is progressive: while the camera moves, each view asks for a
// preview sized from the measured render speed (so previews keep coming at
// >= 10 per second); once the camera is still, it asks for the full
// resolution. One request is in flight per view: a newer camera aborts a
// stale full-resolution render, and the server, which sees the same view id
// on the newer request, stops the stale one too and frees its slot. Full
// frames are kept in a small cache, so flipping times or versions at a still
// camera is instant.
//
// Baked assets (issue 41; baked.js): where WebGL2 is available each panel
// downloads its version's baked asset (GET /api/asset) once and renders it
// itself while the camera moves, with no server render at all; when the
// camera is still it fetches the exact server render of that view
// (frames=auto, the default). frames=baked never asks the server for a
// frame; frames=server never uses the asset. While an asset loads, or when
// a version cannot be baked, the panel shows server frames as before. The
// badge says which it shows: "baked" or "exact". Where baked frames are
// slow (software WebGL2), moving ones are drawn with fewer pixels to stay
// near BAKED_MOVING_MS (baked.js FrameScaler; #bakedms=N sets it) and shown
// stretched; a still camera's frame is drawn whole (and, with frames=auto,
// then fetched exact).
'use strict';

(() => {
  const PREVIEW_TARGET_MS = 70;   // A preview's budget: >= 10 frames per second while moving.
  const SETTLE_MS = 120;          // The camera counts as still this long after the last move.
  const CACHE_FRAMES = 48;        // Full-resolution frames kept for instant flips.
  const MIN_PREVIEW_W = 48;
  const BAKED_MOVING_MS = 50;     // A moving baked frame's default budget (#bakedms).

  const $ = (id) => document.getElementById(id);
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => Math.hypot(a[0], a[1], a[2]);
  const unit = (a) => { const n = norm(a) || 1; return mul(a, 1 / n); };
  // Rotates v about unit axis k by angle a (Rodrigues).
  const rotate = (v, k, a) => {
    const c = Math.cos(a), s = Math.sin(a);
    return add(add(mul(v, c), mul(cross(k, v), s)), mul(k, dot(k, v) * (1 - c)));
  };
  const fmt = (v) => v.map((x) => +x.toFixed(5)).join(',');

  const state = {
    // The place looked at ("" = the server's "default"); from the URL, and
    // every /api/ request carries it. Changing it reloads the page.
    place: new URLSearchParams(location.hash.slice(1)).get('place') || '',
    scene: null,          // GET /api/scene of the deployed version.
    versions: [],         // [{version, time_steps, ...}]
    cam: null,            // {eye, target, up, fov}
    res: [400, 300],
    mode: 'single',
    swipe: 0.5,
    lastMove: 0,
    dragging: false,
    keys: new Set(),
    token: '',
    frameMode: 'auto',    // auto | baked | server (see above).
    bakedMovingMs: BAKED_MOVING_MS,
    frames: [],           // Recent frames, for the status line and tests.
    bakedLoads: [],       // {key, ms, error}: asset loads, for tests.
    httpErrors: [],       // Responses >= 500 and network failures.
    pageErrors: [],
  };
  window.addEventListener('error', (e) => state.pageErrors.push(String(e.message)));
  window.addEventListener('unhandledrejection', (e) => state.pageErrors.push(String(e.reason)));

  const cache = new Map();  // key -> ImageBitmap (full resolution), LRU by insertion order.
  function cacheGet(key) {
    const v = cache.get(key);
    if (v) { cache.delete(key); cache.set(key, v); }
    return v;
  }
  function cachePut(key, bmp) {
    cache.set(key, bmp);
    while (cache.size > CACHE_FRAMES) {
      const [k, old] = cache.entries().next().value;
      cache.delete(k);
      if (!isShown(old.bmp)) old.bmp.close();
    }
  }

  class Panel {
    constructor(name) {
      this.name = name;
      this.viewId = name + '-' + Math.random().toString(36).slice(2, 10);
      this.canvas = $('canvas-' + name);
      this.ctx = this.canvas.getContext('2d');
      this.badge = $('badge-' + name);
      this.message = $('message-' + name);
      this.versionSel = $('version-' + name);
      this.timeInput = $('time-' + name);
      this.timeLabel = $('time-label-' + name);
      this.ticks = $('ticks-' + name);
      this.version = 0;    // 0 = the deployed one.
      this.time = null;    // null = the version's latest.
      this.inflight = null;  // {abort, key, full}
      this.shown = null;     // {bmp, key, full, w, h, t, v, renderMs}
      this.baked = null;     // {canvas, renderer, key, loading, failed}: its baked asset (bakedFor).
      this.renderMsPerPx = 0.002;  // Server render ms per pixel (EMA).
      this.overheadMs = 15;        // Request + decode overhead (EMA).
      this.error = '';
    }
    timeSteps() {
      const v = this.version || (state.scene && state.scene.deployed_version);
      const info = state.versions.find((x) => x.version === v);
      return info ? info.time_steps : (state.scene ? state.scene.time_steps : 0);
    }
    effectiveTime() { return this.time === null ? this.timeSteps() - 1 : Math.min(this.time, this.timeSteps() - 1); }
    effectiveVersion() { return this.version || (state.scene ? state.scene.deployed_version : 0); }
    key(w, h) {
      const c = state.cam;
      return [fmt(c.eye), fmt(c.target), fmt(c.up), c.fov.toFixed(3), w, h, this.effectiveTime(),
              this.effectiveVersion()].join('|');
    }
  }
  const panels = { A: new Panel('A'), B: new Panel('B') };
  const activePanels = () => (state.mode === 'single' ? [panels.A] : [panels.A, panels.B]);
  const isShown = (bmp) => Object.values(panels).some((p) => p.shown && p.shown.bmp === bmp);

  // ---- HTTP -----------------------------------------------------------------
  function withPlace(path) {
    if (!state.place) return path;
    return path + (path.includes('?') ? '&' : '?') + 'place=' + encodeURIComponent(state.place);
  }
  async function api(path, opts = {}) {
    let r;
    try {
      r = await fetch(withPlace(path), opts);
    } catch (e) {
      if (e.name === 'AbortError') throw e;
      state.httpErrors.push(path + ': ' + e);
      throw e;
    }
    if (r.status >= 500) state.httpErrors.push(path + ': HTTP ' + r.status);
    return r;
  }
  async function apiJson(path, opts) {
    const r = await api(path, opts);
    const body = await r.json();
    if (!r.ok) { const e = new Error(body.error || ('HTTP ' + r.status)); e.status = r.status; e.code = body.code; throw e; }
    return body;
  }

  // ---- Scene, versions, jobs ---------------------------------------------------
  async function loadScene() {
    try {
      state.scene = await apiJson('/api/scene');
    } catch (e) {
      state.scene = null;
      const msg = e.status === 409
        ? 'No model is deployed yet.<br>Upload a scan: <code>clnerf upload SCAN_DIR' +
          (state.place ? ' --place ' + escapeHtml(state.place) : '') + ' --watch</code>'
        : 'Cannot load the scene: ' + escapeHtml(e.message);
      for (const p of Object.values(panels)) showMessage(p, msg);
      $('status').textContent = e.status === 409 ? 'no model deployed yet' : 'error';
      return false;
    }
    state.versions = state.scene.versions;
    $('auth').hidden = !state.scene.auth_required;
    $('status').textContent = 'deployed v' + state.scene.deployed_version + ' · ' + state.scene.time_steps +
      ' scan' + (state.scene.time_steps === 1 ? '' : 's') + ' · ' + state.scene.cameras + ' cameras';
    fillVersionSelects();
    fillJump();
    for (const p of Object.values(panels)) { syncTimeSlider(p); showMessage(p, ''); }
    if (!state.cam) state.cam = cameraFromHash() || defaultCamera();
    return true;
  }

  function defaultCamera() {
    const c = state.scene.default_camera;
    return { eye: c.eye, target: c.target, up: state.scene.up, fov: c.fov };
  }

  function fillVersionSelects() {
    for (const p of Object.values(panels)) {
      const sel = p.versionSel;
      const keep = String(p.version);
      sel.innerHTML = '';
      const dep = document.createElement('option');
      dep.value = '0';
      dep.textContent = 'deployed (v' + state.scene.deployed_version + ')';
      sel.appendChild(dep);
      for (const v of [...state.versions].reverse()) {
        const o = document.createElement('option');
        o.value = String(v.version);
        o.textContent = 'v' + v.version + ' · ' + v.time_steps + ' scan' + (v.time_steps === 1 ? '' : 's');
        if (v.unavailable) { o.disabled = true; o.textContent = 'v' + v.version + ' · unavailable'; o.title = v.unavailable; }
        sel.appendChild(o);
      }
      sel.value = [...sel.options].some((o) => o.value === keep) ? keep : '0';
      p.version = Number(sel.value);
    }
  }

  function fillJump() {
    const sel = $('jump');
    sel.innerHTML = '<option value="">—</option>';
    state.scene.scans.forEach((s, i) => {
      const o = document.createElement('option');
      o.value = String(i);
      o.textContent = 'scan ' + i + ' camera';
      sel.appendChild(o);
    });
  }

  function syncTimeSlider(p) {
    const n = Math.max(1, p.timeSteps());
    p.timeInput.max = String(n - 1);
    p.timeInput.disabled = n <= 1;
    p.ticks.innerHTML = '';
    for (let t = 0; t < n; ++t) {
      const o = document.createElement('option');
      o.value = String(t);
      p.ticks.appendChild(o);
    }
    p.timeInput.value = String(p.effectiveTime());
    p.timeLabel.textContent = 't' + p.effectiveTime() + (p.time === null ? ' (latest)' : '');
  }

  let jobsTimer = 0;
  const knownDone = new Set();
  async function pollJobs() {
    clearTimeout(jobsTimer);
    let running = false;
    try {
      const j = await apiJson('/api/jobs?limit=6');
      running = renderJobs(j.jobs);
      await loadPlaces();
    } catch (e) { /* shown by the next successful poll */ }
    jobsTimer = setTimeout(pollJobs, running ? 700 : 2500);
  }

  // What a live job is doing, in its phase's own unit.
  function progressText(j) {
    if (j.phase === 'posing') {
      const stages = ['finding features', 'matching photos', 'building the model'];
      return 'COLMAP: ' + stages[Math.min(j.iteration, 2)] + ' (stage ' + Math.min(j.iteration + 1, 3) + ' / 3)';
    }
    if (j.phase === 'registering') return 'frame ' + j.iteration + ' / ' + j.total_iterations + ' localised';
    return 'step ' + j.iteration + ' / ' + j.total_iterations;
  }

  // How a finished job's scan was posed and placed in the place's frame.
  function placementText(m) {
    const parts = [];
    if (m.posing_frames) parts.push('posed ' + m.posing_registered + ' / ' + m.posing_frames + ' photos');
    if (m.registration_identity === 1) {
      parts.push('already in the place\'s frame');
    } else if (m.registration_scale) {
      parts.push('placed: ' + m.registration_rotation_deg.toFixed(1) + '°, ×' + m.registration_scale.toFixed(3) +
        ', ' + m.registration_frames_agreeing + ' frames agree');
    }
    if (m.registration_unverified === 1) parts.push('frame not verified');
    return parts.join(' · ');
  }

  function renderJobs(jobs) {
    const box = $('jobs');
    if (!jobs.length) { box.innerHTML = '<p class="muted">No jobs yet.</p>'; return false; }
    let running = false, newVersion = false;
    box.innerHTML = '';
    for (const j of jobs) {
      const live = !j.done;
      running = running || live;
      const div = document.createElement('div');
      div.className = 'job ' + (live ? (j.phase === 'queued' ? 'queued' : 'running') : j.phase);
      div.dataset.job = j.job_id;
      const pct = j.total_iterations ? Math.round(100 * j.iteration / j.total_iterations) : 0;
      let html = '<div class="title"><span>' + escapeHtml(j.scan_name || j.scan_id) + ' → t' + j.time_step +
        '</span><span class="phase">' + escapeHtml(j.phase.replace('_', ' ')) + '</span></div>';
      if (live && j.phase !== 'queued') {
        html += '<div class="bar"><span style="width:' + pct + '%"></span></div>' +
          '<div class="muted progress">' + progressText(j) +
          (j.psnr ? ' · PSNR ' + j.psnr.toFixed(1) + ' dB' : '') +
          (j.eta_seconds > 0 ? ' · ETA ' + Math.ceil(j.eta_seconds) + ' s' : '') + '</div>';
        html += '<a data-cancel="' + escapeHtml(j.job_id) + '">cancel</a>';
      } else if (j.phase === 'done' && j.version) {
        html += '<div class="muted">v' + j.version + ' · ' + (j.elapsed_seconds || 0).toFixed(0) + ' s · ' +
          '<a data-view-version="' + j.version + '">view v' + j.version + '</a></div>';
        const placed = placementText(j.metrics || {});
        if (placed) html += '<div class="muted placement">' + escapeHtml(placed) + '</div>';
        if (!knownDone.has(j.job_id)) { knownDone.add(j.job_id); newVersion = true; }
      } else if (j.error) {
        html += '<div class="muted">' + escapeHtml(j.error).slice(0, 200) + '</div>';
      }
      div.innerHTML = html;
      box.appendChild(div);
    }
    if (newVersion && jobsSeenOnce) refreshScene();
    jobsSeenOnce = true;
    return running;
  }
  let jobsSeenOnce = false;

  async function refreshScene() {
    const hadCam = !!state.cam;
    if (await loadScene()) {
      if (!hadCam) resetAll();
      requestAll();
    }
  }

  $('jobs').addEventListener('click', async (e) => {
    const v = e.target.dataset.viewVersion;
    if (v) {
      await refreshScene();
      panels.A.version = Number(v);
      panels.A.versionSel.value = v;
      syncTimeSlider(panels.A);
      requestAll();
      return;
    }
    const id = e.target.dataset.cancel;
    if (id) {
      const headers = state.token ? { Authorization: 'Bearer ' + state.token } : {};
      try {
        await apiJson('/api/jobs/' + encodeURIComponent(id) + '/cancel', { method: 'POST', headers });
      } catch (err) {
        alert('Cancel failed: ' + err.message);
      }
      pollJobs();
    }
  });
  $('token').addEventListener('input', (e) => { state.token = e.target.value; });

  function escapeHtml(s) {
    return String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));
  }

  // ---- Rendering ---------------------------------------------------------------
  function moving() { return state.dragging || state.keys.size > 0 || performance.now() - state.lastMove < SETTLE_MS; }

  function previewSize(p) {
    const [W, H] = state.res;
    const budget = Math.max(10, PREVIEW_TARGET_MS - p.overheadMs);
    const px = budget / Math.max(p.renderMsPerPx, 1e-6);
    let w = Math.floor(Math.sqrt(px * W / H) / 4) * 4;
    w = Math.max(MIN_PREVIEW_W, Math.min(W, w));
    return [w, Math.max(4, Math.round(w * H / W))];
  }

  function requestAll() { for (const p of activePanels()) pump(p); present(); }

  // ---- Baked assets --------------------------------------------------------------
  const bakedSupported = typeof BakedRenderer !== 'undefined' && BakedRenderer.supported();
  // The panel's renderer when its version and time step's asset is loaded;
  // otherwise starts loading it (once; a failure is remembered) and null.
  function bakedFor(p) {
    if (!bakedSupported || state.frameMode === 'server' || !state.scene) return null;
    const v = p.effectiveVersion(), t = p.effectiveTime(), want = v + '|' + t;
    if (!p.baked) {
      const canvas = document.createElement('canvas');
      try {
        p.baked = { canvas, renderer: new BakedRenderer(canvas), key: '', loading: '', failed: {},
          scaler: new FrameScaler(state.bakedMovingMs) };
      } catch (e) {
        state.bakedLoads.push({ key: want, error: String(e) });
        return null;
      }
    }
    const b = p.baked;
    if (b.key === want) return b.renderer;
    if (b.loading === want || b.failed[want] || !(v > 0)) return null;
    b.loading = want;
    const t0 = performance.now();
    const url = (name) => withPlace('/api/asset?version=' + v + '&time=' + t + '&file=' + encodeURIComponent(name));
    b.renderer.load(url).then(() => {
      b.key = want;  // The textures hold the asset that loaded last.
      state.bakedLoads.push({ key: want, ms: performance.now() - t0 });
    }, (e) => {
      b.failed[want] = String(e.message || e);
      state.bakedLoads.push({ key: want, error: b.failed[want] });
    }).finally(() => {
      if (b.loading === want) b.loading = '';
      requestAll();
    });
    return null;
  }

  // The OpenCV camera of the view (as the server's look-at form builds it).
  function bakedCamera(W, H) {
    const c = state.cam;
    const z = unit(sub(c.target, c.eye)), x = unit(cross(z, unit(c.up))), y = cross(z, x);
    const f = 0.5 * H / Math.tan(c.fov * Math.PI / 360);
    return { c2w: [x[0], y[0], z[0], c.eye[0], x[1], y[1], z[1], c.eye[1], x[2], y[2], z[2], c.eye[2]],
      fx: f, fy: f, cx: W / 2, cy: H / 2 };
  }

  // Draws panel p's baked frame for the current camera at the next
  // animation frame (one draw per frame however many moves arrive).
  function drawBaked(p, renderer, key) {
    p.bakedWant = { renderer, key };
    if (p.bakedScheduled) return;
    p.bakedScheduled = true;
    requestAnimationFrame(() => {
      p.bakedScheduled = false;
      const want = p.bakedWant;
      if (!want || (p.shown && p.shown.full && p.shown.key === want.key)) return;
      // Fewer pixels while moving where frames are slow; whole when still.
      const [W, H] = state.res, cv = p.baked.canvas, still = !moving();
      const scale = p.baked.scaler.next(!still);
      const w = Math.max(1, Math.round(W * scale)), h = Math.max(1, Math.round(H * scale));
      if (cv.width !== w || cv.height !== h) { cv.width = w; cv.height = h; }
      let ms;
      try {
        ms = want.renderer.drawTimed(bakedCamera(w, h));
      } catch (e) {
        p.baked.failed[p.baked.key] = String(e.message || e);
        p.baked.key = '';
        requestAll();
        return;
      }
      if (!still) p.baked.scaler.report(scale, ms);
      const old = p.shown;
      if (old && old.bmp && !old.full && !old.baked && old.bmp.close) old.bmp.close();
      p.shown = { bmp: cv, baked: true, full: false, key: want.key, w, h, scale, t: p.effectiveTime(),
        v: p.effectiveVersion(), renderMs: ms };
      state.frames.push({ panel: p.name, baked: true, full: false, w, h, scale, t: p.shown.t, v: p.shown.v,
        at: performance.now(), ms, renderMs: ms });
      if (state.frames.length > 400) state.frames.splice(0, 200);
      showMessage(p, '');
      present();
    });
  }

  function pump(p) {
    if (!state.scene || !state.cam) return;
    const [W, H] = state.res;
    const fullKey = p.key(W, H);
    const baked = bakedFor(p);
    if (baked) {
      // The asset while moving (or always, with frames=baked); the exact
      // frame once still, from the cache or the server.
      const exact = state.frameMode === 'auto' && !moving();
      const cachedExact = exact ? cacheGet(fullKey) : null;
      if (cachedExact) {
        if (!p.shown || p.shown.key !== fullKey || !p.shown.full) {
          p.shown = { ...cachedExact.meta, bmp: cachedExact.bmp, key: fullKey };
          present();
        }
        return;
      }
      const partial = p.shown && p.shown.baked && p.shown.scale < 1 && !moving();
      if (!p.shown || p.shown.key !== fullKey || partial) drawBaked(p, baked, fullKey);
      if (p.inflight && (!exact || p.inflight.key !== fullKey)) { p.inflight.abort.abort(); p.inflight = null; }
      if (exact && !p.inflight && !(p.shown && p.shown.full && p.shown.key === fullKey)) {
        fetchFrame(p, W, H, fullKey, true, fullKey);
      }
      return;
    }
    // frames=baked waits for the asset that is loading (the old frame stays);
    // a failed one falls back to server frames.
    if (state.frameMode === 'baked' && p.baked && p.baked.loading) return;
    const cached = cacheGet(fullKey);
    if (cached) {
      if (p.inflight) { p.inflight.abort.abort(); p.inflight = null; }
      if (!p.shown || p.shown.key !== fullKey) { p.shown = { ...cached.meta, bmp: cached.bmp, key: fullKey }; present(); }
      return;
    }
    const wantFull = !moving();
    if (p.inflight) {
      if (p.inflight.key === fullKey && p.inflight.full) return;  // Already refining this camera.
      // While moving, a preview in flight finishes quickly: pump again then.
      // Otherwise the frame in flight is stale (a preview once the camera
      // stopped, or an old full render): drop it; the server, seeing the
      // same view id on the next request, stops it too.
      if (!p.inflight.full && !wantFull) return;
      p.inflight.abort.abort();
      p.inflight = null;
    }
    if (p.shown && p.shown.key === fullKey && p.shown.full) return;
    const [w, h] = wantFull ? [W, H] : previewSize(p);
    const key = p.key(w, h);
    if (!wantFull && p.shown && p.shown.key === key) return;  // This preview is on screen.
    fetchFrame(p, w, h, key, wantFull, fullKey);
  }

  async function fetchFrame(p, w, h, key, full, fullKey) {
    const c = state.cam;
    const q = new URLSearchParams({
      width: w, height: h, eye: fmt(c.eye), target: fmt(c.target), up: fmt(c.up), fov: c.fov.toFixed(3),
      time: String(p.effectiveTime()), version: String(p.effectiveVersion()), format: 'jpeg',
      quality: full ? '90' : '75', view: p.viewId,
    });
    const abort = new AbortController();
    const mine = { abort, key, full };
    p.inflight = mine;
    if (full) setBadge(p, true);
    const t0 = performance.now();
    try {
      const r = await api('/api/render?' + q.toString(), { signal: abort.signal });
      if (!r.ok) {
        const body = await r.json().catch(() => ({}));
        if (r.status !== 499) showMessage(p, 'Render failed (HTTP ' + r.status + '): ' + escapeHtml(body.error || ''));
        return;
      }
      const renderMs = Number(r.headers.get('X-Clnerf-Render-Ms')) || 0;
      const blob = await r.blob();
      const bmp = await createImageBitmap(blob);
      const total = performance.now() - t0;
      p.renderMsPerPx = 0.7 * p.renderMsPerPx + 0.3 * Math.max(renderMs, 1) / (w * h);
      p.overheadMs = 0.7 * p.overheadMs + 0.3 * Math.max(0, total - renderMs);
      if (p.inflight !== mine) { bmp.close(); return; }
      p.inflight = null;
      const meta = { full, w, h, t: Number(r.headers.get('X-Clnerf-Time-Step')),
        v: Number(r.headers.get('X-Clnerf-Version')), renderMs, totalMs: total };
      if (full) cachePut(fullKey, { bmp, meta });
      const old = p.shown;
      p.shown = { ...meta, bmp, key };
      if (old && old.bmp !== bmp && !old.full && !old.baked) old.bmp.close();  // A baked frame's is the GL canvas.
      showMessage(p, '');
      state.frames.push({ panel: p.name, full, w, h, t: meta.t, v: meta.v, at: performance.now(), ms: total,
        renderMs });
      if (state.frames.length > 400) state.frames.splice(0, 200);
      present();
    } catch (e) {
      if (e.name !== 'AbortError') {
        showMessage(p, 'Render failed: ' + escapeHtml(e.message));
        if (!(e instanceof TypeError && /fetch/i.test(e.message))) state.pageErrors.push('frame: ' + e);  // A bug, not the network.
      }
    } finally {
      if (p.inflight === mine) p.inflight = null;
      // Keep going: the camera may have moved meanwhile, or settled.
      setTimeout(() => pump(p), 0);
    }
  }

  function setBadge(p, refining) {
    const s = p.shown;
    const [W, H] = state.res;
    let text = s ? 'v' + s.v + ' · t' + s.t + ' · ' + s.w + '×' + s.h + (s.baked ? ' · baked' : ' · exact') : '';
    if (s && !s.full && !s.baked) text += ' preview';
    if (s && s.baked && !refining) text += ' · drawn in this browser';
    else if (refining || (s && !s.full)) text += ' · refining to ' + W + '×' + H + '…';
    else if (s) text += ' · ' + Math.round(s.renderMs) + ' ms';
    p.badge.textContent = text;
    p.badge.classList.toggle('refining', !!(refining || (s && !s.full && !s.baked)));
    p.badge.classList.toggle('baked', !!(s && s.baked));
  }

  function showMessage(p, html) {
    p.message.hidden = !html;
    p.message.innerHTML = html;
  }

  // Draws what each panel has onto the visible canvases.
  function present() {
    const [W, H] = state.res;
    for (const name of ['A', 'B']) {
      const cv = panels[name].canvas;
      if (cv.width !== W || cv.height !== H) { cv.width = W; cv.height = H; }
    }
    const draw = (ctx, s, x0, x1) => {
      if (!s) return;
      ctx.save();
      ctx.beginPath();
      ctx.rect(x0, 0, x1 - x0, H);
      ctx.clip();
      ctx.imageSmoothingEnabled = true;
      ctx.imageSmoothingQuality = 'high';
      ctx.drawImage(s.bmp, 0, 0, W, H);
      ctx.restore();
    };
    const a = panels.A, b = panels.B;
    if (state.mode === 'swipe') {
      const x = Math.round(state.swipe * W);
      draw(a.ctx, a.shown, 0, x);
      draw(a.ctx, b.shown, x, W);
      $('divider').style.left = (state.swipe * 100) + '%';
    } else {
      draw(a.ctx, a.shown, 0, W);
      if (state.mode === 'side') draw(b.ctx, b.shown, 0, W);
    }
    for (const p of activePanels()) setBadge(p, p.inflight && p.inflight.full);
    if (state.mode === 'swipe') {
      panels.A.badge.textContent = 'left: ' + panels.A.badge.textContent + '  |  right: ' + panels.B.badge.textContent;
    }
  }

  // ---- Camera ------------------------------------------------------------------
  function touched() {
    state.lastMove = performance.now();
    requestAll();
    scheduleSettle();
    scheduleHash();
  }
  let settleTimer = 0;
  function scheduleSettle() {
    clearTimeout(settleTimer);
    settleTimer = setTimeout(() => { if (moving()) scheduleSettle(); else requestAll(); }, SETTLE_MS + 10);
  }

  function orbit(dx, dy) {
    const c = state.cam;
    const up = unit(state.scene.up);
    let off = sub(c.eye, c.target);
    off = rotate(off, up, -dx * 0.008);
    const right = unit(cross(sub(c.target, c.eye), up));
    const next = rotate(off, right, -dy * 0.008);
    // Stop short of the poles.
    if (Math.abs(dot(unit(next), up)) < 0.985) off = next;
    c.eye = add(c.target, off);
    c.up = up;
  }
  function pan(dx, dy) {
    const c = state.cam;
    const fwd = sub(c.target, c.eye);
    const dist = norm(fwd);
    const right = unit(cross(fwd, c.up));
    const upv = unit(cross(right, fwd));
    const k = 2 * dist * Math.tan(c.fov * Math.PI / 360) / panels.A.canvas.clientHeight;
    const d = add(mul(right, -dx * k), mul(upv, dy * k));
    c.eye = add(c.eye, d);
    c.target = add(c.target, d);
  }
  function dolly(amount) {
    const c = state.cam;
    const off = sub(c.eye, c.target);
    const dist = norm(off);
    const minDist = 1e-3 * (state.scene.radius || 1);
    c.eye = add(c.target, mul(off, Math.max(minDist, dist * Math.exp(amount)) / dist));
  }
  function fly(dt) {
    const c = state.cam;
    const fwd = unit(sub(c.target, c.eye));
    const right = unit(cross(fwd, c.up));
    const speed = 0.5 * (state.scene.radius || 1) * dt;
    let move = [0, 0, 0];
    const k = state.keys;
    if (k.has('w')) move = add(move, fwd);
    if (k.has('s')) move = sub(move, fwd);
    if (k.has('d')) move = add(move, right);
    if (k.has('a')) move = sub(move, right);
    if (k.has('e')) move = add(move, unit(c.up));
    if (k.has('q')) move = sub(move, unit(c.up));
    const d = mul(move, speed);
    c.eye = add(c.eye, d);
    c.target = add(c.target, d);
    // Arrow keys turn the view about the eye.
    const turn = 1.2 * dt;
    let dir = sub(c.target, c.eye);
    if (k.has('arrowleft')) dir = rotate(dir, unit(c.up), turn);
    if (k.has('arrowright')) dir = rotate(dir, unit(c.up), -turn);
    const r2 = unit(cross(dir, c.up));
    if (k.has('arrowup')) { const n = rotate(dir, r2, turn); if (Math.abs(dot(unit(n), unit(c.up))) < 0.985) dir = n; }
    if (k.has('arrowdown')) { const n = rotate(dir, r2, -turn); if (Math.abs(dot(unit(n), unit(c.up))) < 0.985) dir = n; }
    c.target = add(c.eye, dir);
  }

  function attachControls(canvas) {
    let last = null, mode = '';
    canvas.addEventListener('contextmenu', (e) => e.preventDefault());
    canvas.addEventListener('pointerdown', (e) => {
      if (!state.cam) return;
      canvas.setPointerCapture(e.pointerId);
      last = [e.clientX, e.clientY];
      mode = e.button === 2 || e.shiftKey ? 'pan' : 'orbit';
      state.dragging = true;
      canvas.classList.add('dragging');
      touched();
    });
    canvas.addEventListener('pointermove', (e) => {
      if (!last) return;
      const dx = e.clientX - last[0], dy = e.clientY - last[1];
      last = [e.clientX, e.clientY];
      if (!dx && !dy) return;
      if (mode === 'pan') pan(dx, dy); else orbit(dx, dy);
      touched();
    });
    const end = () => {
      if (!last) return;
      last = null;
      state.dragging = false;
      canvas.classList.remove('dragging');
      // Released: the camera is still now, so refine at once.
      state.lastMove = 0;
      state.releasedAt = performance.now();
      requestAll();
      scheduleHash();
    };
    canvas.addEventListener('pointerup', end);
    canvas.addEventListener('pointercancel', end);
    canvas.addEventListener('wheel', (e) => {
      if (!state.cam) return;
      e.preventDefault();
      dolly(Math.sign(e.deltaY) * Math.min(0.25, Math.abs(e.deltaY) * 0.0015));
      touched();
    }, { passive: false });
  }
  attachControls(panels.A.canvas);
  attachControls(panels.B.canvas);

  const FLY_KEYS = new Set(['w', 'a', 's', 'd', 'q', 'e', 'arrowleft', 'arrowright', 'arrowup', 'arrowdown']);
  let flyLast = 0;
  function flyLoop(now) {
    if (!state.keys.size) return;
    const dt = Math.min(0.1, (now - flyLast) / 1000);
    flyLast = now;
    fly(dt);
    touched();
    requestAnimationFrame(flyLoop);
  }
  window.addEventListener('keydown', (e) => {
    if (!state.cam || e.target.tagName === 'INPUT' || e.target.tagName === 'SELECT') return;
    const k = e.key.toLowerCase();
    if (!FLY_KEYS.has(k)) return;
    e.preventDefault();
    if (!state.keys.size) { flyLast = performance.now(); requestAnimationFrame(flyLoop); }
    state.keys.add(k);
  });
  window.addEventListener('keyup', (e) => { state.keys.delete(e.key.toLowerCase()); if (!state.keys.size) touched(); });
  window.addEventListener('blur', () => { state.keys.clear(); });

  // Swipe divider.
  (() => {
    const div = $('divider');
    let dragging = false;
    div.addEventListener('pointerdown', (e) => { dragging = true; div.setPointerCapture(e.pointerId); e.stopPropagation(); });
    div.addEventListener('pointermove', (e) => {
      if (!dragging) return;
      const r = panels.A.canvas.getBoundingClientRect();
      state.swipe = Math.min(1, Math.max(0, (e.clientX - r.left) / r.width));
      present();
      scheduleHash();
    });
    div.addEventListener('pointerup', () => { dragging = false; });
  })();

  // ---- Controls ----------------------------------------------------------------
  for (const p of Object.values(panels)) {
    p.versionSel.addEventListener('change', () => {
      p.version = Number(p.versionSel.value);
      syncTimeSlider(p);
      requestAll();
      scheduleHash();
    });
    p.timeInput.addEventListener('input', () => {
      const t = Number(p.timeInput.value);
      p.time = t === p.timeSteps() - 1 ? null : t;
      syncTimeSlider(p);
      requestAll();
      scheduleHash();
    });
  }
  $('mode').addEventListener('change', (e) => setMode(e.target.value));
  $('place').addEventListener('change', (e) => {
    // Another place is another scene: start over there, at its default camera.
    const q = new URLSearchParams({ place: e.target.value, res: state.res.join('x'), mode: state.mode });
    location.hash = q.toString();
    location.reload();
  });
  async function loadPlaces() {
    const sel = $('place');
    try {
      const r = await fetch('/api/places');
      const body = await r.json();
      // Polled with the jobs: rebuild only when places or their versions changed.
      const key = JSON.stringify((body.places || []).map((p) => [p.name, p.deployed_version]));
      if (key === loadPlaces.last) return;
      loadPlaces.last = key;
      sel.innerHTML = '';
      for (const p of body.places || []) {
        const o = document.createElement('option');
        o.value = p.name === 'default' ? '' : p.name;
        o.textContent = p.name + (p.deployed_version ? ' (v' + p.deployed_version + ')' : ' (no model yet)');
        sel.appendChild(o);
      }
      if (![...sel.options].some((o) => o.value === state.place)) {
        const o = document.createElement('option');  // A place the URL names but the server does not have.
        o.value = state.place;
        o.textContent = state.place + ' (unknown)';
        sel.appendChild(o);
      }
      sel.value = state.place;
    } catch (e) {
      state.httpErrors.push('/api/places: ' + e);
    }
  }
  $('resolution').addEventListener('change', (e) => {
    state.res = e.target.value.split('x').map(Number);
    requestAll();
    scheduleHash();
  });
  $('frames').addEventListener('change', (e) => {
    state.frameMode = e.target.value;
    for (const p of Object.values(panels)) if (p.shown && p.shown.baked && state.frameMode === 'server') p.shown = null;
    requestAll();
    scheduleHash();
  });
  $('reset').addEventListener('click', () => { resetAll(); touched(); });
  $('jump').addEventListener('change', (e) => {
    if (e.target.value === '') return;
    const i = Number(e.target.value);
    const s = state.scene.scans[i];
    state.cam = { eye: s.eye, target: s.target, up: state.scene.up, fov: s.fov };
    panels.A.time = i === state.scene.time_steps - 1 ? null : i;
    syncTimeSlider(panels.A);
    e.target.value = '';
    touched();
  });

  function setMode(mode) {
    state.mode = mode;
    $('mode').value = mode;
    $('panel-B').hidden = mode !== 'side';
    $('divider').hidden = mode !== 'swipe';
    // Panel B's controls stay usable in swipe mode: show them under A.
    if (mode === 'swipe') $('panel-A').appendChild(panels.B.versionSel.closest('.controls'));
    else $('panel-B').appendChild(panels.B.versionSel.closest('.controls'));
    requestAll();
    scheduleHash();
  }

  function resetAll() {
    state.cam = defaultCamera();
  }

  // ---- URL ---------------------------------------------------------------------
  let hashTimer = 0;
  function scheduleHash() {
    clearTimeout(hashTimer);
    hashTimer = setTimeout(writeHash, 250);
  }
  function writeHash() {
    if (!state.cam) return;
    const c = state.cam;
    const q = new URLSearchParams({ eye: fmt(c.eye), target: fmt(c.target), up: fmt(c.up), fov: c.fov.toFixed(2),
      res: state.res.join('x'), mode: state.mode });
    if (state.frameMode !== 'auto') q.set('frames', state.frameMode);
    if (state.bakedMovingMs !== BAKED_MOVING_MS) q.set('bakedms', String(state.bakedMovingMs));
    if (state.place) q.set('place', state.place);
    const put = (p, k) => {
      if (p.version) q.set('v' + k, String(p.version));
      if (p.time !== null) q.set('t' + k, String(p.time));
    };
    put(panels.A, 'a');
    put(panels.B, 'b');
    if (state.mode === 'swipe') q.set('swipe', state.swipe.toFixed(3));
    history.replaceState(null, '', '#' + q.toString());
  }
  function cameraFromHash() {
    const q = new URLSearchParams(location.hash.slice(1));
    const vec = (k) => {
      const v = (q.get(k) || '').split(',').map(Number);
      return v.length === 3 && v.every(Number.isFinite) ? v : null;
    };
    const eye = vec('eye'), target = vec('target'), up = vec('up');
    const fov = Number(q.get('fov'));
    if (!eye || !target || !up || !(fov > 0 && fov < 170)) return null;
    return { eye, target, up, fov };
  }
  function readHashSettings() {
    const q = new URLSearchParams(location.hash.slice(1));
    const res = (q.get('res') || '').split('x').map(Number);
    if (res.length === 2 && res.every((x) => x > 0 && x <= 4096)) {
      state.res = res;
      const opt = [...$('resolution').options].find((o) => o.value === res.join('x'));
      if (opt) $('resolution').value = opt.value;
    }
    for (const [p, k] of [[panels.A, 'a'], [panels.B, 'b']]) {
      const v = Number(q.get('v' + k));
      if (Number.isInteger(v) && v > 0) p.version = v;
      const t = q.get('t' + k);
      if (t !== null && Number.isInteger(Number(t)) && Number(t) >= 0) p.time = Number(t);
    }
    if (['auto', 'baked', 'server'].includes(q.get('frames'))) state.frameMode = q.get('frames');
    const bakedMs = Number(q.get('bakedms'));
    if (q.has('bakedms') && bakedMs > 0 && bakedMs <= 10000) state.bakedMovingMs = bakedMs;
    $('frames').value = state.frameMode;
    const sw = Number(q.get('swipe'));
    if (sw >= 0 && sw <= 1 && q.has('swipe')) state.swipe = sw;
    return ['single', 'side', 'swipe'].includes(q.get('mode')) ? q.get('mode') : null;
  }

  // ---- Start ---------------------------------------------------------------------
  async function start() {
    const mode = readHashSettings();
    await loadPlaces();
    // Panel B starts on the first scan, so "compare" shows then and now.
    if (!new URLSearchParams(location.hash.slice(1)).has('tb')) panels.B.time = 0;
    while (!(await loadScene())) await new Promise((r) => setTimeout(r, 3000));
    for (const [p, k] of [[panels.A, 'a'], [panels.B, 'b']]) {
      const want = new URLSearchParams(location.hash.slice(1)).get('v' + k);
      if (want && [...p.versionSel.options].some((o) => o.value === want)) { p.versionSel.value = want; p.version = Number(want); }
      syncTimeSlider(p);
    }
    setMode(mode || 'single');
    requestAll();
    pollJobs();
  }

  // For tests and the curious: read-only views of the viewer's state, and the
  // same actions the controls perform.
  window.clnerfViewer = {
    get frames() { return state.frames; },
    // performance.now() of the last pointer release (frames carry `at` on the same clock).
    get releasedAt() { return state.releasedAt || 0; },
    get httpErrors() { return state.httpErrors; },
    get pageErrors() { return state.pageErrors; },
    get camera() { return state.cam && { ...state.cam }; },
    get resolution() { return state.res.slice(); },
    get scene() { return state.scene; },
    shown(name) {
      const s = panels[name].shown;
      return s && { full: s.full, baked: !!s.baked, w: s.w, h: s.h, scale: s.scale, t: s.t, v: s.v };
    },
    get bakedSupported() { return bakedSupported; },
    get bakedLoads() { return state.bakedLoads; },
    badge(name) { return panels[name].badge.textContent; },
    busy(name) { return !!panels[name].inflight; },
    setMode,
  };

  start();
})();
