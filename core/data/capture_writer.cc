#include "core/data/capture_writer.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/data/content_sweep.h"
#include "core/data/image.h"
#include "Eigen/Geometry"
#include "nlohmann/json.hpp"

namespace clnerf {

namespace fs = std::filesystem;

const char* CaptureFormatName(CaptureFormat format) {
  switch (format) {
    case CaptureFormat::kNgp:
      return "ngp";
    case CaptureFormat::kColmap:
      return "colmap";
    case CaptureFormat::kLlff:
      return "llff";
  }
  return "?";
}

namespace {

absl::Status WriteText(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
  out.close();
  if (!out) return absl::InternalError(absl::StrCat("cannot write '", path.string(), "'"));
  return absl::OkStatus();
}

// A minimal NPY v1.0 writer for a 2-D little-endian float64 array.
absl::Status WriteNpy(const fs::path& path, const std::vector<double>& data, int rows, int cols) {
  std::string header = absl::StrFormat("{'descr': '<f8', 'fortran_order': False, 'shape': (%d, %d), }", rows, cols);
  // Magic (6) + version (2) + header length (2) + header + '\n', padded to 64.
  const size_t unpadded = 10 + header.size() + 1;
  header.append((64 - unpadded % 64) % 64, ' ');
  header.push_back('\n');
  std::string out("\x93NUMPY\x01\x00", 8);
  const uint16_t len = uint16_t(header.size());
  out.push_back(char(len & 0xff));
  out.push_back(char(len >> 8));
  out += header;
  const size_t at = out.size();
  out.resize(at + data.size() * sizeof(double));
  std::memcpy(out.data() + at, data.data(), data.size() * sizeof(double));  // Little-endian hosts only (x86-64).
  return WriteText(path, out);
}

}  // namespace

absl::Status WriteCapture(const Scene& scene, CaptureFormat format, const std::string& dir) {
  std::vector<const View*> views;
  for (const View& v : scene.train) views.push_back(&v);
  for (const View& v : scene.test) views.push_back(&v);
  if (views.empty()) return absl::InvalidArgumentError("capture writer: the scene has no views");
  for (const View* v : views) {
    if (v->image.empty()) return absl::InvalidArgumentError(absl::StrCat("capture writer: view '", v->name, "' has no image"));
    const Intrinsics& in = v->camera.intrinsics;
    if (format == CaptureFormat::kLlff &&
        (in.fx != in.fy || std::abs(in.cx - 0.5f * in.width) > 1e-3f || std::abs(in.cy - 0.5f * in.height) > 1e-3f)) {
      return absl::InvalidArgumentError(absl::StrCat(
          "capture writer: LLFF holds one focal length and a centred principal point; view '", v->name, "' has neither"));
    }
  }
  std::error_code ec;
  const fs::path root(dir);
  fs::create_directories(root / "images", ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create '", (root / "images").string(), "': ", ec.message()));
  std::vector<std::string> names;
  for (size_t i = 0; i < views.size(); ++i) {
    names.push_back(absl::StrFormat("%04d.png", int(i)));
    if (absl::Status s = WriteImage((root / "images" / names.back()).string(), views[i]->image); !s.ok()) return s;
  }

  if (format == CaptureFormat::kNgp) {
    const Intrinsics& in0 = views[0]->camera.intrinsics;
    nlohmann::json j = {{"fl_x", in0.fx}, {"fl_y", in0.fy}, {"cx", in0.cx}, {"cy", in0.cy},
                        {"w", in0.width}, {"h", in0.height}, {"aabb_scale", 16}};
    nlohmann::json frames = nlohmann::json::array();
    for (size_t i = 0; i < views.size(); ++i) {
      const Camera& c = views[i]->camera;
      const Pose gl = ExportPose(c.c2w, PoseConvention::kOpenGL);
      nlohmann::json m = nlohmann::json::array();
      for (int r = 0; r < 3; ++r) m.push_back({gl(r, 0), gl(r, 1), gl(r, 2), gl(r, 3)});
      m.push_back({0.0, 0.0, 0.0, 1.0});
      nlohmann::json f = {{"file_path", "images/" + names[i]}, {"transform_matrix", m}};
      const Intrinsics& in = c.intrinsics;
      if (in.fx != in0.fx || in.fy != in0.fy || in.cx != in0.cx || in.cy != in0.cy || in.width != in0.width ||
          in.height != in0.height) {
        f["fl_x"] = in.fx;
        f["fl_y"] = in.fy;
        f["cx"] = in.cx;
        f["cy"] = in.cy;
        f["w"] = in.width;
        f["h"] = in.height;
      }
      frames.push_back(f);
    }
    j["frames"] = frames;
    if (!scene.sparse_points.empty()) {  // nerfstudio's point-cloud key, an ASCII PLY.
      std::string ply = absl::StrFormat("ply\nformat ascii 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
                                        "property float z\nend_header\n",
                                        int(scene.sparse_points.size()));
      for (const Eigen::Vector3f& p : scene.sparse_points) absl::StrAppendFormat(&ply, "%.9g %.9g %.9g\n", p.x(), p.y(), p.z());
      if (absl::Status s = WriteText(root / "points.ply", ply); !s.ok()) return s;
      j["ply_file_path"] = "points.ply";
    }
    return WriteText(root / "transforms.json", j.dump(2));
  }

  if (format == CaptureFormat::kColmap) {
    const fs::path sparse = root / "sparse" / "0";
    fs::create_directories(sparse, ec);
    if (ec) return absl::InternalError(absl::StrCat("cannot create '", sparse.string(), "': ", ec.message()));
    std::string cameras = "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
    std::string images = "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n# POINTS2D[]\n";
    for (size_t i = 0; i < views.size(); ++i) {
      const Camera& c = views[i]->camera;
      const Intrinsics& in = c.intrinsics;
      absl::StrAppendFormat(&cameras, "%d PINHOLE %d %d %.9g %.9g %.9g %.9g\n", int(i + 1), in.width, in.height,
                            in.fx, in.fy, in.cx, in.cy);
      const Eigen::Matrix3d r_c2w = c.c2w.leftCols<3>().cast<double>();
      const Eigen::Matrix3d r_w2c = r_c2w.transpose();
      const Eigen::Vector3d t = -r_w2c * c.c2w.col(3).cast<double>();
      const Eigen::Quaterniond q(r_w2c);
      absl::StrAppendFormat(&images, "%d %.12g %.12g %.12g %.12g %.12g %.12g %.12g %d %s\n\n", int(i + 1), q.w(), q.x(),
                            q.y(), q.z(), t.x(), t.y(), t.z(), int(i + 1), names[i]);
    }
    if (absl::Status s = WriteText(sparse / "cameras.txt", cameras); !s.ok()) return s;
    if (!scene.sparse_points.empty()) {  // Without tracks: the loaders read only the positions.
      std::string pts = "# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n";
      for (size_t k = 0; k < scene.sparse_points.size(); ++k) {
        const Eigen::Vector3f& p = scene.sparse_points[k];
        absl::StrAppendFormat(&pts, "%d %.9g %.9g %.9g 128 128 128 1\n", int(k + 1), p.x(), p.y(), p.z());
      }
      if (absl::Status s = WriteText(sparse / "points3D.txt", pts); !s.ok()) return s;
    }
    return WriteText(sparse / "images.txt", images);
  }

  // LLFF: bounds from the images' own content points, per camera.
  std::vector<View> all;
  for (const View* v : views) all.push_back(*v);
  const std::vector<Eigen::Vector3f> points =
      scene.sparse_points.empty() ? EstimateContentPoints(all) : scene.sparse_points;
  std::vector<double> rows;
  for (const View* v : views) {
    const Camera& c = v->camera;
    const Eigen::Vector3f centre = c.c2w.col(3), forward = c.c2w.col(2);
    std::vector<float> depth;
    for (const Eigen::Vector3f& p : points) {
      const float z = (p - centre).dot(forward);
      if (z > 1e-6f && std::isfinite(z)) depth.push_back(z);
    }
    double near = 0.1, far = 100.0;  // No content found: LLFF's usual guess in camera units.
    if (!depth.empty()) {
      std::sort(depth.begin(), depth.end());
      near = depth[size_t(0.001 * (depth.size() - 1))];
      far = std::max(double(depth[size_t(0.999 * (depth.size() - 1))]), near);
    }
    const Intrinsics& in = c.intrinsics;
    for (int r = 0; r < 3; ++r) {
      rows.push_back(c.c2w(r, 1));   // down.
      rows.push_back(c.c2w(r, 0));   // right.
      rows.push_back(-c.c2w(r, 2));  // back.
      rows.push_back(c.c2w(r, 3));   // centre.
      rows.push_back(r == 0 ? in.height : r == 1 ? in.width : in.fx);
    }
    rows.push_back(near);
    rows.push_back(far);
  }
  return WriteNpy(root / "poses_bounds.npy", rows, int(views.size()), 17);
}

}  // namespace clnerf
