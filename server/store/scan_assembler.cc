#include "server/store/scan_assembler.h"

#include <limits>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "server/common/log_util.h"

namespace clnerf {

absl::Status ValidateName(std::string_view name, const std::string& what) {
  if (name.size() > UploadLimits::kMaxNameBytes) {
    return absl::InvalidArgumentError(
        absl::StrCat(what, " is ", name.size(), " bytes; the limit is ", UploadLimits::kMaxNameBytes));
  }
  for (size_t i = 0; i < name.size(); ++i) {
    const unsigned char c = static_cast<unsigned char>(name[i]);
    if (c < 0x20 || c == 0x7f) {
      return absl::InvalidArgumentError(
          absl::StrCat(what, " contains control character 0x", absl::Hex(c, absl::kZeroPad2), " at byte ", i));
    }
    unsigned cp = 0;
    if (LineBreakOrBidiAt(name, i, &cp) > 0) {
      return absl::InvalidArgumentError(absl::StrCat(what, " contains U+", absl::AsciiStrToUpper(absl::StrCat(absl::Hex(cp, absl::kZeroPad4))),
                                                     " (a line break or bidirectional control) at byte ", i));
    }
  }
  return absl::OkStatus();
}

absl::Status CheckUploadLimits(const ScanUpload& upload, const UploadLimits& limits) {
  if (int64_t(upload.frames.size()) > limits.max_frames) {
    return absl::InvalidArgumentError(
        absl::StrCat("scan has ", upload.frames.size(), " frames; the limit is ", limits.max_frames));
  }
  if (upload.num_bytes() > limits.max_scan_bytes) {
    return absl::InvalidArgumentError(
        absl::StrCat("scan is ", upload.num_bytes(), " bytes; the limit is ", limits.max_scan_bytes));
  }
  if (absl::Status s = ValidateName(upload.name, "scan name"); !s.ok()) return s;
  if (int64_t(upload.points.size()) > limits.max_points) {
    return absl::InvalidArgumentError(
        absl::StrCat("scan has ", upload.points.size(), " points; the limit is ", limits.max_points));
  }
  for (size_t i = 0; i < upload.frames.size(); ++i) {
    if (absl::Status s = ValidateName(upload.frames[i].name, absl::StrCat("frame ", i, " name")); !s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::Status ScanAssembler::Begin(ScanHeaderDecl header) {
  if (begun_) return absl::InvalidArgumentError("only one scan header is allowed per upload");
  const int64_t n = int64_t(header.frames.size());
  if (n == 0) return absl::InvalidArgumentError("scan header lists no frames");
  if (n > limits_.max_frames) {
    return absl::InvalidArgumentError(absl::StrCat("scan has ", n, " frames; the limit is ", limits_.max_frames));
  }
  if (absl::Status s = ValidateName(header.name, "scan name"); !s.ok()) return s;
  if (int64_t(header.points.size()) > limits_.max_points) {
    return absl::InvalidArgumentError(
        absl::StrCat("scan has ", header.points.size(), " points; the limit is ", limits_.max_points));
  }
  // Each size is checked against the limit before it is added, so the sum
  // never exceeds 2 * max_scan_bytes and cannot overflow.
  int64_t total = 0;
  for (int64_t i = 0; i < n; ++i) {
    const DeclaredFrame& f = header.frames[size_t(i)];
    const std::string what = absl::StrCat(f.frame.test ? "test frame " : "frame ", i);
    if (absl::Status s = ValidateName(f.frame.name, what + " name"); !s.ok()) return s;
    if (f.image_bytes <= 0) return absl::InvalidArgumentError(absl::StrCat(what, ": image_bytes must be > 0"));
    if (f.mask_bytes < 0) return absl::InvalidArgumentError(absl::StrCat(what, ": mask_bytes must be >= 0"));
    for (int64_t b : {f.image_bytes, f.mask_bytes}) {
      if (b > limits_.max_scan_bytes - total) {
        return absl::InvalidArgumentError(absl::StrCat("scan declares more than ", limits_.max_scan_bytes,
                                                       " bytes (the limit) by ", what));
      }
      total += b;
    }
  }
  upload_.name = std::move(header.name);
  upload_.scene_kind = std::move(header.scene_kind);
  upload_.mask_nonzero_is_exclude = header.mask_nonzero_is_exclude;
  upload_.pose_frame = std::move(header.pose_frame);
  upload_.sequential = header.sequential;
  upload_.points = std::move(header.points);
  for (DeclaredFrame& f : header.frames) {
    want_image_.push_back(f.image_bytes);
    want_mask_.push_back(f.mask_bytes);
    upload_.frames.push_back(std::move(f.frame));
  }
  begun_ = true;
  return absl::OkStatus();
}

absl::Status ScanAssembler::Add(int frame_index, bool is_mask, int64_t offset, std::string_view data) {
  if (!begun_) return absl::InvalidArgumentError("the first upload message must be the scan header");
  const int n = int(upload_.frames.size());
  if (frame_index < 0 || frame_index >= n) {
    return absl::InvalidArgumentError(absl::StrCat("chunk for frame ", frame_index, " but the scan has ", n, " frames"));
  }
  if (int64_t(data.size()) > limits_.max_chunk_bytes) {
    return absl::InvalidArgumentError(
        absl::StrCat("chunk of ", data.size(), " bytes exceeds the limit of ", limits_.max_chunk_bytes));
  }
  ScanFrame& f = upload_.frames[size_t(frame_index)];
  std::string& dst = is_mask ? f.mask : f.image;
  const int64_t want = is_mask ? want_mask_[size_t(frame_index)] : want_image_[size_t(frame_index)];
  const char* kind = is_mask ? " mask" : " image";
  if (offset != int64_t(dst.size())) {
    return absl::InvalidArgumentError(absl::StrCat("frame ", frame_index, kind, ": chunk at offset ", offset, " but ",
                                                   dst.size(), " bytes were received (missing or reordered chunk)"));
  }
  if (int64_t(data.size()) > want - int64_t(dst.size())) {
    return absl::InvalidArgumentError(
        absl::StrCat("frame ", frame_index, kind, ": more bytes than the ", want, " declared"));
  }
  if (dst.empty() && want > 0) dst.reserve(size_t(want));
  dst.append(data);
  received_ += int64_t(data.size());
  return absl::OkStatus();
}

absl::StatusOr<ScanUpload> ScanAssembler::Finish() {
  if (!begun_) return absl::InvalidArgumentError("upload has no scan header");
  for (size_t i = 0; i < upload_.frames.size(); ++i) {
    const ScanFrame& f = upload_.frames[i];
    if (int64_t(f.image.size()) != want_image_[i] || int64_t(f.mask.size()) != want_mask_[i]) {
      return absl::InvalidArgumentError(absl::StrCat("upload is truncated: frame ", i, " ('", f.name, "') has ",
                                                     f.image.size(), " of ", want_image_[i], " image bytes and ",
                                                     f.mask.size(), " of ", want_mask_[i], " mask bytes"));
    }
  }
  begun_ = false;
  return std::move(upload_);
}

}  // namespace clnerf
