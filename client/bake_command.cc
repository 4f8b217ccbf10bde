// `clnerf bake`: a model baked into the asset the browser renders, and
// `clnerf eval --model DIR` on such an asset (the C++ reference renderer).
#include <cstdio>
#include <map>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/commands.h"
#include "client/verb_set.h"
#include "client/core_flags.h"
#include "core/bake/baked_renderer.h"
#include "core/continual/replay_memory.h"
#include "core/data/dataset.h"
#include "core/io/checkpoint.h"
#include "core/io/durable_file.h"
#include "nlohmann/json.hpp"
#include "server/frontends/web_assets.h"

namespace clnerf {

// The standalone page's files, compiled in from server/frontends/web/
// (client/CMakeLists.txt).
const WebAsset* FindBakedPageFile(std::string_view path);

namespace {

// baked.html and baked.js beside the asset, so the folder is a page that any
// static web server shows (python3 -m http.server in it).
absl::Status WriteStandalonePage(const std::string& dir) {
  for (const char* name : {"baked.html", "baked.js"}) {
    const WebAsset* f = FindBakedPageFile(std::string("/") + name);
    if (f == nullptr) return absl::InternalError(absl::StrCat("the standalone page's ", name, " is not compiled in"));
    if (absl::Status s = AtomicWriteFile(dir + "/" + name, f->body); !s.ok()) return s;
  }
  return absl::OkStatus();
}

// The cameras to bake with: the model file's own (a service version keeps
// every scan's cameras in its replay memory), else --data's training views.
absl::StatusOr<std::vector<Camera>> BakeCameras(const BakeArgs& a, const LoadedCheckpoint& ck, std::string* from) {
  std::vector<Camera> cams;
  if (a.data.empty()) {
    const std::string* mem = ck.extras.FindSection("replay_memory");
    if (mem == nullptr) {
      return absl::InvalidArgumentError(
          "the model file holds no cameras (a service version's model.ckpt does): give the capture it was trained "
          "on with --data, so that the bake knows what the photos saw");
    }
    absl::StatusOr<ReplayMemory> memory = ReplayMemory::Deserialize(*mem);
    if (!memory.ok()) return memory.status();
    for (uint32_t i = 0; i < memory->num_cameras(); ++i) cams.push_back(memory->GetCamera(i));
    *from = "the model's replay memory";
    return cams;
  }
  DatasetOptions d = a.dataset;
  d.load_images = false;
  absl::StatusOr<Scene> scene = LoadScene(a.data, d);
  if (!scene.ok()) return scene.status();
  for (const View& v : scene->train) cams.push_back(v.camera);
  *from = a.data;
  return cams;
}
}  // namespace

CLI::App* BindBake(CLI::App* parent, BakeArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "bake", "Bake a model into the voxel asset the browser renders itself (view it with web/baked.html)");
  c->add_option("--model", a->model, "Model file (clnerf train's output, or a version's model.ckpt)")->required();
  c->add_option("--out", a->out, "Folder to write the asset into")->required();
  c->add_option("--data", a->data, "The capture the model was trained on (its training cameras decide what is kept)");
  c->add_option("--time-step", a->time_step, "Time step to bake (-1 = latest)")->capture_default_str();
  c->add_option("--resolution", a->bake.resolution,
                "Cells per axis over the field space, a multiple of 32 (0 = derived: 256 objects, 512 unbounded; "
                "unbounded finer up to 1024 where the download budget allows; coarser down to half where it is over)")
      ->capture_default_str();
  c->add_option("--visibility-rays", a->bake.visibility_rays,
                "Training-camera rays that decide which blocks are kept (a strided grid; every border pixel too)")
      ->capture_default_str();
  c->add_flag("--in-between-views,!--training-views-only", a->bake.in_between_views,
              "Visibility rays also from a camera halfway between each training camera and its nearest neighbour "
              "(default), or from the training cameras only")
      ->capture_default_str();
  c->add_option("--min-block-weight", a->bake.min_block_weight,
                "Keep a block when some training ray puts at least this much weight in it")
      ->capture_default_str();
  c->add_option("--max-asset-bytes", a->bake.max_asset_bytes,
                "Download budget of an unbounded scene: a derived grid over it is baked coarser; then the least-seen "
                "blocks are dropped until the asset compresses to about this, and the faintest view-dependent codes "
                "rounded to none if still over (0 = none)")
      ->capture_default_str();
  c->add_option("--max-object-asset-bytes", a->bake.max_object_asset_bytes,
                "The same for a bounded (object) scene (0 = none)")
      ->capture_default_str();
  c->add_option("--fit-rays", a->bake.fit.rays,
                "Training-camera rays the colour fit matches to the model's renders, at most (0 = no fit)")
      ->capture_default_str();
  c->add_option("--fit-max-entries", a->bake.fit.max_nonzeros,
                "Fewer fit rays where their weights would exceed this many entries (sets the fit's time; 0 = no limit)")
      ->capture_default_str();
  c->add_option("--fit-max-model-samples", a->bake.fit.max_model_samples,
                "Fewer fit rays where the model's renders of their targets would take more samples than this "
                "(0 = no limit)")
      ->capture_default_str();
  c->add_flag("--view-dependent,!--diffuse", a->bake.view_dependent,
              "Fit a view-dependent colour term too (c0 + H d per lattice point), or only diffuse colours")
      ->capture_default_str();
  c->add_option("--view-term", a->bake.view_term,
                "Where rays apply the view-dependent term: median (once per ray, format 3) or sample (every sample, "
                "format 2)")
      ->transform(CLI::CheckedTransformer(
          std::map<std::string, BakedViewTerm>{{"median", BakedViewTerm::kAtMedian},
                                               {"sample", BakedViewTerm::kPerSample}}))
      ->capture_default_str();
  c->add_option("--step-cells", a->bake.step_cells,
                "Ray step in cells of the baked grid (derived finer grids too), a multiple of 1/32 in [0.5, 2]")
      ->check(CLI::Range(0.5f, 2.0f))
      ->capture_default_str();
  c->add_option("--fit-iters", a->bake.fit.iterations, "Colour-fit solver iterations")->capture_default_str();
  c->add_option("--fit-prior", a->bake.fit.prior, "Colour-fit damping towards the field's own colours")
      ->capture_default_str();
  c->add_option("--density-fit-rays", a->bake.density_fit.rays,
                "Fit rays the density fit uses before the colour fit (0 = no density fit; e.g. 262144)")
      ->capture_default_str();
  c->add_option("--density-fit-steps", a->bake.density_fit.steps, "Density-fit Gauss-Newton steps")
      ->capture_default_str();
  c->add_option("--density-fit-iters", a->bake.density_fit.iterations, "Density-fit solver iterations per step")
      ->capture_default_str();
  c->add_option("--density-fit-prior", a->bake.density_fit.prior,
                "Density-fit damping towards the current codes")
      ->capture_default_str();
  c->add_option("--json", a->json, "Write the report as JSON to this file ('-' = stdout)");
  BindThreadsFlag(c, &a->threads);
  BindDatasetFlags(c, &a->dataset);
  return c;
}

