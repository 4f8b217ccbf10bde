// Remote verb `upload`: a dataset folder becomes one scan on the server.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "absl/strings/str_format.h"
#include "client/job_watch.h"
#include "client/verb_set.h"
#include "client/progress_bar.h"
#include "client/proto_json.h"
#include "client/remote_client.h"
#include "client/remote_commands.h"
#include "client/remote_format.h"
#include "client/scan_upload.h"
#include "core/data/dataset.h"
#include "core/pose/video_frames.h"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

constexpr const char* kUploadVerb = "upload";
// The held-out views to send with the scan (`split` is test, val or none).
std::vector<View>* TestViews(Scene& scene, const std::string& split) {
  static std::vector<View> none;
  if (split == "none") return &none;
  if (split == "val") return &scene.val;
  return scene.test.empty() ? &scene.val : &scene.test;
}

}  // namespace

CLI::App* BindUpload(CLI::App* parent, UploadArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "upload",
      "Upload a scan: a dataset folder (Blender, transforms.json, COLMAP or LLFF), a folder of photos, or a "
      "video; photos and videos are posed by the server (COLMAP)");
  c->add_option("dir", a->dir, "Dataset or photo folder, or a video file")->required();
  c->add_option("--name", a->name, "Scan name (default: the folder's name)");
  c->add_option("--test-split", a->test_split, "Held-out frames: test (falls back to val), val or none")
      ->capture_default_str();
  c->add_flag("--watch", a->watch, "Then follow the update job until it ends");
  c->add_option("--pose-frame", a->pose_frame,
                "own: the poses are in this capture's own frame (its own COLMAP run or AR session; the server "
                "registers the scan into the place's frame); place: already in the place's frame")
      ->check(CLI::IsMember({"own", "place"}))
      ->capture_default_str();
  c->add_flag("--unposed", a->unposed, "Send a dataset's photos without their poses (the server poses them)");
  c->add_flag("--sequential", a->sequential,
              "Unposed photos are in capture order: match neighbours (COLMAP's sequential matcher; a video always is)");
  c->add_option("--frames", a->video_frames, "Video: frames to keep (the sharpest of each window)")
      ->check(CLI::Range(3, 2000))
      ->capture_default_str();
  c->add_option("--max-side", a->video_max_side, "Video: longer side of the kept frames in pixels")
      ->check(CLI::Range(64, 4096))
      ->capture_default_str();
  BindRemoteFlags(c, &a->remote);
  return c;
}

namespace {

// A scan's encoding from what `a.dir` holds: a video (frames extracted into
// `scratch`), a dataset (posed unless --unposed) or a folder of photos only.
absl::StatusOr<EncodedScan> EncodeUpload(const UploadArgs& a, const std::string& scratch) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::is_regular_file(a.dir, ec)) {
    VideoFrameOptions vo;
    vo.frames = a.video_frames;
    vo.max_side = a.video_max_side;
    spdlog::info("extracting frames from {} with ffmpeg", a.dir);
    absl::StatusOr<VideoFrames> v = ExtractVideoFrames(a.dir, scratch, vo);
    if (!v.ok()) return v.status();
    spdlog::info("kept {} of {} frames ({:.1f} s of {}x{} video, the sharpest of each window) in {:.1f} s",
                 v->files.size(), v->candidates, v->duration_seconds, v->width, v->height, v->seconds);
    return EncodeUnposedPhotos(a.name.empty() ? fs::path(a.dir).stem().string() : a.name, v->files, true);
  }
  absl::StatusOr<Scene> scene = LoadScene(a.dir);
  if (!scene.ok()) {
    const std::vector<std::string> photos = ListPhotos(a.dir);
    if (!absl::IsNotFound(scene.status()) || photos.empty()) return scene.status();
    spdlog::info("{} holds {} photos and no poses: uploading them unposed (the server poses them with COLMAP)",
                 a.dir, photos.size());
    std::string name = a.name.empty() ? fs::path(a.dir).filename().string() : a.name;
    if (name.empty()) name = fs::path(a.dir).parent_path().filename().string();
    return EncodeUnposedPhotos(name, photos, a.sequential);
  }
  if (scene->train.empty()) return absl::InvalidArgumentError(a.dir + " has no training views");
  std::vector<View>* test = TestViews(*scene, a.test_split);
  absl::StatusOr<EncodedScan> scan = EncodeScan(a.name.empty() ? scene->name : a.name, scene->kind, scene->train,
                                                *test, scene->sparse_points);
  if (!scan.ok()) return scan.status();
  scan->header.mutable_header()->set_pose_frame(a.pose_frame);
  if (a.unposed) DropPoses(&*scan, a.sequential);
  return scan;
}

}  // namespace

int RunUpload(const UploadArgs& a) {
  if (a.test_split != "test" && a.test_split != "val" && a.test_split != "none") {
    return FailRemote(kUploadVerb, absl::InvalidArgumentError("--test-split must be test, val or none, not '" +
                                                        a.test_split + "'"));
  }
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote(kUploadVerb, client.status());
  char scratch_template[] = "/tmp/clnerf-upload-XXXXXX";
  const char* scratch = mkdtemp(scratch_template);
  if (scratch == nullptr) return FailRemote(kUploadVerb, absl::InternalError("cannot create a scratch folder in /tmp"));
  absl::StatusOr<EncodedScan> scan = EncodeUpload(a, std::string(scratch) + "/frames");
  std::error_code ec;
  std::filesystem::remove_all(scratch, ec);
  if (!scan.ok()) return FailRemote(kUploadVerb, scan.status());
  scan->header.mutable_header()->set_place(a.remote.place);
  const clnerf::v1::ScanHeader* header = &scan->header.header();
  const bool unposed = header->frames_size() > 0 && !header->frames(0).has_camera();
  spdlog::info("scan '{}' from {} ({}): {} frames + {} test frames, {} encoded", header->name(), a.dir,
               unposed ? "unposed" : header->scene_kind() + " scene", header->frames_size(),
               header->test_frames_size(), FormatBytes(scan->total_bytes));

  ProgressBar bar("upload", scan->total_bytes);
  const SendResult sent_scan = SendScan(**client, *scan, &bar);
  if (!sent_scan.status.ok()) {
    bar.Abort();
    return FailRemote(kUploadVerb, sent_scan.status, a.remote);
  }
  const clnerf::v1::UploadScanResponse& response = sent_scan.response;
  const int64_t sent = sent_scan.bytes_sent;
  const double seconds = sent_scan.seconds;
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
  return ReportJob(kUploadVerb, FollowJob(**client, response.job_id(), a.remote.place), a.remote, a.remote.json ? j : nullptr);
}

}  // namespace clnerf
