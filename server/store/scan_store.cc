#include "server/store/scan_store.h"

#include <cstring>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <set>

#include "absl/strings/str_cat.h"
#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "core/io/durable_file.h"
#include "core/data/image.h"
#include "core/data/sparse_depth.h"
#include "nlohmann/json.hpp"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace fs = std::filesystem;

namespace {

constexpr char kTmpPrefix[] = ".tmp-";

nlohmann::json CameraToJson(const Camera& c) {
  nlohmann::json pose = nlohmann::json::array();
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 4; ++k) pose.push_back(c.c2w(r, k));
  const Intrinsics& in = c.intrinsics;
  return {{"pose_opencv", pose},
          {"width", in.width}, {"height", in.height},
          {"fx", in.fx}, {"fy", in.fy}, {"cx", in.cx}, {"cy", in.cy},
          {"k1", in.k1}, {"k2", in.k2}, {"p1", in.p1}, {"p2", in.p2}};
}

Camera CameraFromJson(const nlohmann::json& j) {
  Camera c;
  const auto& pose = j.at("pose_opencv");
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 4; ++k) c.c2w(r, k) = pose.at(r * 4 + k).get<float>();
  Intrinsics& in = c.intrinsics;
  in.width = j.at("width");
  in.height = j.at("height");
  in.fx = j.at("fx");
  in.fy = j.at("fy");
  in.cx = j.at("cx");
  in.cy = j.at("cy");
  in.k1 = j.at("k1");
  in.k2 = j.at("k2");
  in.p1 = j.at("p1");
  in.p2 = j.at("p2");
  return c;
}

std::string FrameFile(int i, bool mask, const std::string& ext) {
  return absl::StrFormat("%s_%05d%s", mask ? "mask" : "frame", i, ext);
}

absl::Status FrameError(const ScanFrame& f, size_t i, const absl::Status& s) {
  return absl::InvalidArgumentError(absl::StrCat(f.test ? "test " : "", "frame ", i, " ('", f.name, "'): ", s.message()));
}

}  // namespace

