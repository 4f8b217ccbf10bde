#include "core/io/checkpoint.h"

#include <signal.h>
#include <stdlib.h>
#include <sys/resource.h>
#include <unistd.h>
#include <zlib.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <algorithm>
#include <bit>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "Eigen/Geometry"
#include "core/io/half.h"
#include "core/render/renderer.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------
// Independent reference implementations of the documented layout.

// Bitwise CRC-32 (zlib polynomial), independent of the table-driven one.
uint32_t RefCrc32(std::string_view data) {
  uint32_t crc = 0xFFFFFFFFu;
  for (unsigned char b : data) {
    crc ^= b;
    for (int k = 0; k < 8; ++k) crc = (crc & 1) ? (crc >> 1) ^ 0xEDB88320u : crc >> 1;
  }
  return ~crc;
}

template <typename T>
T LoadLE(std::string_view s, size_t at) {
  T v{};
  std::memcpy(&v, s.data() + at, sizeof(T));  // Tests run on little-endian hosts.
  return v;
}

template <typename T>
void StoreLE(std::string* s, size_t at, T v) {
  std::memcpy(s->data() + at, &v, sizeof(T));
}

template <typename T>
std::string LE(T v) {
  std::string s(sizeof(T), '\0');
  std::memcpy(s.data(), &v, sizeof(T));
  return s;
}

constexpr size_t kHeader = 20;

uint32_t Tag(const char (&s)[5]) {
  uint32_t t;
  std::memcpy(&t, s, 4);
  return t;
}

struct Section {
  uint32_t tag;
  std::string payload;
};

// Splits a valid checkpoint into its sections.
std::vector<Section> SplitSections(const std::string& bytes) {
  std::vector<Section> out;
  size_t pos = kHeader;
  while (pos < bytes.size() - 4) {
    const uint32_t tag = LoadLE<uint32_t>(bytes, pos);
    const uint64_t len = LoadLE<uint64_t>(bytes, pos + 4);
    out.push_back({tag, bytes.substr(pos + 12, len)});
    pos += 12 + len;
  }
  EXPECT_EQ(pos, bytes.size() - 4);
  return out;
}

// Builds a file with a correct size field and checksum around `sections`.
std::string BuildFile(const std::vector<Section>& sections, uint32_t version = kCheckpointFormatVersion) {
  std::string out = "CLNERFCK" + LE<uint32_t>(version) + LE<uint64_t>(0);
  for (const Section& s : sections) out += LE<uint32_t>(s.tag) + LE<uint64_t>(s.payload.size()) + s.payload;
  StoreLE<uint64_t>(&out, 12, out.size() + 4);
  out += LE<uint32_t>(RefCrc32(out));
  return out;
}

Section* Find(std::vector<Section>* sections, const char (&tag)[5]) {
  for (Section& s : *sections) {
    if (s.tag == Tag(tag)) return &s;
  }
  ADD_FAILURE() << "no section " << tag;
  return nullptr;
}

// ---------------------------------------------------------------------------
// Models.

ModelOptions TinyOptions(bool use_embeddings = true) {
  ModelOptions o;
  o.grid.levels = 4;
  o.grid.log2_table_size = 12;
  o.grid.base_resolution = 4;
  o.grid.finest_resolution = 64;
  o.network.density_hidden = 16;
  o.network.density_hidden_layers = 1;
  o.network.colour_hidden = 16;
  o.network.colour_hidden_layers = 2;
  o.network.appearance_dim = 6;
  o.network.geometry_dim = 3;
  o.network.use_embeddings = use_embeddings;
  o.occupancy.resolution = 16;
  o.occupancy.update_interval = 8;
  o.occupancy.warmup_iterations = 64;
  o.occupancy.decay = 0.9f;
  o.occupancy.density_threshold = 0.0f;
  o.march.max_samples = 200;
  o.march.steps_per_diagonal = 96.0f;
  o.march.cone_angle = 0.0f;
  o.march.near = 0.07f;
  // Occupancy marching unless a test asks for proposals (auto would pick
  // proposals for the unbounded fixtures, and files before version 5 hold
  // occupancy models).
  // (Files before version 5 do not store the proposal options: they load
  // with the defaults, which these fixtures keep.)
  o.sampler = SamplerKind::kOccupancy;
  return o;
}

ModelOptions TinyProposalOptions() {
  ModelOptions o = TinyOptions();
  o.sampler = SamplerKind::kProposal;
  o.proposal.samples0 = 12;
  o.proposal.samples1 = 10;
  o.proposal.nerf_samples = 8;
  for (ProposalFieldOptions* f : {&o.proposal.field0, &o.proposal.field1}) {
    f->levels = 3;
    f->log2_table_size = 10;
    f->base_resolution = 4;
    f->finest_resolution = 16;
    f->hidden = 8;
  }
  return o;
}

Camera TestCamera(const Normalization& norm, float focal) {
  Camera c;
  c.intrinsics.width = 24;
  c.intrinsics.height = 18;
  c.intrinsics.fx = c.intrinsics.fy = focal;
  c.intrinsics.cx = 12;
  c.intrinsics.cy = 9;
  c.c2w.col(3) = norm.center + Eigen::Vector3f(0.05f, -0.02f, -1.8f / norm.scale);
  return c;
}

// A tiny model with non-trivial parameters and occupancy state (some cells
// invisible, densities updated, bits not all set).
NgpModel MakeModel(const ModelOptions& options, int steps, uint64_t seed,
                   SceneKind kind = SceneKind::kBounded) {
  Normalization norm;
  norm.center = Eigen::Vector3f(0.1f, -0.2f, 0.3f);
  norm.scale = 0.7f;
  norm.bound = kind == SceneKind::kBounded ? 0.5f : 2.0f;
  const Eigen::Vector3f bg = kind == SceneKind::kBounded ? Eigen::Vector3f(1, 1, 1) : Eigen::Vector3f(0.1f, 0.2f, 0.3f);
  absl::StatusOr<NgpModel> model = NgpModel::Create(options, norm, kind, bg, steps, seed);
  EXPECT_TRUE(model.ok()) << model.status();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (float& v : model->mutable_params().grid) v = u(rng);
  for (float& v : model->mutable_params().mlp) v *= 2.0f;
  model->mutable_occupancy().MarkInvisible({model->ToModelCamera(TestCamera(norm, 60.0f))}, options.march.near);
  model->UpdateOccupancy(0, &rng);
  model->UpdateOccupancy(options.occupancy.warmup_iterations, &rng);
  return *std::move(model);
}

bool SameBits(float a, float b) { return std::memcmp(&a, &b, sizeof(float)) == 0; }

template <typename T>
bool SameBits(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0);
}

// The documented density restoration (checkpoint.h/.cc): a loaded grid keeps
// the threshold, visibility and occupancy bits exactly; its density EMA is
// the saved one on occupied cells to within half a code (1/16 octave; ratios
// to the threshold clamped to [2^-16, 2^15.9]) and 0 elsewhere.
void ExpectRestoredDensities(const OccupancyGrid& saved, const OccupancyGrid& loaded) {
  const std::vector<float>& b = loaded.density();
  ASSERT_EQ(saved.density().size(), b.size());
  EXPECT_TRUE(SameBits(saved.threshold(), loaded.threshold()));
  EXPECT_TRUE(SameBits(saved.bits(), loaded.bits()));
  const double t = saved.threshold();
  size_t bad = 0;
  for (size_t i = 0; i < b.size(); ++i) {
    bool ok = b[i] == 0.0f;
    double want = 0;
    if (saved.OccupiedCell(uint32_t(i)) && t > 0) {
      want = std::clamp(double(saved.density()[i]), t * std::exp2(-16.0), t * std::exp2(127.0 / 8));
      ok = b[i] > 0 && std::abs(std::log2(double(b[i]) / want)) <= 1.0 / 16 + 1e-6;
    }
    if (!ok && ++bad <= 5) ADD_FAILURE() << "cell " << i << ": loaded " << b[i] << ", want " << want;
  }
  EXPECT_EQ(bad, 0u);
}

