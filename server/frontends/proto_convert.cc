#include "server/frontends/proto_convert.h"

#include <cmath>

#include "absl/strings/str_cat.h"
#include "core/data/image.h"

namespace clnerf {

absl::StatusOr<ScanHeaderDecl> HeaderFromProto(const v1::ScanHeader& h) {
  ScanHeaderDecl decl;
  decl.name = h.name();
  decl.scene_kind = h.scene_kind();
  decl.mask_nonzero_is_exclude = h.mask_nonzero_is_exclude();
  decl.pose_frame = h.pose_frame();
  if (!decl.pose_frame.empty() && decl.pose_frame != "own" && decl.pose_frame != "place") {
    return absl::InvalidArgumentError("scan header: pose_frame must be \"own\" or \"place\"");
  }
  if (h.points_size() % 3 != 0) {
    return absl::InvalidArgumentError(absl::StrCat("scan header: points holds ", h.points_size(),
                                                   " numbers, not x y z triples"));
  }
  decl.points.reserve(size_t(h.points_size() / 3));
  for (int i = 0; i < h.points_size(); i += 3) {
    const Eigen::Vector3f p(h.points(i), h.points(i + 1), h.points(i + 2));
    if (!p.allFinite()) return absl::InvalidArgumentError(absl::StrCat("scan header: point ", i / 3, " is not finite"));
    decl.points.push_back(p);
  }
  if (h.frames_size() == 0) return absl::InvalidArgumentError("scan header lists no training frames");
  // Unposed: no frame has a camera (the server poses the scan).
  const bool unposed = !h.frames(0).has_camera();
  if (unposed && decl.pose_frame == "place") {
    return absl::InvalidArgumentError("scan header: an unposed scan (frames without cameras) cannot be \"place\"");
  }
  if (unposed) decl.pose_frame = "unposed";
  decl.sequential = h.sequential();
  const int n = h.frames_size() + h.test_frames_size();
  for (int i = 0; i < n; ++i) {
    const bool test = i >= h.frames_size();
    const v1::Frame& f = test ? h.test_frames(i - h.frames_size()) : h.frames(i);
    const std::string what = absl::StrCat(test ? "test frame " : "frame ", test ? i - h.frames_size() : i);
    if (f.has_camera() == unposed) {
      return absl::InvalidArgumentError(absl::StrCat(
          what, ": a scan's frames must be all posed or all unposed (", unposed ? "frame 0 has no camera" : "no camera",
          ")"));
    }
    DeclaredFrame df;
    df.frame.name = f.name().empty() ? absl::StrCat(test ? "test_" : "frame_", i) : f.name();
    df.frame.posed = !unposed;
    if (!unposed) {
      absl::StatusOr<Camera> cam = CameraFromProto(f.camera(), what);
      if (!cam.ok()) return cam.status();
      df.frame.camera = *cam;
    }
    df.frame.test = test;
    df.image_bytes = f.image_bytes();
    df.mask_bytes = f.mask_bytes();
    decl.frames.push_back(std::move(df));
  }
  return decl;
}

absl::StatusOr<PhotoQuery> PhotoFromProto(const v1::Photo& photo, int index) {
  PhotoQuery q;
  q.name = photo.name().empty() ? absl::StrCat("photo_", index) : photo.name();
  if (absl::Status s = ValidateName(q.name, absl::StrCat("photo ", index, " name")); !s.ok()) return s;
  auto bad = [&](const std::string& why) {
    return absl::InvalidArgumentError(absl::StrCat("photo ", index, " ('", q.name, "'): ", why));
  };
  const std::string ext = SniffImageExtension(photo.image());
  if (ext.empty()) return bad("image is not PNG, JPEG, EXR, TIFF or BMP");
  absl::StatusOr<Image> img = DecodeImage(photo.image(), q.name + ext);
  if (!img.ok()) return bad(std::string(img.status().message()));
  q.image = *std::move(img);
  if (photo.has_intrinsics() && photo.intrinsics().width() > 0) {
    const v1::Intrinsics& in = photo.intrinsics();
    q.intrinsics = Intrinsics{in.width(), in.height(), in.fx(), in.fy(), in.cx(), in.cy(),
                              in.k1(),    in.k2(),     in.p1(), in.p2()};
    if (in.width() != q.image.width || in.height() != q.image.height) {
      return bad(absl::StrCat("image is ", q.image.width, "x", q.image.height, " but the intrinsics say ",
                              in.width(), "x", in.height()));
    }
    for (float v : {in.fx(), in.fy(), in.cx(), in.cy(), in.k1(), in.k2(), in.p1(), in.p2()}) {
      if (!std::isfinite(v)) return bad("intrinsics are not finite");
    }
    if (!(in.fx() > 0 && in.fy() > 0)) return bad("focal lengths must be > 0");
  }
  return q;
}

v1::LocalizeResponse ToProto(const LocalizeResult& r) {
  v1::LocalizeResponse p;
  p.set_version(r.version);
  p.set_references(r.report.references);
  p.set_seconds(r.seconds);
  for (const PhotoLocation& l : r.report.photos) {
    v1::PhotoPose* out = p.add_photos();
    out->set_name(l.name);
    out->set_placed(l.found.placed);
    if (l.found.placed) *out->mutable_camera() = CameraToProto(l.camera);
    out->set_matches(l.found.matches);
    out->set_inliers(l.found.inliers);
    out->set_reprojection_px(l.found.reprojection_px);
    out->set_intrinsics_guessed(l.intrinsics_guessed);
  }
  return p;
}

v1::Job ToProto(const JobStatus& j) {
  v1::Job p;
  p.set_job_id(j.job_id);
  p.set_scan_id(j.scan_id);
  p.set_scan_name(j.scan_name);
  p.set_phase(static_cast<v1::JobPhase>(static_cast<int>(j.phase) + 1));
  p.set_time_step(j.time_step);
  p.set_iteration(j.iteration);
  p.set_total_iterations(j.total_iterations);
  p.set_elapsed_seconds(j.elapsed_seconds);
  p.set_eta_seconds(j.eta_seconds);
  p.set_loss(j.loss);
  p.set_psnr(j.psnr);
  p.set_version(j.version);
  p.set_error(j.error);
  p.set_created_unix_ms(j.created_unix_ms);
  p.set_finished_unix_ms(j.finished_unix_ms);
  for (const auto& [k, v] : j.metrics) (*p.mutable_metrics())[k] = v;
  return p;
}

v1::Version ToProto(const VersionInfo& v, int64_t deployed_version) {
  v1::Version p;
  p.set_version(v.version);
  p.set_parent(v.parent);
  p.set_time_steps(v.time_steps);
  p.set_size_bytes(v.size_bytes);
  p.set_model_bytes(v.model_bytes);
  p.set_replay_bytes(v.replay_bytes);
  p.set_created_unix_ms(v.created_unix_ms);
  p.set_scan_id(v.scan_id);
  p.set_deployed(v.version == deployed_version);
  for (const auto& [k, val] : v.metrics) (*p.mutable_metrics())[k] = val;
  p.set_unavailable(v.unavailable);
  return p;
}

}  // namespace clnerf
