#include "proto/wire/wire.h"
#include "client/scan_upload.h"

#include <algorithm>
#include <chrono>
#include <filesystem>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/remote_format.h"
#include "core/data/image.h"
#include "core/io/durable_file.h"

namespace clnerf {

namespace {
constexpr size_t kChunkBytes = size_t(1) << 20;  // The protocol's maximum.
}  // namespace

absl::StatusOr<EncodedScan> EncodeScan(const std::string& name, SceneKind kind, const std::vector<View>& train,
                                       const std::vector<View>& test, const std::vector<Eigen::Vector3f>& points) {
  EncodedScan out;
  clnerf::v1::ScanHeader* header = out.header.mutable_header();
  header->set_name(name);
  header->set_scene_kind(kind == SceneKind::kBounded ? "bounded" : "unbounded");
  header->set_mask_nonzero_is_exclude(false);
  const size_t keep = std::min(points.size(), kMaxUploadPoints);
  header->mutable_points()->Reserve(int(3 * keep));
  for (size_t k = 0; k < keep; ++k) {
    const Eigen::Vector3f& p = points[k * points.size() / keep];
    if (!p.allFinite()) continue;
    for (int c = 0; c < 3; ++c) header->add_points(p[c]);
  }
  for (const std::vector<View>* views : {&train, &test}) {
    for (const View& view : *views) {
      absl::StatusOr<std::string> png = EncodePng(view.image);
      if (!png.ok()) return absl::Status(png.status().code(), absl::StrCat(view.name, ": ", png.status().message()));
      std::string mask;
      if (!view.mask.empty()) {
        absl::StatusOr<std::string> m = EncodeMaskPng(view.mask);
        if (!m.ok()) return absl::Status(m.status().code(), absl::StrCat(view.name, ": ", m.status().message()));
        mask = std::move(*m);
      }
      clnerf::v1::Frame* frame = views == &train ? header->add_frames() : header->add_test_frames();
      frame->set_name(view.name);
      *frame->mutable_camera() = CameraToProto(view.camera);
      frame->set_image_bytes(int64_t(png->size()));
      frame->set_mask_bytes(int64_t(mask.size()));
      out.total_bytes += int64_t(png->size() + mask.size());
      out.files.emplace_back(std::move(*png), std::move(mask));
    }
  }
  return out;
}

absl::StatusOr<EncodedScan> EncodeUnposedPhotos(const std::string& name, const std::vector<std::string>& files,
                                                bool sequential) {
  EncodedScan out;
  clnerf::v1::ScanHeader* header = out.header.mutable_header();
  header->set_name(name);
  header->set_sequential(sequential);
  for (const std::string& file : files) {
    absl::StatusOr<std::string> bytes = ReadFileToString(file, "photo");
    if (!bytes.ok()) return bytes.status();
    clnerf::v1::Frame* frame = header->add_frames();
    frame->set_name(std::filesystem::path(file).filename().string());
    frame->set_image_bytes(int64_t(bytes->size()));
    out.total_bytes += int64_t(bytes->size());
    out.files.emplace_back(*std::move(bytes), std::string());
  }
  return out;
}

void DropPoses(EncodedScan* scan, bool sequential) {
  clnerf::v1::ScanHeader* header = scan->header.mutable_header();
  for (clnerf::v1::Frame& f : *header->mutable_frames()) f.clear_camera();
  for (clnerf::v1::Frame& f : *header->mutable_test_frames()) f.clear_camera();
  header->clear_points();
  header->clear_pose_frame();
  header->set_sequential(sequential);
}

std::vector<std::string> ListPhotos(const std::string& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
    if (!e.is_regular_file()) continue;
    const std::string ext = absl::AsciiStrToLower(e.path().extension().string());
    if (ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".tif" || ext == ".tiff" || ext == ".bmp") {
      out.push_back(e.path().string());
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

SendResult SendScan(RemoteClient& client, const EncodedScan& scan, ProgressBar* bar) {
  SendResult r;
  const auto start = std::chrono::steady_clock::now();
  auto seconds = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); };
  std::unique_ptr<grpc::ClientContext> ctx = client.Context(kNoDeadline);
  std::unique_ptr<grpc::ClientWriter<clnerf::v1::UploadScanRequest>> writer =
      client.service().UploadScan(ctx.get(), &r.response);
  bool open = writer->Write(scan.header);
  clnerf::v1::UploadScanRequest request;
  clnerf::v1::Chunk* chunk = request.mutable_chunk();
  for (size_t i = 0; open && i < scan.files.size(); ++i) {
    for (const bool is_mask : {false, true}) {
      const std::string& bytes = is_mask ? scan.files[i].second : scan.files[i].first;
      for (size_t off = 0; open && off < bytes.size(); off += kChunkBytes) {
        const size_t n = std::min(kChunkBytes, bytes.size() - off);
        chunk->set_frame_index(int(i));
        chunk->set_is_mask(is_mask);
        chunk->set_offset(int64_t(off));
        chunk->set_data(bytes.data() + off, n);
        open = writer->Write(request);
        if (!open) break;
        r.bytes_sent += int64_t(n);
        if (bar != nullptr) {
          const double s = seconds();
          bar->Update(r.bytes_sent, absl::StrFormat("%.2f MB/s", s > 0 ? r.bytes_sent / 1e6 / s : 0.0));
        }
      }
    }
  }
  if (open) writer->WritesDone();
  r.status = writer->Finish();
  r.seconds = seconds();
  return r;
}

}  // namespace clnerf
