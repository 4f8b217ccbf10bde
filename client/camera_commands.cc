// Remote verbs on cameras: `cameras` (the poses a version was trained on, in
// the place's frame) and `localize` (where photos were taken).
#include <cstdio>
#include <filesystem>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/proto_json.h"
#include "client/remote_client.h"
#include "client/remote_commands.h"
#include "client/remote_format.h"
#include "client/scan_upload.h"
#include "client/text_table.h"
#include "core/data/image.h"
#include "core/io/durable_file.h"

namespace clnerf {

namespace {

// "x y z" of a camera's centre and its viewing direction (OpenCV +z).
std::string Centre(const clnerf::v1::CameraSpec& c) {
  return absl::StrFormat("%.4f %.4f %.4f", c.pose(3), c.pose(7), c.pose(11));
}
std::string Looks(const clnerf::v1::CameraSpec& c) {
  return absl::StrFormat("%.3f %.3f %.3f", c.pose(2), c.pose(6), c.pose(10));
}

}  // namespace

CLI::App* BindCameras(CLI::App* parent, CamerasArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "cameras", "The camera of every frame a version was trained on, in the place's frame (--json: full poses)");
  c->add_option("--version", a->version, "Version (default: the deployed one)");
  c->add_option("--time-step", a->time_step, "Only this time step (scan)");
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunCameras(const CamerasArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("cameras", client.status());
  clnerf::v1::ListCamerasRequest request;
  request.set_place(a.remote.place);
  request.set_version(a.version);
  if (a.time_step >= 0) request.set_time_step(a.time_step);
  clnerf::v1::ListCamerasResponse response;
  grpc::Status s =
      (*client)->service().ListCameras((*client)->Context(kUnaryTimeoutSeconds).get(), request, &response);
  if (!s.ok()) return FailRemote("cameras", s, a.remote);
  if (a.remote.json) {
    std::printf("%s\n", ProtoToJson(response).dump(2).c_str());
    return 0;
  }
  TextTable table({"TIME STEP", "INDEX", "FRAME", "CENTRE (x y z)", "LOOKS ALONG", "SIZE", "FX"});
  for (const clnerf::v1::TrainedCamera& t : response.cameras()) {
    const clnerf::v1::Intrinsics& in = t.camera().intrinsics();
    table.AddRow({absl::StrCat(t.time_step()), absl::StrCat(t.index()), t.name().empty() ? "-" : t.name(),
                  Centre(t.camera()), Looks(t.camera()),
                  absl::StrCat(in.width(), "x", in.height()), absl::StrFormat("%.1f", in.fx())});
  }
  table.Print();
  std::printf("version %lld: %d cameras over %d time step(s), place frame, OpenCV convention (camera looks along "
              "+z); --json for the 4x4 camera-to-world poses\n",
              (long long)response.version(), response.cameras_size(), response.time_steps());
  return 0;
}

CLI::App* BindLocalize(CLI::App* parent, LocalizeArgs* a) {
  CLI::App* c = parent->add_subcommand("localize", "Where were these photos taken? Poses in the place's frame");
  c->add_option("photos", a->photos, "Photo files or folders of photos")->required();
  c->add_option("--version", a->version, "Version to localise against (default: the deployed one)");
  c->add_option("--fx", a->fx, "Focal length in pixels of every photo (default: the server guesses)");
  c->add_option("--fy", a->fy, "Vertical focal length (default: --fx)");
  c->add_option("--cx", a->cx, "Principal point x (default: the image centre)");
  c->add_option("--cy", a->cy, "Principal point y (default: the image centre)");
  BindRemoteFlags(c, &a->remote);
  return c;
}

namespace {

// Requests of photos that fit a gRPC message (3.5 MiB of images, at most
// 32 photos each).
absl::StatusOr<std::vector<clnerf::v1::LocalizeRequest>> LocalizeRequests(const LocalizeArgs& a) {
  std::vector<std::string> files;
  for (const std::string& p : a.photos) {
    if (std::filesystem::is_directory(p)) {
      for (const std::string& f : ListPhotos(p)) files.push_back(f);
    } else {
      files.push_back(p);
    }
  }
  if (files.empty()) return absl::InvalidArgumentError("no photos found");
  std::vector<clnerf::v1::LocalizeRequest> out;
  int64_t bytes = 0;
  for (const std::string& f : files) {
    absl::StatusOr<std::string> data = ReadFileToString(f, "photo");
    if (!data.ok()) return data.status();
    if (out.empty() || out.back().photos_size() >= 32 || bytes + int64_t(data->size()) > (int64_t(7) << 19)) {
      out.emplace_back();
      out.back().set_place(a.remote.place);
      out.back().set_version(a.version);
      bytes = 0;
    }
    clnerf::v1::Photo* photo = out.back().add_photos();
    photo->set_name(std::filesystem::path(f).filename().string());
    if (a.fx > 0) {
      absl::StatusOr<ImageSize> size = ReadImageSize(f);
      if (!size.ok()) return size.status();
      clnerf::v1::Intrinsics* in = photo->mutable_intrinsics();
      in->set_width(size->width);
      in->set_height(size->height);
      in->set_fx(a.fx);
      in->set_fy(a.fy > 0 ? a.fy : a.fx);
      in->set_cx(a.cx >= 0 ? a.cx : size->width / 2.0f);
      in->set_cy(a.cy >= 0 ? a.cy : size->height / 2.0f);
    }
    bytes += int64_t(data->size());
    photo->set_image(*std::move(data));
  }
  return out;
}

}  // namespace

int RunLocalize(const LocalizeArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("localize", client.status());
  absl::StatusOr<std::vector<clnerf::v1::LocalizeRequest>> requests = LocalizeRequests(a);
  if (!requests.ok()) return FailRemote("localize", requests.status());
  clnerf::v1::LocalizeResponse all;
  for (const clnerf::v1::LocalizeRequest& request : *requests) {
    clnerf::v1::LocalizeResponse response;
    grpc::Status s = (*client)->service().Localize((*client)->Context(kNoDeadline).get(), request, &response);
    if (!s.ok()) return FailRemote("localize", s, a.remote);
    all.set_version(response.version());
    all.set_references(response.references());
    all.set_seconds(all.seconds() + response.seconds());
    for (const clnerf::v1::PhotoPose& p : response.photos()) *all.add_photos() = p;
  }
  if (a.remote.json) {
    std::printf("%s\n", ProtoToJson(all).dump(2).c_str());
    return 0;
  }
  TextTable table({"PHOTO", "PLACED", "CENTRE (x y z)", "LOOKS ALONG", "INLIERS", "REPROJ PX", "FX"});
  int placed = 0;
  for (const clnerf::v1::PhotoPose& p : all.photos()) {
    placed += p.placed();
    const std::string fx = p.placed() ? absl::StrFormat("%.1f%s", p.camera().intrinsics().fx(),
                                                        p.intrinsics_guessed() ? " (guessed)" : "")
                                      : "-";
    table.AddRow({p.name(), p.placed() ? "yes" : "no", p.placed() ? Centre(p.camera()) : "-",
                  p.placed() ? Looks(p.camera()) : "-", absl::StrCat(p.inliers(), "/", p.matches()),
                  p.placed() ? absl::StrFormat("%.2f", p.reprojection_px()) : "-", fx});
  }
  table.Print();
  std::printf("%d of %d photos placed against version %lld (%d renders of the place, %.1f s); --json for poses\n",
              placed, all.photos_size(), (long long)all.version(), all.references(), all.seconds());
  return placed > 0 ? 0 : 1;
}

}  // namespace clnerf