// Every field bit for bit, except the occupancy densities, which are either
// compared bit for bit (`exact_density`) or as documented for restoration.
void ExpectBitEqual(const NgpModel& a, const NgpModel& b, bool exact_density = false) {
  const ModelOptions &oa = a.options(), &ob = b.options();
  EXPECT_EQ(oa.grid.levels, ob.grid.levels);
  EXPECT_EQ(oa.grid.features_per_level, ob.grid.features_per_level);
  EXPECT_EQ(oa.grid.log2_table_size, ob.grid.log2_table_size);
  EXPECT_EQ(oa.grid.base_resolution, ob.grid.base_resolution);
  EXPECT_EQ(oa.grid.finest_resolution, ob.grid.finest_resolution);
  EXPECT_EQ(oa.network.density_hidden, ob.network.density_hidden);
  EXPECT_EQ(oa.network.density_hidden_layers, ob.network.density_hidden_layers);
  EXPECT_EQ(oa.network.density_out, ob.network.density_out);
  EXPECT_EQ(oa.network.colour_hidden, ob.network.colour_hidden);
  EXPECT_EQ(oa.network.colour_hidden_layers, ob.network.colour_hidden_layers);
  EXPECT_EQ(oa.network.appearance_dim, ob.network.appearance_dim);
  EXPECT_EQ(oa.network.geometry_dim, ob.network.geometry_dim);
  EXPECT_EQ(oa.network.use_embeddings, ob.network.use_embeddings);
  EXPECT_EQ(oa.sampler, ob.sampler);
  EXPECT_EQ(oa.proposal.samples0, ob.proposal.samples0);
  EXPECT_EQ(oa.proposal.samples1, ob.proposal.samples1);
  EXPECT_EQ(oa.proposal.nerf_samples, ob.proposal.nerf_samples);
  EXPECT_TRUE(SameBits(oa.proposal.histogram_padding, ob.proposal.histogram_padding));
  EXPECT_EQ(oa.proposal.field1.finest_resolution, ob.proposal.field1.finest_resolution);
  EXPECT_EQ(oa.proposal.field0.hidden, ob.proposal.field0.hidden);
  EXPECT_TRUE(SameBits(a.params().proposal, b.params().proposal));
  EXPECT_EQ(oa.occupancy.resolution, ob.occupancy.resolution);
  EXPECT_EQ(oa.occupancy.update_interval, ob.occupancy.update_interval);
  EXPECT_EQ(oa.occupancy.warmup_iterations, ob.occupancy.warmup_iterations);
  EXPECT_TRUE(SameBits(oa.occupancy.decay, ob.occupancy.decay));
  EXPECT_TRUE(SameBits(oa.occupancy.density_threshold, ob.occupancy.density_threshold));
  EXPECT_EQ(oa.march.max_samples, ob.march.max_samples);
  EXPECT_TRUE(SameBits(oa.march.steps_per_diagonal, ob.march.steps_per_diagonal));
  EXPECT_TRUE(SameBits(oa.march.cone_angle, ob.march.cone_angle));
  EXPECT_TRUE(SameBits(oa.march.near, ob.march.near));
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(SameBits(a.normalization().center[i], b.normalization().center[i]));
    EXPECT_TRUE(SameBits(a.background()[i], b.background()[i]));
  }
  EXPECT_TRUE(SameBits(a.normalization().scale, b.normalization().scale));
  EXPECT_TRUE(SameBits(a.normalization().bound, b.normalization().bound));
  EXPECT_EQ(a.kind(), b.kind());
  EXPECT_EQ(a.num_time_steps(), b.num_time_steps());
  EXPECT_TRUE(SameBits(a.params().grid, b.params().grid));
  EXPECT_TRUE(SameBits(a.params().mlp, b.params().mlp));
  EXPECT_TRUE(SameBits(a.params().emb, b.params().emb));
  EXPECT_EQ(a.occupancy().num_cascades(), b.occupancy().num_cascades());
  if (exact_density) {
    EXPECT_TRUE(SameBits(a.occupancy().density(), b.occupancy().density()));
  } else {
    ExpectRestoredDensities(a.occupancy(), b.occupancy());
  }
  EXPECT_TRUE(SameBits(a.occupancy().visible(), b.occupancy().visible()));
  EXPECT_TRUE(SameBits(a.occupancy().bits(), b.occupancy().bits()));
  EXPECT_TRUE(SameBits(a.occupancy().threshold(), b.occupancy().threshold()));
  EXPECT_EQ(a.num_bytes(), b.num_bytes());
}

std::string Serialize(const NgpModel& m, const CheckpointExtras& extras = {}, const CheckpointOptions& options = {}) {
  absl::StatusOr<std::string> bytes = SerializeCheckpoint(m, extras, options);
  EXPECT_TRUE(bytes.ok()) << bytes.status();
  return bytes.ok() ? *bytes : std::string();
}

// Shared fixture model (built once; tests only read it).
const NgpModel& SharedModel() {
  static const NgpModel* model = new NgpModel(MakeModel(TinyOptions(), 2, 7));
  return *model;
}

const std::string& SharedBytes() {
  static const std::string* bytes = new std::string(Serialize(SharedModel()));
  return *bytes;
}

class TempDir {
 public:
  TempDir() {
    std::string tmpl = (fs::path(::testing::TempDir()) / "clnerf_ckpt_XXXXXX").string();
    EXPECT_NE(::mkdtemp(tmpl.data()), nullptr);
    path_ = tmpl;
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  std::string File(const std::string& name) const { return (fs::path(path_) / name).string(); }
  std::vector<std::string> Entries() const {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(path_)) names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  }

 private:
  std::string path_;
};

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

// ---------------------------------------------------------------------------
// Layout.

TEST(CheckpointTest, LayoutMatchesDocumentation) {
  const std::string& bytes = SharedBytes();
  ASSERT_GT(bytes.size(), kHeader + 4);
  EXPECT_EQ(bytes.substr(0, 8), "CLNERFCK");
  EXPECT_EQ(LoadLE<uint32_t>(bytes, 8), kCheckpointFormatVersion);
  EXPECT_EQ(LoadLE<uint64_t>(bytes, 12), bytes.size());
  EXPECT_EQ(LoadLE<uint32_t>(bytes, bytes.size() - 4), RefCrc32(std::string_view(bytes).substr(0, bytes.size() - 4)));
  EXPECT_EQ(RefCrc32("123456789"), 0xCBF43926u);  // The standard CRC-32 check value.
  const std::vector<Section> sections = SplitSections(bytes);
  std::vector<std::string> tags;
  for (const Section& s : sections) tags.push_back(std::string(reinterpret_cast<const char*>(&s.tag), 4));
  EXPECT_EQ(tags, (std::vector<std::string>{"MODL", "HGOP", "NTOP", "OGOP", "MROP", "SMOP", "PENC", "PGRD", "PMLP",
                                            "PEMB", "PPRP", "OCCP", "occd", "META"}));
  // The raw parameter blocks are stored verbatim (encoding 0: float32).
  std::vector<Section> copy = sections;
  EXPECT_EQ(Find(&copy, "PENC")->payload, LE<uint32_t>(0));
  const Section* grid = Find(&copy, "PGRD");
  ASSERT_NE(grid, nullptr);
  ASSERT_EQ(grid->payload.size(), SharedModel().params().grid.size() * 4);
  EXPECT_EQ(std::memcmp(grid->payload.data(), SharedModel().params().grid.data(), grid->payload.size()), 0);
  // Rebuilding from the parts reproduces the file exactly.
  EXPECT_EQ(BuildFile(sections), bytes);
}

// ---------------------------------------------------------------------------
// Round trips.

void ExpectRoundTrip(const NgpModel& model) {
  const std::string bytes = Serialize(model);
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(bytes);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  ExpectBitEqual(model, loaded->model);
  EXPECT_EQ(loaded->num_bytes, bytes.size());
  EXPECT_EQ(loaded->format_version, kCheckpointFormatVersion);
  EXPECT_FALSE(loaded->fp16_params);
  EXPECT_EQ(Serialize(loaded->model), bytes);  // Re-serialising is the identity.
}

TEST(CheckpointTest, RoundTripIsBitExact) {
  const NgpModel& model = SharedModel();
  // The fixture must exercise non-trivial occupancy state.
  EXPECT_LT(model.occupancy().num_visible(), model.occupancy().num_cells());
  EXPECT_GT(model.occupancy().num_occupied(), 0u);
  EXPECT_LT(model.occupancy().num_occupied(), model.occupancy().num_visible());
  ExpectRoundTrip(model);
}

TEST(CheckpointTest, RoundTripThreeTimeSteps) {
  NgpModel model = MakeModel(TinyOptions(), 3, 11);
  ASSERT_EQ(model.num_time_steps(), 3);
  ASSERT_EQ(model.params().emb.size(), 3u * 9u);
  ExpectRoundTrip(model);
  model.AddTimeStep(99);
  ExpectRoundTrip(model);
}

TEST(CheckpointTest, RoundTripWithoutEmbeddings) {
  const NgpModel model = MakeModel(TinyOptions(/*use_embeddings=*/false), 2, 13);
  ASSERT_TRUE(model.params().emb.empty());
  ExpectRoundTrip(model);
}

