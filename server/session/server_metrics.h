// ServerMetrics: the counters of `octoscope serve` that GET /metrics exposes (docs/api.md), in
// the Prometheus text exposition format 0.0.4. Sessions record what they send; the app adds the
// dataset gauges it knows.
//
// Thread safety: thread-safe (atomics and one mutex for the histograms).
#ifndef OCTOSCOPE_SESSION_SERVER_METRICS_H_
#define OCTOSCOPE_SESSION_SERVER_METRICS_H_

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "protocol/frame_header.h"

namespace octoscope::session {

// A Prometheus histogram of milliseconds with fixed buckets.
class MsHistogram {
 public:
  static constexpr std::array<double, 12> kBounds{1,   2,   5,   10,   20,   50,
                                                  100, 200, 500, 1000, 2000, 5000};
  void Observe(double ms);
  // Appends the _bucket, _sum and _count lines of `name` with `labels` ("tier=\"final\"").
  void Append(std::string* out, std::string_view name, std::string_view labels) const;

 private:
  std::array<uint64_t, kBounds.size() + 1> counts_{};  // Last: +Inf only.
  double sum_ = 0;
  uint64_t count_ = 0;
};

class ServerMetrics {
 public:
  using Clock = std::chrono::steady_clock;

  void SessionOpened() { sessions_.fetch_add(1); }
  void SessionClosed() { sessions_.fetch_sub(1); }
  int64_t sessions() const { return sessions_.load(); }

  void FrameSent(protocol::FrameTier tier, uint64_t bytes);
  void FramesDropped(uint64_t n) { frames_dropped_.fetch_add(n); }
  void Rendered(protocol::FrameTier tier, double ms, uint64_t bricks_uploaded);
  void Encoded(protocol::ImageFormat format, double ms);
  // Where the HTTP response counts come from (the net layer counts every response, static files
  // and refusals included); set once the server runs, cleared before it goes.
  using HttpCounts = std::function<std::vector<std::pair<int, uint64_t>>()>;
  void SetHttpCounts(HttpCounts counts);

  uint64_t frames_sent(protocol::FrameTier tier) const;
  // Frames sent over the last 5 s, per second.
  double FramesPerSecond() const;

  // The exposition text of everything recorded here (each metric with HELP and TYPE lines).
  std::string PrometheusText() const;

 private:
  std::atomic<int64_t> sessions_{0};
  std::array<std::atomic<uint64_t>, 4> frames_sent_{};
  std::atomic<uint64_t> frames_dropped_{0};
  std::atomic<uint64_t> bytes_sent_{0};
  std::atomic<uint64_t> bricks_uploaded_{0};
  mutable std::mutex mu_;
  std::array<MsHistogram, 4> render_ms_;                 // By tier.
  std::array<MsHistogram, 2> encode_ms_;                 // By format.
  HttpCounts http_counts_;                               // Guarded by mu_.
  mutable std::deque<Clock::time_point> recent_frames_;  // Sends within the last 5 s.
};

// Appends "# HELP name help\n# TYPE name type\n" to `out`.
void AppendMetricHeader(std::string* out, std::string_view name, std::string_view type,
                        std::string_view help);
// A label value escaped for the exposition format (backslash, quote, newline).
std::string EscapeLabelValue(std::string_view value);

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_SERVER_METRICS_H_
