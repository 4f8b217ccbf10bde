#include "core/train/optimizer_state.h"

#include <cmath>
#include <random>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

OptimizerState RandomState(uint64_t seed, size_t grid, size_t mlp, size_t emb, size_t prop) {
  std::mt19937 rng{uint32_t(seed)};
  std::normal_distribution<float> n(0.0f, 1e-3f);
  OptimizerState s;
  s.step = 1234567;
  const size_t sizes[] = {grid, mlp, emb, prop};
  for (int b = 0; b < OptimizerState::kBlocks; ++b) {
    for (size_t i = 0; i < sizes[b]; ++i) {
      s.m[b].push_back(n(rng));
      s.v[b].push_back(std::abs(n(rng)) * 1e-3f);
    }
  }
  s.m[1][0] = 1e-40f;  // A denormal must survive too.
  return s;
}

TEST(OptimizerStateTest, RoundTripsBitForBit) {
  const OptimizerState s = RandomState(1, 1000, 300, 64, 0);
  const std::string bytes = s.Serialize();
  EXPECT_EQ(bytes.size(), s.bytes() + 4 + 4 + 8 + 4 + 4 * 8);
  absl::StatusOr<OptimizerState> r = OptimizerState::Deserialize(bytes);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(*r == s);
  EXPECT_EQ(r->Serialize(), bytes);
  OptimizerState other = *r;
  other.m[0][17] = std::nextafter(other.m[0][17], 1.0f);
  EXPECT_FALSE(other == s);  // The comparison sees one ulp.
}

TEST(OptimizerStateTest, CorruptOrTruncatedBytesAreDataLoss) {
  const std::string bytes = RandomState(2, 100, 30, 8, 5).Serialize();
  for (size_t cut : {size_t(0), size_t(3), size_t(10), size_t(30), bytes.size() - 1}) {
    absl::StatusOr<OptimizerState> r = OptimizerState::Deserialize(bytes.substr(0, cut));
    EXPECT_EQ(r.status().code(), absl::StatusCode::kDataLoss) << cut;
  }
  EXPECT_EQ(OptimizerState::Deserialize(bytes + "x").status().code(), absl::StatusCode::kDataLoss);
  std::string bad_magic = bytes;
  bad_magic[0] = 'X';
  EXPECT_EQ(OptimizerState::Deserialize(bad_magic).status().code(), absl::StatusCode::kDataLoss);
  std::string newer = bytes;
  newer[4] = 9;  // Format version 9.
  EXPECT_EQ(OptimizerState::Deserialize(newer).status().code(), absl::StatusCode::kFailedPrecondition);
  // A hostile block length is refused before anything is allocated.
  std::string huge = bytes;
  for (int i = 0; i < 8; ++i) huge[4 + 4 + 8 + 4 + i] = char(0xff);
  EXPECT_EQ(OptimizerState::Deserialize(huge).status().code(), absl::StatusCode::kDataLoss);
  // A negative second moment cannot come from Adam.
  OptimizerState neg = RandomState(3, 10, 10, 4, 0);
  neg.v[1][3] = -1.0f;
  EXPECT_EQ(OptimizerState::Deserialize(neg.Serialize()).status().code(), absl::StatusCode::kDataLoss);
}

TEST(OptimizerStateTest, ResumesOnlyTheModelItBelongsToOrOneThatGrewByATimeStep) {
  ModelParams p;
  p.grid.resize(100);
  p.mlp.resize(30);
  p.emb.resize(8);
  const OptimizerState s = RandomState(4, 100, 30, 8, 0);
  EXPECT_TRUE(s.CompatibleWith(p).ok());
  p.emb.resize(16);  // A new time step's embedding row.
  EXPECT_TRUE(s.CompatibleWith(p).ok());
  p.emb.resize(4);
  EXPECT_EQ(s.CompatibleWith(p).code(), absl::StatusCode::kFailedPrecondition);
  p.emb.resize(8);
  p.grid.resize(101);
  const absl::Status st = s.CompatibleWith(p);
  EXPECT_EQ(st.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(st.message().find("grid"), std::string::npos) << st;
}

}  // namespace
}  // namespace clnerf