TEST(CheckpointTest, RoundTripUnboundedSceneWithCascades) {
  ModelOptions options = TinyOptions();
  options.march.cone_angle = 1.0f / 256;
  options.occupancy.density_threshold = 0.75f;
  const NgpModel model = MakeModel(options, 1, 17, SceneKind::kUnbounded);
  ASSERT_GT(model.occupancy().num_cascades(), 1);
  ExpectRoundTrip(model);
}

TEST(CheckpointTest, RoundTripPreservesSpecialFiniteBits) {
  NgpModel model = MakeModel(TinyOptions(), 1, 19);
  std::vector<float>& grid = model.mutable_params().grid;
  grid[1] = -0.0f;
  grid[3] = std::numeric_limits<float>::denorm_min();
  grid[4] = -std::numeric_limits<float>::max();
  ExpectRoundTrip(model);
}

TEST(CheckpointTest, NonFiniteParametersAreNeitherWrittenNorRead) {
  NgpModel model = MakeModel(TinyOptions(), 1, 19);
  const std::string good = Serialize(model);
  for (float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    NgpModel m = MakeModel(TinyOptions(), 1, 19);
    m.mutable_params().mlp[5] = bad;
    absl::StatusOr<std::string> bytes = SerializeCheckpoint(m);
    ASSERT_FALSE(bytes.ok());
    EXPECT_EQ(bytes.status().code(), absl::StatusCode::kFailedPrecondition) << bytes.status();
    EXPECT_NE(bytes.status().message().find("mlp parameter 5"), std::string::npos) << bytes.status();
  }
  // A file whose CRC is consistent but whose parameters are NaN (a forger or
  // a buggy writer): DATA_LOSS, never a model that renders NaN.
  std::vector<Section> sections = SplitSections(good);
  StoreLE<float>(&Find(&sections, "PMLP")->payload, 8, std::numeric_limits<float>::quiet_NaN());
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(BuildFile(sections), "crafted");
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
  EXPECT_NE(loaded.status().message().find("non-finite parameter"), std::string::npos) << loaded.status();
}

TEST(CheckpointTest, ExtrasRoundTrip) {
  CheckpointExtras extras;
  extras.metadata["created_at"] = "2024-05-01T12:00:00Z";
  extras.metadata["parent_version"] = "3";
  extras.metadata["train_stats"] = R"({"psnr": 31.5, "iterations": [1, 2, 3]})";
  extras.metadata["empty"] = "";
  extras.metadata[std::string("bin\0key", 7)] = std::string("\0\xff\n", 3);
  std::string all_bytes;
  for (int i = 0; i < 4096; ++i) all_bytes.push_back(char(i * 7 % 256));
  extras.sections.emplace_back("replay_memory", all_bytes);
  extras.sections.emplace_back("", "");
  extras.sections.emplace_back("replay_memory", "second entry with the same name");
  extras.sections.emplace_back("tiny", "x");

  const std::string bytes = Serialize(SharedModel(), extras);
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(bytes);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->extras, extras);
  ExpectBitEqual(SharedModel(), loaded->model);
  ASSERT_NE(loaded->extras.FindSection("replay_memory"), nullptr);
  EXPECT_EQ(*loaded->extras.FindSection("replay_memory"), all_bytes);  // The first one.
  EXPECT_EQ(loaded->extras.FindSection("missing"), nullptr);
  // Extras do not change how the model is stored.
  absl::StatusOr<LoadedCheckpoint> plain = DeserializeCheckpoint(SharedBytes());
  ASSERT_TRUE(plain.ok());
  EXPECT_TRUE(plain->extras.metadata.empty());
  EXPECT_TRUE(plain->extras.sections.empty());
}

TEST(CheckpointTest, SaveAndLoadFile) {
  TempDir dir;
  const std::string path = dir.File("model.ckpt");
  CheckpointExtras extras;
  extras.metadata["created_at"] = "now";
  extras.sections.emplace_back("replay", "abc");
  absl::StatusOr<size_t> written = SaveCheckpoint(SharedModel(), path, extras);
  ASSERT_TRUE(written.ok()) << written.status();
  EXPECT_EQ(*written, fs::file_size(path));
  EXPECT_EQ(ReadFile(path), Serialize(SharedModel(), extras));
  absl::StatusOr<LoadedCheckpoint> loaded = LoadCheckpoint(path);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->num_bytes, *written);
  EXPECT_EQ(loaded->extras, extras);
  ExpectBitEqual(SharedModel(), loaded->model);
  EXPECT_EQ(dir.Entries(), std::vector<std::string>{"model.ckpt"});
}

TEST(CheckpointTest, LoadedModelRendersIdenticalPixels) {
  const NgpModel model = MakeModel(TinyOptions(), 3, 23);
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(Serialize(model));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const Camera camera = TestCamera(model.normalization(), 20.0f);
  for (int step : {0, 2}) {
    RenderOptions options;
    options.time_step = step;
    absl::StatusOr<RenderedView> a = RenderView(model, camera, options);
    absl::StatusOr<RenderedView> b = RenderView(loaded->model, camera, options);
    ASSERT_TRUE(a.ok()) << a.status();
    ASSERT_TRUE(b.ok()) << b.status();
    ASSERT_EQ(a->rgb.width, b->rgb.width);
    ASSERT_EQ(a->rgb.height, b->rgb.height);
    EXPECT_TRUE(SameBits(a->rgb.rgb, b->rgb.rgb));
    EXPECT_TRUE(SameBits(a->opacity, b->opacity));
    EXPECT_TRUE(SameBits(a->depth, b->depth));
    EXPECT_EQ(a->samples, b->samples);
    // The view must actually show something, or the comparison is vacuous.
    EXPECT_GT(a->samples, 0);
    const auto [lo, hi] = std::minmax_element(a->rgb.rgb.begin(), a->rgb.rgb.end());
    EXPECT_GT(*hi - *lo, 0.01f);
  }
}

std::vector<Section> SplitV4Sections(const std::string& bytes);

// Proposal models (format 5): the sampler, the proposal options and the
// proposal fields round-trip bit for bit and render the same pixels; a
// version-4 file loads as an occupancy model; forged sampler sections are
// refused.
TEST(CheckpointTest, ProposalModelRoundTripsAndRendersIdenticalPixels) {
  NgpModel model = MakeModel(TinyProposalOptions(), 2, 29, SceneKind::kUnbounded);
  ASSERT_TRUE(model.uses_proposals());
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (float& v : model.mutable_params().proposal) v = u(rng);
  ExpectRoundTrip(model);
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(Serialize(model));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_TRUE(loaded->model.uses_proposals());
  const Camera camera = TestCamera(model.normalization(), 20.0f);
  absl::StatusOr<RenderedView> a = RenderView(model, camera, RenderOptions());
  absl::StatusOr<RenderedView> b = RenderView(loaded->model, camera, RenderOptions());
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_TRUE(SameBits(a->rgb.rgb, b->rgb.rgb));
  EXPECT_GT(a->samples, 0);

  // Version 4 had no sampler: its files are occupancy models.
  const NgpModel occupancy = MakeModel(TinyOptions(), 1, 31, SceneKind::kUnbounded);
  absl::StatusOr<LoadedCheckpoint> v4 = DeserializeCheckpoint(BuildFile(SplitV4Sections(Serialize(occupancy)), 4));
  ASSERT_TRUE(v4.ok()) << v4.status();
  EXPECT_FALSE(v4->model.uses_proposals());
  EXPECT_EQ(v4->model.options().sampler, SamplerKind::kOccupancy);
  // A version-5 file without its sampler section is incomplete.
  EXPECT_EQ(DeserializeCheckpoint(BuildFile(SplitV4Sections(Serialize(model)))).status().code(),
            absl::StatusCode::kDataLoss);

  const std::vector<Section> sections = SplitSections(Serialize(model));
  {
    std::vector<Section> forged = sections;
    StoreLE<uint32_t>(&Find(&forged, "SMOP")->payload, 0, 7);  // No such sampler.
    const absl::Status st = DeserializeCheckpoint(BuildFile(forged)).status();
    EXPECT_EQ(st.code(), absl::StatusCode::kDataLoss) << st;
  }
  {
    std::vector<Section> forged = sections;
    StoreLE<uint32_t>(&Find(&forged, "SMOP")->payload, 12, 0);  // nerf_samples 0.
    const absl::Status st = DeserializeCheckpoint(BuildFile(forged)).status();
    EXPECT_EQ(st.code(), absl::StatusCode::kDataLoss) << st;
  }
  {
    std::vector<Section> forged = sections;
    Find(&forged, "PPRP")->payload.resize(Find(&forged, "PPRP")->payload.size() - 4);  // One parameter short.
    const absl::Status st = DeserializeCheckpoint(BuildFile(forged)).status();
    EXPECT_EQ(st.code(), absl::StatusCode::kDataLoss) << st;
  }
  {
    std::vector<Section> forged = sections;
    StoreLE<float>(&Find(&forged, "PPRP")->payload, 8, std::numeric_limits<float>::quiet_NaN());
    const absl::Status st = DeserializeCheckpoint(BuildFile(forged)).status();
    EXPECT_EQ(st.code(), absl::StatusCode::kDataLoss) << st;
  }
}

