#include "server/store/model_registry.h"

#include <atomic>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

std::shared_ptr<const Servable> MakeServable(int64_t v) {
  auto s = std::make_shared<Servable>();
  s->info.version = v;
  ModelOptions mo;
  mo.grid.levels = 2;
  mo.grid.log2_table_size = 10;
  mo.grid.finest_resolution = 16;
  mo.occupancy.resolution = 16;
  s->state.model = std::make_shared<const NgpModel>(
      *NgpModel::Create(mo, Normalization{}, SceneKind::kBounded, Eigen::Vector3f::Ones(), 1, uint64_t(v)));
  return s;
}

TEST(ModelRegistryTest, GetBeforeDeployIsFailedPreconditionAndUnknownIsNotFound) {
  ModelRegistry reg([](int64_t v) -> absl::StatusOr<std::shared_ptr<const Servable>> {
    if (v == 3) return MakeServable(3);
    return absl::NotFoundError(absl::StrCat("version ", v, " does not exist"));
  }, nullptr);
  EXPECT_EQ(reg.Get(0).status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(reg.Get(9).status().code(), absl::StatusCode::kNotFound);
  auto three = reg.Get(3);
  ASSERT_TRUE(three.ok());
  EXPECT_EQ((*three)->info.version, 3);
  reg.Deploy(MakeServable(1));
  EXPECT_EQ(reg.deployed_version(), 1);
  EXPECT_EQ((*reg.Get(0))->info.version, 1);
}

// Readers take snapshots while a writer keeps swapping the deployed version:
// no reader ever sees null, a torn servable, or a version going backwards,
// and a snapshot stays valid after it was replaced.
TEST(ModelRegistryTest, ReadersSeeMonotonicCompleteSnapshotsWhileAWriterSwaps) {
  constexpr int kVersions = 60;
  std::vector<std::shared_ptr<const Servable>> prepared;
  for (int v = 1; v <= kVersions; ++v) prepared.push_back(MakeServable(v));
  ModelRegistry reg([](int64_t v) -> absl::StatusOr<std::shared_ptr<const Servable>> {
    return absl::NotFoundError("not on disk");
  }, nullptr);
  reg.Deploy(prepared[0]);
  std::atomic<bool> done{false};
  std::atomic<int> failures{0};
  std::atomic<long> reads{0};
  std::vector<std::thread> readers;
  for (int r = 0; r < 4; ++r) {
    readers.emplace_back([&] {
      int64_t last = 0;
      while (!done.load()) {
        auto s = reg.Get(0);
        if (!s.ok() || *s == nullptr || (*s)->state.model == nullptr || (*s)->info.version < last ||
            (*s)->model().num_time_steps() != 1) {
          failures++;
          continue;
        }
        last = (*s)->info.version;
        // Read the snapshot's weights after it may have been swapped out.
        double sum = 0;
        for (float w : (*s)->model().params().mlp) sum += w;
        if (!std::isfinite(sum) || (*s)->model().params().mlp.empty()) failures++;
        reads++;
      }
    });
  }
  for (int v = 1; v < kVersions; ++v) {
    reg.Deploy(prepared[v]);
    // Let the readers make progress between swaps.
    const long target = reads.load() + 4;
    for (int spin = 0; spin < 2000 && reads.load() < target; ++spin)
      std::this_thread::sleep_for(std::chrono::microseconds(100));
  }
  done = true;
  for (auto& t : readers) t.join();
  EXPECT_EQ(failures.load(), 0);
  EXPECT_GE(reads.load(), 4 * (kVersions - 1));
  EXPECT_EQ(reg.deployed_version(), kVersions);
}

}  // namespace
}  // namespace clnerf
