// NpyReader: reads a NumPy .npy file (format versions 1.0, 2.0 and 3.0) of
// little-endian floats into a dense array of doubles. It exists for LLFF's
// poses_bounds.npy and reads only what such files hold: dtype '<f8' (float64)
// or '<f4' (float32), C order, any shape. Other dtypes (integers, big-endian,
// structured), Fortran order, or a data size that does not match the shape are
// INVALID_ARGUMENT naming the file. Pure functions; thread-safe.
#ifndef CLNERF_CORE_DATA_NPY_READER_H_
#define CLNERF_CORE_DATA_NPY_READER_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace clnerf {

struct NpyArray {
  std::vector<int64_t> shape;  // () for a scalar.
  std::vector<double> data;    // Product of shape entries, C (row-major) order.
  // Element (row, col) of a 2-D array.
  double at(int64_t row, int64_t col) const { return data[size_t(row * shape[1] + col)]; }
};

// Parses the bytes of a .npy file; `name` is used in error messages.
absl::StatusOr<NpyArray> ParseNpy(const std::string& bytes, const std::string& name);

// Reads and parses `path`. NOT_FOUND when the file cannot be opened.
absl::StatusOr<NpyArray> ReadNpy(const std::string& path);

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_NPY_READER_H_
