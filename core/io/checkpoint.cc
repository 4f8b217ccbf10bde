#include "core/io/checkpoint.h"

#include "Eigen/LU"

#include <zlib.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <tuple>
#include <type_traits>
#include <utility>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/io/byte_io.h"
#include "core/io/durable_file.h"
#include "core/io/half.h"

namespace clnerf {
namespace {

constexpr size_t kMagicSize = 8;
constexpr size_t kVersionEnd = 12;     // magic + version.
constexpr size_t kHeaderSize = 20;     // magic + version + total size.
constexpr size_t kChecksumSize = 4;
constexpr size_t kSectionHeaderSize = 12;  // tag + length.
static_assert(sizeof(kCheckpointMagic) == kMagicSize + 1);

// Sanity limits applied to untrusted input before any layout is built from it
// (so a crafted file cannot make the layout code loop or allocate without
// bound). They are far above any real model.
constexpr int kMaxTimeSteps = 1 << 20;
constexpr int kMaxLayers = 4096;
constexpr int kMaxWidth = 1 << 16;
constexpr int kMaxGridResolution = 1 << 20;
constexpr float kMaxBound = 1e30f;

// Field-by-field encoders below must list every member of the options structs.
// These asserts catch most additions (a new member usually changes the size):
// when one fires, encode the new field in a new section (see checkpoint.h) and
// update the expected size here.
static_assert(sizeof(HashGridOptions) == 5 * sizeof(int), "update the checkpoint format (HGOP)");
static_assert(sizeof(NetworkOptions) == 8 * sizeof(int), "update the checkpoint format (NTOP)");
static_assert(sizeof(OccupancyGridOptions) == 3 * sizeof(int) + 2 * sizeof(float),
              "update the checkpoint format (OGOP)");
static_assert(sizeof(MarchOptions) == sizeof(int) + 3 * sizeof(float), "update the checkpoint format (MROP)");
static_assert(sizeof(Normalization) == 14 * sizeof(float), "update the checkpoint format (MODL)");
static_assert(sizeof(ProposalFieldOptions) == 5 * sizeof(int), "update the checkpoint format (SMOP)");
static_assert(sizeof(ProposalOptions) == 3 * sizeof(int) + sizeof(float) + 2 * sizeof(ProposalFieldOptions),
              "update the checkpoint format (SMOP)");
constexpr size_t kSamplerOptionsSize = 4 + 3 * 4 + 4 + 2 * 5 * 4;

constexpr uint32_t Tag(const char (&s)[5]) {
  return uint32_t(uint8_t(s[0])) | uint32_t(uint8_t(s[1])) << 8 | uint32_t(uint8_t(s[2])) << 16 |
         uint32_t(uint8_t(s[3])) << 24;
}

// Sections. All are critical (upper-case first letter). Versions 1 and 2 share
// all but the occupancy section; PENC is new in version 2.
constexpr uint32_t kTagModel = Tag("MODL");             // Kind, normalisation, background, steps.
constexpr uint32_t kTagGridOptions = Tag("HGOP");       // HashGridOptions.
constexpr uint32_t kTagNetworkOptions = Tag("NTOP");    // NetworkOptions.
constexpr uint32_t kTagOccupancyOptions = Tag("OGOP");  // OccupancyGridOptions.
constexpr uint32_t kTagMarchOptions = Tag("MROP");      // MarchOptions.
constexpr uint32_t kTagParamEncoding = Tag("PENC");    // v2: uint32 ParamEncoding of the blocks below.
constexpr uint32_t kTagGridParams = Tag("PGRD");        // float32[] or binary16[] hash tables.
constexpr uint32_t kTagMlpParams = Tag("PMLP");         // float32[] or binary16[] MLP weights.
constexpr uint32_t kTagEmbParams = Tag("PEMB");         // float32[] or binary16[] embedding rows.
constexpr uint32_t kTagOccupancyV1 = Tag("OCCG");       // v1: occupancy grid state, raw.
constexpr uint32_t kTagOccupancy = Tag("OCCP");         // v2: occupancy grid state, packed.
constexpr uint32_t kTagSamplerOptions = Tag("SMOP");   // v5: sampler kind + ProposalOptions.
constexpr uint32_t kTagProposalParams = Tag("PPRP");   // v5: float32[] or binary16[] proposal fields.
constexpr uint32_t kTagMetadata = Tag("META");          // CheckpointExtras::metadata.
constexpr uint32_t kTagExtraSection = Tag("XSEC");      // One CheckpointExtras::sections entry.
// Ancillary (rendering never reads it): the occupied cells' density EMA.
constexpr uint32_t kTagOccupiedDensity = Tag("occd");

std::string TagName(uint32_t tag) {
  const char c[4] = {char(tag & 0xff), char((tag >> 8) & 0xff), char((tag >> 16) & 0xff),
                     char((tag >> 24) & 0xff)};
  return absl::CHexEscape(absl::string_view(c, 4));
}

// Whether `tag` is a section of format `version`.
bool KnownTag(uint32_t tag, uint32_t version) {
  switch (tag) {
    case kTagModel:
    case kTagGridOptions:
    case kTagNetworkOptions:
    case kTagOccupancyOptions:
    case kTagMarchOptions:
    case kTagGridParams:
    case kTagMlpParams:
    case kTagEmbParams:
    case kTagMetadata:
    case kTagExtraSection:
      return true;
    case kTagOccupancyV1:
      return version == 1;
    case kTagParamEncoding:
    case kTagOccupancy:
      return version >= 2;
    case kTagSamplerOptions:
    case kTagProposalParams:
      return version >= 5;
  }
  return false;
}

// Ancillary sections (first character a lower-case letter) may be skipped.
bool IsAncillary(uint32_t tag) {
  const uint8_t first = uint8_t(tag & 0xff);
  return first >= 'a' && first <= 'z';
}

// ---------------------------------------------------------------------------
// CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320; same as zlib.crc32),
// slicing-by-8.

using CrcTables = std::array<std::array<uint32_t, 256>, 8>;

constexpr CrcTables MakeCrcTables() {
  CrcTables t{};
  for (uint32_t i = 0; i < 256; ++i) {
    uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1) ? (c >> 1) ^ 0xEDB88320u : c >> 1;
    t[0][i] = c;
  }
  for (int s = 1; s < 8; ++s) {
    for (uint32_t i = 0; i < 256; ++i) t[s][i] = (t[s - 1][i] >> 8) ^ t[0][t[s - 1][i] & 0xff];
  }
  return t;
}

constexpr CrcTables kCrcTables = MakeCrcTables();

uint32_t LoadLE32(const unsigned char* p) {
  return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}

uint32_t Crc32(std::string_view data) {
  const auto& t = kCrcTables;
  const unsigned char* p = reinterpret_cast<const unsigned char*>(data.data());
  size_t n = data.size();
  uint32_t crc = 0xFFFFFFFFu;
  while (n >= 8) {
    const uint32_t lo = LoadLE32(p) ^ crc;
    const uint32_t hi = LoadLE32(p + 4);
    crc = t[7][lo & 0xff] ^ t[6][(lo >> 8) & 0xff] ^ t[5][(lo >> 16) & 0xff] ^ t[4][lo >> 24] ^
          t[3][hi & 0xff] ^ t[2][(hi >> 8) & 0xff] ^ t[1][(hi >> 16) & 0xff] ^ t[0][hi >> 24];
    p += 8;
    n -= 8;
  }
  while (n--) crc = t[0][(crc ^ *p++) & 0xff] ^ (crc >> 8);
  return ~crc;
}

// Sections are written and read with core/io/byte_io.h.
using Reader = ByteReader;
using Writer = ByteWriter;

absl::Status Corrupt(absl::string_view source, absl::string_view detail) {
  return absl::DataLossError(absl::StrCat("checkpoint '", source, "' is corrupt: ", detail));
}

// ---------------------------------------------------------------------------
// Parameter encodings (section PENC, version 2).

enum class ParamEncoding : uint32_t { kFloat32 = 0, kFloat16 = 1 };

// ---------------------------------------------------------------------------
// PackBits (Apple's byte-oriented run-length code, as in TIFF): a header byte
// h, read as int8, is followed by h + 1 literal bytes when h is in [0, 127],
// or by one byte to repeat 1 - h times (2..128) when h is in [-127, -1]; -128
// is a no-op. The encoder is deterministic, so equal input gives equal bytes,
// and incompressible input grows by at most one byte in 128.

void PackBits(std::string_view in, std::string* out) {
  const size_t n = in.size();
  size_t i = 0;
  while (i < n) {
    size_t run = 1;
    while (i + run < n && run < 128 && in[i + run] == in[i]) ++run;
    if (run >= 2) {
      out->push_back(char(int8_t(1 - int(run))));
      out->push_back(in[i]);
      i += run;
      continue;
    }
    // Literal: up to 128 bytes, stopping before a run of 3 or more (a run of
    // two inside a literal costs no more than splitting it off).
    size_t len = 1;
    while (i + len < n && len < 128) {
      if (i + len + 2 < n && in[i + len] == in[i + len + 1] && in[i + len] == in[i + len + 2]) break;
      ++len;
    }
    out->push_back(char(int8_t(len - 1)));
    out->append(in.substr(i, len));
    i += len;
  }
}

// Decodes `in`, which must expand to exactly `size` bytes.
bool UnpackBits(std::string_view in, size_t size, std::string* out) {
  out->clear();
  out->reserve(size);
  size_t i = 0;
  while (i < in.size()) {
    const int h = int8_t(in[i++]);
    if (h >= 0) {
      const size_t len = size_t(h) + 1;
      if (len > in.size() - i || len > size - out->size()) return false;
      out->append(in.substr(i, len));
      i += len;
    } else if (h != -128) {
      const size_t len = size_t(1 - h);
      if (i >= in.size() || len > size - out->size()) return false;
      out->append(len, in[i++]);
    }
  }
  return out->size() == size;
}

// zlib (deflate) of a byte string, and its inverse, which must produce
// exactly `size` bytes.
void Deflate(std::string_view in, std::string* out) {
  uLongf n = compressBound(uLong(in.size()));
  out->resize(n);
  if (compress2(reinterpret_cast<Bytef*>(out->data()), &n, reinterpret_cast<const Bytef*>(in.data()),
                uLong(in.size()), 6) != Z_OK) {
    n = 0;  // Cannot happen with compressBound; an empty stream fails Inflate.
  }
  out->resize(n);
}

bool Inflate(std::string_view in, size_t size, std::string* out) {
  out->assign(size, '\0');
  z_stream z{};
  if (inflateInit(&z) != Z_OK) return false;
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in.data()));
  z.avail_in = uInt(in.size());
  z.next_out = reinterpret_cast<Bytef*>(out->data());
  z.avail_out = uInt(size);
  const int rc = inflate(&z, Z_FINISH);
  // The stream must end exactly at the end of the input with `size` bytes.
  const bool ok = rc == Z_STREAM_END && z.avail_in == 0 && z.total_out == size;
  inflateEnd(&z);
  return ok;
}

