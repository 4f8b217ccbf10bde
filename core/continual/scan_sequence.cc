#include "core/continual/scan_sequence.h"

#include <algorithm>
#include <filesystem>

#include "absl/strings/str_format.h"

namespace clnerf {

namespace {
ScanSequence Shell(const Scene& scene) {
  ScanSequence seq;
  seq.name = scene.name;
  seq.kind = scene.kind;
  seq.background = scene.background;
  seq.aabb_scale = scene.aabb_scale;
  seq.world_scale_hint = scene.world_scale_hint;
  seq.world_offset_hint = scene.world_offset_hint;
  return seq;
}
}  // namespace

Scene ScanSequence::Union(int last) const {
  Scene s;
  s.name = name;
  s.kind = kind;
  s.background = background;
  s.aabb_scale = aabb_scale;
  s.world_scale_hint = world_scale_hint;
  s.world_offset_hint = world_offset_hint;
  for (int t = 0; t <= last && t < size(); ++t) {
    s.train.insert(s.train.end(), scans[t].train.begin(), scans[t].train.end());
    s.test.insert(s.test.end(), scans[t].test.begin(), scans[t].test.end());
  }
  return s;
}

absl::StatusOr<ScanSequence> SplitIntoTasks(const Scene& scene, int num_tasks) {
  if (num_tasks < 1) return absl::InvalidArgumentError("--tasks must be >= 1");
  if (int(scene.train.size()) < num_tasks) {
    return absl::InvalidArgumentError(
        absl::StrFormat("cannot cut %d training views into %d tasks", scene.train.size(), num_tasks));
  }
  ScanSequence seq = Shell(scene);
  seq.scans.resize(num_tasks);
  const size_t n = scene.train.size();
  for (size_t i = 0; i < n; ++i) {
    const int t = int(i * num_tasks / n);
    View v = scene.train[i];
    v.camera.time_step = t;
    seq.scans[t].train.push_back(std::move(v));
  }
  for (int t = 0; t < num_tasks; ++t) seq.scans[t].name = absl::StrFormat("task_%02d", t);
  for (const View& test : scene.test) {
    size_t best = 0;
    float best_d = 1e30f;
    for (size_t i = 0; i < n; ++i) {
      const float d = (scene.train[i].camera.position() - test.camera.position()).squaredNorm();
      if (d < best_d) best_d = d, best = i;
    }
    View v = test;
    v.camera.time_step = int(best * num_tasks / n);
    seq.scans[v.camera.time_step].test.push_back(std::move(v));
  }
  return seq;
}

absl::StatusOr<ScanSequence> FromTimeSteps(const Scene& scene) {
  const int steps = scene.num_time_steps();
  if (steps < 1) return absl::InvalidArgumentError("the scene has no views");
  ScanSequence seq = Shell(scene);
  seq.scans.resize(steps);
  for (const View& v : scene.train) seq.scans[v.camera.time_step].train.push_back(v);
  for (const View& v : scene.test) seq.scans[v.camera.time_step].test.push_back(v);
  for (int t = 0; t < steps; ++t) {
    seq.scans[t].name = absl::StrFormat("step_%02d", t);
    if (seq.scans[t].train.empty()) {
      return absl::InvalidArgumentError(absl::StrFormat("time step %d has no training views", t));
    }
  }
  return seq;
}

absl::StatusOr<ScanSequence> LoadScanFolders(const std::string& dir, const DatasetOptions& options) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return absl::NotFoundError(absl::StrFormat("no such directory: %s", dir));
  std::vector<std::string> subdirs;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    if (e.is_directory()) subdirs.push_back(e.path().string());
  }
  std::sort(subdirs.begin(), subdirs.end());
  if (subdirs.empty()) return absl::InvalidArgumentError(absl::StrFormat("'%s' has no scan folders", dir));
  ScanSequence seq;
  for (size_t t = 0; t < subdirs.size(); ++t) {
    absl::StatusOr<Scene> s = LoadScene(subdirs[t], options);
    if (!s.ok()) {
      return absl::Status(s.status().code(), absl::StrFormat("scan '%s': %s", subdirs[t], s.status().message()));
    }
    if (s->train.empty()) return absl::InvalidArgumentError(absl::StrFormat("scan '%s' has no training views", subdirs[t]));
    if (t == 0) {
      seq = Shell(*s);
      seq.name = fs::path(dir).filename().string();
    }
    Scan scan;
    scan.name = fs::path(subdirs[t]).filename().string();
    for (auto* split : {&s->train, &s->test}) {
      for (View& v : *split) v.camera.time_step = int(t);
    }
    scan.train = std::move(s->train);
    scan.test = std::move(s->test);
    seq.scans.push_back(std::move(scan));
  }
  return seq;
}

Scene ScanSequence::ScanScene(int t) const {
  Scene s = Union(-1);  // Header fields only.
  if (t >= 0 && t < size()) {
    s.train = scans[t].train;
    s.test = scans[t].test;
  }
  return s;
}

absl::StatusOr<ScanSequence> LoadScanSequence(const std::string& dir, int num_tasks, const DatasetOptions& options) {
  absl::StatusOr<DatasetFormat> format = DetectDatasetFormat(dir);
  if (!format.ok()) {
    if (!absl::IsNotFound(format.status())) return format.status();
    std::error_code ec;
    if (!std::filesystem::is_directory(dir, ec)) return format.status();
    return LoadScanFolders(dir, options);
  }
  absl::StatusOr<Scene> scene = LoadScene(dir, options);
  if (!scene.ok()) return scene.status();
  if (scene->num_time_steps() > 1) return FromTimeSteps(*scene);
  return SplitIntoTasks(*scene, num_tasks);
}

}  // namespace clnerf
