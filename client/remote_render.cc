// Remote mode of `render` (no --model): the server renders cameras from a
// --pose, a dataset split (--views-from, scored against its images when they
// exist) or a nerfstudio camera path. One camera uses the unary Render call,
// several use RenderStream, whose chunks are reassembled per frame.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>

#include "absl/strings/ascii.h"
#include "absl/strings/str_format.h"
#include "proto/wire/wire.h"
#include "client/camera_path.h"
#include "client/commands.h"
#include "client/progress_bar.h"
#include "client/remote_client.h"
#include "client/remote_format.h"
#include "core/data/dataset.h"
#include "core/render/metrics.h"
#include "nlohmann/json.hpp"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

constexpr const char* kRenderVerb = "render";

// What to render: cameras, their names, and ground truth when known.
struct Shots {
  std::vector<Camera> cameras;
  std::vector<std::string> names;
  std::vector<Image> truth;  // Empty, or one (possibly empty) image per camera.
};

absl::StatusOr<Shots> SplitShots(const RenderArgs& a) {
  DatasetOptions dopt = a.dataset;
  absl::StatusOr<Scene> scene = LoadScene(a.data, dopt);
  if (!scene.ok()) {
    // Cameras alone are enough to render; ground truth is optional.
    dopt.load_images = false;
    absl::StatusOr<Scene> cameras_only = LoadScene(a.data, dopt);
    if (!cameras_only.ok()) return scene.status();
    spdlog::warn("no ground-truth images ({}); rendering without PSNR", std::string(scene.status().message()));
    scene = std::move(cameras_only);
  }
  const std::vector<View>* views = a.split == "train" ? &scene->train
                                   : a.split == "val" ? &scene->val
                                   : a.split == "test" ? &scene->test
                                                       : nullptr;
  if (views == nullptr) return absl::InvalidArgumentError("--split must be train, val or test");
  if (views->empty()) return absl::InvalidArgumentError(absl::StrFormat("split '%s' of %s is empty", a.split, a.data));
  Shots shots;
  for (int i = 0; i < int(views->size()); ++i) {
    if (a.index >= 0 && i != a.index) continue;
    const View& v = (*views)[i];
    shots.cameras.push_back(v.camera);
    shots.names.push_back(std::filesystem::path(v.name).filename().string());
    shots.truth.push_back(v.image);
  }
  if (shots.cameras.empty()) return absl::InvalidArgumentError(absl::StrFormat("--index %d out of range", a.index));
  return shots;
}

absl::StatusOr<Shots> CollectShots(const RenderArgs& a) {
  const int sources = int(!a.pose.empty()) + int(!a.data.empty()) + int(!a.camera_path.empty());
  if (sources != 1) {
    return absl::InvalidArgumentError("give exactly one of --pose, --views-from (--data) or --camera-path");
  }
  if (!a.data.empty()) return SplitShots(a);
  Shots shots;
  if (!a.pose.empty()) {
    absl::StatusOr<Camera> cam = ParsePoseCamera(a.pose, a.width, a.height, a.focal);
    if (!cam.ok()) return cam.status();
    shots.cameras.push_back(*cam);
    shots.names.push_back("pose");
    return shots;
  }
  absl::StatusOr<std::vector<Camera>> path = LoadNerfstudioCameraPath(a.camera_path);
  if (!path.ok()) return path.status();
  shots.cameras = std::move(*path);
  for (size_t i = 0; i < shots.cameras.size(); ++i) shots.names.push_back(absl::StrFormat("path_%05d", int(i)));
  return shots;
}

// Writes PNG bytes as they are to a .png path, else re-encodes by extension.
absl::Status SaveFrame(const std::string& png, const std::string& path) {
  if (absl::AsciiStrToLower(std::filesystem::path(path).extension().string()) == ".png") {
    std::ofstream f(path, std::ios::binary);
    f.write(png.data(), std::streamsize(png.size()));
    if (!f) return absl::InternalError(absl::StrFormat("cannot write '%s'", path));
    return absl::OkStatus();
  }
  absl::StatusOr<Image> img = DecodeImage(png, "render.png");
  if (!img.ok()) return img.status();
  return WriteImage(path, *img);
}

// Collects rendered frames: saves each, scores it against ground truth, and
// summarises the run.
class FrameSink {
 public:
  FrameSink(const RenderArgs& a, const Shots& shots, bool single_file)
      : args_(a), shots_(shots), single_file_(single_file), done_(shots.cameras.size(), false) {}

  absl::Status Add(int index, const std::string& png) {
    if (index < 0 || index >= int(done_.size()) || done_[index]) {
      return absl::DataLossError(absl::StrFormat("unexpected frame index %d from the server", index));
    }
    done_[index] = true;
    const std::string path =
        single_file_ ? args_.out
                     : (std::filesystem::path(args_.out) / absl::StrFormat("frame_%05d.png", index)).string();
    if (absl::Status s = SaveFrame(png, path); !s.ok()) return s;
    nlohmann::json f = {{"index", index}, {"name", shots_.names[index]}, {"path", path}};
    if (index < int(shots_.truth.size()) && !shots_.truth[index].empty()) {
      absl::StatusOr<Image> img = DecodeImage(png, "render.png");
      if (!img.ok()) return img.status();
      const Image& truth = shots_.truth[index];
      if (img->width != truth.width || img->height != truth.height) {
        spdlog::warn("{}: render is {}x{} but the image is {}x{}; no PSNR", shots_.names[index], img->width,
                     img->height, truth.width, truth.height);
      } else {
        const double psnr = Psnr(*img, truth);
        f["psnr"] = psnr;
        psnrs_.push_back(psnr);
      }
    }
    frames_.push_back(std::move(f));
    return absl::OkStatus();
  }

