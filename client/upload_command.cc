// Remote verb `upload`: a dataset folder becomes one scan on the server.
#include <chrono>
#include <cstdio>
#include <filesystem>

#include "absl/strings/str_format.h"
#include "client/job_watch.h"
#include "client/progress_bar.h"
#include "client/proto_json.h"
#include "client/remote_client.h"
#include "client/remote_commands.h"
#include "client/remote_format.h"
#include "core/dataset.h"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

constexpr const char* kVerb = "upload";
constexpr size_t kChunkBytes = size_t(1) << 20;  // The protocol's maximum.

// One frame's encoded files.
struct EncodedFrame {
  std::string image;
  std::string mask;  // Empty: no mask.
};

// Encodes `view` (image as RGB PNG, mask as greyscale PNG, 255 = keep) and
// describes it in `frame`.
absl::StatusOr<EncodedFrame> EncodeView(const View& view, clnerf::v1::Frame* frame) {
  EncodedFrame out;
  absl::StatusOr<std::string> png = EncodePng(view.image);
  if (!png.ok()) return png.status();
  out.image = std::move(*png);
  if (!view.mask.empty()) {
    absl::StatusOr<std::string> mask = EncodeMaskPng(view.mask);
    if (!mask.ok()) return mask.status();
    out.mask = std::move(*mask);
  }
  frame->set_name(view.name);
  *frame->mutable_camera() = ToCameraSpec(view.camera);
  frame->set_image_bytes(int64_t(out.image.size()));
  frame->set_mask_bytes(int64_t(out.mask.size()));
  return out;
}

// The held-out views to send with the scan (`split` is test, val or none).
std::vector<View>* TestViews(Scene& scene, const std::string& split) {
  static std::vector<View> none;
  if (split == "none") return &none;
  if (split == "val") return &scene.val;
  return scene.test.empty() ? &scene.val : &scene.test;
}

}  // namespace

int RunUpload(const UploadArgs& a) {
  if (a.test_split != "test" && a.test_split != "val" && a.test_split != "none") {
    return FailRemote(kVerb, absl::InvalidArgumentError("--test-split must be test, val or none, not '" +
                                                        a.test_split + "'"));
  }
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote(kVerb, client.status());
  absl::StatusOr<Scene> scene = LoadScene(a.dir);
  if (!scene.ok()) return FailRemote(kVerb, scene.status());
  if (scene->train.empty()) return FailRemote(kVerb, absl::InvalidArgumentError(a.dir + " has no training views"));
  std::vector<View>* test = TestViews(*scene, a.test_split);

  clnerf::v1::UploadScanRequest header_request;
  clnerf::v1::ScanHeader* header = header_request.mutable_header();
  header->set_name(a.name.empty() ? scene->name : a.name);
  header->set_scene_kind(scene->kind == SceneKind::kBounded ? "bounded" : "unbounded");
  header->set_mask_nonzero_is_exclude(false);
  std::vector<EncodedFrame> files;
  int64_t total_bytes = 0;
  for (std::vector<View>* views : {&scene->train, test}) {
    for (View& view : *views) {
      absl::StatusOr<EncodedFrame> f =
          EncodeView(view, views == &scene->train ? header->add_frames() : header->add_test_frames());
      if (!f.ok()) {
        return FailRemote(kVerb, absl::Status(f.status().code(), view.name + ": " + std::string(f.status().message())));
      }
      total_bytes += int64_t(f->image.size() + f->mask.size());
      files.push_back(std::move(*f));
      view.image = Image();  // Only the encoded copy is needed from here on.
      view.mask = Mask();
    }
  }
  spdlog::info("scan '{}' from {} ({} scene): {} frames + {} test frames, {} encoded", header->name(), a.dir,
               header->scene_kind(), header->frames_size(), header->test_frames_size(), FormatBytes(total_bytes));

  const auto start = std::chrono::steady_clock::now();
  auto seconds_since_start = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  std::unique_ptr<grpc::ClientContext> ctx = (*client)->Context(kNoDeadline);
  clnerf::v1::UploadScanResponse response;
  std::unique_ptr<grpc::ClientWriter<clnerf::v1::UploadScanRequest>> writer =
      (*client)->service().UploadScan(ctx.get(), &response);
  ProgressBar bar("upload", total_bytes);
  bool open = writer->Write(header_request);
  int64_t sent = 0;
  clnerf::v1::UploadScanRequest request;
  clnerf::v1::Chunk* chunk = request.mutable_chunk();
  for (size_t i = 0; open && i < files.size(); ++i) {
    for (const bool is_mask : {false, true}) {
      const std::string& bytes = is_mask ? files[i].mask : files[i].image;
      for (size_t off = 0; open && off < bytes.size(); off += kChunkBytes) {
        const size_t n = std::min(kChunkBytes, bytes.size() - off);
        chunk->set_frame_index(int(i));
        chunk->set_is_mask(is_mask);
        chunk->set_offset(int64_t(off));
        chunk->set_data(bytes.data() + off, n);
        open = writer->Write(request);
        if (!open) break;
        sent += int64_t(n);
        const double s = seconds_since_start();
        bar.Update(sent, absl::StrFormat("%.2f MB/s", s > 0 ? sent / 1e6 / s : 0.0));
      }
    }
  }
  if (open) writer->WritesDone();
  const grpc::Status status = writer->Finish();
  const double seconds = seconds_since_start();
  if (!status.ok()) {
    bar.Abort();
    return FailRemote(kVerb, status, a.remote);
  }
  const double mb = sent / 1e6, mb_per_s = seconds > 0 ? mb / seconds : 0.0;
  bar.Finish(absl::StrFormat("%.2f MB/s", mb_per_s));

  nlohmann::json j = ProtoToJson(response);
  j["name"] = header->name();
  j["frames"] = header->frames_size();
  j["test_frames"] = header->test_frames_size();
  j["bytes"] = sent;
  j["seconds"] = seconds;
  j["mb_per_s"] = mb_per_s;
  if (!a.remote.json) {
    std::printf("uploaded scan %s (%d frames, %.2f MB in %.2f s, %.2f MB/s): time step %d, job %s\n",
                response.scan_id().c_str(), header->frames_size() + header->test_frames_size(), mb, seconds,
                mb_per_s, response.time_step(), response.job_id().c_str());
    std::fflush(stdout);
  }
  if (!a.watch) {
    if (a.remote.json) std::printf("%s\n", j.dump(2).c_str());
    return 0;
  }
  return ReportJob(kVerb, FollowJob(**client, response.job_id()), a.remote, a.remote.json ? j : nullptr);
}

}  // namespace clnerf
