// Test helper: an occupancy grid whose cells are set from a rule, for the
// tests of the grid and of the ray marcher. Not thread-safe (as the grid's
// updates are not).
#ifndef CLNERF_CORE_FIELD_OCCUPANCY_TEST_UTIL_H_
#define CLNERF_CORE_FIELD_OCCUPANCY_TEST_UTIL_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "core/field/occupancy_grid.h"

namespace clnerf {

// Refreshes every cell of `grid` once with density `sigma(cell)`.
inline void SetEveryCell(OccupancyGrid* grid, const std::function<float(uint32_t)>& sigma) {
  std::vector<uint32_t> cells(grid->num_cells());
  std::vector<float> values(grid->num_cells());
  for (uint32_t i = 0; i < cells.size(); ++i) {
    cells[i] = i;
    values[i] = sigma(i);
  }
  grid->ApplyUpdate(cells, values);
}

}  // namespace clnerf

#endif  // CLNERF_CORE_FIELD_OCCUPANCY_TEST_UTIL_H_
