// Local verbs: train, eval, render, demo.
#include <omp.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <set>
#include <sstream>

#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "client/camera_path.h"
#include "client/commands.h"
#include "client/core_flags.h"
#include "client/verb_set.h"
#include "client/progress_bar.h"
#include "core/bake/baked_asset.h"
#include "core/bake/baked_renderer.h"
#include "core/io/checkpoint.h"
#include "core/data/capture_writer.h"
#include "core/data/content_sweep.h"
#include "core/data/dataset.h"
#include "core/render/evaluate.h"
#include "core/train/fit.h"
#include "core/data/procedural_scene.h"
#include "core/field/bf16_mlp.h"
#include "core/render/renderer.h"
#include "nlohmann/json.hpp"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

const std::vector<View>* Split(const Scene& scene, const std::string& name) {
  if (name == "train") return &scene.train;
  if (name == "val") return &scene.val;
  if (name == "test") return &scene.test;
  return nullptr;
}


// Test views whose poses the pose check disputes cannot be rendered right
// by any model: also report the means over the others.
void AddUndisputedScores(const EvalResult& ev, const std::set<std::string>& disputed, nlohmann::json* j) {
  double psnr = 0, ssim = 0;
  int n = 0;
  for (const ViewScore& v : ev.views) {
    if (disputed.count(v.name)) continue;
    psnr += v.psnr;
    ssim += v.ssim;
    ++n;
  }
  (*j)["test_views_disputed"] = disputed.size();
  if (n > 0) {
    (*j)["psnr_undisputed"] = psnr / n;
    (*j)["ssim_undisputed"] = ssim / n;
    std::printf("test views whose poses the pose check disputes: %zu of %zu; PSNR over the other %d: %.2f dB\n",
                disputed.size(), ev.views.size(), n, psnr / n);
  }
}

}  // namespace

nlohmann::json EvalJson(const EvalResult& r) {
  nlohmann::json per = nlohmann::json::array();
  for (const ViewScore& v : r.views) {
    per.push_back({{"name", v.name}, {"time_step", v.time_step}, {"psnr", v.psnr}, {"ssim", v.ssim},
                   {"psnr_colour_corrected", v.psnr_cc}, {"speckle", v.speckle}, {"blur", v.blur},
                   {"render_ms", v.render_seconds * 1e3}});
  }
  return {{"psnr", r.psnr}, {"ssim", r.ssim}, {"psnr_colour_corrected", r.psnr_cc}, {"speckle", r.speckle},
          {"blur", r.blur}, {"num_images", r.views.size()}, {"mean_render_ms", r.mean_render_seconds * 1e3},
          {"images", per}};
}

absl::StatusOr<FitResult> TrainWithProgress(const Scene& scene, const FitOptions& fo, const std::string& label) {
  ProgressBar bar(label, fo.train.iterations);
  double rays = 0, secs = 0;
  auto result = FitScene(scene, fo, [&](const StepStats& s, const Trainer& t) {
    rays += s.rays;
    secs += s.seconds;
    bar.Update(s.step, absl::StrFormat("%s rays/s | loss %.5f | psnr %.2f", FormatCount(secs > 0 ? rays / secs : 0),
                                       s.loss, s.psnr));
  });
  if (result.ok()) bar.Finish(absl::StrFormat("%s samples/s", FormatCount(result->samples_per_second)));
  else std::fprintf(stderr, "\n");
  return result;
}

void SetThreads(int threads) {
  if (threads > 0) omp_set_num_threads(threads);
}

absl::Status WriteJson(const std::string& path, const nlohmann::json& j) {
  if (path.empty()) return absl::OkStatus();
  if (path == "-") {
    std::printf("%s\n", j.dump(2).c_str());
    return absl::OkStatus();
  }
  std::ofstream f(path);
  f << j.dump(2) << "\n";
  if (!f) return absl::InternalError(absl::StrFormat("cannot write '%s'", path));
  return absl::OkStatus();
}

int Fail(const absl::Status& s) {
  std::fprintf(stderr, "clnerf: error: %s\n", std::string(s.message()).c_str());
  return 1;
}

