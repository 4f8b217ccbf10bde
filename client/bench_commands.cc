// `clnerf bench ...`: benchmarks that print what they measured (a
// human-readable line plus JSON).
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "client/commands.h"
#include "client/core_flags.h"
#include "client/verb_set.h"
#include "core/io/checkpoint.h"
#include "core/data/dataset.h"
#include "core/render/renderer.h"
#include "nlohmann/json.hpp"

namespace clnerf {

CLI::App* BindBenchRender(CLI::App* parent, BenchRenderArgs* a) {
  CLI::App* c = parent->add_subcommand("render", "Time renders of test views at several sizes");
  c->add_option("--model", a->model, "Model file")->required();
  c->add_option("--data", a->data, "Dataset (cameras of its test split)")->required();
  c->add_option("--sizes", a->sizes, "Comma-separated square sizes")->capture_default_str();
  c->add_option("--views", a->views, "Views per size")->capture_default_str();
  c->add_option("--repeats", a->repeats, "Renders per view (median kept)")->capture_default_str();
  BindThreadsFlag(c, &a->threads);
  c->add_option("--json", a->json, "Write JSON here");
  BindDatasetFlags(c, &a->dataset);
  return c;
}

int RunBenchRender(const BenchRenderArgs& a) {
  SetThreads(a.threads);
  absl::StatusOr<LoadedCheckpoint> ck = LoadCheckpoint(a.model);
  if (!ck.ok()) return Fail(ck.status());
  DatasetOptions dopt = a.dataset;
  dopt.load_images = false;
  absl::StatusOr<Scene> scene = LoadScene(a.data, dopt);
  if (!scene.ok()) return Fail(scene.status());
  const std::vector<View>& views = scene->test.empty() ? scene->train : scene->test;
  if (views.empty()) return Fail(absl::InvalidArgumentError("dataset has no views"));
  nlohmann::json results = nlohmann::json::array();
  for (absl::string_view tok : absl::StrSplit(a.sizes, ',', absl::SkipEmpty())) {
    int size = 0;
    if (!absl::SimpleAtoi(tok, &size) || size <= 0) return Fail(absl::InvalidArgumentError("bad --sizes"));
    std::vector<double> ms;
    long long samples = 0;
    const int n = std::min<int>(a.views, int(views.size()));
    for (int i = 0; i < n; ++i) {
      Camera cam = views[size_t(i) * views.size() / n].camera;
      cam.intrinsics = cam.intrinsics.Scaled(size, size);
      std::vector<double> rep;
      for (int r = 0; r < std::max(1, a.repeats); ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        absl::StatusOr<RenderedView> out = RenderView(ck->model, cam, RenderOptions{});
        rep.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
        if (!out.ok()) return Fail(out.status());
        if (r == 0) samples += out->samples;
      }
      std::sort(rep.begin(), rep.end());
      ms.push_back(rep[rep.size() / 2]);
    }
    std::sort(ms.begin(), ms.end());
    const double mean = [&] { double t = 0; for (double v : ms) t += v; return t / ms.size(); }();
    const double p50 = ms[ms.size() / 2], p90 = ms[std::min(ms.size() - 1, size_t(ms.size() * 0.9))];
    std::printf("render %dx%d: mean %.1f ms, p50 %.1f ms, p90 %.1f ms, max %.1f ms over %d views (%.0f samples/view, %d threads)\n",
                size, size, mean, p50, p90, ms.back(), n, double(samples) / n, omp_get_max_threads());
    results.push_back({{"size", size}, {"views", n}, {"mean_ms", mean}, {"p50_ms", p50}, {"p90_ms", p90},
                       {"max_ms", ms.back()}, {"samples_per_view", double(samples) / n}});
  }
  nlohmann::json j = {{"model", a.model}, {"threads", omp_get_max_threads()}, {"results", results}};
  std::printf("%s\n", j.dump().c_str());
  if (absl::Status s = WriteJson(a.json, j); !s.ok()) return Fail(s);
  return 0;
}

}  // namespace clnerf