// ---------------------------------------------------------------------------
// Corruption.

TEST(CheckpointTest, TruncatedFileIsDataLoss) {
  TempDir dir;
  const std::string& bytes = SharedBytes();
  const size_t n = bytes.size();
  for (size_t cut : {size_t(0), size_t(1), size_t(7), size_t(8), size_t(11), size_t(12), size_t(19), size_t(20),
                     size_t(21), size_t(40), n / 3, n / 2, n - 5, n - 4, n - 1}) {
    SCOPED_TRACE(cut);
    const std::string path = dir.File("cut.ckpt");
    WriteFile(path, bytes.substr(0, cut));
    absl::StatusOr<LoadedCheckpoint> loaded = LoadCheckpoint(path);
    ASSERT_FALSE(loaded.ok());
    EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
    const std::string want =
        cut < kHeader ? "checkpoint '" + path + "' is truncated: expected at least 20 bytes, got " + std::to_string(cut)
                      : "checkpoint '" + path + "' is truncated: expected " + std::to_string(n) + " bytes, got " +
                            std::to_string(cut);
    EXPECT_EQ(loaded.status().message(), want);
  }
}

TEST(CheckpointTest, TrailingBytesAreDataLoss) {
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(SharedBytes() + "x");
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
}

TEST(CheckpointTest, FlippedByteIsDataLoss) {
  const std::string& bytes = SharedBytes();
  const size_t n = bytes.size();
  std::vector<size_t> positions;
  for (size_t p = 12; p < 40; ++p) positions.push_back(p);  // Size field and first section header.
  for (size_t p = 40; p < n - 8; p += n / 50) positions.push_back(p);
  for (size_t p = n - 8; p < n; ++p) positions.push_back(p);  // End of data and the checksum.
  for (size_t p : positions) {
    for (unsigned char mask : {0x01, 0x80}) {
      SCOPED_TRACE(testing::Message() << "byte " << p << " mask " << int(mask));
      std::string bad = bytes;
      bad[p] = char(bad[p] ^ mask);
      absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(bad, "flipped");
      ASSERT_FALSE(loaded.ok());
      EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
    }
  }
  std::string bad = bytes;
  bad[n / 2] ^= 0x10;
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(bad, "flipped.ckpt");
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("checkpoint 'flipped.ckpt' is corrupt: checksum mismatch"),
            std::string::npos)
      << loaded.status();
}

TEST(CheckpointTest, WrongMagicIsInvalidArgument) {
  TempDir dir;
  std::string bad = SharedBytes();
  bad[3] = 'x';
  const std::string path = dir.File("bad.ckpt");
  WriteFile(path, bad);
  absl::StatusOr<LoadedCheckpoint> loaded = LoadCheckpoint(path);
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument) << loaded.status();
  EXPECT_NE(loaded.status().message().find("not a clnerf checkpoint"), std::string::npos) << loaded.status();
  // Short files that are not checkpoints at all.
  for (const std::string text : {"hello world, this is a text file", "PK", "{}"}) {
    absl::StatusOr<LoadedCheckpoint> other = DeserializeCheckpoint(text);
    ASSERT_FALSE(other.ok());
    EXPECT_EQ(other.status().code(), absl::StatusCode::kInvalidArgument) << other.status();
  }
}

TEST(CheckpointTest, UnsupportedVersionNamesBothVersions) {
  const std::vector<Section> sections = SplitSections(SharedBytes());
  for (uint32_t version : {kCheckpointFormatVersion + 1, 77u, 0u}) {
    SCOPED_TRACE(version);
    absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(BuildFile(sections, version), "future.ckpt");
    ASSERT_FALSE(loaded.ok());
    EXPECT_EQ(loaded.status().code(), absl::StatusCode::kFailedPrecondition) << loaded.status();
    const std::string msg(loaded.status().message());
    EXPECT_NE(msg.find("format version " + std::to_string(version)), std::string::npos) << msg;
    EXPECT_NE(msg.find("reads format versions 1 to " + std::to_string(kCheckpointFormatVersion)), std::string::npos) << msg;
    EXPECT_NE(msg.find("future.ckpt"), std::string::npos) << msg;
  }
  // A newer version is recognised even when the rest of the file differs.
  std::string future = "CLNERFCK" + LE<uint32_t>(9) + "whatever follows";
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(future);
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kFailedPrecondition) << loaded.status();
}

TEST(CheckpointTest, MissingFileIsNotFound) {
  TempDir dir;
  absl::StatusOr<LoadedCheckpoint> loaded = LoadCheckpoint(dir.File("does_not_exist.ckpt"));
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kNotFound) << loaded.status();
  EXPECT_NE(loaded.status().message().find("does_not_exist.ckpt"), std::string::npos);
}

TEST(CheckpointTest, UnknownSections) {
  std::vector<Section> sections = SplitSections(SharedBytes());
  // Ancillary (lower-case) sections are skipped.
  std::vector<Section> with_note = sections;
  with_note.insert(with_note.begin() + 3, Section{Tag("note"), "written by a newer tool"});
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(BuildFile(with_note));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  ExpectBitEqual(SharedModel(), loaded->model);
  // Unknown critical sections are rejected.
  std::vector<Section> with_critical = sections;
  with_critical.push_back(Section{Tag("QUNT"), "int8 weights"});
  loaded = DeserializeCheckpoint(BuildFile(with_critical));
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kFailedPrecondition) << loaded.status();
  EXPECT_NE(loaded.status().message().find("QUNT"), std::string::npos) << loaded.status();
}

