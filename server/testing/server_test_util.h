// Test helpers for server/ tests: tiny server options and a gRPC upload
// helper (with store_test_util.h's scans and uploads). Header-only; test code only.
#ifndef CLNERF_SERVER_SERVER_TEST_UTIL_H_
#define CLNERF_SERVER_SERVER_TEST_UTIL_H_

#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "clnerf/v1/clnerf.grpc.pb.h"
#include "core/data/image.h"
#include "core/data/procedural_scene.h"
#include "proto/wire/wire.h"
#include "gtest/gtest.h"
#include "server/store/scan_store.h"
#include "server/testing/store_test_util.h"
#include "server/server_options.h"

namespace clnerf {
namespace testing_util {

// ThreadSanitizer builds (scripts/tsan.sh) run the server's concurrency tests
// about 50 times slower; there TinyServerOptions trains a fixed batch of 128
// rays instead of ~512 (the same threads and phases, less arithmetic).
#if defined(__SANITIZE_THREAD__)
inline constexpr bool kThreadSanitizerBuild = true;
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
inline constexpr bool kThreadSanitizerBuild = true;
#else
inline constexpr bool kThreadSanitizerBuild = false;
#endif
#else
inline constexpr bool kThreadSanitizerBuild = false;
#endif

inline ServerOptions TinyServerOptions(const std::string& store, int iterations = 30) {
  ServerOptions o;
  o.listen = "localhost:0";
  o.store_dir = store;
  o.train_threads = 2;
  o.render_threads = 1;
  // Training at the renders' priority: tests that render in a loop during an
  // update (and TSan, ~50x slower) would otherwise wait minutes for the
  // niced training (measured: RendersDuringAnUpdate 174 s under TSan). The
  // default (10) is covered by thread_priority_test and the browser test.
  o.train_nice = 0;
  o.update.train.iterations = iterations;
  o.first_scan_iterations = 0;  // As every update: tests stay fast.
  o.update.train.target_samples = kThreadSanitizerBuild ? 0 : 1 << 13;  // 0: a fixed batch.
  o.update.train.batch_rays = kThreadSanitizerBuild ? 128 : 512;
  o.update.model.grid.levels = 8;
  o.update.capacity.max_log2_table_size = 14;
  o.update.model.occupancy.warmup_iterations = 64;
  o.gate.min_new_psnr = 8.0f;  // A 30-iteration model is blurry but far above noise.
  o.gate.min_replay_consistency_psnr = 10.0f;
  o.gate.max_replay_drop_db = 10.0f;
  o.gate.validation_views = 2;
  o.shutdown_grace_seconds = 2;
  // The place-frame check matches the tiny scans at their own size: scaled
  // to the default 240 px it renders many times the pixels (measured, two at
  // a time: StressedScans... 10.5 -> 51 s, KeepVersions... 7 -> 35 s,
  // LaterScansAreRegistered... 46 -> 83 s; CI took 35 min instead of 29).
  o.registration.localizer.min_side = 1;
  // Each publish bakes: a coarse grid and few rays keep it to milliseconds.
  o.bake.resolution = 64;
  o.bake.visibility_rays = 1 << 12;
  o.bake.fit.rays = 1 << 11;
  if (kThreadSanitizerBuild) {
    // ~50x slower under TSan: the place-frame check and the bake still run
    // on their threads, on less work (RendersDuringAnUpdate: 100 s).
    o.registration.max_references = 4;
    o.bake.resolution = 32;
    o.bake.visibility_rays = 1 << 10;
    o.bake.fit.rays = 1 << 9;
  }
  return o;
}

// --- gRPC side ---------------------------------------------------------------

inline void FillCamera(const Camera& c, v1::CameraSpec* spec) { *spec = CameraToProto(c); }

// The header and chunks (<= chunk_bytes) of an upload, in order.
inline std::vector<v1::UploadScanRequest> UploadMessages(const ScanUpload& up, size_t chunk_bytes = 1 << 20) {
  std::vector<v1::UploadScanRequest> msgs(1);
  v1::ScanHeader* h = msgs[0].mutable_header();
  h->set_name(up.name);
  h->set_scene_kind(up.scene_kind);
  h->set_pose_frame(up.pose_frame == "unposed" ? "" : up.pose_frame);
  h->set_sequential(up.sequential);
  for (const Eigen::Vector3f& p : up.points) {
    for (int c = 0; c < 3; ++c) h->add_points(p[c]);
  }
  std::vector<const ScanFrame*> order;
  for (const ScanFrame& f : up.frames)
    if (!f.test) order.push_back(&f);
  for (const ScanFrame& f : up.frames)
    if (f.test) order.push_back(&f);
  for (const ScanFrame* f : order) {
    v1::Frame* pf = f->test ? h->add_test_frames() : h->add_frames();
    pf->set_name(f->name);
    if (f->posed) FillCamera(f->camera, pf->mutable_camera());
    pf->set_image_bytes(int64_t(f->image.size()));
    pf->set_mask_bytes(int64_t(f->mask.size()));
  }
  for (size_t i = 0; i < order.size(); ++i) {
    for (int m = 0; m < 2; ++m) {
      const std::string& bytes = m ? order[i]->mask : order[i]->image;
      for (size_t off = 0; off < bytes.size(); off += chunk_bytes) {
        v1::UploadScanRequest r;
        v1::Chunk* c = r.mutable_chunk();
        c->set_frame_index(int(i));
        c->set_is_mask(m == 1);
        c->set_offset(int64_t(off));
        c->set_data(bytes.substr(off, chunk_bytes));
        msgs.push_back(std::move(r));
      }
    }
  }
  return msgs;
}

}  // namespace testing_util
}  // namespace clnerf

#endif  // CLNERF_SERVER_SERVER_TEST_UTIL_H_
