// PLY point clouds: reads the vertex positions of a .ply file, as nerfstudio's
// transforms.json key `ply_file_path` names one (ns-process-data writes
// `x y z red green blue` in ASCII; Open3D and COLMAP write binary). Formats
// `ascii 1.0` and `binary_little_endian 1.0`; the vertex element may carry
// any scalar properties (only x, y, z are kept) but no lists; other elements
// (faces) after the vertices are ignored.
//
// Pure function; thread-safe.
#ifndef CLNERF_CORE_DATA_PLY_READER_H_
#define CLNERF_CORE_DATA_PLY_READER_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "Eigen/Core"

namespace clnerf {

// Most vertices a cloud may hold (a larger header is refused before any
// allocation).
inline constexpr long long kMaxPlyVertices = 20'000'000;

// The vertices' positions. NOT_FOUND when the file is missing;
// INVALID_ARGUMENT naming the problem for a malformed, truncated or
// unsupported file, or a non-finite coordinate.
absl::StatusOr<std::vector<Eigen::Vector3f>> ReadPlyPoints(const std::string& path);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_PLY_READER_H_
