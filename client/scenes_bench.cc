// `clnerf bench scenes DIR...`: the scene-suite benchmark. Each dataset is
// trained exactly as `clnerf train` trains it with its defaults (capacity
// derived from the scene), with a PSNR-vs-training-time curve on held-out
// views; the model is saved, the test split scored (PSNR/SSIM, render time per
// view at the dataset's resolution) and a few training views too (train-view
// PSNR: how much the model overfits). With --capacity-sweep every scene is also
// trained with the hash tables around the derived size, for a PSNR-vs-bytes
// (Pareto) chart: "model no more than a scene needs".
//
// Output directory:
//   <scene>.clnerf, <scene>_t<T>.clnerf   the models (T = log2 table size)
//   runs/<scene>.json, runs/<scene>_t<T>.json
//                                         one run's figures; a run whose JSON
//                                         exists (same --iters) is not redone
//                                         unless --force, so an interrupted
//                                         suite resumes where it stopped
//   scenes.json                           every figure, curves included
//   scenes.csv, scenes_sweep.csv          one row per scene / per sweep run
//   scenes.md                             the same as markdown tables
//   scenes_psnr_vs_time.png, scenes_psnr_vs_bytes.png
//                                         charts by bench/plot_scenes.py
// Stdout: one human-readable line per scene (and per sweep run), then the
// figures as one line of JSON (without the curves).
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <set>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "client/commands.h"
#include "client/core_flags.h"
#include "client/verb_set.h"
#include "client/progress_bar.h"
#include "core/io/checkpoint.h"
#include "core/data/dataset.h"
#include "core/data/procedural_scene.h"
#include "core/render/evaluate.h"
#include "core/train/fit.h"
#include "nlohmann/json.hpp"
#include "spdlog/spdlog.h"

#ifndef CLNERF_SOURCE_DIR
#define CLNERF_SOURCE_DIR "."
#endif

