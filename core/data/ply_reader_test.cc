// PLY point clouds: ASCII and binary little-endian vertices with extra
// properties, and every malformed file a clear INVALID_ARGUMENT.
#include "core/data/ply_reader.h"

#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

std::string Write(const std::string& name, const std::string& bytes) {
  const std::string p = (std::filesystem::temp_directory_path() /
                         ("clnerf_ply_" + name + "_" + std::to_string(::getpid()) + ".ply"))
                            .string();
  std::ofstream(p, std::ios::binary) << bytes;
  return p;
}

TEST(PlyReaderTest, ReadsAsciiWithColours) {
  const std::string p = Write("ascii",
                              "ply\nformat ascii 1.0\ncomment nerfstudio\nelement vertex 2\nproperty float x\n"
                              "property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n"
                              "property uchar blue\nend_header\n1 2 3 255 0 0\n-0.5 4e-1 7 0 255 0\n");
  absl::StatusOr<std::vector<Eigen::Vector3f>> pts = ReadPlyPoints(p);
  ASSERT_TRUE(pts.ok()) << pts.status();
  ASSERT_EQ(pts->size(), 2u);
  EXPECT_EQ((*pts)[0], Eigen::Vector3f(1, 2, 3));
  EXPECT_EQ((*pts)[1], Eigen::Vector3f(-0.5f, 0.4f, 7));
  std::filesystem::remove(p);
}

TEST(PlyReaderTest, ReadsBinaryLittleEndianWithMixedTypesAndFaces) {
  std::string b =
      "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty uchar red\nproperty double x\n"
      "property double y\nproperty double z\nproperty float nx\nelement face 1\nproperty list uchar int vertex_indices\n"
      "end_header\n";
  for (int v = 0; v < 2; ++v) {
    const unsigned char red = 7;
    const double xyz[3] = {0.25 + v, -1.5, 1e3};
    const float nx = 1.0f;
    b.append(reinterpret_cast<const char*>(&red), 1);
    b.append(reinterpret_cast<const char*>(xyz), sizeof(xyz));
    b.append(reinterpret_cast<const char*>(&nx), sizeof(nx));
  }
  b += "faces are ignored";
  const std::string p = Write("binary", b);
  absl::StatusOr<std::vector<Eigen::Vector3f>> pts = ReadPlyPoints(p);
  ASSERT_TRUE(pts.ok()) << pts.status();
  ASSERT_EQ(pts->size(), 2u);
  EXPECT_EQ((*pts)[1], Eigen::Vector3f(1.25f, -1.5f, 1000.0f));
  std::filesystem::remove(p);
}

TEST(PlyReaderTest, MalformedFilesAreInvalidArgument) {
  const std::string head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  const std::string cases[] = {
      "not a ply\n",
      "ply\nformat binary_big_endian 1.0\nelement vertex 0\nend_header\n",
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\nend_header\n",
      "ply\nformat ascii 1.0\nelement vertex 99999999999\nproperty float x\nend_header\n",
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",  // No end_header.
      head + "1 2 3\n",                                              // Truncated.
      head + "1 2 3\nnan 0 0\n",                                     // Not finite.
      head + "1 2 3\n1 two 3\n",                                     // Not a number.
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nend_header\n0123456789ab",                  // Truncated binary.
  };
  int k = 0;
  for (const std::string& c : cases) {
    const std::string p = Write("bad" + std::to_string(k++), c);
    absl::StatusOr<std::vector<Eigen::Vector3f>> pts = ReadPlyPoints(p);
    EXPECT_EQ(pts.status().code(), absl::StatusCode::kInvalidArgument) << "case " << k << ": " << pts.status();
    std::filesystem::remove(p);
  }
  EXPECT_EQ(ReadPlyPoints("/nonexistent/cloud.ply").status().code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace clnerf
