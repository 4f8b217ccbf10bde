// Metrics: the server's counters, gauges and histograms, exposed in the
// Prometheus text format on the HTTP port (GET /metrics). Built on Debian's
// prometheus-cpp (core library only; the HTTP side is ours, http_api.h).
//
// What is counted: renders (by status code, and their latency), uploads (by
// status code, and their bytes), updates (by outcome, and their duration),
// deployment-gate refusals, model loads (and their latency), evictions,
// resident model bytes, fenced commits and lease changes. Labels are bounded
// sets (status codes, outcomes); there are no per-place labels, so a store
// of thousands of places does not blow up the series count.
//
// Thread-safety: every method is thread-safe (prometheus-cpp's metrics are
// atomic; families are created once, in the constructor).
#ifndef CLNERF_SERVER_METRICS_H_
#define CLNERF_SERVER_METRICS_H_

#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/status.h"

namespace prometheus {
class Registry;
class Counter;
class Gauge;
class Histogram;
template <typename T>
class Family;
}  // namespace prometheus

namespace clnerf {

class Metrics {
 public:
  Metrics();
  ~Metrics();
  Metrics(const Metrics&) = delete;
  Metrics& operator=(const Metrics&) = delete;

  void RenderDone(absl::StatusCode code, double seconds);
  void UploadDone(absl::StatusCode code, int64_t bytes);
  // Baked-asset files served (GET /api/asset; 304s count with 0 bytes) and
  // time steps baked on request.
  void AssetServed(absl::StatusCode code, int64_t bytes);
  void AssetBaked(double seconds);
  // An asset file read from disk into the asset cache (a cache miss): with
  // many viewers of one version this stays at one per file.
  void AssetFileRead(int64_t bytes);
  // outcome: "published", "refused" (by the gate), "failed", "cancelled".
  void UpdateDone(const std::string& outcome, double seconds);
  void ModelLoaded(double seconds);
  void ModelLoadFailed();
  void ModelEvicted();
  void SetModelBytes(int64_t bytes);
  void FencedCommit();
  void LeaseChanged();

  // Every metric in the Prometheus text exposition format (version 0.0.4).
  std::string Text() const;

 private:
  std::shared_ptr<prometheus::Registry> registry_;
  prometheus::Family<prometheus::Counter>* renders_;
  prometheus::Family<prometheus::Counter>* uploads_;
  prometheus::Family<prometheus::Counter>* updates_;
  prometheus::Histogram* render_seconds_;
  prometheus::Histogram* update_seconds_;
  prometheus::Histogram* load_seconds_;
  prometheus::Counter* upload_bytes_;
  prometheus::Family<prometheus::Counter>* assets_;
  prometheus::Counter* asset_bytes_;
  prometheus::Counter* asset_bakes_;
  prometheus::Counter* asset_bake_seconds_;
  prometheus::Counter* asset_file_reads_;
  prometheus::Counter* asset_file_read_bytes_;
  prometheus::Counter* gate_refusals_;
  prometheus::Counter* loads_;
  prometheus::Counter* load_failures_;
  prometheus::Counter* evictions_;
  prometheus::Counter* fenced_;
  prometheus::Counter* lease_changes_;
  prometheus::Gauge* model_bytes_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_METRICS_H_
