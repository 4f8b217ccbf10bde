#include "core/data/ngp_loader.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <vector>

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "core/data/dataset.h"
#include "core/data/image.h"
#include "core/data/ply_reader.h"
#include "core/data/transforms_json.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

enum Split { kTrain = 0, kVal = 1, kTest = 2 };

// One frame to load: the frame object, the document it came from, its split.
struct FrameRef {
  const json* frame;
  const json* doc;
  std::string file;  // The json file, for error messages.
  size_t index;      // Index within the file's "frames".
  Split split = kTrain;
};

// Optional numeric field; INVALID_ARGUMENT when present but not a number.
absl::StatusOr<std::optional<double>> OptNumber(const json& obj, const char* key,
                                                const std::string& ctx) {
  if (!obj.contains(key)) return std::optional<double>();
  if (!obj[key].is_number()) {
    return absl::InvalidArgumentError(absl::StrCat(ctx, ": field '", key, "' must be a number"));
  }
  return std::optional<double>(obj[key].get<double>());
}

// Global intrinsics keys overridden by the frame's own.
json MergedIntrinsics(const json& doc, const json& frame) {
  static const char* const kKeys[] = {"fl_x",
                                      "fl_y",
                                      "cx",
                                      "cy",
                                      "w",
                                      "h",
                                      "k1",
                                      "k2",
                                      "k3",
                                      "k4",
                                      "p1",
                                      "p2",
                                      "camera_angle_x",
                                      "camera_angle_y",
                                      "camera_model"};
  json merged = json::object();
  for (const char* key : kKeys) {
    if (frame.contains(key)) {
      merged[key] = frame[key];
    } else if (doc.contains(key)) {
      merged[key] = doc[key];
    }
  }
  return merged;
}

// Fills everything but width/height (already set) from the merged keys.
absl::Status ParseIntrinsics(const json& k, const std::string& ctx, Intrinsics* in) {
  if (k.contains("camera_model")) {
    const std::string model =
        k["camera_model"].is_string() ? k["camera_model"].get<std::string>() : "";
    if (model != "OPENCV" && model != "PINHOLE" && model != "SIMPLE_PINHOLE" &&
        model != "SIMPLE_RADIAL" && model != "RADIAL") {
      return absl::InvalidArgumentError(
          absl::StrCat(ctx, ": unsupported 'camera_model' ", k["camera_model"].dump(),
                       " (only pinhole / OPENCV radial-tangential cameras are supported)"));
    }
  }
  std::optional<double> v[12];
  static const char* const kNames[12] = {
      "fl_x",           "fl_y",          "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4",
      "camera_angle_x", "camera_angle_y"};
  for (int i = 0; i < 12; ++i) {
    absl::StatusOr<std::optional<double>> n = OptNumber(k, kNames[i], ctx);
    if (!n.ok()) return n.status();
    v[i] = *n;
  }
  auto& [fl_x, fl_y, cx, cy, k1, k2, p1, p2, k3, k4, ax, ay] = v;
  if (k3.value_or(0) != 0 || k4.value_or(0) != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(ctx, ": non-zero 'k3'/'k4' distortion is not supported"));
  }
  if (!fl_x && ax) fl_x = 0.5 * in->width / std::tan(0.5 * *ax);
  if (!fl_y && ay) fl_y = 0.5 * in->height / std::tan(0.5 * *ay);
  if (!fl_x) fl_x = fl_y;
  if (!fl_y) fl_y = fl_x;
  if (!fl_x) {
    return absl::InvalidArgumentError(absl::StrCat(
        ctx, ": no focal length: need 'fl_x'/'fl_y' or 'camera_angle_x'/'camera_angle_y'"));
  }
  in->fx = float(*fl_x);
  in->fy = float(*fl_y);
  in->cx = float(cx.value_or(0.5 * in->width));
  in->cy = float(cy.value_or(0.5 * in->height));
  in->k1 = float(k1.value_or(0));
  in->k2 = float(k2.value_or(0));
  in->p1 = float(p1.value_or(0));
  in->p2 = float(p2.value_or(0));
  return absl::OkStatus();
}

// Reads `path` as a mask and ANDs it into `mask` (which may be empty).
absl::Status AddMask(const fs::path& path, bool nonzero_is_exclude, Mask* mask) {
  absl::StatusOr<Mask> m = ReadMask(path.string(), nonzero_is_exclude);
  if (!m.ok()) return m.status();
  if (mask->empty()) {
    *mask = *std::move(m);
  } else if (m->width != mask->width || m->height != mask->height) {
    return absl::InvalidArgumentError(
        absl::StrCat("mask ", path.string(), " has a different size"));
  } else {
    for (size_t i = 0; i < mask->keep.size(); ++i) mask->keep[i] &= m->keep[i];
  }
  return absl::OkStatus();
}

