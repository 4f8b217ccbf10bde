#include "core/train/optimizer_state.h"

#include <cstring>

#include "absl/strings/str_cat.h"
#include "core/io/byte_io.h"

namespace clnerf {
namespace {

constexpr char kMagic[4] = {'C', 'L', 'O', 'S'};
constexpr uint32_t kVersion = 1;
constexpr const char* kBlockNames[OptimizerState::kBlocks] = {"grid", "mlp", "emb", "proposal"};

const std::vector<float>& Block(const ModelParams& p, int b) {
  switch (b) {
    case 0:
      return p.grid;
    case 1:
      return p.mlp;
    case 2:
      return p.emb;
    default:
      return p.proposal;
  }
}

bool SameBits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0);
}

}  // namespace

size_t OptimizerState::bytes() const {
  size_t n = 0;
  for (int b = 0; b < kBlocks; ++b) n += (m[b].size() + v[b].size()) * sizeof(float);
  return n;
}

absl::Status OptimizerState::CompatibleWith(const ModelParams& params) const {
  for (int b = 0; b < kBlocks; ++b) {
    const size_t have = m[b].size(), want = Block(params, b).size();
    if (b == 2 ? have > want : have != want) {
      return absl::FailedPreconditionError(absl::StrCat("the optimiser state does not match the model: its ",
                                                        kBlockNames[b], " block has ", have,
                                                        " entries, the model ", want));
    }
  }
  return absl::OkStatus();
}

std::string OptimizerState::Serialize() const {
  std::string out;
  out.reserve(bytes() + 64);
  ByteWriter w(&out);
  w.Bytes(std::string_view(kMagic, 4));
  w.Put(kVersion);
  w.Put(uint64_t(step));
  w.Put(uint32_t(kBlocks));
  for (int b = 0; b < kBlocks; ++b) {
    w.Put(uint64_t(m[b].size()));
    w.Array(m[b]);
    w.Array(v[b]);
  }
  return out;
}

absl::StatusOr<OptimizerState> OptimizerState::Deserialize(const std::string& bytes) {
  ByteReader r(bytes);
  const auto corrupt = [](const std::string& what) {
    return absl::DataLossError(absl::StrCat("optimiser state is corrupt: ", what));
  };
  std::string_view magic;
  uint32_t version = 0, blocks = 0;
  if (!r.Bytes(4, &magic) || std::memcmp(magic.data(), kMagic, 4) != 0) return corrupt("bad magic");
  if (!r.Get(&version)) return corrupt("truncated header");
  if (version != kVersion) {
    return absl::FailedPreconditionError(
        absl::StrCat("optimiser state format version ", version, " is not supported (this build reads ", kVersion, ")"));
  }
  OptimizerState s;
  if (!r.Get(&s.step) || !r.Get(&blocks)) return corrupt("truncated header");
  if (blocks != uint32_t(kBlocks)) return corrupt(absl::StrCat(blocks, " blocks, expected ", kBlocks));
  for (int b = 0; b < kBlocks; ++b) {
    uint64_t n = 0;
    if (!r.Get(&n) || n > r.remaining() / (2 * sizeof(float))) return corrupt(absl::StrCat("block ", kBlockNames[b]));
    if (!r.Array(n, &s.m[b]) || !r.Array(n, &s.v[b])) return corrupt(absl::StrCat("block ", kBlockNames[b]));
    for (float x : s.v[b]) {
      if (!(x >= 0)) return corrupt(absl::StrCat("a negative or NaN second moment in block ", kBlockNames[b]));
    }
  }
  if (!r.done()) return corrupt("trailing bytes");
  return s;
}

bool operator==(const OptimizerState& a, const OptimizerState& b) {
  if (a.step != b.step) return false;
  for (int i = 0; i < OptimizerState::kBlocks; ++i) {
    if (!SameBits(a.m[i], b.m[i]) || !SameBits(a.v[i], b.v[i])) return false;
  }
  return true;
}

}  // namespace clnerf
