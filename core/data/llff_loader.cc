#include "core/data/llff_loader.h"

#include <cmath>
#include <filesystem>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/data/dataset.h"
#include "core/data/image.h"
#include "core/data/image_folder.h"
#include "core/data/npy_reader.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

constexpr int kColumns = 17;  // 3x5 pose-hwf matrix + near + far.

// Row `i` of poses_bounds as an OpenCV camera-to-world pose.
Pose ToPose(const NpyArray& a, int64_t i) {
  const auto m = [&](int r, int c) { return float(a.at(i, r * 5 + c)); };
  Pose c2w;
  for (int r = 0; r < 3; ++r) {
    c2w(r, 0) = m(r, 1);   // right = LLFF column 1.
    c2w(r, 1) = m(r, 0);   // down = LLFF column 0.
    c2w(r, 2) = -m(r, 2);  // forward = -(LLFF "backwards" column 2).
    c2w(r, 3) = m(r, 3);   // centre.
  }
  return c2w;
}

}  // namespace

absl::StatusOr<Scene> LoadLlffScene(const std::string& dir, const DatasetOptions& opts) {
  if (absl::Status s = CheckDatasetDir(dir, opts); !s.ok()) return s;
  const fs::path root(dir);
  const fs::path npy_path = root / "poses_bounds.npy";
  absl::StatusOr<NpyArray> npy = ReadNpy(npy_path.string());
  if (!npy.ok()) return npy.status();
  if (npy->shape.size() != 2 || npy->shape[1] != kColumns || npy->shape[0] < 1) {
    std::string shape;
    for (int64_t d : npy->shape) absl::StrAppend(&shape, shape.empty() ? "" : ", ", d);
    return absl::InvalidArgumentError(
        absl::StrCat(npy_path.string(), ": expected shape (N, 17) with N >= 1, got (", shape, ")"));
  }
  const int64_t n = npy->shape[0];

  absl::StatusOr<ImageFolder> folder = FindImageFolder(root, opts.images_dir, opts.downscale);
  if (!folder.ok()) return folder.status();
  absl::StatusOr<std::vector<std::string>> files = ListImageFiles(folder->path);
  if (!files.ok()) return files.status();
  if (int64_t(files->size()) != n) {
    return absl::InvalidArgumentError(absl::StrCat(npy_path.string(), " has ", n, " poses but ",
                                                   folder->path.string(), " has ", files->size(),
                                                   " images"));
  }
  fs::path folder_name = folder->path.lexically_relative(root.lexically_normal());
  if (folder_name.empty()) folder_name = folder->path;

  Scene scene;
  scene.name = DatasetName(dir);
  scene.kind = SceneKind::kUnbounded;
  scene.background = Eigen::Vector3f::Zero();

  for (int64_t i = 0; i < n; ++i) {
    const std::string row_ctx = absl::StrCat(npy_path.string(), ": row ", i);
    const double h = npy->at(i, 4), w = npy->at(i, 9), f = npy->at(i, 14);
    const double near = npy->at(i, 15), far = npy->at(i, 16);
    if (!(h >= 1 && w >= 1 && f > 0 && h < (1 << 30) && w < (1 << 30) && std::isfinite(f))) {
      return absl::InvalidArgumentError(
          absl::StrCat(row_ctx, ": h, w, f must be positive, got ", h, ", ", w, ", ", f));
    }
    if (!(near > 0 && far >= near && std::isfinite(far))) {
      return absl::InvalidArgumentError(
          absl::StrCat(row_ctx, ": bounds must satisfy 0 < near <= far, got ", near, ", ", far));
    }
    const Pose c2w = ToPose(*npy, i);
    const Eigen::Vector3f centre = c2w.col(3), forward = c2w.col(2);
    scene.content_points.push_back(centre + float(near) * forward);
    scene.content_points.push_back(centre + float(std::sqrt(near * far)) * forward);

    const bool is_test = opts.test_every > 0 && i % opts.test_every == 0;
    std::vector<View>& out = is_test ? scene.test : scene.train;
    if (opts.max_images_per_split > 0 && int(out.size()) >= opts.max_images_per_split) continue;

    const std::string& file = (*files)[size_t(i)];
    const fs::path image_path = folder->path / file;
    const std::string ctx = absl::StrCat(dir, ": image '", file, "'");
    const auto annotate = [&](const absl::Status& s) {
      return absl::Status(s.code(), absl::StrCat(ctx, ": ", s.message()));
    };
    View view;
    view.name = (folder_name / file).generic_string();
    view.camera.c2w = c2w;
    Intrinsics& in = view.camera.intrinsics;
    in.width = int(std::lround(w));
    in.height = int(std::lround(h));
    in.fx = in.fy = float(f);
    in.cx = float(0.5 * w);
    in.cy = float(0.5 * h);
    if (opts.load_images) {
      absl::StatusOr<Image> image = ReadImage(image_path.string(), scene.background);
      if (!image.ok()) return annotate(image.status());
      view.image = *std::move(image);
      if (absl::Status s =
              ScaleIntrinsicsToImage(view.image.width, view.image.height, image_path.string(), &in);
          !s.ok()) {
        return annotate(s);
      }
    } else {
      absl::StatusOr<ImageSize> size = ReadImageSize(image_path.string());
      if (!size.ok()) return annotate(size.status());
      if (absl::Status s =
              ScaleIntrinsicsToImage(size->width, size->height, image_path.string(), &in);
          !s.ok()) {
        return annotate(s);
      }
    }
    DownscaleView(folder->residual_downscale, &view);
    out.push_back(std::move(view));
  }
  return scene;
}

}  // namespace clnerf
