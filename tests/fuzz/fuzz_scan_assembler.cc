// libFuzzer harness: the upload path's limits. The input drives a header
// (frame count, declared sizes, names) and a sequence of chunks through
// ScanAssembler; it must never crash, overflow, over-allocate beyond the
// declared (limited) bytes, or accept an upload whose frames do not match
// what was declared.
#include <cstddef>
#include <cstdint>
#include <string>

#include "server/store/scan_assembler.h"

namespace {

class Input {
 public:
  Input(const uint8_t* d, size_t n) : d_(d), n_(n) {}
  bool empty() const { return i_ >= n_; }
  uint8_t Byte() { return i_ < n_ ? d_[i_++] : 0; }
  int64_t Int64() {
    uint64_t v = 0;
    for (int k = 0; k < 8; ++k) v = (v << 8) | Byte();
    return int64_t(v);
  }
  std::string String(size_t max) {
    const size_t len = std::min<size_t>(Byte(), max);
    std::string s;
    for (size_t k = 0; k < len && !empty(); ++k) s.push_back(char(Byte()));
    return s;
  }

 private:
  const uint8_t* d_;
  size_t n_, i_ = 0;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Input in(data, size);
  clnerf::UploadLimits limits;
  limits.max_frames = 8;
  limits.max_scan_bytes = 4096;
  limits.max_chunk_bytes = 512;
  clnerf::ScanAssembler a(limits);
  clnerf::ScanHeaderDecl h;
  h.name = in.String(300);
  const int frames = in.Byte() % 12;
  for (int f = 0; f < frames; ++f) {
    clnerf::DeclaredFrame df;
    df.frame.name = in.String(16);
    df.frame.test = in.Byte() & 1;
    // Mostly small sizes, sometimes huge or negative ones.
    df.image_bytes = (in.Byte() & 3) == 0 ? in.Int64() : int64_t(in.Byte()) * 4;
    df.mask_bytes = (in.Byte() & 7) == 0 ? in.Int64() : int64_t(in.Byte() & 1) * in.Byte();
    h.frames.push_back(std::move(df));
  }
  const clnerf::ScanHeaderDecl declared = h;
  if (!a.Begin(std::move(h)).ok()) return 0;
  while (!in.empty()) {
    const int frame = int(in.Byte()) - 2;
    const bool mask = in.Byte() & 1;
    const int64_t offset = (in.Byte() & 15) == 0 ? in.Int64() : int64_t(in.Byte()) * 4;
    const std::string chunk = in.String(255);
    (void)a.Add(frame, mask, offset, chunk);
  }
  absl::StatusOr<clnerf::ScanUpload> up = a.Finish();
  if (!up.ok()) return 0;
  if (up->frames.size() != declared.frames.size()) __builtin_trap();
  int64_t total = 0;
  for (size_t i = 0; i < up->frames.size(); ++i) {
    if (int64_t(up->frames[i].image.size()) != declared.frames[i].image_bytes) __builtin_trap();
    if (int64_t(up->frames[i].mask.size()) != declared.frames[i].mask_bytes) __builtin_trap();
    total += int64_t(up->frames[i].image.size() + up->frames[i].mask.size());
  }
  if (total > limits.max_scan_bytes || up->name.size() > clnerf::UploadLimits::kMaxNameBytes) __builtin_trap();
  return 0;
}
