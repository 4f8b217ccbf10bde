#include "proto/wire/wire.h"

#include <cmath>

#include "absl/strings/str_cat.h"

namespace clnerf {

v1::CameraSpec CameraToProto(const Camera& camera) {
  clnerf::v1::CameraSpec spec;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) spec.add_pose(camera.c2w(r, c));
  for (float x : {0.0f, 0.0f, 0.0f, 1.0f}) spec.add_pose(x);
  spec.set_convention(clnerf::v1::POSE_CONVENTION_OPENCV);
  const Intrinsics& in = camera.intrinsics;
  clnerf::v1::Intrinsics* out = spec.mutable_intrinsics();
  out->set_width(in.width);
  out->set_height(in.height);
  out->set_fx(in.fx);
  out->set_fy(in.fy);
  out->set_cx(in.cx);
  out->set_cy(in.cy);
  out->set_k1(in.k1);
  out->set_k2(in.k2);
  out->set_p1(in.p1);
  out->set_p2(in.p2);
  return spec;
}

grpc::Status ToGrpcStatus(const absl::Status& s) {
  if (s.ok()) return grpc::Status::OK;
  // absl and gRPC share the canonical code numbering.
  return grpc::Status(static_cast<grpc::StatusCode>(static_cast<int>(s.code())), std::string(s.message()));
}

absl::StatusOr<Camera> CameraFromProto(const v1::CameraSpec& spec, const std::string& what) {
  auto bad = [&](const std::string& why) { return absl::InvalidArgumentError(absl::StrCat(what, ": ", why)); };
  if (spec.pose_size() != 16) return bad(absl::StrCat("pose must have 16 numbers (4x4 row-major), got ", spec.pose_size()));
  for (float v : spec.pose()) {
    if (!std::isfinite(v)) return bad("pose has NaN/Inf entries");
  }
  if (std::abs(spec.pose(12)) > 1e-4f || std::abs(spec.pose(13)) > 1e-4f || std::abs(spec.pose(14)) > 1e-4f ||
      std::abs(spec.pose(15) - 1.0f) > 1e-4f) {
    return bad("pose bottom row must be 0 0 0 1");
  }
  Pose p;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) p(r, c) = spec.pose(r * 4 + c);
  PoseConvention conv;
  switch (spec.convention()) {
    case v1::POSE_CONVENTION_UNSPECIFIED:
    case v1::POSE_CONVENTION_OPENGL: conv = PoseConvention::kOpenGL; break;
    case v1::POSE_CONVENTION_OPENCV: conv = PoseConvention::kOpenCV; break;
    default: return bad(absl::StrCat("unknown pose convention ", int(spec.convention())));
  }
  if (!spec.has_intrinsics()) return bad("intrinsics are missing");
  const v1::Intrinsics& in = spec.intrinsics();
  Camera cam;
  cam.intrinsics = Intrinsics{in.width(), in.height(), in.fx(), in.fy(), in.cx(), in.cy(),
                              in.k1(),    in.k2(),     in.p1(), in.p2()};
  cam.c2w = ConvertPose(p, conv);
  if (absl::Status s = ValidateCamera(cam); !s.ok()) return bad(std::string(s.message()));
  return cam;
}

absl::Status FromGrpcStatus(const grpc::Status& s) {
  if (s.ok()) return absl::OkStatus();
  return absl::Status(static_cast<absl::StatusCode>(static_cast<int>(s.error_code())), s.error_message());
}

const char* StatusCodeName(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::OK: return "OK";
    case grpc::StatusCode::CANCELLED: return "CANCELLED";
    case grpc::StatusCode::UNKNOWN: return "UNKNOWN";
    case grpc::StatusCode::INVALID_ARGUMENT: return "INVALID_ARGUMENT";
    case grpc::StatusCode::DEADLINE_EXCEEDED: return "DEADLINE_EXCEEDED";
    case grpc::StatusCode::NOT_FOUND: return "NOT_FOUND";
    case grpc::StatusCode::ALREADY_EXISTS: return "ALREADY_EXISTS";
    case grpc::StatusCode::PERMISSION_DENIED: return "PERMISSION_DENIED";
    case grpc::StatusCode::RESOURCE_EXHAUSTED: return "RESOURCE_EXHAUSTED";
    case grpc::StatusCode::FAILED_PRECONDITION: return "FAILED_PRECONDITION";
    case grpc::StatusCode::ABORTED: return "ABORTED";
    case grpc::StatusCode::OUT_OF_RANGE: return "OUT_OF_RANGE";
    case grpc::StatusCode::UNIMPLEMENTED: return "UNIMPLEMENTED";
    case grpc::StatusCode::INTERNAL: return "INTERNAL";
    case grpc::StatusCode::UNAVAILABLE: return "UNAVAILABLE";
    case grpc::StatusCode::DATA_LOSS: return "DATA_LOSS";
    case grpc::StatusCode::UNAUTHENTICATED: return "UNAUTHENTICATED";
    default: return "UNKNOWN";
  }
}

}  // namespace clnerf