namespace {

// One frame: camera (when posed), image, its size, its pixels, its mask.
// `size` is the image's width and height, for the caller's checks.
absl::Status ValidateFrame(const ScanFrame& f, bool mask_nonzero_is_exclude, Eigen::Vector2i* size) {
  if (f.posed) {
    if (absl::Status s = ValidateCamera(f.camera); !s.ok()) return s;
  }
  const std::string ext = SniffImageExtension(f.image);
  if (ext.empty()) return absl::InvalidArgumentError("image is not PNG, JPEG, EXR, TIFF or BMP");
  absl::StatusOr<Image> img = DecodeImage(f.image, f.name + ext);
  if (!img.ok()) return img.status();
  *size = {img->width, img->height};
  if (f.posed && (img->width != f.camera.intrinsics.width || img->height != f.camera.intrinsics.height)) {
    return absl::InvalidArgumentError(absl::StrCat("image is ", img->width, "x", img->height,
                                                   " but the intrinsics say ", f.camera.intrinsics.width, "x",
                                                   f.camera.intrinsics.height));
  }
  for (float v : img->rgb) {
    if (!std::isfinite(v)) return absl::InvalidArgumentError("image has non-finite pixels");
  }
  if (f.mask.empty()) return absl::OkStatus();
  const std::string mext = SniffImageExtension(f.mask);
  if (mext.empty()) return absl::InvalidArgumentError("mask is not a known image format");
  absl::StatusOr<Mask> m = DecodeMask(f.mask, f.name + "_mask" + mext, mask_nonzero_is_exclude);
  if (!m.ok()) return m.status();
  if (m->width != img->width || m->height != img->height) {
    return absl::InvalidArgumentError(
        absl::StrCat("mask is ", m->width, "x", m->height, " but the image is ", img->width, "x", img->height));
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ValidateScanUpload(const ScanUpload& scan) {
  if (scan.frames.empty()) return absl::InvalidArgumentError("scan has no frames");
  for (size_t i = 0; i < scan.points.size(); ++i) {
    if (!scan.points[i].allFinite()) return absl::InvalidArgumentError(absl::StrCat("point ", i, " is not finite"));
  }
  const bool unposed = !scan.frames[0].posed;
  if (unposed && !scan.points.empty()) {
    return absl::InvalidArgumentError("an unposed scan cannot carry points (they would have no frame)");
  }
  if (unposed && int(scan.frames.size()) < kMinUnposedFrames) {
    return absl::InvalidArgumentError(absl::StrCat("an unposed scan needs at least ", kMinUnposedFrames,
                                                   " frames to be posed, not ", scan.frames.size()));
  }
  int train = 0;
  std::set<std::string> names;
  Eigen::Vector2i first_size(0, 0);
  for (size_t i = 0; i < scan.frames.size(); ++i) {
    const ScanFrame& f = scan.frames[i];
    if (!f.test) ++train;
    if (!names.insert(f.name).second) {
      return absl::InvalidArgumentError(absl::StrCat("frame name '", f.name, "' appears twice"));
    }
    if (f.posed == unposed) {
      return FrameError(f, i, absl::InvalidArgumentError(
                                  "a scan's frames must be all posed or all unposed (this one is not like frame 0)"));
    }
    Eigen::Vector2i size(0, 0);
    if (absl::Status s = ValidateFrame(f, scan.mask_nonzero_is_exclude, &size); !s.ok()) return FrameError(f, i, s);
    if (i == 0) first_size = size;
    if (unposed && size != first_size) {
      return FrameError(f, i, absl::InvalidArgumentError(absl::StrCat(
                                  "image is ", size.x(), "x", size.y(), " but frame 0 is ", first_size.x(), "x",
                                  first_size.y(), " (an unposed scan is one camera: every image the same size)")));
    }
  }
  if (train == 0) return absl::InvalidArgumentError("scan has only test frames; at least one training frame is needed");
  if (!scan.scene_kind.empty() && scan.scene_kind != "bounded" && scan.scene_kind != "unbounded") {
    return absl::InvalidArgumentError(absl::StrCat("scene_kind '", scan.scene_kind, "' is not bounded|unbounded"));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<ScanStore>> ScanStore::Open(const std::string& root, bool clean_temps) {
  const std::string dir = (fs::path(root) / "scans").string();
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create '", dir, "': ", ec.message()));
  if (clean_temps) RemoveTempEntries(dir);
  return std::unique_ptr<ScanStore>(new ScanStore(dir));
}

absl::Status ScanStore::Save(const ScanRecord& record, const ScanUpload& scan) {
  std::vector<std::pair<std::string, std::string_view>> files;
  nlohmann::json frames = nlohmann::json::array();
  for (size_t i = 0; i < scan.frames.size(); ++i) {
    const ScanFrame& f = scan.frames[i];
    nlohmann::json fj = {{"name", f.name}, {"test", f.test}};
    if (f.posed) fj["camera"] = CameraToJson(f.camera);
    fj["image"] = FrameFile(int(i), false, SniffImageExtension(f.image));
    files.emplace_back(fj["image"], f.image);
    if (!f.mask.empty()) {
      fj["mask"] = FrameFile(int(i), true, SniffImageExtension(f.mask));
      files.emplace_back(fj["mask"], f.mask);
    }
    frames.push_back(std::move(fj));
  }
  // Points: raw little-endian float32 x y z.
  const std::string_view points_bytes(reinterpret_cast<const char*>(scan.points.data()),
                                      scan.points.size() * sizeof(Eigen::Vector3f));
  if (!scan.points.empty()) files.emplace_back("points.f32", points_bytes);
  nlohmann::json j = {{"scan_id", record.scan_id},
                            {"job_id", record.job_id},
                            {"name", record.name},
                            {"scene_kind", record.scene_kind},
                            {"mask_nonzero_is_exclude", record.mask_nonzero_is_exclude},
                            {"pose_frame", record.pose_frame},
                            {"sequential", record.sequential},
                            {"created_unix_ms", record.created_unix_ms},
                            {"num_frames", record.num_frames},
                            {"num_test_frames", record.num_test_frames},
                            {"num_bytes", record.num_bytes},
                            {"frames", frames}};
  if (!scan.points.empty()) {
    j["points"] = "points.f32";
    j["num_points"] = scan.points.size();
  }
  const std::string manifest = j.dump(1);
  files.emplace_back("scan.json", manifest);
  absl::Status s = WriteDirectoryAtomically((fs::path(dir_) / record.scan_id).string(), files);
  if (!s.ok()) return absl::Status(s.code(), absl::StrCat("cannot store scan ", record.scan_id, ": ", s.message()));
  return absl::OkStatus();
}

namespace {

absl::StatusOr<nlohmann::json> ReadScanJson(const fs::path& dir) {
  absl::StatusOr<std::string> text = ReadFileToString((dir / "scan.json").string(), "scan manifest");
  if (!text.ok()) return text.status();
  try {
    return nlohmann::json::parse(*text);
  } catch (const std::exception& e) {
    return absl::DataLossError(absl::StrCat("corrupt ", (dir / "scan.json").string(), ": ", e.what()));
  }
}

// The record of the scan in `dir`, from its scan.json.
absl::StatusOr<ScanRecord> ReadScanRecord(const fs::path& dir) {
  absl::StatusOr<nlohmann::json> j = ReadScanJson(dir);
  if (!j.ok()) return j.status();
  try {
    ScanRecord r;
    r.scan_id = j->at("scan_id");
    r.job_id = j->at("job_id");
    r.name = j->at("name");
    r.scene_kind = j->at("scene_kind");
    r.mask_nonzero_is_exclude = j->at("mask_nonzero_is_exclude");
    r.pose_frame = j->value("pose_frame", std::string("place"));
    r.sequential = j->value("sequential", false);
    r.created_unix_ms = j->at("created_unix_ms");
    r.num_frames = j->at("num_frames");
    r.num_test_frames = j->at("num_test_frames");
    r.num_bytes = j->at("num_bytes");
    return r;
  } catch (const std::exception& ex) {
    return absl::DataLossError(absl::StrCat("corrupt scan manifest in ", dir.string(), ": ", ex.what()));
  }
}

}  // namespace

absl::StatusOr<ScanRecord> ScanStore::Record(const std::string& scan_id) const {
  const fs::path dir = fs::path(dir_) / scan_id;
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return absl::NotFoundError(absl::StrCat("scan ", scan_id, " is not stored"));
  return ReadScanRecord(dir);
}

absl::StatusOr<std::vector<ScanRecord>> ScanStore::List() const {
  std::vector<ScanRecord> out;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir_, ec)) {
    const std::string name = e.path().filename().string();
    if (!e.is_directory() || name.rfind(kTmpPrefix, 0) == 0) continue;
    absl::StatusOr<ScanRecord> r = ReadScanRecord(e.path());
    // Removed (trained, cancelled or parked) by another replica or thread
    // between the directory read and this one: not in the store any more.
    if (!r.ok() && absl::IsNotFound(r.status()) && !fs::exists(e.path())) continue;
    if (!r.ok()) return r.status();
    out.push_back(*std::move(r));
  }
  if (ec) return absl::InternalError(absl::StrCat("cannot list '", dir_, "': ", ec.message()));
  std::sort(out.begin(), out.end(), [](const ScanRecord& a, const ScanRecord& b) { return a.scan_id < b.scan_id; });
  return out;
}

absl::StatusOr<Scene> ScanStore::Load(const std::string& scan_id, int time_step,
                                      const std::optional<Eigen::Vector3f>& background) const {
  const fs::path dir = fs::path(dir_) / scan_id;
  absl::StatusOr<nlohmann::json> j = ReadScanJson(dir);
  if (!j.ok()) return j.status();
  Scene scene;
  try {
    scene.name = j->at("name");
    scene.kind = j->at("scene_kind") == "unbounded" ? SceneKind::kUnbounded : SceneKind::kBounded;
    scene.background = background.value_or(scene.kind == SceneKind::kUnbounded ? Eigen::Vector3f::Zero()
                                                                                : Eigen::Vector3f::Ones());
    const bool nonzero_excl = j->at("mask_nonzero_is_exclude");
    for (const auto& fj : j->at("frames")) {
      View v;
      v.name = fj.at("name");
      if (!fj.contains("camera")) {
        return absl::FailedPreconditionError(absl::StrCat("scan ", scan_id, " is not posed yet"));
      }
      v.camera = CameraFromJson(fj.at("camera"));
      v.camera.time_step = time_step;
      const std::string img_file = fj.at("image");
      absl::StatusOr<std::string> bytes = ReadFileToString((dir / img_file).string(), "scan image");
      if (!bytes.ok()) return bytes.status();
      absl::StatusOr<Image> img = DecodeImage(*bytes, img_file, scene.background);
      if (!img.ok()) return img.status();
      v.image = *std::move(img);
      if (fj.contains("mask")) {
        const std::string mask_file = fj.at("mask");
        absl::StatusOr<std::string> mb = ReadFileToString((dir / mask_file).string(), "scan mask");
        if (!mb.ok()) return mb.status();
        absl::StatusOr<Mask> m = DecodeMask(*mb, mask_file, nonzero_excl);
        if (!m.ok()) return m.status();
        v.mask = *std::move(m);
      }
      (fj.at("test").get<bool>() ? scene.test : scene.train).push_back(std::move(v));
    }
    if (j->contains("points")) {
      const std::string file = j->at("points");
      const size_t n = j->at("num_points");
      absl::StatusOr<std::string> bytes = ReadFileToString((dir / file).string(), "scan points");
      if (!bytes.ok()) return bytes.status();
      if (bytes->size() != n * sizeof(Eigen::Vector3f)) {
        return absl::DataLossError(absl::StrCat("corrupt scan ", scan_id, ": ", file, " holds ", bytes->size(),
                                                " bytes, not ", n, " points"));
      }
      scene.sparse_points.resize(n);
      std::memcpy(static_cast<void*>(scene.sparse_points.data()), bytes->data(), bytes->size());
      for (const Eigen::Vector3f& p : scene.sparse_points) {
        if (!p.allFinite()) return absl::DataLossError(absl::StrCat("corrupt scan ", scan_id, ": a point is not finite"));
      }
      AttachSparseDepth(scene.sparse_points, SparseDepthOptions(), &scene.train);
    }
  } catch (const std::exception& e) {
    return absl::DataLossError(absl::StrCat("corrupt scan ", scan_id, ": ", e.what()));
  }
  return scene;
}

absl::StatusOr<std::vector<std::string>> ScanStore::ImageFiles(const std::string& scan_id) const {
  const fs::path dir = fs::path(dir_) / scan_id;
  absl::StatusOr<nlohmann::json> j = ReadScanJson(dir);
  if (!j.ok()) return j.status();
  std::vector<std::string> out;
  try {
    for (const auto& fj : j->at("frames")) out.push_back((dir / fj.at("image").get<std::string>()).string());
  } catch (const std::exception& e) {
    return absl::DataLossError(absl::StrCat("corrupt scan ", scan_id, ": ", e.what()));
  }
  return out;
}

absl::Status ScanStore::SetPoses(const std::string& scan_id, const std::vector<std::optional<Camera>>& cameras,
                                 const std::vector<Eigen::Vector3f>& points) {
  const fs::path dir = fs::path(dir_) / scan_id;
  absl::StatusOr<nlohmann::json> j = ReadScanJson(dir);
  if (!j.ok()) return j.status();
  try {
    const nlohmann::json& in = j->at("frames");
    if (in.size() != cameras.size()) {
      return absl::InvalidArgumentError(absl::StrCat("scan ", scan_id, " has ", in.size(), " frames, not ",
                                                     cameras.size()));
    }
    nlohmann::json kept = nlohmann::json::array();
    int train = 0, test = 0;
    for (size_t i = 0; i < in.size(); ++i) {
      if (!cameras[i]) continue;
      nlohmann::json fj = in[i];
      fj["camera"] = CameraToJson(*cameras[i]);
      (fj.at("test").get<bool>() ? test : train)++;
      kept.push_back(std::move(fj));
    }
    if (train == 0) {
      return absl::FailedPreconditionError(absl::StrCat("no training frame of scan ", scan_id, " was posed"));
    }
    (*j)["frames"] = std::move(kept);
    (*j)["num_frames"] = train;
    (*j)["num_test_frames"] = test;
    (*j)["pose_frame"] = "own";
    (*j)["posed_by_server"] = true;
    if (j->at("scene_kind").get<std::string>().empty()) (*j)["scene_kind"] = "unbounded";
    j->erase("points");
    j->erase("num_points");
    if (!points.empty()) {
      const std::string_view bytes(reinterpret_cast<const char*>(points.data()), points.size() * sizeof(points[0]));
      if (absl::Status s = WriteFileSynced((dir / "points.f32").string(), bytes); !s.ok()) return s;
      (*j)["points"] = "points.f32";
      (*j)["num_points"] = points.size();
    }
  } catch (const std::exception& e) {
    return absl::DataLossError(absl::StrCat("corrupt scan ", scan_id, ": ", e.what()));
  }
  return AtomicWriteFile((dir / "scan.json").string(), j->dump(1));
}

absl::StatusOr<int> ScanStore::RecordAttempt(const std::string& scan_id) {
  const fs::path dir = fs::path(dir_) / scan_id;
  const int n = Attempts(scan_id) + 1;
  if (absl::Status s = WriteFileSynced((dir / "attempts").string(), absl::StrCat(n, "\n")); !s.ok()) return s;
  if (absl::Status s = SyncDirectory(dir.string()); !s.ok()) return s;
  return n;
}

int ScanStore::Attempts(const std::string& scan_id) const {
  absl::StatusOr<std::string> text = ReadFileToString((fs::path(dir_) / scan_id / "attempts").string(), "attempts");
  int n = 0;
  if (!text.ok() || !absl::SimpleAtoi(absl::StripAsciiWhitespace(*text), &n) || n < 0) return 0;
  return n;
}

void ScanStore::ClearAttempts(const std::string& scan_id) {
  std::error_code ec;
  fs::remove(fs::path(dir_) / scan_id / "attempts", ec);
}

std::string ScanStore::parked_dir() const { return (fs::path(dir_).parent_path() / "parked").string(); }

absl::Status ScanStore::Park(const std::string& scan_id, const std::string& reason) {
  const fs::path from = fs::path(dir_) / scan_id, to = fs::path(parked_dir()) / scan_id;
  std::error_code ec;
  fs::create_directories(parked_dir(), ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create '", parked_dir(), "': ", ec.message()));
  (void)WriteFileSynced((from / "parked_reason.txt").string(), reason + "\n");
  fs::rename(from, to, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot park scan ", scan_id, ": ", ec.message()));
  (void)SyncDirectory(parked_dir());
  return SyncDirectory(dir_);
}

absl::Status ScanStore::Remove(const std::string& scan_id) {
  // Renamed away first (atomic), then deleted: a concurrent List() sees the
  // whole scan or none of it, never a folder emptied half-way; a crash
  // mid-delete leaves a temporary that the next Open(clean_temps) removes.
  const fs::path from = fs::path(dir_) / scan_id;
  const fs::path doomed = fs::path(dir_) / absl::StrCat(kTmpPrefix, "removed-", scan_id);
  std::error_code ec;
  fs::remove_all(doomed, ec);  // Left by a crash in an earlier removal of this id.
  fs::rename(from, doomed, ec);
  if (ec && ec != std::errc::no_such_file_or_directory) {
    return absl::InternalError(absl::StrCat("cannot remove scan ", scan_id, ": ", ec.message()));
  }
  if (absl::Status s = SyncDirectory(dir_); !s.ok()) return s;
  fs::remove_all(doomed, ec);
  if (ec) spdlog::warn("scan {} is removed; its files were not all deleted: {}", scan_id, ec.message());
  return absl::OkStatus();
}

}  // namespace clnerf
