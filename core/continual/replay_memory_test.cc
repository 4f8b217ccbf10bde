#include "core/continual/replay_memory.h"

#include "core/io/byte_io.h"

#include <cmath>
#include <random>

#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

Camera RandomCamera(std::mt19937_64* rng, int step) {
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  Camera c;
  const Eigen::Vector3f axis = Eigen::Vector3f(u(*rng), u(*rng), u(*rng)).normalized();
  c.c2w.leftCols<3>() = Eigen::AngleAxisf(3.0f * u(*rng), axis).toRotationMatrix();
  c.c2w.col(3) = Eigen::Vector3f(4 * u(*rng), 4 * u(*rng), 4 * u(*rng));
  c.intrinsics = {100, 100, 138.9f, 138.9f, 50, 50};
  c.time_step = step;
  return c;
}

TEST(ReplayMemoryTest, CameraRoundTripIsCompactAndAccurate) {
  std::mt19937_64 rng(1);
  ReplayMemory m;
  std::vector<Camera> cams;
  for (int i = 0; i < 1000; ++i) {
    cams.push_back(RandomCamera(&rng, i / 100));
    EXPECT_EQ(m.AddCamera(cams.back()), uint32_t(i));
  }
  ASSERT_EQ(m.intrinsics().size(), 1u);  // Shared intrinsics are stored once.
  for (int i = 0; i < 1000; ++i) {
    const Camera c = m.GetCamera(i);
    EXPECT_LT((c.c2w - cams[i].c2w).cwiseAbs().maxCoeff(), 2e-5f) << i;
    EXPECT_EQ(c.time_step, cams[i].time_step);
    EXPECT_EQ(c.intrinsics.fx, cams[i].intrinsics.fx);
  }
  // The paper quotes ~45 bytes per image; we store 28 + a shared intrinsics record.
  EXPECT_LT(m.bytes_per_camera(), 29.0);
  EXPECT_EQ(m.camera_bytes(), 1000 * 28 + 40);
}

// Reservoir sampling keeps each of N offered images with probability K/N.
// Over R independent runs the number of runs in which image i survives is
// Binomial(R, K/N); every count must lie within 5 standard deviations.
TEST(ReplayMemoryTest, ReservoirIsUniform) {
  constexpr int kN = 60, kK = 10, kRuns = 3000;
  std::mt19937_64 rng(12345);
  std::vector<int> kept(kN, 0);
  Image tiny(1, 1);
  for (int run = 0; run < kRuns; ++run) {
    ReplayMemory m(kK);
    for (int i = 0; i < kN; ++i) m.OfferReservoir(uint32_t(i), tiny, {}, &rng);
    ASSERT_EQ(m.buffer().size(), size_t(kK));
    ASSERT_EQ(m.num_seen(), uint64_t(kN));
    for (const BufferedImage& b : m.buffer()) ++kept[b.camera];
  }
  const double p = double(kK) / kN, mean = kRuns * p, sd = std::sqrt(kRuns * p * (1 - p));
  for (int i = 0; i < kN; ++i) {
    EXPECT_NEAR(kept[i], mean, 5 * sd) << "image " << i;
  }
  // Early and late images are equally likely (no recency bias).
  double first = 0, last = 0;
  for (int i = 0; i < 10; ++i) first += kept[i], last += kept[kN - 1 - i];
  EXPECT_NEAR(first / 10, last / 10, 5 * sd / std::sqrt(10.0));
}

TEST(ReplayMemoryTest, FillsFirstThenReplaces) {
  std::mt19937_64 rng(3);
  ReplayMemory m(3);
  Image img(2, 2, 0.5f);
  for (uint32_t i = 0; i < 3; ++i) EXPECT_TRUE(m.OfferReservoir(i, img, {}, &rng));
  EXPECT_EQ(m.buffer().size(), 3u);
  EXPECT_TRUE(m.InBuffer(0) && m.InBuffer(1) && m.InBuffer(2));
  int stored = 0;
  for (uint32_t i = 3; i < 300; ++i) stored += m.OfferReservoir(i, img, {}, &rng);
  EXPECT_EQ(m.buffer().size(), 3u);
  // Expected number of replacements: sum_{i=4}^{300} 3/i ~= 13.8.
  EXPECT_GT(stored, 4);
  EXPECT_LT(stored, 30);
}

TEST(ReplayMemoryTest, ZeroCapacityStoresNothing) {
  std::mt19937_64 rng(3);
  ReplayMemory m(0);
  for (uint32_t i = 0; i < 20; ++i) EXPECT_FALSE(m.OfferReservoir(i, Image(2, 2), {}, &rng));
  EXPECT_TRUE(m.buffer().empty());
  EXPECT_EQ(m.buffer_bytes(), 0u);
}