// ---------------------------------------------------------------------------
// Occupancy density EMA quantisation (section OCCP, version 2; read only:
// version 3 stores no densities).
//
// Each cell's density d becomes one byte, relative to a reference density r
// (the threshold when it is positive and finite, else 1):
//   0       d == 0 (also for negative or NaN d, which the grid never holds)
//   1       0 < d < r / 4: restored to one shared value, the mean of these
//           densities over the visible cells (so the mean density, which sets
//           the next threshold, is preserved)
//   2..255  r * 2^((code - 18) / 8), the nearest on a log2 scale in steps of
//           1/8 (relative error <= 2^(1/16) - 1 = 4.4 %), from r / 4 up to
//           r * 2^29.6; larger densities (and +inf) saturate at 255.
// Quantising a dequantised value gives back the same code, so re-saving a
// loaded model reproduces its file.

constexpr int kCodeZero = 0;
constexpr int kCodeLow = 1;
constexpr int kCodeRef = 18;  // The code of r itself.
constexpr double kCodesPerOctave = 8.0;

float LowLimit(float ref) { return ref * 0.25f; }

std::array<float, 256> DensityTable(float ref, float low) {
  std::array<float, 256> t{};
  t[kCodeZero] = 0.0f;
  t[kCodeLow] = low;
  for (int c = kCodeLow + 1; c < 256; ++c) t[c] = float(double(ref) * std::exp2((c - kCodeRef) / kCodesPerOctave));
  return t;
}

// ---------------------------------------------------------------------------
// Encoding.

uint32_t EncodeKind(SceneKind kind) {
  switch (kind) {
    case SceneKind::kBounded:
      return 0;
    case SceneKind::kUnbounded:
      return 1;
  }
  return 0xFFFFFFFFu;
}

bool DecodeKind(uint32_t v, SceneKind* kind) {
  switch (v) {
    case 0:
      *kind = SceneKind::kBounded;
      return true;
    case 1:
      *kind = SceneKind::kUnbounded;
      return true;
  }
  return false;
}