absl::StatusOr<View> LoadFrame(const fs::path& dir, const FrameRef& ref, const DatasetOptions& opts,
                               const Eigen::Vector3f& background) {
  const json& f = *ref.frame;
  const std::string file_path = f["file_path"].get<std::string>();
  const std::string ctx = absl::StrCat(ref.file, ": frame ", ref.index, " ('", file_path, "')");
  const fs::path image_path = ResolveImagePath(dir, file_path);
  View view;
  view.name = image_path.lexically_relative(dir).lexically_normal().generic_string();
  absl::StatusOr<Pose> pose = ParsePose(f, ctx);
  if (!pose.ok()) return pose.status();
  view.camera.c2w = ConvertPose(*pose, PoseConvention::kOpenGL);
  absl::StatusOr<int> t = ParseTimeStep(f, ctx);
  if (!t.ok()) return t.status();
  view.camera.time_step = *t;

  const json k = MergedIntrinsics(*ref.doc, f);
  absl::StatusOr<std::optional<double>> w = OptNumber(k, "w", ctx), h = OptNumber(k, "h", ctx);
  if (!w.ok()) return w.status();
  if (!h.ok()) return h.status();
  Intrinsics& in = view.camera.intrinsics;
  in.width = int(std::lround(w->value_or(0)));
  in.height = int(std::lround(h->value_or(0)));
  const bool has_size = w->has_value() && h->has_value();
  if (opts.load_images || !has_size) {
    absl::StatusOr<Image> image = ReadImage(image_path.string(), background);
    if (!image.ok()) return Annotate(image.status(), ctx);
    if (has_size && (image->width != in.width || image->height != in.height)) {
      return absl::InvalidArgumentError(absl::StrCat(ctx, ": image is ", image->width, "x",
                                                     image->height, " but 'w'/'h' say ", in.width,
                                                     "x", in.height));
    }
    in.width = image->width;
    in.height = image->height;
    if (opts.load_images) view.image = *std::move(image);
  }
  if (absl::Status s = ParseIntrinsics(k, ctx, &in); !s.ok()) return s;

  if (opts.load_images) {
    if (f.contains("mask_path")) {
      if (!f["mask_path"].is_string()) {
        return absl::InvalidArgumentError(
            absl::StrCat(ctx, ": field 'mask_path' must be a string"));
      }
      absl::Status s = AddMask(dir / f["mask_path"].get<std::string>(), false, &view.mask);
      if (!s.ok()) return Annotate(s, ctx);
    }
    const fs::path dynamic = image_path.parent_path() /
                             absl::StrCat("dynamic_mask_", image_path.stem().string(), ".png");
    std::error_code ec;
    if (fs::is_regular_file(dynamic, ec)) {
      if (absl::Status s = AddMask(dynamic, true, &view.mask); !s.ok()) return Annotate(s, ctx);
    }
  }
  DownscaleView(opts.downscale, &view);
  return view;
}

// Assigns splits for a single transforms.json: explicit "split" keys, else
// every test_every-th frame after sorting by file_path.
absl::Status AssignSplits(int test_every, std::vector<FrameRef>* refs) {
  const bool explicit_split = std::any_of(
      refs->begin(), refs->end(), [](const FrameRef& r) { return r.frame->contains("split"); });
  if (explicit_split) {
    for (FrameRef& r : *refs) {
      const json& f = *r.frame;
      const json split = f.value("split", json("train"));
      const std::string s = split.is_string() ? split.get<std::string>() : "";
      if (s == "train") {
        r.split = kTrain;
      } else if (s == "val") {
        r.split = kVal;
      } else if (s == "test") {
        r.split = kTest;
      } else {
        return absl::InvalidArgumentError(absl::StrCat(r.file, ": frame ", r.index,
                                                       ": field 'split' must be \"train\", \"val\" "
                                                       "or \"test\", got ",
                                                       split.dump()));
      }
    }
    return absl::OkStatus();
  }
  std::stable_sort(refs->begin(), refs->end(), [](const FrameRef& a, const FrameRef& b) {
    return (*a.frame)["file_path"].get<std::string>() < (*b.frame)["file_path"].get<std::string>();
  });
  for (size_t i = 0; i < refs->size(); ++i) {
    (*refs)[i].split = (test_every > 0 && i % test_every == 0) ? kTest : kTrain;
  }
  return absl::OkStatus();
}