// Files with a valid checksum but hostile or inconsistent content must fail
// cleanly (and quickly: nothing may be allocated from unchecked lengths).
TEST(CheckpointTest, InconsistentContentIsRejected) {
  const std::vector<Section> good = SplitSections(SharedBytes());
  struct Case {
    const char* name;
    std::function<void(std::vector<Section>*)> edit;
  };
  const std::vector<Case> cases = {
      {"section length beyond the end",
       [](std::vector<Section>* s) { s->push_back(Section{Tag("XSEC"), ""}); }},  // Patched below.
      {"missing section", [](std::vector<Section>* s) { s->erase(s->begin() + 1); }},
      {"duplicate section", [](std::vector<Section>* s) { s->push_back((*s)[1]); }},
      {"short options", [](std::vector<Section>* s) { Find(s, "HGOP")->payload.pop_back(); }},
      {"huge finest resolution",
       [](std::vector<Section>* s) { StoreLE<int32_t>(&Find(s, "HGOP")->payload, 16, 0x7fffffff); }},
      {"huge layer count",
       [](std::vector<Section>* s) { StoreLE<int32_t>(&Find(s, "NTOP")->payload, 4, 0x7fffffff); }},
      {"invalid levels", [](std::vector<Section>* s) { StoreLE<int32_t>(&Find(s, "HGOP")->payload, 0, 1000); }},
      {"more levels than stored",
       [](std::vector<Section>* s) { StoreLE<int32_t>(&Find(s, "HGOP")->payload, 0, 5); }},
      {"huge time step count",
       [](std::vector<Section>* s) { StoreLE<uint32_t>(&Find(s, "MODL")->payload, 36, 0x80000000u); }},
      {"more time steps than stored",
       [](std::vector<Section>* s) { StoreLE<uint32_t>(&Find(s, "MODL")->payload, 36, 3); }},
      {"infinite bound",
       [](std::vector<Section>* s) {
         StoreLE<float>(&Find(s, "MODL")->payload, 20, std::numeric_limits<float>::infinity());
       }},
      {"NaN scene centre",
       [](std::vector<Section>* s) {
         StoreLE<float>(&Find(s, "MODL")->payload, 4, std::numeric_limits<float>::quiet_NaN());
       }},
      {"scene centre at 3e38",
       [](std::vector<Section>* s) { StoreLE<float>(&Find(s, "MODL")->payload, 8, 3e38f); }},
      {"NaN background",
       [](std::vector<Section>* s) {
         StoreLE<float>(&Find(s, "MODL")->payload, 24, std::numeric_limits<float>::quiet_NaN());
       }},
      {"background above 1", [](std::vector<Section>* s) { StoreLE<float>(&Find(s, "MODL")->payload, 28, 7.0f); }},
      {"infinite embedding",
       [](std::vector<Section>* s) {
         StoreLE<float>(&Find(s, "PEMB")->payload, 0, std::numeric_limits<float>::infinity());
       }},
      {"steps per diagonal 1.9e22 (found by fuzzing: marching never ends)",
       [](std::vector<Section>* s) { StoreLE<float>(&Find(s, "MROP")->payload, 4, 1.888946593147858e22f); }},
      {"max samples 2^30", [](std::vector<Section>* s) { StoreLE<int32_t>(&Find(s, "MROP")->payload, 0, 1 << 30); }},
      {"larger bound (more cascades)",
       [](std::vector<Section>* s) { StoreLE<float>(&Find(s, "MODL")->payload, 20, 4.0f); }},
      {"unknown scene kind", [](std::vector<Section>* s) { StoreLE<uint32_t>(&Find(s, "MODL")->payload, 0, 9); }},
      {"bad embedding flag", [](std::vector<Section>* s) { Find(s, "NTOP")->payload[28] = 2; }},
      {"occupancy resolution", [](std::vector<Section>* s) { StoreLE<int32_t>(&Find(s, "OGOP")->payload, 0, 32); }},
      {"huge cell count",
       [](std::vector<Section>* s) { StoreLE<uint64_t>(&Find(s, "OCCP")->payload, 4, uint64_t(1) << 62); }},
      {"truncated occupancy", [](std::vector<Section>* s) { Find(s, "OCCP")->payload.resize(100); }},
      {"negative density reference",
       [](std::vector<Section>* s) { StoreLE<float>(&Find(s, "OCCP")->payload, 12, -1.0f); }},
      {"low density value above its limit",
       [](std::vector<Section>* s) {
         Section* occ = Find(s, "OCCP");
         StoreLE<float>(&occ->payload, 16, LoadLE<float>(occ->payload, 12));
       }},
      {"empty visibility stream",
       [](std::vector<Section>* s) {
         Section* occ = Find(s, "OCCP");
         const uint64_t n = LoadLE<uint64_t>(occ->payload, 20);
         occ->payload.erase(28, n);
         StoreLE<uint64_t>(&occ->payload, 20, 0);
       }},
      {"missing density code", [](std::vector<Section>* s) { Find(s, "OCCP")->payload.pop_back(); }},
      {"extra density code", [](std::vector<Section>* s) { Find(s, "OCCP")->payload += std::string("\0x", 2); }},
      {"unknown parameter encoding", [](std::vector<Section>* s) { Find(s, "PENC")->payload = LE<uint32_t>(7); }},
      {"short parameter encoding", [](std::vector<Section>* s) { Find(s, "PENC")->payload = LE<uint16_t>(1); }},
      {"float16 encoding of float32 blocks",
       [](std::vector<Section>* s) { Find(s, "PENC")->payload = LE<uint32_t>(1); }},
      {"odd float block", [](std::vector<Section>* s) { Find(s, "PMLP")->payload.push_back('\0'); }},
      {"huge metadata count",
       [](std::vector<Section>* s) { Find(s, "META")->payload = LE<uint64_t>(uint64_t(1) << 60); }},
      {"metadata string beyond the end",
       [](std::vector<Section>* s) {
         Find(s, "META")->payload = LE<uint64_t>(1) + LE<uint64_t>(uint64_t(1) << 60) + LE<uint64_t>(0);
       }},
      {"extra section name beyond the end",
       [](std::vector<Section>* s) { s->push_back(Section{Tag("XSEC"), LE<uint64_t>(1000) + "abc"}); }},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    SCOPED_TRACE(cases[i].name);
    std::vector<Section> sections = good;
    cases[i].edit(&sections);
    std::string file = BuildFile(sections);
    if (i == 0) {
      // Make the last section claim 2^62 bytes, then re-checksum.
      const size_t at = file.size() - 4 - 12;
      StoreLE<uint64_t>(&file, at + 4, uint64_t(1) << 62);
      file.resize(file.size() - 4);
      file += LE<uint32_t>(RefCrc32(file));
    }
    absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(file, "crafted");
    ASSERT_FALSE(loaded.ok());
    EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
    EXPECT_NE(loaded.status().message().find("checkpoint 'crafted' is corrupt"), std::string::npos)
        << loaded.status();
  }
}

// ---------------------------------------------------------------------------
// Format version 3: MODL without the rotation that version 4 appends.

// A version-4 file: no sampler section and no proposal block.
std::vector<Section> SplitV4Sections(const std::string& bytes) {
  std::vector<Section> sections = SplitSections(bytes);
  std::vector<Section> out;
  for (const Section& s : sections) {
    const std::string tag(reinterpret_cast<const char*>(&s.tag), 4);
    if (tag != "SMOP" && tag != "PPRP") out.push_back(s);
  }
  return out;
}

std::vector<Section> SplitV3Sections(const std::string& bytes) {
  std::vector<Section> sections = SplitV4Sections(bytes);
  Section* modl = Find(&sections, "MODL");
  modl->payload.resize(modl->payload.size() - 9 * sizeof(float));
  return sections;
}

TEST(CheckpointTest, ReadsVersionThreeWithTheIdentityRotationAndKeepsVersionFours) {
  ModelOptions options = TinyOptions();
  options.march.cone_angle = 1.0f / 256;
  NgpModel model = MakeModel(options, 1, 17, SceneKind::kUnbounded);
  // A version-3 file: no rotation, which is what its model was trained with.
  absl::StatusOr<LoadedCheckpoint> v3 = DeserializeCheckpoint(BuildFile(SplitV3Sections(Serialize(model)), 3));
  ASSERT_TRUE(v3.ok()) << v3.status();
  EXPECT_EQ(v3->format_version, 3u);
  EXPECT_TRUE(v3->model.normalization().rotation.isIdentity());
  // A version-3 MODL under a version-4 header is the wrong size.
  EXPECT_EQ(DeserializeCheckpoint(BuildFile(SplitV3Sections(Serialize(model)), 4)).status().code(),
            absl::StatusCode::kDataLoss);

  // Version 4 keeps a rotation bit for bit.
  Normalization norm = model.normalization();
  norm.rotation = Eigen::AngleAxisf(0.7f, Eigen::Vector3f(1, 2, 3).normalized()).toRotationMatrix();
  absl::StatusOr<NgpModel> rotated = NgpModel::FromParts(model.options(), norm, model.kind(), model.background(),
                                                         model.num_time_steps(), model.params());
  ASSERT_TRUE(rotated.ok()) << rotated.status();
  absl::StatusOr<LoadedCheckpoint> v4 = DeserializeCheckpoint(Serialize(*rotated));
  ASSERT_TRUE(v4.ok()) << v4.status();
  EXPECT_EQ(v4->model.normalization().rotation, norm.rotation);

  // A forged rotation (a reflection, or a non-rotation) is corrupt data.
  std::vector<Section> sections = SplitSections(Serialize(*rotated));
  Section* modl = Find(&sections, "MODL");
  const size_t at = modl->payload.size() - 9 * sizeof(float);
  for (float f : {-1.0f, 2.0f}) {
    std::vector<Section> forged = sections;
    Section* m = Find(&forged, "MODL");
    const float x = LoadLE<float>(m->payload, at) * f;
    std::memcpy(&m->payload[at], &x, sizeof(x));
    absl::StatusOr<LoadedCheckpoint> bad = DeserializeCheckpoint(BuildFile(forged), "forged");
    ASSERT_FALSE(bad.ok());
    EXPECT_EQ(bad.status().code(), absl::StatusCode::kDataLoss) << bad.status();
    EXPECT_NE(bad.status().message().find("rotation"), std::string::npos) << bad.status();
  }
  (void)modl;
}

// ---------------------------------------------------------------------------
// Format version 1.

// A version-1 file of `model`, built from the documented version-1 layout:
// float32 parameters without a PENC section, and the raw occupancy state in
// OCCG (threshold | cells | float32 density[] | uint8 visible[] | bits[]).
std::string BuildV1File(const NgpModel& model) {
  std::vector<Section> v1;
  for (const Section& s : SplitV3Sections(Serialize(model))) {
    if (s.tag == Tag("PENC")) continue;
    if (s.tag != Tag("OCCP")) {
      v1.push_back(s);
      continue;
    }
    const OccupancyGrid& occ = model.occupancy();
    std::string p = LE<float>(occ.threshold()) + LE<uint64_t>(occ.num_cells());
    p.append(reinterpret_cast<const char*>(occ.density().data()), occ.density().size() * sizeof(float));
    p.append(reinterpret_cast<const char*>(occ.visible().data()), occ.visible().size());
    p.append(reinterpret_cast<const char*>(occ.bits().data()), occ.bits().size() * sizeof(uint64_t));
    v1.push_back(Section{Tag("OCCG"), p});
  }
  return BuildFile(v1, 1);
}