namespace clnerf {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

constexpr int kMinSweepLog2 = 12, kMaxSweepLog2 = 20;
constexpr double kParetoToleranceDb = 0.2;

std::string Bytes(double b) {
  if (b >= 1e6) return absl::StrFormat("%.1f MB", b / 1e6);
  return absl::StrFormat("%.0f kB", b / 1e3);
}

// Trains one configuration (log2_table = 0: derived) and scores it.
absl::StatusOr<json> RunOne(const Scene& scene, const std::string& dir, const BenchScenesArgs& a, int log2_table,
                            const std::string& model_path, const std::string& label) {
  FitOptions fo = a.fit;  // `clnerf train`'s defaults, but for what the suite sets.
  const int iterations = fo.train.iterations;
  // The sweep runs only need their final figures.
  fo.curve_every = log2_table > 0 ? 0 : (a.curve_every > 0 ? a.curve_every : std::max(1, iterations / 10));
  if (log2_table > 0) fo.overrides.log2_table_size = log2_table;
  absl::StatusOr<FitResult> fit = TrainWithProgress(scene, fo, label);
  if (!fit.ok()) return fit.status();
  absl::StatusOr<size_t> file_bytes = SaveCheckpoint(*fit->model, model_path);
  if (!file_bytes.ok()) return file_bytes.status();
  const NgpModel& model = *fit->model;
  const ModelOptions& mo = model.options();
  json j = {{"scene", scene.name},
            {"data", dir},
            {"kind", scene.kind == SceneKind::kBounded ? "bounded" : "unbounded"},
            {"model", model_path},
            {"iterations", fit->iterations},
            {"log2_table_size", mo.grid.log2_table_size},
            {"finest_resolution", mo.grid.finest_resolution},
            {"levels", mo.grid.levels},
            {"model_bytes", model.num_bytes()},
            {"file_bytes", *file_bytes},
            {"train_seconds", fit->train_seconds},
            {"samples_per_second", fit->samples_per_second},
            {"composited_samples_per_second", fit->composited_samples_per_second},
            {"rays_per_second", fit->rays_per_second},
            {"samples_per_ray", fit->rays_per_second > 0 ? fit->samples_per_second / fit->rays_per_second : 0.0},
            {"train_images", scene.train.size()}};
  json curve = json::array();
  for (const CurvePoint& c : fit->curve) {
    curve.push_back({{"iteration", c.iteration}, {"train_seconds", c.train_seconds}, {"psnr", c.psnr}, {"ssim", c.ssim}});
  }
  j["curve"] = curve;
  // The test split (val when there is none), every view, at the dataset's resolution.
  const bool has_test = !scene.test.empty();
  const std::vector<View>& held_out = has_test ? scene.test : scene.val;
  j["eval_split"] = held_out.empty() ? "none" : (has_test ? "test" : "val");
  if (!held_out.empty()) {
    absl::StatusOr<EvalResult> ev = EvaluateViews(model, held_out, EvalOptions{});
    if (!ev.ok()) return ev.status();
    j["psnr"] = ev->psnr;
    j["ssim"] = ev->ssim;
    j["psnr_colour_corrected"] = ev->psnr_cc;
    j["speckle"] = ev->speckle;  // core/render/speckle.h: high-pass energy the photo lacks
    j["blur"] = ev->blur;
    j["test_images"] = ev->views.size();
    j["render_ms"] = ev->mean_render_seconds * 1e3;
    j["width"] = held_out[0].camera.intrinsics.width;
    j["height"] = held_out[0].camera.intrinsics.height;
  } else {
    j["psnr"] = j["ssim"] = j["render_ms"] = j["psnr_colour_corrected"] = j["speckle"] = j["blur"] = nullptr;
    j["test_images"] = 0;
    j["width"] = scene.train[0].camera.intrinsics.width;
    j["height"] = scene.train[0].camera.intrinsics.height;
  }
  EvalOptions train_eval;
  train_eval.max_views = std::max(1, a.train_views);
  absl::StatusOr<EvalResult> tv = EvaluateViews(model, scene.train, train_eval);
  if (!tv.ok()) return tv.status();
  j["train_view_psnr"] = tv->psnr;
  j["train_view_ssim"] = tv->ssim;
  j["train_view_images"] = tv->views.size();
  return j;
}

double Num(const json& j, const char* key) { return j.contains(key) && j[key].is_number() ? j[key].get<double>() : NAN; }

// `v` with `decimals` decimals, "-" when missing.
std::string Fmt(int decimals, double v) { return std::isnan(v) ? "-" : absl::StrFormat("%.*f", decimals, v); }

std::string SceneLine(const json& r) {
  return absl::StrFormat(
      "%s: test PSNR %s dB, SSIM %s, speckle %s, blur %s | train-view PSNR %s | %.0f s, %s samples/s, %s rays/s, "
      "%.0f samples/ray | model %s, file %s | render %s ms/view (%dx%d)",
      r["scene"].get<std::string>(), Fmt(2, Num(r, "psnr")), Fmt(3, Num(r, "ssim")), Fmt(5, Num(r, "speckle")),
      Fmt(5, Num(r, "blur")),
      Fmt(1, Num(r, "train_view_psnr")), Num(r, "train_seconds"), FormatCount(Num(r, "samples_per_second")),
      FormatCount(Num(r, "rays_per_second")), Num(r, "samples_per_ray"), Bytes(Num(r, "model_bytes")),
      Bytes(Num(r, "file_bytes")), Fmt(0, Num(r, "render_ms")), r["width"].get<int>(), r["height"].get<int>());
}

// A CSV field, quoted when it needs to be.
std::string Csv(const json& v) {
  if (v.is_null()) return "";
  if (v.is_number_float()) return absl::StrFormat("%.6g", v.get<double>());
  if (!v.is_string()) return v.dump();
  std::string s = v.get<std::string>();
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
  return q + "\"";
}

absl::Status WriteText(const fs::path& path, const std::string& text) {
  std::ofstream f(path);
  f << text;
  if (!f) return absl::InternalError(absl::StrFormat("cannot write '%s'", path.string()));
  return absl::OkStatus();
}

std::string CsvTable(const std::vector<std::string>& cols, const json& rows) {
  std::string out = absl::StrJoin(cols, ",") + "\n";
  for (const json& r : rows) {
    std::vector<std::string> f;
    for (const std::string& c : cols) f.push_back(r.contains(c) ? Csv(r[c]) : "");
    out += absl::StrJoin(f, ",") + "\n";
  }
  return out;
}

// A previous run's figures, when they can be reused.
std::optional<json> Cached(const fs::path& path, const BenchScenesArgs& a) {
  if (a.force || !fs::exists(path)) return std::nullopt;
  std::ifstream f(path);
  json j = json::parse(f, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object() || j.value("iterations", -1) != a.fit.train.iterations) return std::nullopt;
  return j;
}

std::string ShellQuote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

// Runs bench/plot_scenes.py on `out`; prints the command when it cannot.
void Plot(const fs::path& out) {
  const fs::path script = fs::path(CLNERF_SOURCE_DIR) / "bench" / "plot_scenes.py";
  // Debian's python3 (where apt puts python3-matplotlib) even when another python3 is first in PATH.
  const std::string py = fs::exists("/usr/bin/python3") ? "/usr/bin/python3" : "python3";
  const std::string cmd = py + " " + ShellQuote(script.string()) + " " + ShellQuote(out.string());
  std::fflush(stdout);
  if (fs::exists(script) && std::system(cmd.c_str()) == 0) return;
  absl::PrintF("charts not written (needs python3 with matplotlib: scripts/install-deps.sh); then run: %s\n",
              cmd.c_str());
}

}  // namespace