absl::Status CheckModelConsistent(const NgpModel& model) {
  const int steps = model.num_time_steps();
  if (steps < 1 || steps > kMaxTimeSteps) {
    return absl::FailedPreconditionError(
        absl::StrFormat("cannot checkpoint model: %d time steps (must be in [1, %d])", steps, kMaxTimeSteps));
  }
  const ModelParams& p = model.params();
  const size_t want_emb = size_t(steps) * model.network().embedding_row_size();
  if (p.grid.size() != model.grid().num_params() || p.mlp.size() != model.network().num_mlp_params() ||
      p.emb.size() != want_emb) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "cannot checkpoint model: parameter blocks (grid %d, mlp %d, emb %d) do not match its layout "
        "(grid %d, mlp %d, emb %d)",
        p.grid.size(), p.mlp.size(), p.emb.size(), model.grid().num_params(), model.network().num_mlp_params(),
        want_emb));
  }
  if (p.proposal.size() != model.num_proposal_params()) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "cannot checkpoint model: proposal block has %d parameters, its layout %d", p.proposal.size(),
        model.num_proposal_params()));
  }
  const OccupancyGrid& occ = model.occupancy();
  const size_t cells = occ.num_cells();
  if (occ.density().size() != cells || occ.visible().size() != cells || occ.bits().size() != (cells + 63) / 64) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "cannot checkpoint model: occupancy state (density %d, visible %d, bits %d) does not match its %d cells",
        occ.density().size(), occ.visible().size(), occ.bits().size(), cells));
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------
// Decoding helpers.

struct RawSection {
  uint32_t tag;
  std::string_view payload;
};

// Returns the payload of the one section with `tag`, or an error if it is
// missing or repeated.
absl::StatusOr<std::string_view> Single(const std::vector<RawSection>& sections, uint32_t tag,
                                        const std::string& source) {
  const std::string_view* found = nullptr;
  for (const RawSection& s : sections) {
    if (s.tag != tag) continue;
    if (found != nullptr) return Corrupt(source, absl::StrCat("section '", TagName(tag), "' appears twice"));
    found = &s.payload;
  }
  if (found == nullptr) return Corrupt(source, absl::StrCat("required section '", TagName(tag), "' is missing"));
  return *found;
}

absl::Status WrongSize(const std::string& source, uint32_t tag, size_t got, size_t want) {
  return Corrupt(source, absl::StrFormat("section '%s' has %d bytes, expected %d", TagName(tag), got, want));
}

// Reads a parameter block whose length must be exactly `count` float32 (or,
// with `fp16`, binary16) values.
absl::Status ReadParams(std::string_view payload, uint32_t tag, size_t count, bool fp16, const std::string& source,
                        std::vector<float>* out) {
  const size_t width = fp16 ? sizeof(uint16_t) : sizeof(float);
  if (payload.size() / width != count || payload.size() % width != 0) {
    return Corrupt(source, absl::StrFormat("section '%s' has %d bytes, but the model options imply %d %s values "
                                           "(%d bytes)",
                                           TagName(tag), payload.size(), count, fp16 ? "binary16" : "float32",
                                           count * width));
  }
  Reader r(payload);
  if (!fp16) {
    r.Array(count, out);
  } else {
    out->resize(count);
    for (float& x : *out) {
      uint16_t h = 0;
      r.Get(&h);
      x = HalfToFloat(h);
    }
  }
  // A checksum only proves the bytes are the ones written; a writer (or a
  // forger who recomputed the CRC) may still have stored NaN/Inf.
  for (size_t i = 0; i < out->size(); ++i) {
    if (!std::isfinite((*out)[i])) {
      return Corrupt(source, absl::StrFormat("section '%s' holds a non-finite parameter (%g at index %d)",
                                             TagName(tag), (*out)[i], i));
    }
  }
  return absl::OkStatus();
}

// Version 2 occupancy payload after threshold and cell count (layout in
// SerializeCheckpoint).
absl::Status ReadOccupancy(Reader* r, uint64_t cells, const std::string& source, std::vector<float>* density,
                           std::vector<uint8_t>* visible, std::vector<uint64_t>* bits) {
  float ref = 0, low = 0;
  std::string packed_visible;
  const uint64_t words = (cells + 63) / 64;
  if (!r->Get(&ref) || !r->Get(&low) || !r->String(&packed_visible) || !r->Array(words, bits)) {
    return Corrupt(source, "occupancy section is truncated");
  }
  if (!(ref > 0) || !std::isfinite(ref) || !(low >= 0) || !(low < LowLimit(ref))) {
    return Corrupt(source, absl::StrFormat("invalid occupancy density scale (reference %g, low value %g)", ref, low));
  }
  std::string flags;
  if (!UnpackBits(packed_visible, size_t((cells + 7) / 8), &flags)) {
    return Corrupt(source, "occupancy visibility flags do not decode to one bit per cell");
  }
  if (cells % 8 != 0 && (uint8_t(flags.back()) >> (cells % 8)) != 0) {
    return Corrupt(source, "occupancy visibility flags have bits set beyond the last cell");
  }
  std::string codes;
  std::string_view rest;
  r->Bytes(r->remaining(), &rest);
  if (!Inflate(rest, size_t(cells), &codes)) {
    return Corrupt(source, "occupancy densities do not decode to one code per cell");
  }
  const std::array<float, 256> table = DensityTable(ref, low);
  density->resize(size_t(cells));
  visible->resize(size_t(cells));
  for (size_t i = 0; i < size_t(cells); ++i) {
    (*density)[i] = table[uint8_t(codes[i])];
    (*visible)[i] = (uint8_t(flags[i / 8]) >> (i % 8)) & 1;
  }
  return absl::OkStatus();
}

// Section occd (ancillary): uint64 n (the occupied cells) | zlib (deflate)
// of n bytes, one per occupied cell in index order: the cell's density EMA
// over the grid's threshold as round(8 log2(EMA / threshold)) + 128, clamped
// to [0, 255] (1/8 octave, 9 %; ratios 2^-16 to 2^16). A warm-started update
// reads it: with only the threshold restored, a cell dense in the last
// training dropped out at its first refresh where the field dipped, where in
// memory it stayed occupied for many (decay^k), and an update from a stored
// version trained differently from one from the state in memory (beer_2,
// known poses: 26.63 against 28.07 dB). Not written without a positive
// threshold.
constexpr double kDensityCodesPerOctave = 8.0;