CLI::App* BindTrain(CLI::App* parent, TrainArgs* a) {
  CLI::App* c = parent->add_subcommand("train", "Train a model on a dataset (Blender, transforms.json, COLMAP or LLFF)");
  c->add_option("--data", a->data, "Dataset directory")->required();
  c->add_option("--out", a->out, "Output model file")->required();
  c->add_option("--json", a->json, "Write results as JSON to this file ('-' = stdout)");
  c->add_flag("!--no-eval", a->eval_after, "Skip the final test-split evaluation");
  c->add_flag("--fp16", a->fp16, "Save the parameters as fp16 (about half the file; relative error <= 2^-11)");
  c->add_option("--pose-check", a->pose_check,
                "Check the capture's poses against its photos first: warn about frames turned against the rest, "
                "drop them from training, repair them (moved into the others' frame), or off")
      ->check(CLI::IsMember({"warn", "drop", "repair", "off"}))
      ->capture_default_str();
  BindPoseCheckFlags(c, &a->check);
  BindFitFlags(c, &a->fit);
  BindDatasetFlags(c, &a->dataset);
  return c;
}

int RunTrain(const TrainArgs& a) {
  SetThreads(a.fit.train.threads);
  absl::StatusOr<Scene> scene = LoadScene(a.data, a.dataset);
  if (!scene.ok()) return Fail(scene.status());
  const absl::StatusOr<DatasetFormat> format = DetectDatasetFormat(a.data);
  spdlog::info("loaded '{}' ({} loader): {} train, {} val, {} test views, {} time step(s)", scene->name,
               format.ok() ? DatasetFormatName(*format) : "?", scene->train.size(), scene->val.size(),
               scene->test.size(), scene->num_time_steps());
  std::set<std::string> disputed_test;
  std::vector<View> given_test;
  absl::StatusOr<nlohmann::json> check = CheckTrainingPoses(a, &*scene, &disputed_test, &given_test);
  if (!check.ok()) return Fail(check.status());
  absl::StatusOr<FitResult> fit = TrainWithProgress(*scene, a.fit);
  if (!fit.ok()) return Fail(fit.status());
  CheckpointOptions save_options;
  save_options.fp16_params = a.fp16;
  absl::StatusOr<size_t> bytes = SaveCheckpoint(*fit->model, a.out, {}, save_options);
  if (!bytes.ok()) return Fail(bytes.status());
  spdlog::info("saved model to {} ({} bytes of parameters, {} bytes on disk{})", a.out, fit->model->num_bytes(),
               *bytes, a.fp16 ? ", fp16 parameters" : "");
  // model_bytes: parameters (+ occupancy bits) in memory; file_bytes: the
  // checkpoint on disk.
  nlohmann::json j = {{"model", a.out},
                      {"model_bytes", fit->model->num_bytes()},
                      {"file_bytes", *bytes},
                      {"fp16", a.fp16},
                      {"iterations", fit->iterations},
                      {"train_seconds", fit->train_seconds},
                      {"samples_per_second", fit->samples_per_second},
                      {"composited_samples_per_second", fit->composited_samples_per_second},
                      {"rays_per_second", fit->rays_per_second},
                      {"finest_resolution", fit->model->options().grid.finest_resolution},
                      {"log2_table_size", fit->model->options().grid.log2_table_size},
                      {"levels", fit->model->options().grid.levels}};
  nlohmann::json curve = nlohmann::json::array();
  for (const CurvePoint& c : fit->curve) {
    curve.push_back({{"iteration", c.iteration}, {"train_seconds", c.train_seconds}, {"psnr", c.psnr}, {"ssim", c.ssim}});
  }
  j["curve"] = curve;
  if (!check->is_null()) j["pose_check"] = *check;
  if (a.eval_after && !scene->test.empty()) {
    EvalOptions eo;
    absl::StatusOr<EvalResult> ev = EvaluateViews(*fit->model, scene->test, eo);
    if (!ev.ok()) return Fail(ev.status());
    j["psnr"] = ev->psnr;
    j["ssim"] = ev->ssim;
    j["psnr_colour_corrected"] = ev->psnr_cc;
    j["speckle"] = ev->speckle;
    j["blur"] = ev->blur;
    j["num_images"] = ev->views.size();
    j["mean_render_ms"] = ev->mean_render_seconds * 1e3;
    if (!disputed_test.empty()) AddUndisputedScores(*ev, disputed_test, &j);
    if (!given_test.empty()) {  // Repaired test poses: also scored at the poses they came with.
      absl::StatusOr<EvalResult> given = EvaluateViews(*fit->model, given_test, eo);
      if (!given.ok()) return Fail(given.status());
      j["psnr_given_test_poses"] = given->psnr;
      std::printf("test PSNR at the test views' poses as they came (before the repair): %.2f dB\n", given->psnr);
    }
    std::printf("test PSNR %.2f dB (colour-corrected %.2f), SSIM %.4f, speckle %.4f, blur %.4f over %zu images | "
                "train %.1fs, %.0f samples/s | model %zu bytes, file %zu bytes\n",
                ev->psnr, ev->psnr_cc, ev->ssim, ev->speckle, ev->blur, ev->views.size(), fit->train_seconds,
                fit->samples_per_second,
                fit->model->num_bytes(), *bytes);
  } else {
    std::printf("trained %d steps in %.1fs, %.0f samples/s | model %zu bytes, file %zu bytes\n", fit->iterations,
                fit->train_seconds, fit->samples_per_second, fit->model->num_bytes(), *bytes);
  }
  if (absl::Status s = WriteJson(a.json, j); !s.ok()) return Fail(s);
  return 0;
}