int RunBake(const BakeArgs& a) {
  SetThreads(a.threads);
  absl::StatusOr<LoadedCheckpoint> ck = LoadCheckpoint(a.model);
  if (!ck.ok()) return Fail(ck.status());
  std::string from;
  absl::StatusOr<std::vector<Camera>> cams = BakeCameras(a, *ck, &from);
  if (!cams.ok()) return Fail(cams.status());
  BakeOptions o = a.bake;
  o.threads = a.threads;
  BakeReport rep;
  absl::StatusOr<BakedAsset> asset = BakeModel(ck->model, a.time_step, *cams, o, &rep);
  if (!asset.ok()) return Fail(asset.status());
  if (absl::Status s = SaveBakedAsset(*asset, a.out); !s.ok()) return Fail(s);
  if (absl::Status s = WriteStandalonePage(a.out); !s.ok()) return Fail(s);
  absl::StatusOr<uint64_t> stored = BakedAssetBytes(a.out);
  if (!stored.ok()) return Fail(stored.status());
  const uint64_t bytes = *stored;
  std::printf("baked time step %d at %d^3 (%zu cameras from %s): %d of %d candidate blocks kept, %.1f MB raw, "
              "%.2f MB on disk, in %.1f s (candidates %.1f, density and visibility %.1f: %d blocks reached, colour %.1f, "
              "fit %.1f: density %lld rays, rms %.4f -> %.4f in %.1f s, %d steps; colour %lld rays, rms %.4f -> %.4f)\n",
              asset->time_step, rep.resolution, cams->size(), from.c_str(), rep.kept_blocks, rep.candidate_blocks,
              double(asset->raw_bytes()) / 1e6, double(bytes) / 1e6, rep.total_seconds, rep.candidate_seconds,
              rep.visibility_seconds, rep.evaluated_blocks, rep.colour_seconds, rep.fit_seconds, rep.density_fit.rays,
              rep.density_fit.rms_before, rep.density_fit.rms_after, rep.density_fit.seconds,
              rep.density_fit.accepted_steps, rep.fit.rays, rep.fit.rms_before, rep.fit.rms_after);
  std::printf("view it: python3 -m http.server -d %s 8000, then open http://localhost:8000/baked.html\n",
              a.out.c_str());
  nlohmann::json j = {{"model", a.model},          {"out", a.out},
                      {"time_step", asset->time_step}, {"resolution", rep.resolution},
                      {"candidate_blocks", rep.candidate_blocks}, {"kept_blocks", rep.kept_blocks},
                      {"visible_blocks", rep.visible_blocks},
                      {"visibility_rays", rep.visibility_rays},
                      {"base_resolution_bytes", rep.base_resolution_bytes},
                      {"estimated_bytes", rep.estimated_bytes},
                      {"stored_bytes_estimate", rep.stored_bytes},
                      {"view_dead_zone", rep.view_dead_zone},
                      {"over_budget_rebakes", rep.over_budget_rebakes},
                      {"raw_bytes", asset->raw_bytes()},
                      {"asset_bytes", bytes},                     {"bake_seconds", rep.total_seconds},
                      {"candidate_seconds", rep.candidate_seconds}, {"visibility_seconds", rep.visibility_seconds},
                      {"evaluated_blocks", rep.evaluated_blocks},
                      {"colour_seconds", rep.colour_seconds},     {"fit_seconds", rep.fit_seconds},
                      {"view_dependent", asset->view_dependent()},
                      {"view_term", asset->view_term == BakedViewTerm::kAtMedian ? "median" : "sample"},
                      {"step_cells", asset->step_cells},
                      {"fit", {{"rays", rep.fit.rays}, {"candidate_rays", rep.fit.candidate_rays},
                               {"estimated_nonzeros", rep.fit.estimated_nonzeros},
                               {"estimated_model_samples", rep.fit.estimated_model_samples},
                               {"unknowns", rep.fit.unknowns}, {"nonzeros", rep.fit.nonzeros},
                               {"rms_before", rep.fit.rms_before}, {"rms_after", rep.fit.rms_after},
                               {"target_seconds", rep.fit.target_seconds}, {"rows_seconds", rep.fit.rows_seconds},
                               {"solve_seconds", rep.fit.solve_seconds}}},
                      {"density_fit", {{"rays", rep.density_fit.rays}, {"unknowns", rep.density_fit.unknowns},
                                       {"nonzeros", rep.density_fit.nonzeros},
                                       {"accepted_steps", rep.density_fit.accepted_steps},
                                       {"rms_before", rep.density_fit.rms_before},
                                       {"rms_after", rep.density_fit.rms_after},
                                       {"seconds", rep.density_fit.seconds}}}};
  if (absl::Status s = WriteJson(a.json, j); !s.ok()) return Fail(s);
  return 0;
}