uint8_t DensityCode(float density, float threshold) {
  if (!(density > 0)) return 0;
  const double c = std::round(kDensityCodesPerOctave * std::log2(double(density) / threshold)) + 128.0;
  return uint8_t(std::clamp(c, 0.0, 255.0));
}

float DensityFromCode(uint8_t code, float threshold) {
  return float(threshold * std::exp2((double(code) - 128.0) / kDensityCodesPerOctave));
}

template <typename W>
void WriteOccupiedDensity(const OccupancyGrid& occ, W* w) {
  const float threshold = occ.threshold();
  if (!(threshold > 0) || !std::isfinite(threshold)) return;
  std::string codes;
  for (size_t i = 0; i < occ.num_cells(); ++i) {
    if (occ.OccupiedCell(uint32_t(i))) codes.push_back(char(DensityCode(occ.density()[i], threshold)));
  }
  std::string packed;
  Deflate(codes, &packed);
  const size_t at = w->BeginSection(kTagOccupiedDensity);
  w->Put(uint64_t(codes.size()));
  w->Bytes(packed);
  w->EndSection(at);
}

// Reads section occd, when there is one, into the occupied cells of
// `density` (bits: the occupancy bitfield, one bit per cell).
absl::Status ReadOccupiedDensity(const std::vector<RawSection>& sections, float threshold,
                                 const std::vector<uint64_t>& bits, const std::string& source,
                                 std::vector<float>* density) {
  const RawSection* found = nullptr;
  for (const RawSection& s : sections) {
    if (s.tag != kTagOccupiedDensity) continue;
    if (found != nullptr) return Corrupt(source, "section 'occd' appears twice");
    found = &s;
  }
  if (found == nullptr || !(threshold > 0) || !std::isfinite(threshold)) return absl::OkStatus();
  const auto occupied = [&](size_t i) { return (bits[i / 64] >> (i % 64)) & 1; };
  uint64_t count = 0;
  for (size_t i = 0; i < density->size(); ++i) count += occupied(i);
  Reader r(found->payload);
  uint64_t n = 0;
  if (!r.Get(&n) || n != count) {
    return Corrupt(source,
                   absl::StrFormat("occupied-density section holds %d cells, the grid has %d occupied", n, count));
  }
  std::string_view rest;
  r.Bytes(r.remaining(), &rest);
  std::string codes;
  if (!Inflate(rest, size_t(n), &codes)) return Corrupt(source, "occupied-density codes do not decode");
  size_t k = 0;  // The next code: cells in index order, as written.
  for (size_t i = 0; i < density->size(); ++i) {
    if (occupied(i)) (*density)[i] = DensityFromCode(uint8_t(codes[k++]), threshold);
  }
  return absl::OkStatus();
}

// The density EMA a version-3 checkpoint restores: the threshold on occupied
// cells, 0 elsewhere. Rendering reads only the bits (stored exactly); a warm
// start's first occupancy updates (every cell during warm-up, new =
// max(decay * old, sigma)) rebuild the EMA from the field itself.
float RestoredDensity(bool occupied, float threshold) {
  return occupied && threshold > 0 && std::isfinite(threshold) ? threshold : 0.0f;
}

// Version 3 occupancy payload after threshold and cell count (see
// SerializeCheckpoint).
absl::Status ReadOccupancyV3(Reader* r, uint64_t cells, float threshold, const std::string& source,
                             std::vector<float>* density, std::vector<uint8_t>* visible,
                             std::vector<uint64_t>* bits) {
  std::string packed_visible;
  if (!r->String(&packed_visible)) return Corrupt(source, "occupancy section is truncated");
  const size_t nbytes = size_t((cells + 7) / 8);
  std::string flags, occupied;
  if (!UnpackBits(packed_visible, nbytes, &flags)) {
    return Corrupt(source, "occupancy visibility flags do not decode to one bit per cell");
  }
  std::string_view rest;
  r->Bytes(r->remaining(), &rest);
  if (!Inflate(rest, nbytes, &occupied)) {
    return Corrupt(source, "occupancy bits do not decode to one bit per cell");
  }
  if (cells % 8 != 0 && ((uint8_t(flags.back()) >> (cells % 8)) != 0 || (uint8_t(occupied.back()) >> (cells % 8)) != 0)) {
    return Corrupt(source, "occupancy bitfields have bits set beyond the last cell");
  }
  density->resize(size_t(cells));
  visible->resize(size_t(cells));
  bits->assign(size_t((cells + 63) / 64), 0);
  for (size_t i = 0; i < size_t(cells); ++i) {
    const bool occ = (uint8_t(occupied[i / 8]) >> (i % 8)) & 1;
    (*visible)[i] = (uint8_t(flags[i / 8]) >> (i % 8)) & 1;
    (*density)[i] = RestoredDensity(occ, threshold);
    if (occ) (*bits)[i / 64] |= uint64_t(1) << (i % 64);
  }
  return absl::OkStatus();
}

// Version 1 occupancy payload after threshold and cell count: float32
// density[cells] | uint8 visible[cells] (0 or 1) | uint64 bits[(cells + 63) / 64].
absl::Status ReadOccupancyV1(Reader* r, std::string_view payload, uint64_t cells, const std::string& source,
                             std::vector<float>* density, std::vector<uint8_t>* visible,
                             std::vector<uint64_t>* bits) {
  const uint64_t words = (cells + 63) / 64;
  const uint64_t want_bytes = 12 + cells * (sizeof(float) + 1) + words * sizeof(uint64_t);
  if (payload.size() != want_bytes) return WrongSize(source, kTagOccupancyV1, payload.size(), want_bytes);
  r->Array(cells, density);
  r->Array(cells, visible);
  r->Array(words, bits);
  for (uint8_t v : *visible) {
    if (v > 1) return Corrupt(source, absl::StrCat("invalid occupancy visibility flag ", int(v)));
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------
// Per-section readers of DeserializeCheckpoint (steps 6-10).

// The header fields: everything a model's layout is built from.
struct CheckpointHeader {
  ModelOptions options;
  Normalization norm;
  SceneKind kind = SceneKind::kBounded;
  Eigen::Vector3f background = Eigen::Vector3f::Zero();
  uint32_t steps = 0;
};

// MODL: kind, normalisation, background, time steps.
absl::Status ReadModelSection(const std::vector<RawSection>& sections, uint32_t version, const std::string& source,
                              CheckpointHeader* h) {
  auto payload = Single(sections, kTagModel, source);
  if (!payload.ok()) return payload.status();
  // Version 4 appends the rotation (9 floats, row-major).
  const size_t kSize = 4 + 3 * 4 + 4 + 4 + 3 * 4 + 4 + (version >= 4 ? 9 * 4 : 0);
  if (payload->size() != kSize) return WrongSize(source, kTagModel, payload->size(), kSize);
  Reader r(*payload);
  uint32_t kind_code = 0;
  r.Get(&kind_code);
  for (int i = 0; i < 3; ++i) r.Get(&h->norm.center[i]);
  r.Get(&h->norm.scale);
  r.Get(&h->norm.bound);
  for (int i = 0; i < 3; ++i) r.Get(&h->background[i]);
  r.Get(&h->steps);
  h->norm.rotation.setIdentity();
  if (version >= 4) {
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) r.Get(&h->norm.rotation(i, j));
    }
  }
  if (!DecodeKind(kind_code, &h->kind)) return Corrupt(source, absl::StrCat("unknown scene kind ", kind_code));
  if (version < 2 && h->kind == SceneKind::kUnbounded) {
    return absl::FailedPreconditionError(absl::StrCat(
        "checkpoint '", source, "' predates format version 2 and holds an unbounded scene; format 2 represents "
        "unbounded scenes in contracted space, so this model cannot be loaded: re-train it with this clnerf"));
  }
  return absl::OkStatus();
}

