#include "core/continual/replay_memory.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "core/io/byte_io.h"
#include "Eigen/Geometry"

namespace clnerf {

namespace {

bool SameIntrinsics(const Intrinsics& a, const Intrinsics& b) {
  return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx &&
         a.cy == b.cy && a.k1 == b.k1 && a.k2 == b.k2 && a.p1 == b.p1 && a.p2 == b.p2;
}

constexpr char kMagic[4] = {'C', 'L', 'R', 'M'};
// 2: buffered images as 8-bit PNG (as CLNeRF's own code keeps them); 1:
// float32 pixels (still read).
constexpr uint32_t kVersion = 2;
constexpr uint32_t kOldestVersion = 1;

absl::Status Corrupt(const std::string& what) {
  return absl::DataLossError(absl::StrCat("replay memory is corrupt: ", what));
}

// One buffered image's pixels: float32 (version 1) or a PNG (version 2) of
// exactly w x h.
absl::Status ReadBufferPixels(ByteReader* r, uint32_t version, int32_t w, int32_t h, Image* image) {
  if (version == 1) {
    if (uint64_t(w) * uint64_t(h) * 12 > r->remaining()) return Corrupt("bad buffer image");
    *image = Image(w, h);
    if (!r->Array(uint64_t(w) * h * 3, &image->rgb)) return Corrupt("truncated buffer image");
    return absl::OkStatus();
  }
  uint64_t n = 0;
  std::string_view png;
  if (!r->Get(&n) || n > r->remaining() || !r->Bytes(size_t(n), &png)) return Corrupt("truncated buffer image");
  absl::StatusOr<Image> decoded = DecodeImage(std::string(png), "buffer.png");
  if (!decoded.ok()) return Corrupt(absl::StrCat("buffer image: ", decoded.status().message()));
  if (decoded->width != w || decoded->height != h) return Corrupt("buffer image size does not match");
  *image = *std::move(decoded);
  return absl::OkStatus();
}

}  // namespace

uint32_t ReplayMemory::AddCamera(const Camera& camera) {
  uint16_t k = 0;
  while (k < intrinsics_.size() && !SameIntrinsics(intrinsics_[k], camera.intrinsics)) ++k;
  if (k == intrinsics_.size()) intrinsics_.push_back(camera.intrinsics);
  CameraRecord r;
  const Eigen::AngleAxisf aa(Eigen::Matrix3f(camera.c2w.leftCols<3>()));
  const Eigen::Vector3f v = aa.axis() * aa.angle();
  for (int i = 0; i < 3; ++i) {
    r.rotation[i] = v[i];
    r.translation[i] = camera.c2w(i, 3);
  }
  r.intrinsics = k;
  r.time_step = uint16_t(camera.time_step);
  cameras_.push_back(r);
  return uint32_t(cameras_.size() - 1);
}

Camera ReplayMemory::GetCamera(uint32_t i) const {
  const CameraRecord& r = cameras_[i];
  Camera c;
  c.intrinsics = intrinsics_[r.intrinsics];
  const Eigen::Vector3f v(r.rotation[0], r.rotation[1], r.rotation[2]);
  const float angle = v.norm();
  const Eigen::Matrix3f rot =
      angle > 0 ? Eigen::AngleAxisf(angle, v / angle).toRotationMatrix() : Eigen::Matrix3f::Identity();
  c.c2w.leftCols<3>() = rot;
  c.c2w.col(3) = Eigen::Vector3f(r.translation[0], r.translation[1], r.translation[2]);
  c.time_step = r.time_step;
  return c;
}

bool ReplayMemory::OfferReservoir(uint32_t camera_index, const Image& image, const Mask& mask,
                                  std::mt19937_64* rng) {
  ++seen_;
  if (capacity_ <= 0) return false;
  if (buffer_.size() < size_t(capacity_)) {
    buffer_.push_back({camera_index, image, mask});
    return true;
  }
  std::uniform_int_distribution<uint64_t> pick(0, seen_ - 1);
  const uint64_t j = pick(*rng);
  if (j >= uint64_t(capacity_)) return false;
  buffer_[j] = {camera_index, image, mask};
  return true;
}

void ReplayMemory::SetBuffer(std::vector<BufferedImage> buffer) { buffer_ = std::move(buffer); }

int ReplayMemory::MaxTimeStep() const {
  int max_step = -1;
  for (const CameraRecord& c : cameras_) max_step = std::max(max_step, int(c.time_step));
  return max_step;
}

bool ReplayMemory::InBuffer(uint32_t i) const {
  for (const BufferedImage& b : buffer_) {
    if (b.camera == i) return true;
  }
  return false;
}

size_t ReplayMemory::camera_bytes() const {
  // Per intrinsics record: 2 ints + 8 floats.
  return cameras_.size() * sizeof(CameraRecord) + intrinsics_.size() * (2 * 4 + 8 * 4);
}

size_t ReplayMemory::buffer_bytes() const {
  size_t n = 0;
  for (const BufferedImage& b : buffer_) n += b.image.rgb.size() * sizeof(float) + b.mask.keep.size();
  return n;
}

// The serialized form (little-endian, core/io/byte_io.h):
//   "CLRM" | u32 version | i32 capacity | u64 seen
//   u64 n | n x (i32 w, i32 h, f32 fx fy cx cy k1 k2 p1 p2)
//   u64 m | m x (f32 rotation[3], f32 translation[3], u16 intrinsics, u16 time step)
//   u64 k | k x (u32 camera, i32 w, i32 h, u64 png_bytes, u8 png[png_bytes],
//                u8 has_mask, [u8 keep[w*h]])
// (version 1 held f32 rgb[w*h*3] where version 2 holds the PNG.)
std::string ReplayMemory::Serialize() const {
  std::string out;
  ByteWriter w(&out);
  w.Bytes(std::string_view(kMagic, 4));
  w.Put(kVersion);
  w.Put(int32_t(capacity_));
  w.Put(uint64_t(seen_));
  w.Put(uint64_t(intrinsics_.size()));
  for (const Intrinsics& in : intrinsics_) {
    w.Put(int32_t(in.width));
    w.Put(int32_t(in.height));
    for (float f : {in.fx, in.fy, in.cx, in.cy, in.k1, in.k2, in.p1, in.p2}) w.Put(f);
  }
  w.Put(uint64_t(cameras_.size()));
  for (const CameraRecord& c : cameras_) {
    for (float f : c.rotation) w.Put(f);
    for (float f : c.translation) w.Put(f);
    w.Put(c.intrinsics);
    w.Put(c.time_step);
  }
  w.Put(uint64_t(buffer_.size()));
  for (const BufferedImage& b : buffer_) {
    w.Put(b.camera);
    w.Put(int32_t(b.image.width));
    w.Put(int32_t(b.image.height));
    absl::StatusOr<std::string> png = EncodePng(b.image);
    const std::string bytes = png.ok() ? *std::move(png) : std::string();  // Encoding in memory cannot fail.
    w.Put(uint64_t(bytes.size()));
    w.Bytes(bytes);
    w.Put(uint8_t(b.mask.empty() ? 0 : 1));
    if (!b.mask.empty()) w.Array(b.mask.keep);
  }
  return out;
}

absl::StatusOr<ReplayMemory> ReplayMemory::Deserialize(const std::string& bytes) {
  ByteReader r(bytes);
  std::string_view magic;
  uint32_t version = 0;
  if (!r.Bytes(4, &magic) || std::memcmp(magic.data(), kMagic, 4) != 0) return Corrupt("bad magic");
  if (!r.Get(&version)) return Corrupt("truncated header");
  if (version < kOldestVersion || version > kVersion) {
    return absl::FailedPreconditionError(absl::StrCat("replay memory format version ", version,
                                                      " is not supported (this build reads ", kOldestVersion, " to ",
                                                      kVersion, ")"));
  }
  int32_t capacity = 0;
  uint64_t seen = 0, n = 0;
  if (!r.Get(&capacity) || !r.Get(&seen) || !r.Get(&n)) return Corrupt("truncated header");
  if (capacity < 0 || n > r.remaining() / 40) return Corrupt("bad sizes");
  ReplayMemory m(capacity);
  m.seen_ = seen;
  for (uint64_t i = 0; i < n; ++i) {
    Intrinsics in;
    int32_t w = 0, h = 0;
    float f[8];
    bool ok = r.Get(&w) && r.Get(&h);
    for (float& x : f) ok = ok && r.Get(&x);
    if (!ok) return Corrupt("truncated intrinsics");
    in.width = w;
    in.height = h;
    in.fx = f[0], in.fy = f[1], in.cx = f[2], in.cy = f[3], in.k1 = f[4], in.k2 = f[5], in.p1 = f[6], in.p2 = f[7];
    for (float x : f) {
      if (!std::isfinite(x)) return Corrupt("non-finite intrinsics");
    }
    m.intrinsics_.push_back(in);
  }
  if (!r.Get(&n) || n > r.remaining() / sizeof(CameraRecord)) return Corrupt("bad camera count");
  m.cameras_.resize(n);
  for (CameraRecord& c : m.cameras_) {
    bool ok = true;
    for (float& x : c.rotation) ok = ok && r.Get(&x);
    for (float& x : c.translation) ok = ok && r.Get(&x);
    if (!ok || !r.Get(&c.intrinsics) || !r.Get(&c.time_step)) return Corrupt("truncated cameras");
    if (c.intrinsics >= m.intrinsics_.size()) return Corrupt("camera refers to missing intrinsics");
    for (float x : c.rotation) {
      if (!std::isfinite(x)) return Corrupt("non-finite camera rotation");
    }
    for (float x : c.translation) {
      if (!std::isfinite(x)) return Corrupt("non-finite camera position");
    }
  }
  if (!r.Get(&n) || n > uint64_t(std::max(capacity, 0)) || n > r.remaining()) return Corrupt("bad buffer count");
  for (uint64_t i = 0; i < n; ++i) {
    BufferedImage b;
    int32_t w = 0, h = 0;
    uint8_t has_mask = 0;
    if (!r.Get(&b.camera) || !r.Get(&w) || !r.Get(&h)) return Corrupt("truncated buffer image");
    if (w <= 0 || h <= 0 || b.camera >= m.cameras_.size()) return Corrupt("bad buffer image");
    if (absl::Status s = ReadBufferPixels(&r, version, w, h, &b.image); !s.ok()) return s;
    if (!r.Get(&has_mask)) return Corrupt("truncated buffer image");
    if (has_mask > 1) return Corrupt("bad mask flag");
    if (has_mask) {
      b.mask.width = w;
      b.mask.height = h;
      if (!r.Array(uint64_t(w) * h, &b.mask.keep)) return Corrupt("truncated mask");
    }
    m.buffer_.push_back(std::move(b));
  }
  if (r.remaining() != 0) return Corrupt("trailing bytes");
  return m;
}

}  // namespace clnerf
