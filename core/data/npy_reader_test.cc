#include "core/data/npy_reader.h"

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <unistd.h>

namespace clnerf {
namespace {

// A .npy file as numpy writes it: magic, version, header length, the header
// dict padded with spaces to a multiple of 64 bytes and ended by '\n', data.
std::string Npy(const std::string& dict, const std::string& data, int major = 1) {
  std::string out = "\x93NUMPY";
  out.push_back(char(major));
  out.push_back(0);
  const size_t len_bytes = major == 1 ? 2 : 4;
  std::string header = dict;
  while ((out.size() + len_bytes + header.size() + 1) % 64 != 0) header.push_back(' ');
  header.push_back('\n');
  const uint32_t len = uint32_t(header.size());
  out.append(reinterpret_cast<const char*>(&len), len_bytes);
  return out + header + data;
}

template <typename T>
std::string Bytes(const std::vector<T>& v) {
  return std::string(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
}

TEST(NpyReaderTest, ReadsFloat64Version1) {
  const std::vector<double> v = {1.5, -2.25, 3e10, 4, 5, 6};
  absl::StatusOr<NpyArray> a =
      ParseNpy(Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", Bytes(v)), "x");
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->shape, (std::vector<int64_t>{2, 3}));
  EXPECT_EQ(a->data, v);
  EXPECT_EQ(a->at(1, 0), 4.0);
  EXPECT_EQ(a->at(0, 2), 3e10);
}

TEST(NpyReaderTest, ReadsFloat32AndVersion2Headers) {
  const std::vector<float> v = {0.5f, 1.25f, -7.0f};
  for (int major : {1, 2, 3}) {
    absl::StatusOr<NpyArray> a = ParseNpy(
        Npy("{\"descr\":\"<f4\",\"fortran_order\":False,\"shape\":(3,)}", Bytes(v), major), "x");
    ASSERT_TRUE(a.ok()) << a.status();
    EXPECT_EQ(a->shape, (std::vector<int64_t>{3}));
    EXPECT_EQ(a->data, (std::vector<double>{0.5, 1.25, -7.0}));
  }
  // A scalar, and a Python 2 "L" suffix.
  absl::StatusOr<NpyArray> s =
      ParseNpy(Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (), }",
                   Bytes(std::vector<double>{2.0})),
               "x");
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_TRUE(s->shape.empty());
  EXPECT_EQ(s->data, std::vector<double>{2.0});
  absl::StatusOr<NpyArray> l =
      ParseNpy(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (1L, 2L), }",
                   Bytes(std::vector<float>{1, 2})),
               "x");
  ASSERT_TRUE(l.ok()) << l.status();
  EXPECT_EQ(l->shape, (std::vector<int64_t>{1, 2}));
}

TEST(NpyReaderTest, RejectsWhatItCannotRead) {
  const std::string d8 = Bytes(std::vector<double>{1, 2});
  const auto expect_invalid = [](const std::string& bytes, const std::string& what) {
    absl::StatusOr<NpyArray> a = ParseNpy(bytes, "poses.npy");
    EXPECT_EQ(a.status().code(), absl::StatusCode::kInvalidArgument) << what;
    EXPECT_NE(a.status().message().find("poses.npy"), std::string::npos) << a.status();
    EXPECT_NE(a.status().message().find(what), std::string::npos) << a.status();
  };
  expect_invalid(Npy("{'descr': '>f8', 'fortran_order': False, 'shape': (2,), }", d8), "'>f8'");
  expect_invalid(Npy("{'descr': '<i8', 'fortran_order': False, 'shape': (2,), }", d8), "'<i8'");
  expect_invalid(Npy("{'descr': '<f8', 'fortran_order': True, 'shape': (2,), }", d8), "Fortran");
  expect_invalid(Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }", d8), "truncated");
  expect_invalid(Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (1,), }", d8), "trailing");
  expect_invalid(Npy("{'descr': '<f8', 'shape': (2,), }", d8), "malformed");
  expect_invalid(Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (2,), 'x': 1}", d8),
                 "malformed");
  expect_invalid(Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (a,), }", d8), "malformed");
  expect_invalid(Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (2,), }", d8, 9),
                 "version");
  expect_invalid("PK\x03\x04 a zip file", "magic");
  const std::string good = Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (2,), }", d8);
  expect_invalid(good.substr(0, 30), "truncated");
}

TEST(NpyReaderTest, ReadsFilesAndReportsMissingOnes) {
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() / ("clnerf_npy_" + std::to_string(getpid()) + ".npy");
  std::ofstream(path, std::ios::binary)
      << Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (1, 2), }",
             Bytes(std::vector<double>{3, 4}));
  absl::StatusOr<NpyArray> a = ReadNpy(path.string());
  std::filesystem::remove(path);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->data, (std::vector<double>{3, 4}));
  EXPECT_EQ(ReadNpy(path.string()).status().code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace clnerf