// HGOP, NTOP, OGOP, MROP: the option structs.
absl::Status ReadOptionSections(const std::vector<RawSection>& sections, const std::string& source,
                                ModelOptions* options) {
  {
    auto payload = Single(sections, kTagGridOptions, source);
    if (!payload.ok()) return payload.status();
    if (payload->size() != 5 * 4) return WrongSize(source, kTagGridOptions, payload->size(), 5 * 4);
    Reader r(*payload);
    r.I32(&options->grid.levels);
    r.I32(&options->grid.features_per_level);
    r.I32(&options->grid.log2_table_size);
    r.I32(&options->grid.base_resolution);
    r.I32(&options->grid.finest_resolution);
  }
  {
    auto payload = Single(sections, kTagNetworkOptions, source);
    if (!payload.ok()) return payload.status();
    if (payload->size() != 7 * 4 + 1) return WrongSize(source, kTagNetworkOptions, payload->size(), 7 * 4 + 1);
    Reader r(*payload);
    r.I32(&options->network.density_hidden);
    r.I32(&options->network.density_hidden_layers);
    r.I32(&options->network.density_out);
    r.I32(&options->network.colour_hidden);
    r.I32(&options->network.colour_hidden_layers);
    r.I32(&options->network.appearance_dim);
    r.I32(&options->network.geometry_dim);
    uint8_t use = 0;
    r.Get(&use);
    if (use > 1) return Corrupt(source, absl::StrCat("invalid use_embeddings flag ", int(use)));
    options->network.use_embeddings = use == 1;
  }
  {
    auto payload = Single(sections, kTagOccupancyOptions, source);
    if (!payload.ok()) return payload.status();
    if (payload->size() != 5 * 4) return WrongSize(source, kTagOccupancyOptions, payload->size(), 5 * 4);
    Reader r(*payload);
    r.I32(&options->occupancy.resolution);
    r.I32(&options->occupancy.update_interval);
    r.I32(&options->occupancy.warmup_iterations);
    r.Get(&options->occupancy.decay);
    r.Get(&options->occupancy.density_threshold);
  }
  {
    auto payload = Single(sections, kTagMarchOptions, source);
    if (!payload.ok()) return payload.status();
    if (payload->size() != 4 * 4) return WrongSize(source, kTagMarchOptions, payload->size(), 4 * 4);
    Reader r(*payload);
    r.I32(&options->march.max_samples);
    r.Get(&options->march.steps_per_diagonal);
    r.Get(&options->march.cone_angle);
    r.Get(&options->march.near);
  }
  return absl::OkStatus();
}

// SMOP (version 5): the sampler and the proposal fields' options.
absl::Status ReadSamplerSection(const std::vector<RawSection>& sections, const std::string& source,
                                ModelOptions* options) {
  auto payload = Single(sections, kTagSamplerOptions, source);
  if (!payload.ok()) return payload.status();
  if (payload->size() != kSamplerOptionsSize) {
    return WrongSize(source, kTagSamplerOptions, payload->size(), kSamplerOptionsSize);
  }
  Reader r(*payload);
  uint32_t kind = 0;
  r.Get(&kind);
  if (kind != uint32_t(SamplerKind::kOccupancy) && kind != uint32_t(SamplerKind::kProposal)) {
    return Corrupt(source, absl::StrCat("unknown sampler kind ", kind));
  }
  options->sampler = SamplerKind(kind);
  ProposalOptions& po = options->proposal;
  r.I32(&po.samples0);
  r.I32(&po.samples1);
  r.I32(&po.nerf_samples);
  r.Get(&po.histogram_padding);
  for (ProposalFieldOptions* f : {&po.field0, &po.field1}) {
    r.I32(&f->levels);
    r.I32(&f->log2_table_size);
    r.I32(&f->base_resolution);
    r.I32(&f->finest_resolution);
    r.I32(&f->hidden);
  }
  for (const ProposalFieldOptions* f : {&po.field0, &po.field1}) {
    if (f->finest_resolution > kMaxGridResolution || f->levels > kMaxLayers) {
      return Corrupt(source, "proposal options exceed the sanity limits for checkpoints");
    }
  }
  return absl::OkStatus();
}