TEST(CheckpointTest, ReadsVersionOneBoundedScenes) {
  const std::string v1 = BuildV1File(SharedModel());
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(v1);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->format_version, 1u);
  EXPECT_FALSE(loaded->fp16_params);
  ExpectBitEqual(SharedModel(), loaded->model, /*exact_density=*/true);
  // Saving it again writes the current format.
  EXPECT_EQ(Serialize(loaded->model), SharedBytes());

  // Each version's own sections are unknown critical sections to the other.
  std::vector<Section> sections = SplitSections(v1);
  sections.insert(sections.begin() + 5, Section{Tag("PENC"), LE<uint32_t>(0)});
  loaded = DeserializeCheckpoint(BuildFile(sections, 1));
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kFailedPrecondition) << loaded.status();
  EXPECT_NE(loaded.status().message().find("PENC"), std::string::npos) << loaded.status();
  sections = SplitSections(SharedBytes());
  sections.push_back(*Find(&sections, "OCCP"));
  sections.back().tag = Tag("OCCG");
  loaded = DeserializeCheckpoint(BuildFile(sections));
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kFailedPrecondition) << loaded.status();
  EXPECT_NE(loaded.status().message().find("OCCG"), std::string::npos) << loaded.status();

  // Version-1 content is still checked.
  sections = SplitSections(v1);
  Section* occ = Find(&sections, "OCCG");
  occ->payload[12 + LoadLE<uint64_t>(occ->payload, 4) * 4] = 7;  // The first visibility flag.
  loaded = DeserializeCheckpoint(BuildFile(sections, 1), "crafted");
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
  EXPECT_NE(loaded.status().message().find("invalid occupancy visibility flag 7"), std::string::npos)
      << loaded.status();
}

// ---------------------------------------------------------------------------
// Format version 2.

// A version-2 file of `model`, built from the documented version-2 OCCP
// layout: threshold | cells | float32 reference density | float32 low value |
// uint64 n | n bytes PackBits(visibility bitfield) | uint64 bits[] | deflate of
// one 8-bit log2 density code per cell (0: zero, 1: below reference / 4,
// else round(8 * log2(d / ref)) + 18).
std::string BuildV2File(const NgpModel& model) {
  std::vector<Section> v2 = SplitV3Sections(Serialize(model));
  const OccupancyGrid& occ = model.occupancy();
  const size_t cells = occ.num_cells();
  const float ref = occ.threshold() > 0 ? occ.threshold() : 1.0f;
  std::string flags((cells + 7) / 8, '\0'), packed, codes(cells, '\0');
  for (size_t i = 0; i < cells; ++i) {
    if (occ.visible()[i]) flags[i / 8] = char(uint8_t(flags[i / 8]) | (1u << (i % 8)));
    const float d = occ.density()[i];
    codes[i] = char(!(d > 0) ? 0 : d < ref / 4 ? 1
                   : int(std::clamp(std::round(8.0 * std::log2(double(d) / ref)) + 18.0, 2.0, 255.0)));
  }
  for (size_t i = 0; i < flags.size(); i += 128) {  // PackBits literals only.
    const size_t len = std::min<size_t>(128, flags.size() - i);
    packed += char(int8_t(len - 1));
    packed += flags.substr(i, len);
  }
  uLongf zn = compressBound(uLong(cells));
  std::string z(zn, '\0');
  EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(z.data()), &zn, reinterpret_cast<const Bytef*>(codes.data()),
                      uLong(cells), 6),
            Z_OK);
  z.resize(zn);
  std::string p = LE<float>(occ.threshold()) + LE<uint64_t>(cells) + LE<float>(ref) + LE<float>(0.0f) +
                  LE<uint64_t>(packed.size()) + packed;
  p.append(reinterpret_cast<const char*>(occ.bits().data()), occ.bits().size() * sizeof(uint64_t));
  p += z;
  Find(&v2, "OCCP")->payload = p;
  return BuildFile(v2, 2);
}

TEST(CheckpointTest, ReadsVersionTwoWithItsQuantisedDensities) {
  const NgpModel& model = SharedModel();
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(BuildV2File(model));
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->format_version, 2u);
  const OccupancyGrid &a = model.occupancy(), &b = loaded->model.occupancy();
  EXPECT_TRUE(SameBits(a.bits(), b.bits()));
  EXPECT_TRUE(SameBits(a.visible(), b.visible()));
  EXPECT_TRUE(SameBits(a.threshold(), b.threshold()));
  EXPECT_TRUE(SameBits(model.params().grid, loaded->model.params().grid));
  const float ref = a.threshold() > 0 ? a.threshold() : 1.0f;
  size_t bad = 0, coded = 0;
  for (size_t i = 0; i < a.density().size(); ++i) {
    const float x = a.density()[i], y = b.density()[i];
    const bool ok = !(x > 0) ? y == 0
                    : x < ref / 4 ? y == 0  // The low value this file stores.
                                  : std::abs(std::log2(double(y) / x)) <= 1.0 / 16 + 1e-6;
    coded += x >= ref / 4;
    if (!ok && ++bad <= 5) ADD_FAILURE() << "cell " << i << ": saved " << x << ", loaded " << y;
  }
  EXPECT_EQ(bad, 0u);
  EXPECT_GT(coded, 0u);  // The fixture exercises the log codes.
  // Saving it again writes the current format, which loads.
  EXPECT_TRUE(DeserializeCheckpoint(Serialize(loaded->model)).ok());
}

TEST(CheckpointTest, RefusesVersionOneUnboundedScenes) {
  ModelOptions options = TinyOptions();
  options.march.cone_angle = 1.0f / 256;
  const NgpModel model = MakeModel(options, 1, 17, SceneKind::kUnbounded);
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(BuildV1File(model), "old.ckpt");
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kFailedPrecondition) << loaded.status();
  const std::string msg(loaded.status().message());
  EXPECT_NE(msg.find("checkpoint 'old.ckpt' predates format version 2"), std::string::npos) << msg;
  EXPECT_NE(msg.find("re-train"), std::string::npos) << msg;
  // The same model in the current format loads.
  EXPECT_TRUE(DeserializeCheckpoint(Serialize(model)).ok());
}

// ---------------------------------------------------------------------------
// Half precision.

// The value of binary16 `h` from its definition.
double HalfValue(uint16_t h) {
  const int sign = h >> 15, e = (h >> 10) & 0x1f, m = h & 0x3ff;
  const double v = e == 0 ? std::ldexp(double(m), -24) : std::ldexp(1.0 + m / 1024.0, e - 15);
  return sign ? -v : v;
}

// The binary16 value nearest to finite `x` (ties to even), or +-inf beyond
// the range, computed in double.
double RefHalfValue(float x) {
  const double a = std::abs(double(x));
  double r;
  if (a >= 65520.0) {
    r = std::numeric_limits<double>::infinity();
  } else {
    const int e = a == 0 ? -14 : std::max(std::ilogb(a), -14);
    const double ulp = std::ldexp(1.0, e - 10);
    r = std::nearbyint(a / ulp) * ulp;  // Exact quotient; default rounding is to nearest even.
  }
  return std::signbit(x) ? -r : r;
}

