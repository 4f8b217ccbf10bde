#include "server/store/version_store.h"

#include <cstdio>
#include <filesystem>
#include <random>

#include "core/io/durable_file.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/testing/store_test_util.h"

namespace clnerf {
namespace {

NgpModel TinyModel(uint64_t seed) {
  ModelOptions mo;
  mo.grid.levels = 4;
  mo.grid.log2_table_size = 10;
  mo.grid.finest_resolution = 32;
  auto m = NgpModel::Create(mo, Normalization{}, SceneKind::kBounded, Eigen::Vector3f::Ones(), 2, seed);
  EXPECT_TRUE(m.ok()) << m.status();
  return *std::move(m);
}

// A memory with one 8x8 camera of time step `t`.
ReplayMemory OneCameraMemory(int t) {
  ReplayMemory memory(3);
  Camera cam;
  cam.intrinsics = Intrinsics{8, 8, 10, 10, 4, 4};
  cam.time_step = t;
  memory.AddCamera(cam);
  return memory;
}

// A replay memory that does not belong to its model (as a mutated file whose
// CRC was fixed up would be: here written with a valid CRC) is DATA_LOSS at
// load, the status every other check of stored data gives.
TEST(VersionStoreTest, AMemoryThatDoesNotMatchItsModelIsDataLoss) {
  const std::string root = testing_util::TempDir("versions_mismatch");
  auto store = VersionStore::Open(root);
  ASSERT_TRUE(store.ok());
  const NgpModel model = TinyModel(1);  // 2 time steps.
  const ReplayMemory memory = OneCameraMemory(5);
  VersionInfo info;
  info.version = 1;
  info.time_steps = 2;
  ASSERT_TRUE((*store)->Write(model, memory, info).ok());
  auto loaded = (*store)->Load(1);
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
  EXPECT_NE(loaded.status().message().find("does not match its model"), std::string::npos) << loaded.status();
}

// Model no more than a scene needs, on disk too: a version with a full
// replay buffer of photos is stored within 1.25x its model plus its buffer
// as stored (8-bit PNGs), and reports both.
TEST(VersionStoreTest, AVersionIsStoredWithinAQuarterOverItsModelAndBuffer) {
  const std::string root = testing_util::TempDir("versions_size");
  auto store = VersionStore::Open(root);
  ASSERT_TRUE(store.ok());
  const NgpModel model = TinyModel(1);
  const Scene scans = testing_util::TinyScans(1, 48, 12, 1);
  ReplayMemory memory(10);
  std::mt19937_64 rng(1);
  for (const View& v : scans.train) {
    Camera c = v.camera;
    c.time_step = 1;
    memory.OfferReservoir(memory.AddCamera(c), v.image, Mask(), &rng);
  }
  ASSERT_EQ(memory.buffer().size(), 10u);
  VersionInfo info;
  info.version = 1;
  info.time_steps = 2;
  absl::StatusOr<VersionInfo> written = (*store)->Write(model, memory, info);
  ASSERT_TRUE(written.ok()) << written.status();
  EXPECT_GT(written->replay_bytes, 0);
  EXPECT_LT(written->replay_bytes, int64_t(memory.buffer_bytes() / 4));  // Float pixels in memory, 8-bit stored.
  EXPECT_LE(double(written->size_bytes), 1.25 * double(written->model_bytes + written->replay_bytes));
  std::printf("version: %lld bytes stored, model %lld + replay %lld (buffer %zu bytes in memory)\n",
              (long long)written->size_bytes, (long long)written->model_bytes, (long long)written->replay_bytes,
              memory.buffer_bytes());
  absl::StatusOr<VersionInfo> listed = (*store)->Info(1);
  ASSERT_TRUE(listed.ok());
  EXPECT_EQ(listed->replay_bytes, written->replay_bytes);
}

TEST(VersionStoreTest, WriteLoadListAndManifest) {
  const std::string root = testing_util::TempDir("versions");
  auto store = VersionStore::Open(root);
  ASSERT_TRUE(store.ok());
  const NgpModel model = TinyModel(1);
  const ReplayMemory memory = OneCameraMemory(1);
  VersionInfo info;
  info.version = 1;
  info.time_steps = 2;
  info.scan_id = "scan-000001";
  info.metrics["new_psnr"] = 25.5;
  auto written = (*store)->Write(model, memory, info);
  ASSERT_TRUE(written.ok()) << written.status();
  EXPECT_GT(written->size_bytes, 0);
  EXPECT_EQ(written->model_bytes, int64_t(model.num_bytes()));
  EXPECT_EQ(written->size_bytes, int64_t(std::filesystem::file_size(root + "/versions/000001/model.ckpt")));
  const nlohmann::json json = nlohmann::json::parse(*ReadFileToString(root + "/versions/000001/version.json"));
  EXPECT_EQ(json.at("file_bytes"), written->size_bytes);
  EXPECT_EQ(json.at("size_bytes"), written->size_bytes);
  EXPECT_EQ(json.at("model_bytes"), written->model_bytes);
  EXPECT_EQ((*store)->Write(model, memory, info).status().code(), absl::StatusCode::kAlreadyExists);

  auto loaded = (*store)->Load(1);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->info.scan_id, "scan-000001");
  EXPECT_DOUBLE_EQ(loaded->info.metrics.at("new_psnr"), 25.5);
  EXPECT_EQ(loaded->info.model_bytes, int64_t(model.num_bytes()));
  EXPECT_EQ(loaded->model.params().grid, model.params().grid);
  EXPECT_EQ(loaded->memory.num_cameras(), 1u);
  EXPECT_EQ((*store)->Load(7).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ((*store)->List()->size(), 1u);

  auto m0 = (*store)->ReadManifest();
  ASSERT_TRUE(m0.ok());
  EXPECT_EQ(m0->deployed, 0);
  Manifest m;
  m.deployed = 1;
  m.next_version = 2;
  m.next_scan = 5;
  m.next_job = 6;
  ASSERT_TRUE((*store)->WriteManifest(m).ok());
  auto m1 = (*store)->ReadManifest();
  ASSERT_TRUE(m1.ok());
  EXPECT_EQ(m1->deployed, 1);
  EXPECT_EQ(m1->next_scan, 5);
  EXPECT_EQ(m1->next_job, 6);
}

TEST(VersionStoreTest, TornWritesAreInvisibleAndCorruptionIsDataLoss) {
  const std::string root = testing_util::TempDir("versions_torn");
  std::filesystem::create_directories(root + "/versions/.tmp-000003");
  auto store = VersionStore::Open(root);
  ASSERT_TRUE(store.ok());
  EXPECT_TRUE((*store)->List()->empty());
  VersionInfo one;
  one.version = 1;
  ASSERT_TRUE((*store)->Write(TinyModel(2), ReplayMemory(), one).ok());
  // Flip a byte in the checkpoint: the CRC catches it.
  const std::string ck = root + "/versions/000001/model.ckpt";
  std::string bytes = *ReadFileToString(ck);
  bytes[bytes.size() / 2] ^= 0x40;
  std::FILE* f = std::fopen(ck.c_str(), "wb");
  std::fwrite(bytes.data(), 1, bytes.size(), f);
  std::fclose(f);
  EXPECT_EQ((*store)->Load(1).status().code(), absl::StatusCode::kDataLoss);
}

}  // namespace
}  // namespace clnerf