CLI::App* BindBenchScenes(CLI::App* parent, BenchScenesArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "scenes", "Scene suite: train (default flags) and evaluate each dataset; table, CSV and charts");
  c->add_option("dirs", a->dirs,
                "Dataset directories, or procedural:orbit, procedural:forward, procedural:room (generated, 96 px)")
      ->required();
  c->add_option("--out", a->out, "Output directory (models, JSON, CSV, markdown, PNG charts)")->capture_default_str();
  c->add_option("--iters", a->fit.train.iterations, "Training steps per run (as `train`)")->capture_default_str();
  c->add_flag("--capacity-sweep", a->capacity_sweep,
              "Also train with log2 tables derived-2..derived+1 (PSNR vs bytes chart)");
  BindThreadsFlag(c, &a->fit.train.threads);
  // Ablations: the regularisers as `train` takes them (use a separate --out).
  BindRegulariserFlags(c, &a->fit.train);
  c->add_option("--curve-every", a->curve_every, "PSNR-vs-time curve every N steps (default: iters / 10)");
  c->add_option("--curve-views", a->fit.curve_views, "Held-out views per curve point")->capture_default_str();
  c->add_option("--train-views", a->train_views, "Training views for the train-view PSNR")->capture_default_str();
  c->add_flag("--force", a->force, "Re-run configurations whose results are already in --out");
  return c;
}

namespace {
// "procedural:<layout>" (orbit, forward or room) names a generated scene:
// 96x96 pixels, 100 training and 8 held-out views, seed 0.
constexpr char kProceduralPrefix[] = "procedural:";

bool IsProcedural(const std::string& dir) { return dir.rfind(kProceduralPrefix, 0) == 0; }

absl::StatusOr<Scene> LoadBenchScene(const std::string& dir) {
  if (!IsProcedural(dir)) return LoadScene(dir, DatasetOptions{});
  ProceduralSceneOptions po;
  if (absl::Status s = ParseProceduralLayout(dir.substr(sizeof(kProceduralPrefix) - 1), &po.layout); !s.ok()) {
    return s;
  }
  po.width = po.height = 96;
  po.num_train_views = 100;
  po.num_test_views = 8;
  po.name = absl::StrFormat("procedural_%s", ProceduralLayoutName(po.layout));
  return GenerateProceduralScene(po);
}

std::string BenchSceneName(const std::string& dir) {
  if (IsProcedural(dir)) return absl::StrFormat("procedural_%s", dir.substr(sizeof(kProceduralPrefix) - 1));
  return DatasetName(dir);
}
}  // namespace