// eval on a baked folder: every view through the reference renderer.
int EvalBakedAsset(const EvalArgs& a, const std::vector<View>& views) {
  absl::StatusOr<BakedAsset> asset = LoadBakedAsset(a.model);
  if (!asset.ok()) return Fail(asset.status());
  absl::StatusOr<uint64_t> bytes = BakedAssetBytes(a.model);
  if (!bytes.ok()) return Fail(bytes.status());
  long long samples = 0, steps = 0, pixels = 0;
  BakedRenderOptions ro;
  ro.threads = a.threads;
  absl::StatusOr<EvalResult> ev = EvaluateWith(
      [&](const View& v) {
        absl::StatusOr<RenderedView> r = RenderBakedView(*asset, v.camera, ro);
        if (r.ok()) {
          samples += r->samples;
          steps += r->steps;
          pixels += (long long)r->rgb.num_pixels();
        }
        return r;
      },
      views, a.eval);
  if (!ev.ok()) return Fail(ev.status());
  nlohmann::json j = EvalJson(*ev);
  j["model"] = a.model;
  j["baked"] = true;
  j["asset_bytes"] = *bytes;
  j["samples_per_ray"] = pixels > 0 ? double(samples) / double(pixels) : 0.0;
  j["steps_per_ray"] = pixels > 0 ? double(steps) / double(pixels) : 0.0;  // The shader's loop count.
  j["split"] = a.split;
  std::printf("%s (baked asset, reference renderer): PSNR %.2f dB (colour-corrected %.2f), SSIM %.4f, speckle %.4f, "
              "blur %.4f over %zu images, %.1f ms/image, %.1f samples (%.1f steps) per ray\n",
              a.split.c_str(), ev->psnr, ev->psnr_cc, ev->ssim, ev->speckle, ev->blur, ev->views.size(),
              ev->mean_render_seconds * 1e3, j["samples_per_ray"].get<double>(),
              j["steps_per_ray"].get<double>());
  if (absl::Status s = WriteJson(a.json, j); !s.ok()) return Fail(s);
  return 0;
}

}  // namespace clnerf
