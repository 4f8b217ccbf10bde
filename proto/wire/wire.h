// The clnerf.v1 wire conversions that both ends need, in one place: cameras
// (core Camera <-> CameraSpec, with the pose checks the server applies to
// every incoming camera) and statuses (absl::Status -> grpc::Status at the
// server's boundary, as TF Serving's ToGRPCStatus; grpc::Status ->
// absl::Status and code names on the client). Server-only conversions (jobs,
// versions, scan headers) stay in server/proto_convert.
//
// Thread-safety: pure functions.
#ifndef CLNERF_PROTO_WIRE_WIRE_H_
#define CLNERF_PROTO_WIRE_WIRE_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "clnerf/v1/clnerf.pb.h"
#include "core/data/camera.h"
#include "grpcpp/support/status.h"

namespace clnerf {

// The camera as a wire spec: its pose (OpenCV internally) as a row-major 4x4
// with convention OPENCV, and its intrinsics.
v1::CameraSpec CameraToProto(const Camera& camera);
// Checks the pose (16 finite numbers, bottom row 0 0 0 1), the convention and
// the intrinsics (ValidateCamera); returns the camera in the internal OpenCV
// convention. `what` prefixes error messages (e.g. "frame 3").
absl::StatusOr<Camera> CameraFromProto(const v1::CameraSpec& spec, const std::string& what);

// absl and gRPC share the canonical code numbering.
grpc::Status ToGrpcStatus(const absl::Status& status);
absl::Status FromGrpcStatus(const grpc::Status& status);
// "INVALID_ARGUMENT", "UNAVAILABLE", ...
const char* StatusCodeName(grpc::StatusCode code);

}  // namespace clnerf

#endif  // CLNERF_PROTO_WIRE_WIRE_H_