CLI::App* BindEval(CLI::App* parent, EvalArgs* a) {
  CLI::App* c = parent->add_subcommand("eval", "Render a split and report PSNR/SSIM");
  c->add_option("--model", a->model, "Model file, or a baked asset's folder (clnerf bake)")->required();
  c->add_option("--data", a->data, "Dataset directory")->required();
  c->add_option("--split", a->split, "train|val|test")->capture_default_str();
  c->add_option("--json", a->json, "Write results as JSON to this file ('-' = stdout)");
  c->add_option("--save-dir", a->eval.save_dir, "Also write the renders here (NNNN_name.png, and the photo each is scored against as NNNN_name.photo.png)");
  c->add_option("--max-views", a->eval.max_views, "Evaluate an evenly spaced subset (0 = all)")->capture_default_str();
  c->add_option("--nerf-samples", a->eval.render.nerf_samples,
                "Proposal models: full-field samples per ray (0 = as trained; fewer is faster)")
      ->capture_default_str();
  c->add_option("--min-transmittance", a->eval.render.min_transmittance,
                "Stop rays once their transmittance falls to this (the rest takes the colour they saw)")
      ->capture_default_str();
  c->add_flag("!--float-mlp", a->eval.render.bf16_mlp,
              "Run the MLPs in float even where the CPU has AMX tiles (bfloat16 is the default there)");
  BindThreadsFlag(c, &a->threads);
  BindDatasetFlags(c, &a->dataset);
  return c;
}

int RunEval(const EvalArgs& a) {
  SetThreads(a.threads);
  const bool baked = IsBakedAssetDir(a.model);
  std::optional<LoadedCheckpoint> ck;
  if (!baked) {
    absl::StatusOr<LoadedCheckpoint> c = LoadCheckpoint(a.model);
    if (!c.ok()) return Fail(c.status());
    ck = std::move(*c);
  }
  absl::StatusOr<Scene> scene = LoadScene(a.data, a.dataset);
  if (!scene.ok()) return Fail(scene.status());
  const std::vector<View>* views = Split(*scene, a.split);
  if (views == nullptr) return Fail(absl::InvalidArgumentError("--split must be train, val or test"));
  if (views->empty()) return Fail(absl::InvalidArgumentError(absl::StrFormat("split '%s' is empty", a.split)));
  if (baked) return EvalBakedAsset(a, *views);
  absl::StatusOr<EvalResult> ev = EvaluateViews(ck->model, *views, a.eval);
  if (!ev.ok()) return Fail(ev.status());
  nlohmann::json j = EvalJson(*ev);
  j["model"] = a.model;
  j["model_bytes"] = ck->model.num_bytes();
  j["file_bytes"] = ck->num_bytes;
  j["split"] = a.split;
  const bool bf16 = a.eval.render.bf16_mlp && Bf16TilesAvailable();
  j["mlp"] = bf16 ? "bf16-amx" : "float";
  std::printf("%s: PSNR %.2f dB (colour-corrected %.2f), SSIM %.4f, speckle %.4f, blur %.4f over %zu images, "
              "%.1f ms/image (%s MLPs)\n",
              a.split.c_str(), ev->psnr, ev->psnr_cc, ev->ssim, ev->speckle, ev->blur, ev->views.size(),
              ev->mean_render_seconds * 1e3, bf16 ? "bfloat16 AMX" : "float");
  if (absl::Status s = WriteJson(a.json, j); !s.ok()) return Fail(s);
  return 0;
}