TEST(ReplayMemoryTest, SerializeRoundTrip) {
  std::mt19937_64 rng(7);
  ReplayMemory m(2);
  for (int i = 0; i < 5; ++i) {
    Camera c = RandomCamera(&rng, i);
    if (i == 3) c.intrinsics.fx = 200;  // A second intrinsics record.
    const uint32_t k = m.AddCamera(c);
    Image img(3, 2, 0.1f * i);
    Mask mask;
    if (i == 1) mask = {3, 2, {1, 0, 1, 1, 0, 1}};
    m.OfferReservoir(k, img, mask, &rng);
  }
  const std::string bytes = m.Serialize();
  absl::StatusOr<ReplayMemory> back = ReplayMemory::Deserialize(bytes);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->Serialize(), bytes);
  EXPECT_EQ(back->num_seen(), m.num_seen());
  EXPECT_EQ(back->intrinsics().size(), 2u);
  ASSERT_EQ(back->buffer().size(), m.buffer().size());
  for (size_t i = 0; i < m.buffer().size(); ++i) {
    // Stored as 8 bits: within half a step of 1/255.
    ASSERT_EQ(back->buffer()[i].image.rgb.size(), m.buffer()[i].image.rgb.size());
    for (size_t j = 0; j < m.buffer()[i].image.rgb.size(); ++j) {
      EXPECT_NEAR(back->buffer()[i].image.rgb[j], m.buffer()[i].image.rgb[j], 0.5f / 255 + 1e-6f);
    }
    EXPECT_EQ(back->buffer()[i].mask.keep, m.buffer()[i].mask.keep);
  }
  // Every truncation is detected.
  for (size_t cut = 0; cut < bytes.size(); cut += 7) {
    EXPECT_FALSE(ReplayMemory::Deserialize(bytes.substr(0, cut)).ok()) << cut;
  }
  std::string bad = bytes;
  bad[0] = 'X';
  EXPECT_EQ(ReplayMemory::Deserialize(bad).status().code(), absl::StatusCode::kDataLoss);
}

// A photo (8-bit values) comes back with the same values, and its pixels take less room
// than 8-bit raw, a quarter of the float32 form of version 1.
TEST(ReplayMemoryTest, BufferedPhotosAreStoredAsCompact8BitImages) {
  std::mt19937_64 rng(3);
  ReplayMemory m(1);
  const uint32_t k = m.AddCamera(RandomCamera(&rng, 0));
  Image photo(64, 48);
  for (int y = 0; y < photo.height; ++y) {
    for (int x = 0; x < photo.width; ++x) {
      float* p = photo.pixel(x, y);
      p[0] = float((x * 4) % 256) / 255;
      p[1] = float((y * 5) % 256) / 255;
      p[2] = float(((x + y) * 3) % 256) / 255;
    }
  }
  ASSERT_TRUE(m.OfferReservoir(k, photo, Mask(), &rng));
  const std::string bytes = m.Serialize();
  EXPECT_LT(bytes.size(), size_t(photo.width) * photo.height * 3);
  absl::StatusOr<ReplayMemory> back = ReplayMemory::Deserialize(bytes);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_EQ(back->buffer().size(), 1u);
  ASSERT_EQ(back->buffer()[0].image.rgb.size(), photo.rgb.size());
  for (size_t j = 0; j < photo.rgb.size(); ++j) {
    EXPECT_NEAR(back->buffer()[0].image.rgb[j], photo.rgb[j], 1e-6f) << j;  // The same 8-bit value.
  }
}

// Memories written by earlier builds (format 1: float32 pixels) still load.
TEST(ReplayMemoryTest, ReadsTheFloatFormatOfVersion1) {
  std::string v1;
  ByteWriter w(&v1);
  w.Bytes(std::string_view("CLRM", 4));
  w.Put(uint32_t(1));
  w.Put(int32_t(4));    // capacity
  w.Put(uint64_t(1));   // seen
  w.Put(uint64_t(1));   // intrinsics
  w.Put(int32_t(2));
  w.Put(int32_t(1));
  for (float f : {100.f, 100.f, 1.f, 0.5f, 0.f, 0.f, 0.f, 0.f}) w.Put(f);
  w.Put(uint64_t(1));   // cameras
  for (float f : {0.f, 0.f, 0.f, 1.f, 2.f, 3.f}) w.Put(f);
  w.Put(uint16_t(0));
  w.Put(uint16_t(0));
  w.Put(uint64_t(1));   // buffered images
  w.Put(uint32_t(0));
  w.Put(int32_t(2));
  w.Put(int32_t(1));
  w.Array(std::vector<float>{0.1f, 0.2f, 0.3f, 0.4f, 0.5f, 0.6f});
  w.Put(uint8_t(0));
  absl::StatusOr<ReplayMemory> m = ReplayMemory::Deserialize(v1);
  ASSERT_TRUE(m.ok()) << m.status();
  ASSERT_EQ(m->buffer().size(), 1u);
  EXPECT_EQ(m->buffer()[0].image.rgb, (std::vector<float>{0.1f, 0.2f, 0.3f, 0.4f, 0.5f, 0.6f}));
  EXPECT_EQ(m->GetCamera(0).position(), Eigen::Vector3f(1, 2, 3));
}

}  // namespace
}  // namespace clnerf
