#include "core/render/renderer.h"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cmath>

#include "absl/strings/str_format.h"
#include "core/field/field.h"
#include "core/field/proposal_sampler.h"
#include "core/field/ray_marcher.h"
#include "core/render/volume_rendering.h"

namespace clnerf {

absl::Status RenderOptions::Validate() const {
  if (block_rays < 1) return absl::InvalidArgumentError("render: block_rays must be >= 1");
  if (!(min_weight >= 0.0f && min_weight <= 1.0f) || !(max_skipped_weight >= 0.0f && max_skipped_weight <= 1.0f)) {
    return absl::InvalidArgumentError("render: min_weight and max_skipped_weight must be in [0, 1]");
  }
  if (nerf_samples < 0 || nerf_samples > kMaxProposalSamples) {
    return absl::InvalidArgumentError("render: nerf_samples must be in [0, 1024]");
  }
  if (threads < 0) return absl::InvalidArgumentError("render: threads must be >= 0");
  if (!(min_transmittance > 0.0f && min_transmittance <= 0.5f)) {
    return absl::InvalidArgumentError("render: min_transmittance must be in (0, 0.5]");
  }
  return absl::OkStatus();
}

namespace {

struct RayState {
  float t, t_end, T;
  int samples;  // Marched so far (at most kMaxMarchSamples).
  float rgb[3];
  float depth;
  float median;  // Where T first fell to 1/2 (< 0: not yet).
  float coloured, skipped;  // Weight of the samples that got / skipped the colour MLP.
  float last_alpha;         // Opacity of the ray's last sample.
  bool alive;
  bool stopped;  // Ended at the minimum transmittance, not at the far bound.
};

// Samples to march for a ray in the next wave: the wave, or fewer where the
// ray's last sample was opaque enough that, at that opacity, it would end
// sooner (a ray that has reached a surface needs 1-3 more samples; it used
// to march the whole wave and drop the rest: 20 % of fox_8's evaluated
// samples). Only the batching changes, not the samples.
int SamplesWanted(const RayState& s, int wave, float min_transmittance) {
  if (!(s.last_alpha > 0.05f)) return wave;
  const float needed = std::ceil(std::log(min_transmittance / s.T) / std::log1p(-s.last_alpha));
  return needed >= float(wave) ? wave : std::max(1, int(needed));
}

// Renders one block of rays with a private workspace.
long long RenderBlock(const FieldEvaluator& field, const float* origins, const float* dirs, int n, int time_step,
                      const RenderOptions& options, float* rgb_out, float* opacity_out, float* depth_out) {
  const NgpModel& model = field.model();
  std::vector<RayState> st(n);
  // Scratch reused across blocks and calls on the same thread.
  thread_local FieldContext fc;
  thread_local std::vector<RaySample> samples;
  thread_local std::vector<int> seg, seg_ray, keep, keep_seg, keep_ray;
  thread_local std::vector<float> w;
  field.SetRays(n, dirs, nullptr, time_step, &fc);
  for (int r = 0; r < n; ++r) {
    const Eigen::Map<const Eigen::Vector3f> o(origins + 3 * r), d(dirs + 3 * r);
    RayState& s = st[r];
    s.T = 1.0f;
    s.rgb[0] = s.rgb[1] = s.rgb[2] = 0.0f;
    s.depth = 0.0f;
    s.median = -1.0f;
    s.coloured = s.skipped = 0.0f;
    s.samples = 0;
    s.last_alpha = 0.0f;
    s.stopped = false;
    s.alive = model.RayInterval(o, d, &s.t, &s.t_end);
  }

  long long evaluated = 0;
  int alive = n;
  const int max_samples = kMaxMarchSamples;  // A safety bound no real model reaches.
  const bool proposals = model.uses_proposals();
  // Proposal models: every ray's samples are placed up front, then consumed
  // front to back in waves like marched ones, so rays that terminate early
  // skip the rest of theirs.
  thread_local ProposalContext prop;
  thread_local std::vector<RaySample> placed;
  thread_local std::vector<int> placed_seg, placed_ray, next_placed;
  if (proposals) {
    placed.clear();
    placed_seg.assign(1, 0);
    placed_ray.clear();
    ProposalSampler(field).Place(origins, dirs, n, /*seed=*/0, nullptr, /*anneal=*/1.0f, &prop, &placed, &placed_seg,
                                 &placed_ray, options.nerf_samples);
    next_placed.assign(n, -1);
    for (int r = 0; r < n; ++r) st[r].alive = false;
    for (size_t k = 0; k < placed_ray.size(); ++k) {
      next_placed[placed_ray[k]] = int(k);
      st[placed_ray[k]].alive = true;
      st[placed_ray[k]].samples = placed_seg[k];  // Cursor into `placed`.
    }
  }
  for (;;) {
    // Samples per live ray this wave: the wave's total stays near kWaveBudget
    // so activations stay in cache; few live rays march further per wave.
    constexpr int kWaveBudget = 4096;
    constexpr int kProposalWave = 16;
    const int wave = std::clamp(kWaveBudget / std::max(alive, 1), 2, 64);
    samples.clear();
    seg.assign(1, 0);
    seg_ray.clear();
    for (int r = 0; r < n && proposals; ++r) {
      RayState& s = st[r];
      if (!s.alive) continue;
      const int end = placed_seg[next_placed[r] + 1];
      const int take = std::min(kProposalWave, end - s.samples);
      samples.insert(samples.end(), placed.begin() + s.samples, placed.begin() + s.samples + take);
      s.samples += take;
      if (s.samples >= end) s.alive = false;
      seg.push_back(int(samples.size()));
      seg_ray.push_back(r);
    }
    for (int r = 0; r < n && !proposals; ++r) {
      RayState& s = st[r];
      if (!s.alive) continue;
      const Eigen::Map<const Eigen::Vector3f> o(origins + 3 * r), d(dirs + 3 * r);
      const size_t before = samples.size();
      const float t_before = s.t;
      s.t = model.March(o, d, s.t, s.t_end, std::min(SamplesWanted(s, wave, options.min_transmittance), max_samples - s.samples), &samples);
      if (samples.size() == before) {
        s.alive = false;
        continue;
      }
      // A ray ends after kMaxMarchSamples samples and when its march stops
      // advancing (steps below float spacing): both bound the work of any
      // model, even a pathological one.
      s.samples += int(samples.size() - before);
      if (s.samples >= max_samples || !(s.t > t_before)) s.alive = false;
      seg.push_back(int(samples.size()));
      seg_ray.push_back(r);
    }
    const int m = int(samples.size());
    if (m == 0) break;
    alive = int(seg_ray.size());
    evaluated += m;
    const int nseg = int(seg_ray.size());
    field.ResizeSamples(m, &fc);
    w.resize(m);
    for (int k = 0; k < nseg; ++k) {
      const int r = seg_ray[k];
      const Eigen::Map<const Eigen::Vector3f> o(origins + 3 * r), d(dirs + 3 * r);
      for (int j = seg[k]; j < seg[k + 1]; ++j) field.SetSample(j, o + samples[j].t * d, &fc);
    }
    field.Density(m, seg.data(), seg_ray.data(), nseg, &fc);
    // Front-to-back weights per ray; select samples that matter.
    keep.clear();
    keep_seg.assign(1, 0);
    keep_ray.clear();
    for (int k = 0; k < nseg; ++k) {
      RayState& s = st[seg_ray[k]];
      float T = s.T;
      for (int j = seg[k]; j < seg[k + 1]; ++j) {
        const float alpha = 1.0f - std::exp(-fc.sigma[j] * samples[j].dt);
        w[j] = T * alpha;
        s.last_alpha = alpha;
        if (s.median < 0 && T * (1.0f - alpha) <= 0.5f) s.median = samples[j].t;
        T *= 1.0f - alpha;
        s.depth += w[j] * samples[j].t;  // Proposal samples: t is the interval midpoint.
        if (w[j] >= options.min_weight || s.skipped + w[j] > options.max_skipped_weight) {
          keep.push_back(j);
          s.coloured += w[j];
        } else {
          s.skipped += w[j];
        }
        if (T <= options.min_transmittance) {
          s.alive = false;
          s.stopped = true;
          break;
        }
      }
      s.T = T;
      if (int(keep.size()) > keep_seg.back()) {
        keep_seg.push_back(int(keep.size()));
        keep_ray.push_back(seg_ray[k]);
      }
    }
    const int mk = int(keep.size());
    if (mk == 0) continue;
    // Colour the kept samples and accumulate.
    field.Select(keep.data(), mk, /*for_backward=*/false, &fc);
    field.Colour(mk, keep_seg.data(), keep_ray.data(), int(keep_ray.size()), &fc);
    for (size_t q = 0; q < keep_ray.size(); ++q) {
      RayState& s = st[keep_ray[q]];
      for (int i = keep_seg[q]; i < keep_seg[q + 1]; ++i) {
        const int j = keep[i];
        s.rgb[0] += w[j] * fc.ws.rgb(0, i);
        s.rgb[1] += w[j] * fc.ws.rgb(1, i);
        s.rgb[2] += w[j] * fc.ws.rgb(2, i);
      }
    }
  }
  const Eigen::Vector3f& bg = model.background();
  for (int r = 0; r < n; ++r) {
    RayState& s = st[r];
    // The skipped samples' weight is given the mean colour of the ray's
    // coloured samples instead of black: dropping it would darken every ray
    // by up to its skipped weight; this way only the colour's deviation
    // from that mean is lost.
    if (s.skipped > 0.0f && s.coloured > 0.0f) {
      const float scale = (s.coloured + s.skipped) / s.coloured;
      for (float& c : s.rgb) c *= scale;
    }
    if (s.stopped && options.min_transmittance > kMinTransmittance) {
      // The rest of the ray is taken to look like what it saw (at the
      // training's own stop it is left to the background, as training has it).
      for (float& c : s.rgb) c /= 1.0f - s.T;
      s.depth /= 1.0f - s.T;
      s.T = 0.0f;
    }
    for (int c = 0; c < 3; ++c) rgb_out[3 * r + c] = s.rgb[c] + s.T * bg[c];
    if (opacity_out) opacity_out[r] = 1.0f - s.T;
    if (depth_out) depth_out[r] = !options.median_depth ? s.depth : s.median >= 0 ? s.median : s.t_end;
  }
  return evaluated;
}

}  // namespace

long long RenderRays(const NgpModel& model, const float* origins, const float* dirs, int n, int time_step,
                     const RenderOptions& options, float* rgb, float* opacity, float* depth) {
  const int t = time_step < 0 ? model.num_time_steps() - 1 : std::min(time_step, model.num_time_steps() - 1);
  const FieldEvaluator field(model, options.bf16_mlp);
  // Proposal blocks evaluate all their samples at once: keep them small
  // enough for the activations to stay in cache.
  const int block = model.uses_proposals() ? std::min(options.block_rays, 128) : options.block_rays;
  const int nblocks = (n + block - 1) / block;
  long long total = 0;
  const int threads = options.threads > 0 ? options.threads : omp_get_max_threads();
  std::atomic<bool> stopped{false};
#pragma omp parallel for schedule(dynamic) reduction(+ : total) num_threads(threads)
  for (int b = 0; b < nblocks; ++b) {
    if (stopped.load(std::memory_order_relaxed)) continue;
    if (options.should_stop && options.should_stop()) {
      stopped = true;
      continue;
    }
    const int begin = b * block, m = std::min(block, n - begin);
    total += RenderBlock(field, origins + 3 * size_t(begin), dirs + 3 * size_t(begin), m, t, options, rgb + 3 * size_t(begin), opacity ? opacity + begin : nullptr,
                         depth ? depth + begin : nullptr);
  }
  return stopped ? -1 : total;
}

absl::StatusOr<RenderedView> RenderView(const NgpModel& model, const Camera& world_camera,
                                        const RenderOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (absl::Status s = ValidateCamera(world_camera); !s.ok()) return s;
  if (options.time_step >= model.num_time_steps()) {
    return absl::InvalidArgumentError(absl::StrFormat("time step %d does not exist (model has %d)",
                                                      options.time_step, model.num_time_steps()));
  }
  const Camera cam = model.ToModelCamera(world_camera);
  const int W = cam.intrinsics.width, H = cam.intrinsics.height;
  const size_t n = size_t(W) * H;
  // Rays go in tile order (kTileW x kTileH pixels, one block of rays each by
  // default): neighbouring rays then share hash-grid and occupancy cells in
  // both image directions, which keeps more lookups in cache than rows do.
  constexpr int kTileW = 32, kTileH = 16;
  std::vector<int> order;
  order.reserve(n);
  for (int ty = 0; ty < H; ty += kTileH) {
    for (int tx = 0; tx < W; tx += kTileW) {
      for (int y = ty; y < std::min(H, ty + kTileH); ++y) {
        for (int x = tx; x < std::min(W, tx + kTileW); ++x) order.push_back(y * W + x);
      }
    }
  }
  std::vector<float> o(3 * n), d(3 * n);
  for (size_t k = 0; k < n; ++k) {
    Eigen::Vector3f oo, dd;
    cam.Ray(order[k] % W + 0.5f, order[k] / W + 0.5f, &oo, &dd);
    for (int c = 0; c < 3; ++c) {
      o[3 * k + c] = oo[c];
      d[3 * k + c] = dd[c];
    }
  }
  std::vector<float> rgb(3 * n), opacity(n), depth(n);
  RenderedView out;
  out.samples = RenderRays(model, o.data(), d.data(), int(n), options.time_step, options, rgb.data(),
                           opacity.data(), depth.data());
  out.rgb = Image(W, H);
  out.opacity.resize(n);
  out.depth.resize(n);
  for (size_t k = 0; k < n; ++k) {
    const size_t i = size_t(order[k]);
    for (int c = 0; c < 3; ++c) out.rgb.rgb[3 * i + c] = rgb[3 * k + c];
    out.opacity[i] = opacity[k];
    out.depth[i] = depth[k];
  }
  if (out.samples < 0) return absl::CancelledError("render stopped before it finished");
  for (float& z : out.depth) z /= model.normalization().scale;
  return out;
}

}  // namespace clnerf