// Step 7: the header must describe a sane model before any layout is built.
absl::Status ValidateHeader(const CheckpointHeader& h, const std::string& source) {
  const ModelOptions& options = h.options;
  const Normalization& norm = h.norm;
  const Eigen::Vector3f& background = h.background;
  const uint32_t steps = h.steps;
  if (absl::Status s = options.Validate(); !s.ok()) {
    return Corrupt(source, absl::StrCat("invalid model options: ", s.message()));
  }
  const NetworkOptions& no = options.network;
  if (options.grid.finest_resolution > kMaxGridResolution || no.density_hidden > kMaxWidth ||
      no.colour_hidden > kMaxWidth || no.density_out > kMaxWidth || no.appearance_dim > kMaxWidth ||
      no.geometry_dim > kMaxWidth || no.density_hidden_layers > kMaxLayers || no.colour_hidden_layers > kMaxLayers) {
    return Corrupt(source, "model options exceed the sanity limits for checkpoints");
  }
  if (steps < 1 || steps > uint32_t(kMaxTimeSteps)) {
    return Corrupt(source, absl::StrFormat("%d time steps (must be in [1, %d])", steps, kMaxTimeSteps));
  }
  if (!(norm.bound > 0 && norm.bound <= kMaxBound) || !(norm.scale > 0) || !std::isfinite(norm.scale)) {
    return Corrupt(source, absl::StrFormat("invalid normalisation (scale %g, bound %g)", norm.scale, norm.bound));
  }
  if (!norm.rotation.allFinite() ||
      !(norm.rotation * norm.rotation.transpose()).isApprox(Eigen::Matrix3f::Identity(), 1e-3f) ||
      !(std::abs(norm.rotation.determinant() - 1.0f) < 1e-3f)) {
    return Corrupt(source, "invalid normalisation rotation (not a proper rotation matrix)");
  }
  if (!norm.center.allFinite() || norm.center.cwiseAbs().maxCoeff() > kMaxCameraCoordinate) {
    return Corrupt(source, absl::StrFormat("invalid scene centre (%g, %g, %g)", norm.center.x(), norm.center.y(),
                                           norm.center.z()));
  }
  if (!background.allFinite() || background.minCoeff() < 0.0f || background.maxCoeff() > 1.0f) {
    return Corrupt(source, absl::StrFormat("invalid background colour (%g, %g, %g)", background.x(), background.y(),
                                           background.z()));
  }
  return absl::OkStatus();
}

}  // namespace

const std::string* CheckpointExtras::FindSection(std::string_view name) const {
  for (const auto& [n, data] : sections) {
    if (n == name) return &data;
  }
  return nullptr;
}

absl::StatusOr<std::string> SerializeCheckpoint(const NgpModel& model, const CheckpointExtras& extras,
                                                const CheckpointOptions& options) {
  if (absl::Status s = CheckModelConsistent(model); !s.ok()) return s;
  // Loading refuses non-finite parameters, so never write them.
  for (const auto& [name, block] : {std::pair<const char*, const std::vector<float>*>{"grid", &model.params().grid},
                                    {"mlp", &model.params().mlp},
                                    {"embedding", &model.params().emb},
                                    {"proposal", &model.params().proposal}}) {
    for (size_t i = 0; i < block->size(); ++i) {
      const float x = (*block)[i];
      if (!std::isfinite(x)) {
        return absl::FailedPreconditionError(
            absl::StrFormat("cannot checkpoint model: %s parameter %d is %g (non-finite)", name, i, x));
      }
      if (options.fp16_params) {
        if (std::isinf(HalfToFloat(FloatToHalf(x)))) {
          return absl::FailedPreconditionError(absl::StrFormat(
              "cannot checkpoint model with fp16 parameters: %s parameter %d is %g, beyond the binary16 range "
              "(+-%g); save it as float32",
              name, i, x, kMaxHalf));
        }
      }
    }
  }
  const ModelOptions& o = model.options();
  const ModelParams& p = model.params();
  const OccupancyGrid& occ = model.occupancy();

  size_t estimate = 1024 + (p.grid.size() + p.mlp.size() + p.emb.size() + p.proposal.size()) * sizeof(float) +
                    occ.num_cells() * (sizeof(float) + 1) + occ.bits().size() * sizeof(uint64_t);
  for (const auto& [k, v] : extras.metadata) estimate += 16 + k.size() + v.size();
  for (const auto& [n, d] : extras.sections) estimate += 32 + n.size() + d.size();
  std::string out;
  out.reserve(estimate);
  Writer w(&out);

  w.Bytes(std::string_view(kCheckpointMagic, kMagicSize));
  w.Put(uint32_t(kCheckpointFormatVersion));
  w.Put(uint64_t(0));  // Total size, patched below.

  size_t at = w.BeginSection(kTagModel);
  w.Put(EncodeKind(model.kind()));
  const Normalization& norm = model.normalization();
  for (int i = 0; i < 3; ++i) w.Put(norm.center[i]);
  w.Put(norm.scale);
  w.Put(norm.bound);
  for (int i = 0; i < 3; ++i) w.Put(model.background()[i]);
  w.Put(uint32_t(model.num_time_steps()));
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) w.Put(norm.rotation(i, j));
  }
  w.EndSection(at);

  at = w.BeginSection(kTagGridOptions);
  w.I32(o.grid.levels);
  w.I32(o.grid.features_per_level);
  w.I32(o.grid.log2_table_size);
  w.I32(o.grid.base_resolution);
  w.I32(o.grid.finest_resolution);
  w.EndSection(at);

  at = w.BeginSection(kTagNetworkOptions);
  w.I32(o.network.density_hidden);
  w.I32(o.network.density_hidden_layers);
  w.I32(o.network.density_out);
  w.I32(o.network.colour_hidden);
  w.I32(o.network.colour_hidden_layers);
  w.I32(o.network.appearance_dim);
  w.I32(o.network.geometry_dim);
  w.Put(uint8_t(o.network.use_embeddings ? 1 : 0));
  w.EndSection(at);

  at = w.BeginSection(kTagOccupancyOptions);
  w.I32(o.occupancy.resolution);
  w.I32(o.occupancy.update_interval);
  w.I32(o.occupancy.warmup_iterations);
  w.Put(o.occupancy.decay);
  w.Put(o.occupancy.density_threshold);
  w.EndSection(at);

  at = w.BeginSection(kTagMarchOptions);
  w.I32(o.march.max_samples);
  w.Put(o.march.steps_per_diagonal);
  w.Put(o.march.cone_angle);
  w.Put(o.march.near);
  w.EndSection(at);

  // SMOP (version 5): uint32 sampler kind (1 occupancy, 2 proposal) |
  // int32 samples0 samples1 nerf_samples | float32 histogram_padding |
  // per proposal field (two, even when one is used): int32 levels
  // log2_table_size base_resolution finest_resolution hidden.
  at = w.BeginSection(kTagSamplerOptions);
  w.Put(uint32_t(o.sampler));
  w.I32(o.proposal.samples0);
  w.I32(o.proposal.samples1);
  w.I32(o.proposal.nerf_samples);
  w.Put(o.proposal.histogram_padding);
  for (const ProposalFieldOptions* f : {&o.proposal.field0, &o.proposal.field1}) {
    w.I32(f->levels);
    w.I32(f->log2_table_size);
    w.I32(f->base_resolution);
    w.I32(f->finest_resolution);
    w.I32(f->hidden);
  }
  w.EndSection(at);

  at = w.BeginSection(kTagParamEncoding);
  w.Put(uint32_t(options.fp16_params ? ParamEncoding::kFloat16 : ParamEncoding::kFloat32));
  w.EndSection(at);
  for (const auto& [tag, block] : {std::pair<uint32_t, const std::vector<float>*>{kTagGridParams, &p.grid},
                                   {kTagMlpParams, &p.mlp},
                                   {kTagEmbParams, &p.emb},
                                   {kTagProposalParams, &p.proposal}}) {
    at = w.BeginSection(tag);
    if (options.fp16_params) {
      for (float x : *block) w.Put(FloatToHalf(x));
    } else {
      w.Array(*block);
    }
    w.EndSection(at);
  }

  // Occupancy (OCCP, version 3): float32 threshold | uint64 cells | uint64 n |
  // n bytes: PackBits of the visibility bitfield ((cells + 7) / 8 bytes, cell
  // i in bit i % 8 of byte i / 8) | zlib (deflate) of the occupancy bits as
  // (cells + 7) / 8 bytes in the same order (to the end of the section). The
  // density EMA is not stored: see RestoredDensity.
  {
    const size_t cells = occ.num_cells();
    std::string visible((cells + 7) / 8, '\0'), occupied((cells + 7) / 8, '\0');
    for (size_t i = 0; i < cells; ++i) {
      if (occ.visible()[i]) visible[i / 8] = char(uint8_t(visible[i / 8]) | (1u << (i % 8)));
      if (occ.OccupiedCell(uint32_t(i))) occupied[i / 8] = char(uint8_t(occupied[i / 8]) | (1u << (i % 8)));
    }
    std::string packed;
    PackBits(visible, &packed);
    at = w.BeginSection(kTagOccupancy);
    w.Put(occ.threshold());
    w.Put(uint64_t(cells));
    w.String(packed);
    packed.clear();
    Deflate(occupied, &packed);
    w.Bytes(packed);
    w.EndSection(at);
    WriteOccupiedDensity(occ, &w);
  }

  at = w.BeginSection(kTagMetadata);
  w.Put(uint64_t(extras.metadata.size()));
  for (const auto& [k, v] : extras.metadata) {
    w.String(k);
    w.String(v);
  }
  w.EndSection(at);

  for (const auto& [name, data] : extras.sections) {
    at = w.BeginSection(kTagExtraSection);
    w.String(name);
    w.Bytes(data);
    w.EndSection(at);
  }

  const uint64_t total = ToLittle(uint64_t(out.size() + kChecksumSize));
  std::memcpy(out.data() + kVersionEnd, &total, sizeof(total));
  w.Put(Crc32(out));
  return out;
}