CLI::App* BindRender(CLI::App* parent, RenderArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "render", "Render views to PNG: locally with --model, else on the server (remote flags apply)");
  c->add_option("--model", a->model, "Model file or baked asset folder (omit to render on the server)");
  c->add_option("--out", a->out, "PNG file (one view) or directory")->required();
  c->add_option("--data,--views-from", a->data,
                "Take cameras from this dataset's split (remote: and score the renders against its images)");
  c->add_option("--camera-path", a->camera_path, "nerfstudio camera_path.json");
  c->add_option("--split", a->split, "train|val|test")->capture_default_str();
  c->add_option("--index", a->index, "Only this view of the split (-1 = all)")->capture_default_str();
  c->add_option("--pose", a->pose, "Camera-to-world matrix, OpenGL convention, 12 or 16 numbers row-major");
  c->add_option("--width", a->width, "Image width for --pose")->capture_default_str();
  c->add_option("--height", a->height, "Image height for --pose")->capture_default_str();
  c->add_option("--focal", a->focal, "Focal length in pixels for --pose (0 = NeRF-synthetic FOV)");
  c->add_option("--time-step", a->time_step, "Time step to render (-1 = latest)")->capture_default_str();
  BindThreadsFlag(c, &a->threads);
  c->add_option("--version", a->version, "Remote: model version (0 = the deployed one)")->capture_default_str();
  BindDatasetFlags(c, &a->dataset);
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunRender(const RenderArgs& a) {
  if (a.model.empty()) return RunRemoteRender(a);
  SetThreads(a.threads);
  // A baked asset's folder renders through its reference renderer (the
  // browser's sampling); a model file through the model.
  std::optional<BakedAsset> baked;
  std::optional<LoadedCheckpoint> ck;
  if (IsBakedAssetDir(a.model)) {
    absl::StatusOr<BakedAsset> b = LoadBakedAsset(a.model);
    if (!b.ok()) return Fail(b.status());
    baked = std::move(*b);
  } else {
    absl::StatusOr<LoadedCheckpoint> c = LoadCheckpoint(a.model);
    if (!c.ok()) return Fail(c.status());
    ck = std::move(*c);
  }
  std::vector<Camera> cams;
  std::vector<std::string> names;
  if (!a.pose.empty()) {
    absl::StatusOr<Camera> cam = ParsePoseCamera(a.pose, a.width, a.height, a.focal);
    if (!cam.ok()) return Fail(cam.status());
    cams.push_back(*cam);
    names.push_back("view");
  } else if (!a.camera_path.empty()) {
    absl::StatusOr<std::vector<Camera>> path = LoadNerfstudioCameraPath(a.camera_path);
    if (!path.ok()) return Fail(path.status());
    cams = std::move(*path);
    for (size_t i = 0; i < cams.size(); ++i) names.push_back(absl::StrFormat("path_%05d", int(i)));
  } else if (!a.data.empty()) {
    DatasetOptions dopt = a.dataset;
    dopt.load_images = false;
    absl::StatusOr<Scene> scene = LoadScene(a.data, dopt);
    if (!scene.ok()) return Fail(scene.status());
    const std::vector<View>* views = Split(*scene, a.split);
    if (views == nullptr || views->empty()) return Fail(absl::InvalidArgumentError("no views in that split"));
    for (int i = 0; i < int(views->size()); ++i) {
      if (a.index >= 0 && i != a.index) continue;
      cams.push_back((*views)[i].camera);
      names.push_back(std::filesystem::path((*views)[i].name).filename().string());
    }
    if (cams.empty()) return Fail(absl::InvalidArgumentError(absl::StrFormat("--index %d out of range", a.index)));
  } else {
    return Fail(absl::InvalidArgumentError("give --pose, --data or --camera-path"));
  }
  const bool single = cams.size() == 1 && std::filesystem::path(a.out).has_extension();
  ProgressBar bar("render", (long long)cams.size());
  for (size_t i = 0; i < cams.size(); ++i) {
    RenderOptions ro;
    ro.time_step = a.time_step;
    absl::StatusOr<RenderedView> r = baked ? RenderBakedView(*baked, cams[i]) : RenderView(ck->model, cams[i], ro);
    if (!r.ok()) return Fail(r.status());
    const std::string path = single ? a.out : absl::StrFormat("%s/%04d_%s.png", a.out, int(i), names[i]);
    if (absl::Status s = WriteImage(path, r->rgb); !s.ok()) return Fail(s);
    bar.Update((long long)i + 1);
  }
  bar.Finish();
  std::printf("wrote %zu image(s) to %s\n", cams.size(), a.out.c_str());
  return 0;
}