int RunBenchScenes(const BenchScenesArgs& a) {
  SetThreads(a.fit.train.threads);
  const int iterations = a.fit.train.iterations;
  const fs::path out(a.out);
  std::error_code ec;
  fs::create_directories(out / "runs", ec);
  if (ec) return Fail(absl::InternalError(absl::StrFormat("cannot create '%s': %s", a.out, ec.message())));
  if (iterations < 1) return Fail(absl::InvalidArgumentError("--iters must be positive"));

  json scenes = json::array(), sweep = json::array(), best = json::array();
  std::set<std::string> names;
  int failures = 0;
  for (const std::string& dir : a.dirs) {
    // Scene::name as LoadScene sets it, known before loading (for resuming).
    std::string name = BenchSceneName(dir);
    for (int k = 2; names.count(name); ++k) name = absl::StrFormat("%s_%d", BenchSceneName(dir), k);
    names.insert(name);
    std::optional<Scene> scene;  // Loaded only when something has to be trained.
    auto run = [&](int log2_table, const std::string& stem) -> absl::StatusOr<json> {
      const fs::path runs_json = out / "runs" / (stem + ".json");
      if (std::optional<json> c = Cached(runs_json, a)) {
        spdlog::info("{}: reusing {} (--force re-runs it)", stem, runs_json.string());
        return *c;
      }
      if (!scene) {
        absl::StatusOr<Scene> s = LoadBenchScene(dir);
        if (!s.ok()) return s.status();
        spdlog::info("loaded '{}': {} train, {} val, {} test views", s->name, s->train.size(), s->val.size(),
                     s->test.size());
        s->name = name;
        scene = std::move(*s);
      }
      absl::StatusOr<json> r = RunOne(*scene, dir, a, log2_table, (out / (stem + ".clnerf")).string(), stem);
      if (!r.ok()) return r.status();
      if (absl::Status s = WriteJson(runs_json.string(), *r); !s.ok()) return s;
      return r;
    };
    absl::StatusOr<json> main_run = run(0, name);
    if (!main_run.ok()) {
      absl::PrintF("%s: failed: %s\n", name.c_str(), std::string(main_run.status().message()).c_str());
      ++failures;
      continue;
    }
    absl::PrintF("%s\n", SceneLine(*main_run).c_str());
    std::fflush(stdout);
    scenes.push_back(*main_run);
    if (!a.capacity_sweep) continue;

    const int derived = (*main_run)["log2_table_size"].get<int>();
    std::set<int> tables;
    for (int d = -2; d <= 1; ++d) tables.insert(std::clamp(derived + d, kMinSweepLog2, kMaxSweepLog2));
    std::vector<json> rows;
    for (int t : tables) {
      absl::StatusOr<json> r = t == derived ? main_run : run(t, absl::StrFormat("%s_t%d", name, t));
      if (!r.ok()) {
        absl::PrintF("%s 2^%d: failed: %s\n", name.c_str(), t, std::string(r.status().message()).c_str());
        ++failures;
        continue;
      }
      json row = {{"scene", name}, {"default", t == derived}};
      for (const char* k : {"log2_table_size", "finest_resolution", "model_bytes", "file_bytes", "psnr", "ssim",
                            "train_view_psnr", "train_seconds", "samples_per_second", "iterations"}) {
        row[k] = (*r)[k];
      }
      absl::PrintF("%s 2^%d%s: test PSNR %s dB, SSIM %s | train-view PSNR %s | %.0f s | model %s, file %s\n",
                  name.c_str(), t, t == derived ? " (default)" : "", Fmt(2, Num(row, "psnr")),
                  Fmt(3, Num(row, "ssim")), Fmt(1, Num(row, "train_view_psnr")),
                  Num(row, "train_seconds"), Bytes(Num(row, "model_bytes")), Bytes(Num(row, "file_bytes")));
      std::fflush(stdout);
      rows.push_back(row);
    }
    // The smallest configuration within kParetoToleranceDb of the best tried.
    const json* top = nullptr;
    for (const json& r : rows) {
      if (!std::isnan(Num(r, "psnr")) && (!top || Num(r, "psnr") > Num(*top, "psnr"))) top = &r;
    }
    if (top) {
      const json* pick = nullptr;
      for (const json& r : rows) {
        if (!std::isnan(Num(r, "psnr")) && Num(r, "psnr") >= Num(*top, "psnr") - kParetoToleranceDb &&
            (!pick || Num(r, "model_bytes") < Num(*pick, "model_bytes"))) {
          pick = &r;
        }
      }
      for (json& r : rows) r["smallest_within_tolerance"] = &r == pick;
      best.push_back({{"scene", name}, {"log2_table_size", (*pick)["log2_table_size"]},
                      {"model_bytes", (*pick)["model_bytes"]}, {"file_bytes", (*pick)["file_bytes"]},
                      {"psnr", (*pick)["psnr"]}, {"best_log2_table_size", (*top)["log2_table_size"]},
                      {"best_psnr", (*top)["psnr"]}, {"default_log2_table_size", derived},
                      {"tolerance_db", kParetoToleranceDb}});
      absl::PrintF("%s: smallest within %.1f dB of the best (%.2f dB at 2^%d): 2^%d, model %s, %.2f dB "
                  "(default 2^%d, %s)\n",
                  name.c_str(), kParetoToleranceDb, Num(*top, "psnr"), (*top)["log2_table_size"].get<int>(),
                  (*pick)["log2_table_size"].get<int>(), Bytes(Num(*pick, "model_bytes")), Num(*pick, "psnr"),
                  derived, Bytes(Num(*main_run, "model_bytes")));
    }
    for (json& r : rows) sweep.push_back(std::move(r));
  }

  json j = {{"benchmark", "scenes"}, {"iterations", iterations}, {"threads", omp_get_max_threads()},
            {"capacity_sweep", a.capacity_sweep}, {"pareto_tolerance_db", kParetoToleranceDb},
            {"curve_views", a.fit.curve_views}, {"train_views", a.train_views},
            {"scenes", scenes}, {"sweep", sweep}, {"sweep_best", best}};
  const TrainOptions& t = a.fit.train;  // The regulariser flags an ablation set (< 0: automatic).
  j["regularisers"] = {{"grid_decay", t.grid_decay},
                       {"coarse_to_fine", t.coarse_to_fine}, {"distortion", t.distortion_reg},
                       {"distortion_warmup", t.distortion_warmup},
                       {"near_density", t.near_density_reg}, {"opacity_reg", t.opacity_reg},
                       {"learning_rate", t.learning_rate},   {"random_background", t.random_background}};
  if (absl::Status s = WriteJson((out / "scenes.json").string(), j); !s.ok()) return Fail(s);

  // Tables: CSV (machine) and markdown (README).
  for (json& r : scenes) {
    r["resolution"] = absl::StrFormat("%dx%d", r["width"].get<int>(), r["height"].get<int>());
  }
  const std::vector<std::string> cols = {
      "scene", "resolution", "iterations", "psnr", "ssim", "psnr_colour_corrected", "speckle", "blur",
      "train_view_psnr", "train_seconds", "samples_per_second", "rays_per_second", "samples_per_ray", "model_bytes",
      "file_bytes", "render_ms", "log2_table_size", "finest_resolution", "test_images", "eval_split"};
  if (absl::Status s = WriteText(out / "scenes.csv", CsvTable(cols, scenes)); !s.ok()) return Fail(s);
  std::string md = absl::StrFormat(
      "Default flags, %d iterations, %d threads. Test PSNR/SSIM: means over the test split; train-view PSNR: "
      "up to %d training views; render: mean per test view at the dataset's resolution.\n\n",
      iterations, omp_get_max_threads(), a.train_views);
  md += "| scene | resolution | test PSNR | SSIM | speckle | blur | train-view PSNR | train s | samples/s | rays/s | "
        "samples/ray | model | file | render ms/view |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const json& r : scenes) {
    md += absl::StrFormat("| %s | %s | %s | %s | %s | %s | %s | %.0f | %s | %s | %.0f | %s | %s | %s |\n",
                          r["scene"].get<std::string>(), r["resolution"].get<std::string>(),
                          Fmt(2, Num(r, "psnr")), Fmt(4, Num(r, "ssim")), Fmt(5, Num(r, "speckle")),
                          Fmt(5, Num(r, "blur")),
                          Fmt(2, Num(r, "train_view_psnr")), Num(r, "train_seconds"),
                          FormatCount(Num(r, "samples_per_second")), FormatCount(Num(r, "rays_per_second")),
                          Num(r, "samples_per_ray"), Bytes(Num(r, "model_bytes")), Bytes(Num(r, "file_bytes")),
                          Fmt(0, Num(r, "render_ms")));
  }
  if (a.capacity_sweep) {
    const std::vector<std::string> sweep_cols = {
        "scene", "log2_table_size", "default", "smallest_within_tolerance", "model_bytes", "file_bytes", "psnr",
        "ssim", "train_view_psnr", "train_seconds", "samples_per_second", "finest_resolution", "iterations"};
    if (absl::Status s = WriteText(out / "scenes_sweep.csv", CsvTable(sweep_cols, sweep)); !s.ok()) return Fail(s);
    md += absl::StrFormat(
        "\nCapacity sweep (hash-table entries per level around the derived size, %d iterations each); "
        "**bold**: the smallest within %.1f dB of the best tried.\n\n",
        iterations, kParetoToleranceDb);
    md += "| scene | table | model | file | test PSNR | SSIM | train-view PSNR | train s |\n"
          "|---|---|---|---|---|---|---|---|\n";
    for (const json& r : sweep) {
      const bool pick = r.value("smallest_within_tolerance", false);
      const std::string b = pick ? "**" : "";
      md += absl::StrFormat("| %s | %s2^%d%s%s | %s | %s | %s%s%s | %s | %s | %.0f |\n", r["scene"].get<std::string>(),
                            b, r["log2_table_size"].get<int>(), r["default"].get<bool>() ? " (default)" : "", b,
                            Bytes(Num(r, "model_bytes")), Bytes(Num(r, "file_bytes")), b,
                            Fmt(2, Num(r, "psnr")), b, Fmt(4, Num(r, "ssim")),
                            Fmt(2, Num(r, "train_view_psnr")), Num(r, "train_seconds"));
    }
  }
  if (absl::Status s = WriteText(out / "scenes.md", md); !s.ok()) return Fail(s);

  // The figures as one JSON line (curves are in scenes.json).
  json brief = j;
  for (json& r : brief["scenes"]) r.erase("curve");
  absl::PrintF("%s\n", brief.dump().c_str());
  absl::PrintF("wrote %s/{scenes.json,scenes.csv,%sscenes.md}\n", a.out.c_str(),
              a.capacity_sweep ? "scenes_sweep.csv," : "");
  if (!scenes.empty()) Plot(out);
  return failures > 0 ? 1 : 0;
}

}  // namespace clnerf
