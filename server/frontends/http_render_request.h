// HttpRenderRequest: the query of `GET /api/render`, parsed and checked. The
// web viewer and curl users describe a camera either as a look-at
// (eye, target, up) or as a camera-to-world matrix, with a vertical field of
// view or pixel focal lengths:
//
//   width, height          pixels (required)
//   eye, target, up        "x,y,z" each, world coordinates (look-at form)
//   c2w                    12 numbers, row-major 3x4 [R | t] (matrix form)
//   convention             opencv (default: x right, y down, looks along +z)
//                          or opengl (x right, y up, looks along -z); c2w only
//   fov                    vertical field of view in degrees (default 50)
//   fx, fy, cx, cy         pixel intrinsics instead of fov (cx, cy default
//                          to the image centre)
//   time                   time step (default: the version's latest)
//   version                model version (default 0 = the deployed one)
//   format, quality        jpeg (default, quality 1..100, default 85) or png
//   view                   the client's view id (1..64 of [A-Za-z0-9_-]): a
//                          newer render of the same view cancels this one
//   timeout_ms             the render's deadline (default 30000)
//
// Unknown or repeated parameters are errors, so a typo does not silently
// render something else. Every error is INVALID_ARGUMENT naming the
// parameter. The pixel budget, time-step range and version are checked by
// ModelHost::Render, as for gRPC.
//
// Thread-safety: pure functions.
#ifndef CLNERF_SERVER_HTTP_RENDER_REQUEST_H_
#define CLNERF_SERVER_HTTP_RENDER_REQUEST_H_

#include <cstdint>
#include <map>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "core/data/camera.h"

namespace clnerf {

enum class HttpImageFormat { kJpeg, kPng };

struct HttpRenderRequest {
  Camera camera;  // World space, OpenCV convention; ValidateCamera passed.
  std::optional<int> time_step;
  int64_t version = 0;
  HttpImageFormat format = HttpImageFormat::kJpeg;
  int quality = 85;
  std::string view_id;
  int64_t timeout_ms = 30000;
};

// `params`: the URL query (httplib::Params is this multimap).
absl::StatusOr<HttpRenderRequest> ParseRenderQuery(const std::multimap<std::string, std::string>& params);

// A look-at camera pose in the OpenCV convention: looks from `eye` towards
// `target`, with `up` pointing up in the image. INVALID_ARGUMENT when eye ==
// target or up is parallel to the viewing direction.
absl::StatusOr<Pose> LookAtPose(const Eigen::Vector3f& eye, const Eigen::Vector3f& target, const Eigen::Vector3f& up);

}  // namespace clnerf

#endif  // CLNERF_SERVER_HTTP_RENDER_REQUEST_H_