CLI::App* BindDemo(CLI::App* parent, DemoArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "demo", "Engine-only demo: procedural scene -> train -> render -> PSNR in-process (no data needed)");
  a->scene.num_train_views = 60;
  a->scene.num_test_views = 12;
  a->fit.train.iterations = 600;
  c->add_option("--out", a->out, "Output directory")->capture_default_str();
  c->add_option("--iters", a->fit.train.iterations, "Training steps")->capture_default_str();
  BindSquareSizeFlag(c, &a->scene);
  c->add_option_function<uint64_t>(
       "--seed", [a](uint64_t seed) { a->scene.seed = a->fit.train.seed = seed; }, "Random seed (scene and training)")
      ->default_str(std::to_string(a->scene.seed));
  BindThreadsFlag(c, &a->fit.train.threads);
  c->add_flag("--thin", a->scene.thin_structures, "Add thin rods (about a pixel wide) to the scene");
  c->add_flag("--backdrop", a->scene.backdrop,
              "Unbounded scene: ground plane, pillars and a far backdrop, trained in contracted space "
              "(scene/ is Blender format, which loads back as a bounded scene; scene_ngp/, scene_colmap/ and "
              "scene_llff/ hold the same capture as a real one)");
  c->add_option_function<std::string>(
       "--layout",
       [a](const std::string& name) {
         if (absl::Status s = ParseProceduralLayout(name, &a->scene.layout); !s.ok()) {
           throw CLI::ValidationError("--layout", std::string(s.message()));
         }
       },
       "Camera rig: orbit (an object capture), forward (an LLFF-style forward-facing rig) or room (a walkthrough "
       "of a room with bare walls); forward and room are unbounded")
      ->default_str(ProceduralLayoutName(a->scene.layout));
  return c;
}

int RunDemo(const DemoArgs& a) {
  SetThreads(a.fit.train.threads);
  std::error_code ec;
  std::filesystem::create_directories(a.out, ec);
  if (ec) return Fail(absl::InternalError(absl::StrFormat("cannot create '%s': %s", a.out, ec.message())));
  const ProceduralSceneOptions& po = a.scene;
  spdlog::info("generating a procedural scene ({} train / {} test views at {}x{})", po.num_train_views,
               po.num_test_views, po.width, po.height);
  absl::StatusOr<ProceduralDataset> data = GenerateProceduralDataset(po);
  if (!data.ok()) return Fail(data.status());
  if (absl::Status s = WriteBlenderDataset(*data, a.out + "/scene"); !s.ok()) return Fail(s);
  if (data->scene.kind == SceneKind::kUnbounded) {
    // A real-capture-like scene also goes out in the formats real captures
    // come in, each of which loads back as this unbounded capture, with the
    // sparse points a structure-from-motion run would add (here matched from
    // the images themselves: content_sweep.h).
    Scene capture = data->scene;
    std::vector<View> all = capture.train;
    all.insert(all.end(), capture.test.begin(), capture.test.end());
    capture.sparse_points = EstimateContentPoints(all);
    for (CaptureFormat f : {CaptureFormat::kNgp, CaptureFormat::kColmap, CaptureFormat::kLlff}) {
      const std::string dir = absl::StrFormat("%s/scene_%s", a.out, CaptureFormatName(f));
      if (absl::Status s = WriteCapture(capture, f, dir); !s.ok()) return Fail(s);
    }
    spdlog::info("wrote the capture as {0}/scene_ngp (transforms.json), {0}/scene_colmap and {0}/scene_llff", a.out);
  }
  absl::StatusOr<FitResult> fit = TrainWithProgress(data->scene, a.fit);
  if (!fit.ok()) return Fail(fit.status());
  const std::string model_path = a.out + "/model.clnerf";
  absl::StatusOr<size_t> bytes = SaveCheckpoint(*fit->model, model_path);
  if (!bytes.ok()) return Fail(bytes.status());
  EvalOptions eo;
  eo.save_dir = a.out + "/renders";
  absl::StatusOr<EvalResult> ev = EvaluateViews(*fit->model, data->scene.test, eo);
  if (!ev.ok()) return Fail(ev.status());
  const double base_psnr = ConstantColourPsnr(data->scene.train, data->scene.test);
  std::printf("demo: test PSNR %.2f dB (constant-colour baseline %.2f dB), SSIM %.4f over %zu views\n", ev->psnr,
              base_psnr, ev->ssim, ev->views.size());
  std::printf("demo: trained %d steps in %.1fs (%.0f samples/s); model %zu bytes (file %zu bytes) -> %s; renders in %s\n",
              fit->iterations, fit->train_seconds, fit->samples_per_second, fit->model->num_bytes(), *bytes,
              model_path.c_str(), eo.save_dir.c_str());
  return 0;
}

}  // namespace clnerf
