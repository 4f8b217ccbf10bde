// ReplayMemory: what CLNeRF keeps of the past instead of old images (M_t in
// the paper). It holds the camera parameters of *every* image seen so far, in
// a compact form (axis-angle rotation + translation as float32, an index into
// a deduplicated intrinsics table, and the time step), plus an optional
// reservoir buffer of K real images for experience replay.
//
// Reservoir sampling (Vitter's algorithm R, as in the CLNeRF code): the first
// K images fill the buffer; after that the i-th image seen (1-based) replaces
// a uniformly chosen slot with probability K/i. A prioritized policy (keep the
// K images with the lowest PSNR under the current model) is available too.
//
// A ReplayMemory is a value type with no internal locking; the continual
// update builds M_t from a copy of M_{t-1}, never modifying M_{t-1}.
#ifndef CLNERF_CORE_CONTINUAL_REPLAY_MEMORY_H_
#define CLNERF_CORE_CONTINUAL_REPLAY_MEMORY_H_

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/data/scene.h"

namespace clnerf {

// One image's camera: 28 bytes (+ a share of its intrinsics record).
struct CameraRecord {
  float rotation[3];     // Axis-angle (OpenCV camera-to-world rotation).
  float translation[3];  // Camera centre, world units.
  uint16_t intrinsics;   // Index into ReplayMemory::intrinsics().
  uint16_t time_step;
};
static_assert(sizeof(CameraRecord) == 28, "CameraRecord must stay compact");

struct BufferedImage {
  uint32_t camera = 0;  // Index of its CameraRecord.
  Image image;
  Mask mask;
};

class ReplayMemory {
 public:
  explicit ReplayMemory(int buffer_capacity = 10) : capacity_(buffer_capacity) {}

  int buffer_capacity() const { return capacity_; }
  size_t num_cameras() const { return cameras_.size(); }
  uint64_t num_seen() const { return seen_; }
  const std::vector<CameraRecord>& cameras() const { return cameras_; }
  const std::vector<Intrinsics>& intrinsics() const { return intrinsics_; }
  const std::vector<BufferedImage>& buffer() const { return buffer_; }

  // Records a new view's camera; returns its index. Does not touch the buffer.
  uint32_t AddCamera(const Camera& camera);
  // The camera of record i, reconstructed (poses round-trip to ~1e-6).
  Camera GetCamera(uint32_t i) const;
  // Offers view `camera_index` (with its image) to the reservoir buffer.
  // Returns true if it was stored.
  bool OfferReservoir(uint32_t camera_index, const Image& image, const Mask& mask, std::mt19937_64* rng);
  // Replaces the buffer wholesale (prioritized replay keeps the K worst views).
  void SetBuffer(std::vector<BufferedImage> buffer);
  // True if camera i's image is in the buffer.
  bool InBuffer(uint32_t i) const;
  // The largest time step of any recorded camera; -1 with no cameras. The
  // memory of a model with T time steps reaches exactly T - 1.
  int MaxTimeStep() const;

  // Storage: camera records + intrinsics table, and buffered image pixels.
  size_t camera_bytes() const;
  size_t buffer_bytes() const;
  double bytes_per_camera() const { return cameras_.empty() ? 0.0 : double(camera_bytes()) / cameras_.size(); }

  // Binary form (stored as a checkpoint extra section). Buffered images are
  // stored as 8-bit PNGs, as CLNeRF's code keeps them (photos are 8-bit, so
  // a decoded photo comes back exactly; other values to within 1/510);
  // masks raw. Reads the float32 form of format version 1 too.
  std::string Serialize() const;
  static absl::StatusOr<ReplayMemory> Deserialize(const std::string& bytes);

 private:
  int capacity_;
  uint64_t seen_ = 0;  // Images offered to the reservoir so far.
  std::vector<CameraRecord> cameras_;
  std::vector<Intrinsics> intrinsics_;
  std::vector<BufferedImage> buffer_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_REPLAY_MEMORY_H_
