#include "server/frontends/http_scan_upload.h"

#include <filesystem>

#include "absl/strings/str_cat.h"
#include "core/io/durable_file.h"

namespace clnerf {

namespace fs = std::filesystem;

namespace {
constexpr size_t kMaxFieldBytes = 1024;
}  // namespace

MultipartScanReader::~MultipartScanReader() {
  video_file_.close();
  std::error_code ec;
  fs::remove_all(scratch_, ec);
}

bool MultipartScanReader::BeginPart(const std::string& field, const std::string& filename) {
  if (!status_.ok()) return false;
  if (part_ == Part::kField) {  // The previous part was a plain field: it is complete now.
    if (field_ == "name") upload_.name = field_value_;
    if (field_ == "sequential") upload_.sequential = field_value_ == "1" || field_value_ == "true";
  }
  field_ = field;
  field_value_.clear();
  if (field == "image" || field == "image[]" || field == "images") {
    if (int(upload_.frames.size()) >= limits_.max_frames) {
      status_ = absl::InvalidArgumentError(absl::StrCat("more than ", limits_.max_frames, " images"));
      return false;
    }
    if (absl::Status s = ValidateName(filename, "image file name"); !s.ok()) return status_ = s, false;
    ScanFrame f;
    f.posed = false;
    f.name = filename.empty() ? absl::StrCat("image_", upload_.frames.size()) : filename;
    upload_.frames.push_back(std::move(f));
    part_ = Part::kImage;
  } else if (field == "video") {
    if (has_video_) return status_ = absl::InvalidArgumentError("more than one video"), false;
    std::error_code ec;
    fs::create_directories(scratch_, ec);
    video_file_.open(fs::path(scratch_) / "upload.video", std::ios::binary);
    if (ec || !video_file_) return status_ = absl::InternalError("cannot store the uploaded video"), false;
    has_video_ = true;
    part_ = Part::kVideo;
  } else if (field == "name" || field == "sequential") {
    part_ = Part::kField;
  } else {
    status_ = absl::InvalidArgumentError(
        absl::StrCat("unknown form field '", field.substr(0, 64), "' (image, video, name, sequential)"));
    return false;
  }
  return true;
}

bool MultipartScanReader::AddBytes(const char* data, size_t size) {
  if (!status_.ok()) return false;
  received_ += int64_t(size);
  if (received_ > limits_.max_scan_bytes) {
    status_ = absl::InvalidArgumentError(absl::StrCat("upload over ", limits_.max_scan_bytes, " bytes"));
    return false;
  }
  switch (part_) {
    case Part::kImage: upload_.frames.back().image.append(data, size); break;
    case Part::kVideo:
      video_file_.write(data, std::streamsize(size));
      if (!video_file_) return status_ = absl::InternalError("cannot store the uploaded video"), false;
      break;
    case Part::kField:
      if (field_value_.size() + size > kMaxFieldBytes) {
        return status_ = absl::InvalidArgumentError(absl::StrCat("form field '", field_, "' is too long")), false;
      }
      field_value_.append(data, size);
      break;
    case Part::kNone: return status_ = absl::InvalidArgumentError("bytes before the first part"), false;
  }
  return true;
}

absl::StatusOr<ScanUpload> MultipartScanReader::Finish() {
  if (!status_.ok()) return status_;
  BeginPart("name", "");  // Completes a trailing plain field.
  if (has_video_ && !upload_.frames.empty()) {
    return absl::InvalidArgumentError("send photos (image) or one video, not both");
  }
  if (has_video_) {
    video_file_.close();
    absl::StatusOr<VideoFrames> v =
        ExtractVideoFrames((fs::path(scratch_) / "upload.video").string(), (fs::path(scratch_) / "frames").string(),
                           video_);
    if (!v.ok()) return v.status();
    for (const std::string& file : v->files) {
      absl::StatusOr<std::string> bytes = ReadFileToString(file, "video frame");
      if (!bytes.ok()) return bytes.status();
      ScanFrame f;
      f.posed = false;
      f.name = fs::path(file).filename().string();
      f.image = *std::move(bytes);
      upload_.frames.push_back(std::move(f));
    }
    upload_.sequential = true;
  }
  if (upload_.frames.empty()) return absl::InvalidArgumentError("no images: send photos as 'image' parts or a 'video'");
  if (upload_.name.empty()) upload_.name = "http-upload";
  upload_.pose_frame = "unposed";
  return std::move(upload_);
}

}  // namespace clnerf