absl::Status ReadHints(const json& doc, const std::string& file, Scene* scene) {
  absl::StatusOr<std::optional<double>> aabb = OptNumber(doc, "aabb_scale", file);
  absl::StatusOr<std::optional<double>> scale = OptNumber(doc, "scale", file);
  if (!aabb.ok()) return aabb.status();
  if (!scale.ok()) return scale.status();
  scene->aabb_scale = float(aabb->value_or(1.0));
  scene->world_scale_hint = float(scale->value_or(0.33));
  if (!(scene->aabb_scale > 0) || !(scene->world_scale_hint > 0)) {
    return absl::InvalidArgumentError(absl::StrCat(file, ": 'aabb_scale' and 'scale' must be > 0"));
  }
  if (doc.contains("offset")) {
    const json& o = doc["offset"];
    if (!o.is_array() || o.size() != 3 || !o[0].is_number() || !o[1].is_number() ||
        !o[2].is_number()) {
      return absl::InvalidArgumentError(absl::StrCat(file, ": field 'offset' must be 3 numbers"));
    }
    const Eigen::Vector3f offset(o[0].get<float>(), o[1].get<float>(), o[2].get<float>());
    // x_ngp = x * scale + offset lands on the box centre 0.5 at x = (0.5 - offset) / scale.
    scene->world_offset_hint = (Eigen::Vector3f::Constant(0.5f) - offset) / scene->world_scale_hint;
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<Scene> LoadNgpScene(const std::string& dir, const DatasetOptions& opts) {
  if (absl::Status s = CheckDatasetDir(dir, opts); !s.ok()) return s;
  const fs::path root(dir);
  Scene scene;
  scene.name = DatasetName(dir);
  scene.kind = opts.ngp_bounded ? SceneKind::kBounded : SceneKind::kUnbounded;
  scene.background = opts.ngp_bounded ? Eigen::Vector3f::Ones() : Eigen::Vector3f::Zero();

  std::deque<json> docs;  // Stable addresses for FrameRef.
  std::vector<FrameRef> refs;
  std::string first_file;  // Scene-wide hints come from the first json file.
  const auto add_doc = [&](const fs::path& path, std::optional<Split> split) -> absl::Status {
    absl::StatusOr<json> doc = ReadJson(path);
    if (!doc.ok()) return doc.status();
    docs.push_back(*std::move(doc));
    if (first_file.empty()) first_file = path.string();
    const json& frames = docs.back()["frames"];
    for (size_t i = 0; i < frames.size(); ++i) {
      refs.push_back({&frames[i], &docs.back(), path.string(), i, split.value_or(kTrain)});
    }
    return absl::OkStatus();
  };

  std::error_code ec;
  try {
    if (fs::is_regular_file(root / "transforms_train.json", ec)) {
      const std::pair<const char*, Split> files[] = {{"transforms_train.json", kTrain},
                                                     {"transforms_val.json", kVal},
                                                     {"transforms_test.json", kTest}};
      for (const auto& [name, split] : files) {
        if (!fs::is_regular_file(root / name, ec)) continue;
        if (absl::Status s = add_doc(root / name, split); !s.ok()) return s;
      }
    } else {
      if (absl::Status s = add_doc(root / "transforms.json", std::nullopt); !s.ok()) return s;
      if (absl::Status s = AssignSplits(opts.test_every, &refs); !s.ok()) return s;
    }
    if (absl::Status s = ReadHints(docs.front(), first_file, &scene); !s.ok()) return s;
    // nerfstudio's point cloud, relative to the JSON, in the JSON's frame.
    const json& head = docs.front();
    if (head.contains("ply_file_path")) {
      if (!head["ply_file_path"].is_string()) {
        return absl::InvalidArgumentError(absl::StrCat(first_file, ": field 'ply_file_path' must be a string"));
      }
      const fs::path ply = fs::path(first_file).parent_path() / head["ply_file_path"].get<std::string>();
      absl::StatusOr<std::vector<Eigen::Vector3f>> pts = ReadPlyPoints(ply.string());
      if (!pts.ok()) {
        return absl::InvalidArgumentError(absl::StrCat(first_file, ": 'ply_file_path': ", pts.status().message()));
      }
      scene.sparse_points = *std::move(pts);
    }

    std::vector<View>* outs[3] = {&scene.train, &scene.val, &scene.test};
    for (const FrameRef& ref : refs) {
      std::vector<View>* out = outs[ref.split];
      if (opts.max_images_per_split > 0 && int(out->size()) >= opts.max_images_per_split) continue;
      absl::StatusOr<View> view = LoadFrame(root, ref, opts, scene.background);
      if (!view.ok()) return view.status();
      out->push_back(*std::move(view));
    }
  } catch (const json::exception& e) {
    return absl::InvalidArgumentError(
        absl::StrCat(dir, ": invalid instant-ngp transforms: ", e.what()));
  }
  return scene;
}

}  // namespace clnerf