TEST(HalfTest, KnownValues) {
  EXPECT_EQ(FloatToHalf(0.0f), 0x0000);
  EXPECT_EQ(FloatToHalf(-0.0f), 0x8000);
  EXPECT_EQ(FloatToHalf(1.0f), 0x3c00);
  EXPECT_EQ(FloatToHalf(-2.0f), 0xc000);
  EXPECT_EQ(FloatToHalf(0.1f), 0x2e66);
  EXPECT_EQ(FloatToHalf(65504.0f), 0x7bff);       // Largest finite half.
  EXPECT_EQ(FloatToHalf(65519.996f), 0x7bff);     // Just below the overflow midpoint.
  EXPECT_EQ(FloatToHalf(65520.0f), 0x7c00);       // The midpoint rounds to even: infinity.
  EXPECT_EQ(FloatToHalf(1e6f), 0x7c00);
  EXPECT_EQ(FloatToHalf(-std::numeric_limits<float>::infinity()), 0xfc00);
  EXPECT_EQ(FloatToHalf(std::ldexp(1.0f, -14)), 0x0400);  // Smallest normal.
  EXPECT_EQ(FloatToHalf(std::ldexp(1.0f, -24)), 0x0001);  // Smallest subnormal.
  EXPECT_EQ(FloatToHalf(std::ldexp(1.0f, -25)), 0x0000);  // Tie between 0 and 2^-24: even.
  EXPECT_EQ(FloatToHalf(std::nextafter(std::ldexp(1.0f, -25), 1.0f)), 0x0001);
  EXPECT_EQ(FloatToHalf(std::ldexp(3.0f, -25)), 0x0002);  // Tie between 1 and 2 units: even.
  EXPECT_EQ(FloatToHalf(std::ldexp(1023.5f, -24)), 0x0400);  // Largest subnormal + 1/2: rounds up to normal.
  EXPECT_EQ(FloatToHalf(1.0f + std::ldexp(1.0f, -11)), 0x3c00);       // Tie: even (down).
  EXPECT_EQ(FloatToHalf(1.0f + 3 * std::ldexp(1.0f, -11)), 0x3c02);   // Tie: even (up).
  EXPECT_EQ(FloatToHalf(std::numeric_limits<float>::denorm_min()), 0x0000);
  const uint16_t nan = FloatToHalf(std::numeric_limits<float>::quiet_NaN());
  EXPECT_EQ(nan & 0x7c00, 0x7c00);
  EXPECT_NE(nan & 0x3ff, 0);
  const uint16_t snan = FloatToHalf(std::bit_cast<float>(0xff800001u));  // Signalling, payload in low bits.
  EXPECT_EQ(snan, 0xfe00);  // Stays a NaN (quiet), keeps its sign.
  EXPECT_TRUE(std::isnan(HalfToFloat(0x7e00)));
  EXPECT_TRUE(std::isnan(HalfToFloat(0x7c01)));
  EXPECT_EQ(HalfToFloat(0x7c00), std::numeric_limits<float>::infinity());
  static_assert(FloatToHalf(1.5f) == 0x3e00 && HalfToFloat(0x3e00) == 1.5f);  // Usable in constant expressions.
}

TEST(HalfTest, EveryHalfConvertsExactlyAndBack) {
  for (uint32_t h = 0; h < 0x10000; ++h) {
    SCOPED_TRACE(h);
    const float f = HalfToFloat(uint16_t(h));
    if (((h >> 10) & 0x1f) == 0x1f && (h & 0x3ff) != 0) {
      ASSERT_TRUE(std::isnan(f));
      ASSERT_EQ(std::signbit(f), bool(h & 0x8000));
      ASSERT_EQ(FloatToHalf(f), h | 0x200);  // Quietened, payload kept.
      continue;
    }
    if (((h >> 10) & 0x1f) == 0x1f) {
      ASSERT_TRUE(std::isinf(f));
    } else {
      ASSERT_EQ(double(f), HalfValue(uint16_t(h)));
    }
    ASSERT_EQ(std::signbit(f), bool(h & 0x8000));
    ASSERT_EQ(FloatToHalf(f), h);
  }
}

TEST(HalfTest, RoundsToNearestEven) {
  std::mt19937 rng(5);
  std::vector<float> xs;
  // Random floats around the whole binary16 range (subnormals to overflow).
  std::uniform_int_distribution<int> exponent(-28, 17);
  std::uniform_int_distribution<uint32_t> mantissa(0, (1u << 23) - 1);
  for (int i = 0; i < 400000; ++i) {
    const uint32_t bits = uint32_t(exponent(rng) + 127) << 23 | mantissa(rng) | (i % 2 ? 0x80000000u : 0);
    xs.push_back(std::bit_cast<float>(bits));
  }
  // Exact midpoints between neighbouring halves, and their float neighbours.
  for (uint32_t h = 0; h < 0x7bff; h += 7) {
    const float mid = float((HalfValue(uint16_t(h)) + HalfValue(uint16_t(h + 1))) / 2);
    xs.insert(xs.end(), {mid, std::nextafter(mid, 0.0f), std::nextafter(mid, 1e9f), -mid});
  }
  for (float x : xs) {
    const double want = RefHalfValue(x);
    const float got = HalfToFloat(FloatToHalf(x));
    ASSERT_EQ(double(got), want) << "x = " << x << std::hexfloat << " (" << x << ")";
    ASSERT_EQ(std::signbit(got), std::signbit(x)) << x;
  }
}

// ---------------------------------------------------------------------------
// fp16 storage.

TEST(CheckpointTest, Fp16ParametersRoundTripWithinHalfPrecision) {
  const NgpModel model = MakeModel(TinyOptions(), 3, 31);
  CheckpointOptions half;
  half.fp16_params = true;
  const std::string bytes = Serialize(model, {}, half);
  const std::string full = Serialize(model);
  std::vector<Section> sections = SplitSections(bytes);
  EXPECT_EQ(Find(&sections, "PENC")->payload, LE<uint32_t>(1));
  EXPECT_EQ(Find(&sections, "PGRD")->payload.size(), model.params().grid.size() * 2);
  EXPECT_EQ(Find(&sections, "PMLP")->payload.size(), model.params().mlp.size() * 2);
  EXPECT_EQ(Find(&sections, "PEMB")->payload.size(), model.params().emb.size() * 2);
  EXPECT_EQ(full.size() - bytes.size(), model.num_params() * 2);

  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(bytes);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_TRUE(loaded->fp16_params);
  EXPECT_EQ(loaded->format_version, kCheckpointFormatVersion);
  const NgpModel& m = loaded->model;
  for (const auto& [a, b] : {std::pair{&model.params().grid, &m.params().grid},
                             std::pair{&model.params().mlp, &m.params().mlp},
                             std::pair{&model.params().emb, &m.params().emb}}) {
    ASSERT_EQ(a->size(), b->size());
    for (size_t i = 0; i < a->size(); ++i) {
      ASSERT_EQ((*b)[i], HalfToFloat(FloatToHalf((*a)[i]))) << i;
      ASSERT_LE(std::abs((*b)[i] - (*a)[i]), std::abs((*a)[i]) * std::ldexp(1.0f, -11) + std::ldexp(1.0f, -25)) << i;
    }
  }
  // Everything else is as in a float32 checkpoint.
  EXPECT_EQ(m.options().grid.finest_resolution, model.options().grid.finest_resolution);
  EXPECT_EQ(m.num_time_steps(), 3);
  EXPECT_TRUE(SameBits(m.occupancy().bits(), model.occupancy().bits()));
  EXPECT_TRUE(SameBits(m.occupancy().threshold(), model.occupancy().threshold()));
  EXPECT_TRUE(SameBits(m.occupancy().visible(), model.occupancy().visible()));
  ExpectRestoredDensities(model.occupancy(), m.occupancy());
  // Re-saving is the identity, in either precision (halves are exact floats).
  EXPECT_EQ(Serialize(m, {}, half), bytes);
  absl::StatusOr<LoadedCheckpoint> again = DeserializeCheckpoint(Serialize(m));
  ASSERT_TRUE(again.ok()) << again.status();
  ExpectBitEqual(m, again->model, /*exact_density=*/true);

  // Renders stay close to the float32 model's.
  const Camera camera = TestCamera(model.normalization(), 20.0f);
  for (int step : {0, 2}) {
    RenderOptions options;
    options.time_step = step;
    absl::StatusOr<RenderedView> a = RenderView(model, camera, options);
    absl::StatusOr<RenderedView> b = RenderView(m, camera, options);
    ASSERT_TRUE(a.ok()) << a.status();
    ASSERT_TRUE(b.ok()) << b.status();
    ASSERT_EQ(a->rgb.rgb.size(), b->rgb.rgb.size());
    double max_diff = 0, sum_diff = 0;
    for (size_t i = 0; i < a->rgb.rgb.size(); ++i) {
      const double d = std::abs(double(a->rgb.rgb[i]) - b->rgb.rgb[i]);
      max_diff = std::max(max_diff, d);
      sum_diff += d;
    }
    EXPECT_GT(a->samples, 0);
    EXPECT_LT(max_diff, 0.02) << "step " << step;
    EXPECT_LT(sum_diff / double(a->rgb.rgb.size()), 2e-3) << "step " << step;
  }

  // An odd-sized binary16 block is corrupt.
  Find(&sections, "PMLP")->payload.push_back('\0');
  loaded = DeserializeCheckpoint(BuildFile(sections), "crafted");
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
}

