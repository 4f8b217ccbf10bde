#include "core/data/colmap_loader.h"

#include <algorithm>
#include <bit>
#include <cctype>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/data/dataset.h"
#include "core/data/image.h"
#include "core/data/image_folder.h"
#include "Eigen/Geometry"

namespace clnerf {
namespace {

namespace fs = std::filesystem;
static_assert(std::endian::native == std::endian::little,
              "COLMAP binary reader assumes little-endian");

struct ModelInfo {
  int id;
  const char* name;
  int num_params;
};
// COLMAP's camera model table (src/colmap/sensor/models.h).
constexpr ModelInfo kModels[] = {{0, "SIMPLE_PINHOLE", 3},
                                 {1, "PINHOLE", 4},
                                 {2, "SIMPLE_RADIAL", 4},
                                 {3, "RADIAL", 5},
                                 {4, "OPENCV", 8},
                                 {5, "OPENCV_FISHEYE", 8},
                                 {6, "FULL_OPENCV", 12},
                                 {7, "FOV", 5},
                                 {8, "SIMPLE_RADIAL_FISHEYE", 4},
                                 {9, "RADIAL_FISHEYE", 5},
                                 {10, "THIN_PRISM_FISHEYE", 12}};

const ModelInfo* FindModel(int id) {
  for (const ModelInfo& m : kModels)
    if (m.id == id) return &m;
  return nullptr;
}
const ModelInfo* FindModel(const std::string& name) {
  for (const ModelInfo& m : kModels)
    if (name == m.name) return &m;
  return nullptr;
}

struct ColmapCamera {
  const ModelInfo* model = nullptr;
  int64_t width = 0, height = 0;
  std::vector<double> params;
};

struct ColmapImage {
  Eigen::Vector4d qvec;  // w, x, y, z (world-to-camera rotation).
  Eigen::Vector3d tvec;
  uint32_t camera_id = 0;
  std::string name;
};

using Cameras = std::map<uint32_t, ColmapCamera>;

absl::Status Invalid(const fs::path& file, const std::string& what) {
  return absl::InvalidArgumentError(absl::StrCat(file.string(), ": ", what));
}

absl::StatusOr<std::string> ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open ", path.string()));
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// ---- Binary format ---------------------------------------------------------

class BinaryReader {
 public:
  explicit BinaryReader(std::string data) : data_(std::move(data)) {}
  template <typename T>
  bool Read(T* v) {
    if (data_.size() - pos_ < sizeof(T)) return false;
    std::memcpy(v, data_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return true;
  }
  bool ReadString(std::string* s) {
    const size_t end = data_.find('\0', pos_);
    if (end == std::string::npos) return false;
    s->assign(data_, pos_, end - pos_);
    pos_ = end + 1;
    return true;
  }
  bool Skip(uint64_t n) {
    if (data_.size() - pos_ < n) return false;
    pos_ += n;
    return true;
  }
  size_t remaining() const { return data_.size() - pos_; }

 private:
  std::string data_;
  size_t pos_ = 0;
};

absl::StatusOr<Cameras> ReadCamerasBinary(const fs::path& path) {
  absl::StatusOr<std::string> data = ReadFile(path);
  if (!data.ok()) return data.status();
  BinaryReader r(*std::move(data));
  uint64_t n = 0;
  if (!r.Read(&n)) return Invalid(path, "truncated file (no camera count)");
  if (n > r.remaining() / 24)
    return Invalid(path, absl::StrCat("truncated file (claims ", n, " cameras)"));
  Cameras cams;
  for (uint64_t i = 0; i < n; ++i) {
    int32_t id, model_id;
    ColmapCamera cam;
    uint64_t w, h;
    if (!r.Read(&id) || !r.Read(&model_id) || !r.Read(&w) || !r.Read(&h)) {
      return Invalid(path, absl::StrCat("truncated file (camera ", i, ")"));
    }
    cam.model = FindModel(model_id);
    if (!cam.model) return Invalid(path, absl::StrCat("unknown camera model id ", model_id));
    cam.width = int64_t(w);
    cam.height = int64_t(h);
    cam.params.resize(cam.model->num_params);
    for (double& p : cam.params) {
      if (!r.Read(&p)) return Invalid(path, absl::StrCat("truncated file (camera ", i, " params)"));
    }
    cams[uint32_t(id)] = std::move(cam);
  }
  return cams;
}

absl::StatusOr<std::vector<ColmapImage>> ReadImagesBinary(const fs::path& path) {
  absl::StatusOr<std::string> data = ReadFile(path);
  if (!data.ok()) return data.status();
  BinaryReader r(*std::move(data));
  uint64_t n = 0;
  if (!r.Read(&n)) return Invalid(path, "truncated file (no image count)");
  if (n > r.remaining() / 64)
    return Invalid(path, absl::StrCat("truncated file (claims ", n, " images)"));
  std::vector<ColmapImage> images(n);
  for (uint64_t i = 0; i < n; ++i) {
    ColmapImage& im = images[i];
    uint32_t id;
    uint64_t num_points = 0;
    bool ok = r.Read(&id);
    for (int k = 0; k < 4; ++k) ok = ok && r.Read(&im.qvec[k]);
    for (int k = 0; k < 3; ++k) ok = ok && r.Read(&im.tvec[k]);
    ok = ok && r.Read(&im.camera_id) && r.ReadString(&im.name) && r.Read(&num_points);
    // Each 2D point: double x, double y, int64 point3D_id.
    ok = ok && num_points <= r.remaining() / 24 && r.Skip(num_points * 24);
    if (!ok) return Invalid(path, absl::StrCat("truncated file (image ", i, ")"));
  }
  return images;
}

using Points = std::vector<Eigen::Vector3f>;

absl::StatusOr<Points> ReadPointsBinary(const fs::path& path) {
  absl::StatusOr<std::string> data = ReadFile(path);
  if (!data.ok()) return data.status();
  BinaryReader r(*std::move(data));
  uint64_t n = 0;
  if (!r.Read(&n)) return Invalid(path, "truncated file (no point count)");
  // Each point: uint64 id, 3 double xyz, 3 uint8 rgb, double error, uint64
  // track length, then (uint32 image id, uint32 point2D index) per track entry.
  if (n > r.remaining() / 51)
    return Invalid(path, absl::StrCat("truncated file (claims ", n, " points)"));
  Points points(n);
  for (uint64_t i = 0; i < n; ++i) {
    uint64_t id, track = 0;
    double xyz[3], error;
    bool ok = r.Read(&id);
    for (double& v : xyz) ok = ok && r.Read(&v);
    ok = ok && r.Skip(3) && r.Read(&error) && r.Read(&track);
    ok = ok && track <= r.remaining() / 8 && r.Skip(track * 8);
    if (!ok) return Invalid(path, absl::StrCat("truncated file (point ", i, ")"));
    points[i] = Eigen::Vector3d(xyz[0], xyz[1], xyz[2]).cast<float>();
  }
  return points;
}

// ---- Text format -----------------------------------------------------------

std::vector<std::string> Tokens(const std::string& line) {
  std::istringstream ss(line);
  std::vector<std::string> out;
  for (std::string t; ss >> t;) out.push_back(t);
  return out;
}

template <typename T>
bool ParseNumber(const std::string& s, T* v) {
  const char* end = s.data() + s.size();
  auto [ptr, ec] = std::from_chars(s.data(), end, *v);
  return ec == std::errc() && ptr == end;
}

bool IsDataLine(const std::string& line) {
  const size_t first = line.find_first_not_of(" \t\r");
  return first != std::string::npos && line[first] != '#';
}

absl::StatusOr<Cameras> ReadCamerasText(const fs::path& path) {
  absl::StatusOr<std::string> data = ReadFile(path);
  if (!data.ok()) return data.status();
  std::istringstream in(*data);
  Cameras cams;
  int line_no = 0;
  for (std::string line; std::getline(in, line);) {
    ++line_no;
    if (!IsDataLine(line)) continue;
    const std::vector<std::string> t = Tokens(line);
    const std::string where = absl::StrCat("line ", line_no);
    uint32_t id;
    ColmapCamera cam;
    if (t.size() < 4 || !ParseNumber(t[0], &id) || !ParseNumber(t[2], &cam.width) ||
        !ParseNumber(t[3], &cam.height)) {
      return Invalid(path, absl::StrCat(where, ": expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"));
    }
    cam.model = FindModel(t[1]);
    if (!cam.model) return Invalid(path, absl::StrCat(where, ": unknown camera model ", t[1]));
    if (int(t.size()) != 4 + cam.model->num_params) {
      return Invalid(path,
                     absl::StrCat(where, ": ", t[1], " needs ", cam.model->num_params, " params"));
    }
    cam.params.resize(cam.model->num_params);
    for (int k = 0; k < cam.model->num_params; ++k) {
      if (!ParseNumber(t[4 + k], &cam.params[k])) {
        return Invalid(path, absl::StrCat(where, ": bad parameter '", t[4 + k], "'"));
      }
    }
    cams[id] = std::move(cam);
  }
  return cams;
}

absl::StatusOr<std::vector<ColmapImage>> ReadImagesText(const fs::path& path) {
  absl::StatusOr<std::string> data = ReadFile(path);
  if (!data.ok()) return data.status();
  std::istringstream in(*data);
  std::vector<ColmapImage> images;
  int line_no = 0;
  for (std::string line; std::getline(in, line);) {
    ++line_no;
    if (!IsDataLine(line)) continue;
    // IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME; the next line (POINTS2D,
    // possibly empty) belongs to the same image.
    const std::vector<std::string> t = Tokens(line);
    ColmapImage im;
    uint32_t id;
    bool ok = t.size() >= 10 && ParseNumber(t[0], &id) && ParseNumber(t[8], &im.camera_id);
    for (int k = 0; ok && k < 4; ++k) ok = ParseNumber(t[1 + k], &im.qvec[k]);
    for (int k = 0; ok && k < 3; ++k) ok = ParseNumber(t[5 + k], &im.tvec[k]);
    if (!ok) {
      return Invalid(path, absl::StrCat("line ", line_no,
                                        ": expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"));
    }
    im.name = t[9];
    for (size_t k = 10; k < t.size(); ++k) absl::StrAppend(&im.name, " ", t[k]);
    images.push_back(std::move(im));
    std::getline(in, line);  // POINTS2D[] (unused).
    ++line_no;
  }
  return images;
}

absl::StatusOr<Points> ReadPointsText(const fs::path& path) {
  absl::StatusOr<std::string> data = ReadFile(path);
  if (!data.ok()) return data.status();
  std::istringstream in(*data);
  Points points;
  int line_no = 0;
  for (std::string line; std::getline(in, line);) {
    ++line_no;
    if (!IsDataLine(line)) continue;
    // POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX) pairs.
    const std::vector<std::string> t = Tokens(line);
    uint64_t id;
    double xyz[3];
    bool ok = t.size() >= 8 && ParseNumber(t[0], &id);
    for (int k = 0; ok && k < 3; ++k) ok = ParseNumber(t[1 + k], &xyz[k]);
    if (!ok) {
      return Invalid(path, absl::StrCat("line ", line_no,
                                        ": expected POINT3D_ID X Y Z R G B ERROR TRACK[]"));
    }
    points.push_back(Eigen::Vector3d(xyz[0], xyz[1], xyz[2]).cast<float>());
  }
  return points;
}

// ---- Conversion ------------------------------------------------------------

absl::StatusOr<Intrinsics> ToIntrinsics(const ColmapCamera& cam) {
  Intrinsics in;
  in.width = int(std::clamp<int64_t>(cam.width, 0, 1 << 30));
  in.height = int(std::clamp<int64_t>(cam.height, 0, 1 << 30));
  const std::vector<double>& p = cam.params;
  const std::string model = cam.model->name;
  if (model == "SIMPLE_PINHOLE" || model == "SIMPLE_RADIAL" || model == "RADIAL") {
    in.fx = in.fy = float(p[0]);
    in.cx = float(p[1]);
    in.cy = float(p[2]);
    if (model != "SIMPLE_PINHOLE") in.k1 = float(p[3]);
    if (model == "RADIAL") in.k2 = float(p[4]);
  } else if (model == "PINHOLE" || model == "OPENCV") {
    in.fx = float(p[0]);
    in.fy = float(p[1]);
    in.cx = float(p[2]);
    in.cy = float(p[3]);
    if (model == "OPENCV") {
      in.k1 = float(p[4]);
      in.k2 = float(p[5]);
      in.p1 = float(p[6]);
      in.p2 = float(p[7]);
    }
  } else {
    return absl::InvalidArgumentError(
        absl::StrCat("unsupported COLMAP camera model ", model,
                     " (supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV)"));
  }
  return in;
}

Pose ToPose(const ColmapImage& im) {
  const Eigen::Matrix3d r_w2c = Eigen::Quaterniond(im.qvec[0], im.qvec[1], im.qvec[2], im.qvec[3])
                                    .normalized()
                                    .toRotationMatrix();
  Eigen::Matrix<double, 3, 4> c2w;
  c2w.leftCols<3>() = r_w2c.transpose();
  c2w.col(3) = -r_w2c.transpose() * im.tvec;
  return ConvertPose(c2w.cast<float>(), PoseConvention::kOpenCV);
}

// Natural order: digit runs compare by value ("2" < "10"); ties fall back to
// plain string order so the order is total.
bool NaturalLess(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  const auto digit = [](char c) { return std::isdigit(static_cast<unsigned char>(c)) != 0; };
  while (i < a.size() && j < b.size()) {
    if (digit(a[i]) && digit(b[j])) {
      size_t i2 = i, j2 = j;
      while (i2 < a.size() && digit(a[i2])) ++i2;
      while (j2 < b.size() && digit(b[j2])) ++j2;
      size_t i0 = i, j0 = j;  // Skip leading zeros.
      while (i0 + 1 < i2 && a[i0] == '0') ++i0;
      while (j0 + 1 < j2 && b[j0] == '0') ++j0;
      const std::string_view na(a.data() + i0, i2 - i0), nb(b.data() + j0, j2 - j0);
      if (na.size() != nb.size()) return na.size() < nb.size();
      if (na != nb) return na < nb;
      i = i2;
      j = j2;
    } else {
      if (a[i] != b[j]) return a[i] < b[j];
      ++i;
      ++j;
    }
  }
  if (a.size() - i != b.size() - j) return a.size() - i < b.size() - j;
  return a < b;
}

// Finds the model directory and reads it (binary preferred), including
// points3D when that folder has it.
absl::Status ReadModel(const fs::path& root, Cameras* cams, std::vector<ColmapImage>* images,
                       Points* points) {
  std::error_code ec;
  for (const fs::path& dir : {root / "sparse" / "0", root / "sparse"}) {
    const bool binary = fs::is_regular_file(dir / "cameras.bin", ec) &&
                        fs::is_regular_file(dir / "images.bin", ec);
    const bool text = fs::is_regular_file(dir / "cameras.txt", ec) &&
                      fs::is_regular_file(dir / "images.txt", ec);
    if (!binary && !text) continue;
    absl::StatusOr<Cameras> c =
        binary ? ReadCamerasBinary(dir / "cameras.bin") : ReadCamerasText(dir / "cameras.txt");
    if (!c.ok()) return c.status();
    absl::StatusOr<std::vector<ColmapImage>> i =
        binary ? ReadImagesBinary(dir / "images.bin") : ReadImagesText(dir / "images.txt");
    if (!i.ok()) return i.status();
    *cams = *std::move(c);
    *images = *std::move(i);
    points->clear();
    if (fs::is_regular_file(dir / "points3D.bin", ec)) {
      absl::StatusOr<Points> p = ReadPointsBinary(dir / "points3D.bin");
      if (!p.ok()) return p.status();
      *points = *std::move(p);
    } else if (fs::is_regular_file(dir / "points3D.txt", ec)) {
      absl::StatusOr<Points> p = ReadPointsText(dir / "points3D.txt");
      if (!p.ok()) return p.status();
      *points = *std::move(p);
    }
    return absl::OkStatus();
  }
  return absl::NotFoundError(
      absl::StrCat("no COLMAP model in ", root.string(),
                   ": expected sparse/0/ or sparse/ with cameras.{bin,txt} and images.{bin,txt}"));
}

}  // namespace

absl::StatusOr<Scene> LoadColmapScene(const std::string& dir, const DatasetOptions& opts) {
  if (absl::Status s = CheckDatasetDir(dir, opts); !s.ok()) return s;
  const fs::path root(dir);
  Cameras cams;
  std::vector<ColmapImage> images;
  Points points;
  if (absl::Status s = ReadModel(root, &cams, &images, &points); !s.ok()) return s;
  absl::StatusOr<ImageFolder> image_folder =
      FindImageFolder(root, opts.images_dir, opts.downscale);
  if (!image_folder.ok()) return image_folder.status();
  // View names are relative to the dataset directory ("images/a.png",
  // "../images/a.png").
  fs::path folder_name = image_folder->path.lexically_relative(root.lexically_normal());
  if (folder_name.empty()) folder_name = image_folder->path;

  Scene scene;
  scene.name = DatasetName(dir);
  scene.kind = SceneKind::kUnbounded;
  scene.background = Eigen::Vector3f::Zero();
  scene.sparse_points = points;
  scene.content_points = std::move(points);

  // Time steps: rank of the image's subfolder among all subfolders.
  const auto folder = [](const ColmapImage& im) {
    return fs::path(im.name).parent_path().generic_string();
  };
  std::vector<std::string> folders;
  for (const ColmapImage& im : images) folders.push_back(folder(im));
  std::sort(folders.begin(), folders.end(), NaturalLess);
  folders.erase(std::unique(folders.begin(), folders.end()), folders.end());
  const auto time_step = [&](const ColmapImage& im) {
    return int(std::lower_bound(folders.begin(), folders.end(), folder(im), NaturalLess) -
               folders.begin());
  };
  std::sort(images.begin(), images.end(), [&](const ColmapImage& a, const ColmapImage& b) {
    const int ta = time_step(a), tb = time_step(b);
    return ta != tb ? ta < tb : NaturalLess(a.name, b.name);
  });

  int prev_step = -1, index_in_step = 0;
  for (const ColmapImage& im : images) {
    const int step = time_step(im);
    index_in_step = step == prev_step ? index_in_step + 1 : 0;
    prev_step = step;
    const bool is_test = opts.test_every > 0 && index_in_step % opts.test_every == 0;
    std::vector<View>& out = is_test ? scene.test : scene.train;
    if (opts.max_images_per_split > 0 && int(out.size()) >= opts.max_images_per_split) continue;

    const std::string ctx = absl::StrCat(dir, ": image '", im.name, "'");
    const auto cam = cams.find(im.camera_id);
    if (cam == cams.end()) {
      return absl::InvalidArgumentError(absl::StrCat(ctx, ": unknown camera id ", im.camera_id));
    }
    absl::StatusOr<Intrinsics> in = ToIntrinsics(cam->second);
    if (!in.ok()) return absl::InvalidArgumentError(absl::StrCat(ctx, ": ", in.status().message()));
    View view;
    view.name = (folder_name / im.name).generic_string();
    view.camera.intrinsics = *in;
    view.camera.c2w = ToPose(im);
    view.camera.time_step = step;
    const fs::path image_path = image_folder->path / im.name;
    float residual = image_folder->residual_downscale;
    const auto annotate = [&](const absl::Status& s) {
      return absl::Status(s.code(), absl::StrCat(ctx, ": ", s.message()));
    };
    if (opts.load_images) {
      absl::StatusOr<Image> image = ReadImage(image_path.string(), scene.background);
      if (!image.ok()) return annotate(image.status());
      view.image = *std::move(image);
      absl::Status s = ScaleIntrinsicsToImage(view.image.width, view.image.height,
                                              image_path.string(), &view.camera.intrinsics);
      if (!s.ok()) return annotate(s);
    } else if (std::error_code ec; fs::is_regular_file(image_path, ec)) {
      absl::StatusOr<ImageSize> size = ReadImageSize(image_path.string());
      if (!size.ok()) return annotate(size.status());
      absl::Status s = ScaleIntrinsicsToImage(size->width, size->height, image_path.string(),
                                              &view.camera.intrinsics);
      if (!s.ok()) return annotate(s);
    } else {
      residual = opts.downscale;  // Camera-only: the calibration's size, shrunk as asked.
    }
    DownscaleView(residual, &view);
    out.push_back(std::move(view));
  }
  return scene;
}

}  // namespace clnerf
