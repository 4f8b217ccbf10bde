#include "core/data/ply_reader.h"

#include <cmath>
#include <algorithm>
#include <cstring>
#include <fstream>
#include <sstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"

namespace clnerf {
namespace {

// Byte size of a PLY scalar type; 0 when unknown.
int TypeSize(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "int32" || t == "uint32" || t == "float" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

double ReadScalar(const char* p, const std::string& t) {
  auto get = [p](auto v) {
    std::memcpy(&v, p, sizeof(v));
    return double(v);
  };
  if (t == "char" || t == "int8") return get(int8_t());
  if (t == "uchar" || t == "uint8") return get(uint8_t());
  if (t == "short" || t == "int16") return get(int16_t());
  if (t == "ushort" || t == "uint16") return get(uint16_t());
  if (t == "int" || t == "int32") return get(int32_t());
  if (t == "uint" || t == "uint32") return get(uint32_t());
  if (t == "float" || t == "float32") return get(float());
  return get(double());
}

}  // namespace

absl::StatusOr<std::vector<Eigen::Vector3f>> ReadPlyPoints(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("point cloud not found: ", path));
  auto bad = [&](const std::string& why) { return absl::InvalidArgumentError(absl::StrCat(path, ": ", why)); };
  std::string line;
  if (!std::getline(in, line) || absl::StripTrailingAsciiWhitespace(line) != "ply") return bad("not a PLY file");
  bool ascii = false, binary = false, in_vertex = false, seen_vertex = false;
  long long count = 0;
  std::vector<std::string> types, names;
  while (true) {
    if (!std::getline(in, line)) return bad("header ends before end_header");
    const std::vector<std::string> tok = absl::StrSplit(absl::StripAsciiWhitespace(line), ' ', absl::SkipEmpty());
    if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info") continue;
    if (tok[0] == "end_header") break;
    if (tok[0] == "format") {
      if (tok.size() < 2) return bad("bad format line");
      ascii = tok[1] == "ascii";
      binary = tok[1] == "binary_little_endian";
      if (!ascii && !binary) return bad(absl::StrCat("unsupported PLY format '", tok[1], "' (ascii or binary_little_endian)"));
    } else if (tok[0] == "element") {
      if (tok.size() != 3) return bad("bad element line");
      in_vertex = tok[1] == "vertex";
      if (in_vertex) {
        if (seen_vertex) return bad("two vertex elements");
        if (!absl::SimpleAtoi(tok[2], &count) || count < 0 || count > kMaxPlyVertices) {
          return bad(absl::StrCat("vertex count must be in [0, ", kMaxPlyVertices, "]"));
        }
        seen_vertex = true;
      } else if (!seen_vertex) {
        return bad("elements before the vertices are not supported");
      }
    } else if (tok[0] == "property") {
      if (!in_vertex) continue;
      if (tok.size() != 3) return bad("vertex properties must be scalars (no lists)");
      if (TypeSize(tok[1]) == 0) return bad(absl::StrCat("unknown property type '", tok[1], "'"));
      types.push_back(tok[1]);
      names.push_back(tok[2]);
    } else {
      return bad(absl::StrCat("unexpected header line '", line, "'"));
    }
  }
  if (!ascii && !binary) return bad("no format line");
  if (!seen_vertex) return bad("no vertex element");
  int ix = -1, iy = -1, iz = -1;
  for (int k = 0; k < int(names.size()); ++k) {
    if (names[k] == "x") ix = k;
    if (names[k] == "y") iy = k;
    if (names[k] == "z") iz = k;
  }
  if (ix < 0 || iy < 0 || iz < 0) return bad("vertices have no x, y, z");
  std::vector<Eigen::Vector3f> pts;
  pts.reserve(size_t(std::min<long long>(count, 1 << 20)));
  if (ascii) {
    for (long long v = 0; v < count; ++v) {
      if (!std::getline(in, line)) return bad(absl::StrCat("truncated: ", v, " of ", count, " vertices"));
      const std::vector<std::string> tok = absl::StrSplit(absl::StripAsciiWhitespace(line), ' ', absl::SkipEmpty());
      if (tok.size() < names.size()) return bad(absl::StrCat("vertex ", v, " has ", tok.size(), " values"));
      Eigen::Vector3f p;
      const int idx[3] = {ix, iy, iz};
      for (int c = 0; c < 3; ++c) {
        double d = 0;
        if (!absl::SimpleAtod(tok[idx[c]], &d)) return bad(absl::StrCat("vertex ", v, ": bad number"));
        p[c] = float(d);
      }
      if (!p.allFinite()) return bad(absl::StrCat("vertex ", v, " is not finite"));
      pts.push_back(p);
    }
  } else {
    std::vector<int> offset(names.size());
    int stride = 0;
    for (size_t k = 0; k < names.size(); ++k) {
      offset[k] = stride;
      stride += TypeSize(types[k]);
    }
    std::vector<char> rec(stride);
    for (long long v = 0; v < count; ++v) {
      if (!in.read(rec.data(), stride)) return bad(absl::StrCat("truncated: ", v, " of ", count, " vertices"));
      const Eigen::Vector3f p(float(ReadScalar(&rec[offset[ix]], types[ix])),
                              float(ReadScalar(&rec[offset[iy]], types[iy])),
                              float(ReadScalar(&rec[offset[iz]], types[iz])));
      if (!p.allFinite()) return bad(absl::StrCat("vertex ", v, " is not finite"));
      pts.push_back(p);
    }
  }
  return pts;
}

}  // namespace clnerf