absl::StatusOr<LoadedCheckpoint> DeserializeCheckpoint(std::string_view bytes, std::string_view source_name) {
  const std::string source(source_name);  // For messages.
  const size_t n = bytes.size();
  // 1. Magic (a shorter file whose bytes are a prefix of it is truncated).
  if (n > 0 && std::memcmp(bytes.data(), kCheckpointMagic, std::min(n, kMagicSize)) != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("'", source, "' is not a clnerf checkpoint (bad magic bytes; expected \"", kCheckpointMagic,
                     "\")"));
  }
  const auto truncated = [&](const char* at_least, uint64_t want) {
    return absl::DataLossError(
        absl::StrCat("checkpoint '", source, "' is truncated: expected ", at_least, want, " bytes, got ", n));
  };
  if (n < kVersionEnd) return truncated("at least ", kHeaderSize);
  // 2. Version, before anything else: a newer format may differ in all else.
  Reader header(bytes.substr(0, std::min(n, kHeaderSize)));
  std::string_view magic;
  uint32_t version = 0;
  header.Bytes(kMagicSize, &magic);
  header.Get(&version);
  if (version < kOldestReadableCheckpointFormatVersion || version > kCheckpointFormatVersion) {
    return absl::FailedPreconditionError(absl::StrCat(
        "checkpoint '", source, "' has format version ", version, ", but this build reads format versions ",
        kOldestReadableCheckpointFormatVersion, " to ", kCheckpointFormatVersion,
        version > kCheckpointFormatVersion ? " (it was written by a newer clnerf; upgrade to load it)" : ""));
  }
  // 3. Size.
  if (n < kHeaderSize) return truncated("at least ", kHeaderSize);
  uint64_t total = 0;
  header.Get(&total);
  if (total < kHeaderSize + kChecksumSize) {
    return Corrupt(source, absl::StrCat("header declares a size of ", total, " bytes, less than the minimum ",
                                        kHeaderSize + kChecksumSize));
  }
  if (n < total) return truncated("", total);
  if (n > total) {
    return Corrupt(source, absl::StrCat("expected ", total, " bytes, got ", n, " (trailing data)"));
  }
  // 4. Checksum over everything before it.
  {
    Reader tail(bytes.substr(n - kChecksumSize));
    uint32_t stored = 0;
    tail.Get(&stored);
    const uint32_t computed = Crc32(bytes.substr(0, n - kChecksumSize));
#ifndef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION  // Fuzzers cannot fix a CRC; let them reach the sections.
    if (stored != computed) {
      return Corrupt(source, absl::StrFormat("checksum mismatch (stored 0x%08x, computed 0x%08x)", stored, computed));
    }
#endif
  }
  // 5. Sections.
  std::vector<RawSection> sections;
  {
    Reader r(bytes.substr(kHeaderSize, n - kHeaderSize - kChecksumSize));
    while (!r.done()) {
      const size_t offset = n - kChecksumSize - r.remaining();
      uint32_t tag = 0;
      uint64_t len = 0;
      if (!r.Get(&tag) || !r.Get(&len)) {
        return Corrupt(source, absl::StrFormat("incomplete section header at offset %d", offset));
      }
      std::string_view payload;
      if (len > r.remaining() || !r.Bytes(size_t(len), &payload)) {
        return Corrupt(source, absl::StrFormat("section '%s' at offset %d claims %d bytes, but only %d remain",
                                               TagName(tag), offset, len, r.remaining()));
      }
      sections.push_back({tag, payload});
    }
  }
  for (const RawSection& s : sections) {
    if (!KnownTag(s.tag, version) && !IsAncillary(s.tag)) {
      return absl::FailedPreconditionError(
          absl::StrCat("checkpoint '", source, "' contains critical section '", TagName(s.tag),
                       "', which this build does not understand (written by a newer clnerf?)"));
    }
  }

  // 6-7. Header sections, validated before any layout is built from them.
  CheckpointHeader head;
  if (absl::Status s = ReadModelSection(sections, version, source, &head); !s.ok()) return s;
  if (absl::Status s = ReadOptionSections(sections, source, &head.options); !s.ok()) return s;
  if (version >= 5) {
    if (absl::Status s = ReadSamplerSection(sections, source, &head.options); !s.ok()) return s;
  } else {
    head.options.sampler = SamplerKind::kOccupancy;  // What versions 1 to 4 were trained with.
  }
  if (absl::Status s = ValidateHeader(head, source); !s.ok()) return s;
  const ModelOptions& options = head.options;
  const Normalization& norm = head.norm;
  const SceneKind kind = head.kind;
  const Eigen::Vector3f& background = head.background;
  const uint32_t steps = head.steps;
  const HashGrid grid(options.grid);
  const Network network(options.network, grid.output_dim());

  // 8. Parameter blocks (float32 in version 1).
  bool fp16 = false;
  if (version >= 2) {
    auto payload = Single(sections, kTagParamEncoding, source);
    if (!payload.ok()) return payload.status();
    if (payload->size() != 4) return WrongSize(source, kTagParamEncoding, payload->size(), 4);
    Reader r(*payload);
    uint32_t code = 0;
    r.Get(&code);
    if (code != uint32_t(ParamEncoding::kFloat32) && code != uint32_t(ParamEncoding::kFloat16)) {
      return Corrupt(source, absl::StrCat("unknown parameter encoding ", code));
    }
    fp16 = code == uint32_t(ParamEncoding::kFloat16);
  }
  ModelParams params;
  for (const auto& [tag, count, out] :
       {std::tuple<uint32_t, size_t, std::vector<float>*>{kTagGridParams, grid.num_params(), &params.grid},
        {kTagMlpParams, network.num_mlp_params(), &params.mlp},
        {kTagEmbParams, size_t(steps) * network.embedding_row_size(), &params.emb}}) {
    auto payload = Single(sections, tag, source);
    if (!payload.ok()) return payload.status();
    if (absl::Status s = ReadParams(*payload, tag, count, fp16, source, out); !s.ok()) return s;
  }

  if (version >= 5) {
    auto payload = Single(sections, kTagProposalParams, source);
    if (!payload.ok()) return payload.status();
    if (absl::Status s = ReadParams(*payload, kTagProposalParams, ProposalParamCount(options), fp16, source,
                                    &params.proposal);
        !s.ok()) {
      return s;
    }
  }

  // 9. Occupancy state. The cascade count depends only on the bound: ask a
  // minimal grid for it rather than duplicating the rule.
  std::vector<float> density;
  std::vector<uint8_t> visible;
  std::vector<uint64_t> bits;
  float threshold = 0;
  {
    const uint32_t tag = version >= 2 ? kTagOccupancy : kTagOccupancyV1;
    auto payload = Single(sections, tag, source);
    if (!payload.ok()) return payload.status();
    OccupancyGridOptions probe_options = options.occupancy;
    probe_options.resolution = 8;
    const OccupancyGrid probe(probe_options, norm.bound, options.march.min_step());
    const uint64_t res = uint64_t(options.occupancy.resolution);
    const uint64_t want_cells = res * res * res * uint64_t(probe.num_cascades());
    Reader r(*payload);
    uint64_t cells = 0;
    if (!r.Get(&threshold) || !r.Get(&cells)) return WrongSize(source, tag, payload->size(), 12);
    if (cells != want_cells) {
      return Corrupt(source, absl::StrFormat("occupancy grid has %d cells, but the model options imply %d", cells,
                                             want_cells));
    }
    const uint64_t words = (cells + 63) / 64;
    if (absl::Status s = version >= 3   ? ReadOccupancyV3(&r, cells, threshold, source, &density, &visible, &bits)
                         : version == 2 ? ReadOccupancy(&r, cells, source, &density, &visible, &bits)
                                        : ReadOccupancyV1(&r, *payload, cells, source, &density, &visible, &bits);
        !s.ok()) {
      return s;
    }
    if (bits.size() != words) return Corrupt(source, "occupancy bits do not match the cell count");
    if (version >= 3) {  // Older files stored the EMA itself.
      if (absl::Status s = ReadOccupiedDensity(sections, threshold, bits, source, &density); !s.ok()) return s;
    }
  }

  // 10. Extras.
  CheckpointExtras extras;
  {
    auto payload = Single(sections, kTagMetadata, source);
    if (!payload.ok()) return payload.status();
    Reader r(*payload);
    uint64_t count = 0;
    if (!r.Get(&count) || count > r.remaining() / 16) {
      return Corrupt(source, "metadata section is malformed");
    }
    for (uint64_t i = 0; i < count; ++i) {
      std::string key, value;
      if (!r.String(&key) || !r.String(&value)) return Corrupt(source, "metadata section is malformed");
      if (!extras.metadata.emplace(std::move(key), std::move(value)).second) {
        return Corrupt(source, "metadata section has a duplicate key");
      }
    }
    if (!r.done()) return Corrupt(source, "metadata section has trailing bytes");
  }
  for (const RawSection& s : sections) {
    if (s.tag != kTagExtraSection) continue;
    Reader r(s.payload);
    std::string name;
    if (!r.String(&name)) return Corrupt(source, "extra section is malformed");
    std::string_view data;
    r.Bytes(r.remaining(), &data);
    extras.sections.emplace_back(std::move(name), std::string(data));
  }

  // 11. Assemble.
  absl::StatusOr<NgpModel> model =
      NgpModel::FromParts(options, norm, kind, background, int(steps), std::move(params));
  if (!model.ok()) return Corrupt(source, model.status().message());
  if (model->occupancy().num_cells() != density.size()) {
    return Corrupt(source, "occupancy grid size does not match the model");
  }
  model->mutable_occupancy().Restore(std::move(density), std::move(visible), std::move(bits), threshold);
  return LoadedCheckpoint{*std::move(model), std::move(extras), n, version, fp16};
}

absl::StatusOr<size_t> SaveCheckpoint(const NgpModel& model, const std::string& path,
                                      const CheckpointExtras& extras, const CheckpointOptions& options) {
  absl::StatusOr<std::string> bytes = SerializeCheckpoint(model, extras, options);
  if (!bytes.ok()) return bytes.status();
  if (absl::Status s = AtomicWriteFile(path, *bytes); !s.ok()) return s;
  return bytes->size();
}

absl::StatusOr<LoadedCheckpoint> LoadCheckpoint(const std::string& path) {
  absl::StatusOr<std::string> bytes = ReadFileToString(path, "checkpoint");
  if (!bytes.ok()) return bytes.status();
  return DeserializeCheckpoint(*bytes, path);
}

}  // namespace clnerf