TEST(CheckpointTest, Fp16RefusesParametersBeyondItsRange) {
  NgpModel model = MakeModel(TinyOptions(), 1, 37);
  CheckpointOptions half;
  half.fp16_params = true;
  model.mutable_params().mlp[3] = 65519.0f;  // Rounds to 65504.
  absl::StatusOr<std::string> ok = SerializeCheckpoint(model, {}, half);
  ASSERT_TRUE(ok.ok()) << ok.status();
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(*ok);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->model.params().mlp[3], 65504.0f);

  model.mutable_params().emb[1] = -70000.0f;
  absl::StatusOr<std::string> bad = SerializeCheckpoint(model, {}, half);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kFailedPrecondition) << bad.status();
  EXPECT_NE(bad.status().message().find("embedding parameter 1"), std::string::npos) << bad.status();
  EXPECT_NE(bad.status().message().find("binary16"), std::string::npos) << bad.status();
  EXPECT_TRUE(SerializeCheckpoint(model).ok());  // float32 stores it.
}

// ---------------------------------------------------------------------------
// Size: the file is at most 1.25x the model's parameter bytes.

// The capacity the trainer picks for lego (16 levels of 2^16 entries, 128^3
// occupancy): about 7.1 MB of parameters.
ModelOptions LegoLikeOptions() {
  ModelOptions o;
  o.grid.levels = 16;
  o.grid.log2_table_size = 16;
  o.grid.base_resolution = 16;
  o.grid.finest_resolution = 414;
  o.occupancy.resolution = 128;
  o.march.steps_per_diagonal = 414;
  return o;
}

// Fills the occupancy grid with a trained-looking state, modelled on a lego
// checkpoint after 300 steps: dense cells inside the surfaces `sdf` < 0 (up
// to 2^10 x the threshold), a band just outside them near the threshold, and
// low residue from the warm-up everywhere else (most cells).
void FillTrainedLikeOccupancy(NgpModel* model, const std::function<float(const Eigen::Vector3f&)>& sdf,
                              uint64_t seed) {
  OccupancyGrid& occ = model->mutable_occupancy();
  const float thr = occ.threshold();  // The maximum threshold: the grid is fresh.
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<uint32_t> cells(occ.num_cells());
  std::vector<float> sigma(occ.num_cells());
  for (size_t i = 0; i < cells.size(); ++i) {
    cells[i] = uint32_t(i);
    const float d = sdf(occ.CellPosition(uint32_t(i), Eigen::Vector3f::Zero()));
    const float octaves = d < 0 ? 10 * u(rng) : d < 0.03f ? -2 * u(rng) : -2 - 2 * u(rng);
    sigma[i] = thr * std::exp2(octaves);
  }
  occ.ApplyUpdate(cells, sigma);
}

void ExpectCompactFile(const NgpModel& model, double max_ratio) {
  const std::string bytes = Serialize(model);
  const double ratio = double(bytes.size()) / double(model.num_bytes());
  std::printf("[ size     ] %zu cells (%zu occupied, %zu visible): %zu file bytes, %zu parameter bytes: %.3fx\n",
              model.occupancy().num_cells(), model.occupancy().num_occupied(), model.occupancy().num_visible(),
              bytes.size(), model.num_bytes(), ratio);
  EXPECT_LE(ratio, max_ratio);
  absl::StatusOr<LoadedCheckpoint> loaded = DeserializeCheckpoint(bytes);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  ExpectBitEqual(model, loaded->model);  // Bits and threshold exact, densities restored.
  CheckpointOptions half;
  half.fp16_params = true;
  const std::string small = Serialize(model, {}, half);
  std::printf("[ size     ] fp16 parameters: %zu file bytes: %.3fx\n", small.size(),
              double(small.size()) / double(model.num_bytes()));
  EXPECT_EQ(bytes.size() - small.size(), 2 * model.num_params());
}

TEST(CheckpointTest, FileIsAtMostOneAndAQuarterParameterBytes) {
  Normalization norm;
  absl::StatusOr<NgpModel> model =
      NgpModel::Create(LegoLikeOptions(), norm, SceneKind::kBounded, Eigen::Vector3f::Ones(), 1, 3);
  ASSERT_TRUE(model.ok()) << model.status();
  ASSERT_EQ(model->occupancy().num_cascades(), 1);
  ExpectCompactFile(*model, 1.25);  // Fresh: every density is zero.
  // An object of 6 % of the box.
  FillTrainedLikeOccupancy(&*model, [](const Eigen::Vector3f& p) { return p.norm() - 0.24f; }, 3);
  ASSERT_GT(model->occupancy().num_occupied(), model->occupancy().num_cells() / 20);
  ExpectCompactFile(*model, 1.25);
}

TEST(CheckpointTest, FileIsAtMostOneAndAQuarterParameterBytesWithCascades) {
  Normalization norm;
  norm.bound = 2.0f;
  ModelOptions options = LegoLikeOptions();
  options.march.cone_angle = 1.0f / 256;
  absl::StatusOr<NgpModel> model =
      NgpModel::Create(options, norm, SceneKind::kBounded, Eigen::Vector3f::Ones(), 2, 5);
  ASSERT_TRUE(model.ok()) << model.status();
  ASSERT_EQ(model->occupancy().num_cascades(), 3);
  // An object in the middle and a surrounding "room" (a shell 0.2 thick,
  // 10 % of the outer cascade), seen from one side only.
  model->mutable_occupancy().MarkInvisible({model->ToModelCamera(TestCamera(norm, 8.0f))}, options.march.near);
  FillTrainedLikeOccupancy(
      &*model, [](const Eigen::Vector3f& p) { return std::min(p.norm() - 0.24f, std::abs(p.norm() - 1.6f) - 0.1f); },
      5);
  ASSERT_LT(model->occupancy().num_visible(), model->occupancy().num_cells());
  ASSERT_GT(model->occupancy().num_occupied(), model->occupancy().num_cells() / 30);
  ExpectCompactFile(*model, 1.25);
}

// ---------------------------------------------------------------------------
// Atomic saving.

TEST(CheckpointTest, AtomicSaveReplacesOnlyOnSuccess) {
  TempDir dir;
  const std::string path = dir.File("model.ckpt");
  ASSERT_TRUE(SaveCheckpoint(SharedModel(), path).ok());
  const std::string first = ReadFile(path);

  // Overwriting with a different model replaces the file.
  const NgpModel other = MakeModel(TinyOptions(false), 1, 29);
  absl::StatusOr<size_t> written = SaveCheckpoint(other, path);
  ASSERT_TRUE(written.ok()) << written.status();
  const std::string second = ReadFile(path);
  EXPECT_NE(first, second);
  EXPECT_EQ(second.size(), *written);
  absl::StatusOr<LoadedCheckpoint> loaded = LoadCheckpoint(path);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  ExpectBitEqual(other, loaded->model);
  EXPECT_EQ(dir.Entries(), std::vector<std::string>{"model.ckpt"});

  // A model that cannot be serialised leaves the old file untouched.
  NgpModel broken = other;
  broken.mutable_params().grid.pop_back();
  absl::StatusOr<size_t> failed = SaveCheckpoint(broken, path);
  ASSERT_FALSE(failed.ok());
  EXPECT_EQ(failed.status().code(), absl::StatusCode::kFailedPrecondition) << failed.status();
  EXPECT_EQ(ReadFile(path), second);
  EXPECT_EQ(dir.Entries(), std::vector<std::string>{"model.ckpt"});

  // A save into a missing directory fails without side effects.
  EXPECT_FALSE(SaveCheckpoint(other, dir.File("no/such/dir/model.ckpt")).ok());
  EXPECT_EQ(dir.Entries(), std::vector<std::string>{"model.ckpt"});
}

TEST(CheckpointTest, FailedWriteRemovesTemporaryFile) {
  // Make writes fail part-way with EFBIG by limiting the file size.
  TempDir dir;
  const std::string path = dir.File("model.ckpt");
  WriteFile(path, "previous contents");
  rlimit old;
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &old), 0);
  if (old.rlim_max != RLIM_INFINITY && old.rlim_max < 1000) GTEST_SKIP() << "file size limit too low";
  void (*old_handler)(int) = ::signal(SIGXFSZ, SIG_IGN);
  rlimit small = old;
  small.rlim_cur = 1000;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);
  absl::StatusOr<size_t> written = SaveCheckpoint(SharedModel(), path);
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &old), 0);
  ::signal(SIGXFSZ, old_handler);
  ASSERT_FALSE(written.ok());
  EXPECT_NE(written.status().message().find("cannot write"), std::string::npos) << written.status();
  EXPECT_EQ(ReadFile(path), "previous contents");
  EXPECT_EQ(dir.Entries(), std::vector<std::string>{"model.ckpt"});
}

}  // namespace
}  // namespace clnerf