  int count() const { return int(frames_.size()); }

  // Prints the result (line per scored view + summary, or JSON).
  void Report(int64_t version, int time_step, double seconds, bool json) const {
    nlohmann::json j = {{"version", version}, {"time_step", time_step}, {"out", args_.out},
                        {"seconds", seconds}, {"frames", frames_}};
    double mean = 0;
    for (double p : psnrs_) mean += p / double(psnrs_.size());
    if (!psnrs_.empty()) j["mean_psnr"] = mean;
    if (json) {
      std::printf("%s\n", j.dump(2).c_str());
      return;
    }
    for (const nlohmann::json& f : frames_) {
      if (f.contains("psnr")) {
        std::printf("%s  %s  PSNR %.2f dB\n", std::filesystem::path(f["path"].get<std::string>()).filename().c_str(),
                    f["name"].get<std::string>().c_str(), f["psnr"].get<double>());
      }
    }
    std::printf("rendered %d view(s) with version %lld at time step %d -> %s (%.1f s)\n", count(),
                (long long)version, time_step, args_.out.c_str(), seconds);
    if (!psnrs_.empty()) std::printf("mean PSNR %.2f dB over %zu view(s)\n", mean, psnrs_.size());
  }

 private:
  const RenderArgs& args_;
  const Shots& shots_;
  bool single_file_;
  std::vector<bool> done_;
  nlohmann::json frames_ = nlohmann::json::array();
  std::vector<double> psnrs_;
};

}  // namespace

int RunRemoteRender(const RenderArgs& a) {
  absl::StatusOr<Shots> shots = CollectShots(a);
  if (!shots.ok()) return FailRemote(kRenderVerb, shots.status());
  const int n = int(shots->cameras.size());
  namespace fs = std::filesystem;
  const bool single_file = n == 1 && fs::path(a.out).has_extension() && !fs::is_directory(a.out);
  if (!single_file) {
    if (fs::path(a.out).has_extension() && !fs::is_directory(a.out)) {
      return FailRemote(kRenderVerb, absl::InvalidArgumentError(absl::StrFormat(
                                   "%d views need a directory for --out, not the file '%s'", n, a.out)));
    }
    std::error_code ec;
    fs::create_directories(a.out, ec);
    if (ec) return FailRemote(kRenderVerb, absl::InternalError(absl::StrFormat("cannot create '%s': %s", a.out, ec.message())));
  }
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote(kRenderVerb, client.status());
  FrameSink sink(a, *shots, single_file);
  const auto start = std::chrono::steady_clock::now();
  int64_t version = 0;
  int time_step = 0;
  if (n == 1) {
    clnerf::v1::RenderRequest request;
    *request.mutable_camera() = CameraToProto(shots->cameras[0]);
    if (a.time_step >= 0) request.set_time_step(a.time_step);
    request.set_version(a.version);
    request.set_format(clnerf::v1::IMAGE_FORMAT_PNG);
    request.set_place(a.remote.place);
    clnerf::v1::RenderResponse response;
    grpc::Status s = (*client)->service().Render((*client)->Context(kRenderTimeoutSeconds).get(), request, &response);
    if (!s.ok()) return FailRemote(kRenderVerb, s, a.remote);
    if (absl::Status st = sink.Add(0, response.image()); !st.ok()) return FailRemote(kRenderVerb, st);
    version = response.version();
    time_step = response.time_step();
  } else {
    clnerf::v1::RenderStreamRequest request;
    for (const Camera& cam : shots->cameras) *request.add_cameras() = CameraToProto(cam);
    if (a.time_step >= 0) request.set_time_step(a.time_step);
    request.set_version(a.version);
    request.set_format(clnerf::v1::IMAGE_FORMAT_PNG);
    request.set_place(a.remote.place);
    std::unique_ptr<grpc::ClientContext> ctx = (*client)->Context(kNoDeadline);
    std::unique_ptr<grpc::ClientReader<clnerf::v1::RenderChunk>> reader =
        (*client)->service().RenderStream(ctx.get(), request);
    ProgressBar bar("render", n);
    std::map<int, std::string> partial;  // frame_index -> bytes so far.
    clnerf::v1::RenderChunk chunk;
    absl::Status error;
    while (error.ok() && reader->Read(&chunk)) {
      version = chunk.version();
      time_step = chunk.time_step();
      std::string& buf = partial[chunk.frame_index()];
      if (chunk.offset() != int64_t(buf.size()) ||
          int64_t(buf.size() + chunk.data().size()) > chunk.total_bytes()) {
        error = absl::DataLossError(absl::StrFormat("frame %d: chunk at offset %lld does not follow %zu bytes of %lld",
                                                    chunk.frame_index(), (long long)chunk.offset(), buf.size(),
                                                    (long long)chunk.total_bytes()));
        break;
      }
      buf += chunk.data();
      if (int64_t(buf.size()) == chunk.total_bytes()) {
        error = sink.Add(chunk.frame_index(), buf);
        partial.erase(chunk.frame_index());
        bar.Update(sink.count());
      }
    }
    if (!error.ok()) ctx->TryCancel();
    const grpc::Status s = reader->Finish();
    if (!error.ok() || !s.ok()) bar.Abort();
    if (!error.ok()) return FailRemote(kRenderVerb, error);
    if (!s.ok()) return FailRemote(kRenderVerb, s, a.remote);
    if (sink.count() != n) {
      bar.Abort();
      return FailRemote(kRenderVerb, absl::DataLossError(absl::StrFormat("the server sent %d of %d frames", sink.count(), n)));
    }
    bar.Finish();
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  sink.Report(version, time_step, seconds, a.remote.json);
  return 0;
}

}  // namespace clnerf
