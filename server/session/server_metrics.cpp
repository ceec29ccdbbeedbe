#include "session/server_metrics.h"

#include <cstdio>

namespace octoscope::session {
namespace {

constexpr std::chrono::seconds kRateWindow{5};

std::string Number(double v) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.17g", v);
  return buffer;
}

}  // namespace

void MsHistogram::Observe(double ms) {
  size_t i = 0;
  while (i < kBounds.size() && ms > kBounds[i]) ++i;
  ++counts_[i];
  sum_ += ms;
  ++count_;
}

void MsHistogram::Append(std::string* out, std::string_view name, std::string_view labels) const {
  // Appended piece by piece (GCC 12 warns falsely about long temporary concatenations).
  auto line = [&](std::string_view suffix, std::string_view label_text, const std::string& value) {
    out->append(name).append(suffix);
    if (!label_text.empty()) out->append("{").append(label_text).append("}");
    out->append(" ").append(value).append("\n");
  };
  std::string prefix(labels);
  if (!prefix.empty()) prefix += ',';
  uint64_t cumulative = 0;
  for (size_t i = 0; i < kBounds.size(); ++i) {
    cumulative += counts_[i];
    line("_bucket", prefix + "le=\"" + Number(kBounds[i]) + "\"", std::to_string(cumulative));
  }
  line("_bucket", prefix + "le=\"+Inf\"", std::to_string(count_));
  line("_sum", labels, Number(sum_));
  line("_count", labels, std::to_string(count_));
}

void ServerMetrics::FrameSent(protocol::FrameTier tier, uint64_t bytes) {
  frames_sent_[static_cast<size_t>(tier)].fetch_add(1);
  bytes_sent_.fetch_add(bytes);
  std::lock_guard<std::mutex> lock(mu_);
  const auto now = Clock::now();
  recent_frames_.push_back(now);
  while (!recent_frames_.empty() && recent_frames_.front() < now - kRateWindow) {
    recent_frames_.pop_front();
  }
}

void ServerMetrics::Rendered(protocol::FrameTier tier, double ms, uint64_t bricks_uploaded) {
  bricks_uploaded_.fetch_add(bricks_uploaded);
  std::lock_guard<std::mutex> lock(mu_);
  render_ms_[static_cast<size_t>(tier)].Observe(ms);
}

void ServerMetrics::Encoded(protocol::ImageFormat format, double ms) {
  std::lock_guard<std::mutex> lock(mu_);
  encode_ms_[static_cast<size_t>(format)].Observe(ms);
}

void ServerMetrics::SetHttpCounts(HttpCounts counts) {
  std::lock_guard<std::mutex> lock(mu_);
  http_counts_ = std::move(counts);
}

uint64_t ServerMetrics::frames_sent(protocol::FrameTier tier) const {
  return frames_sent_[static_cast<size_t>(tier)].load();
}

double ServerMetrics::FramesPerSecond() const {
  std::lock_guard<std::mutex> lock(mu_);
  const auto now = Clock::now();
  while (!recent_frames_.empty() && recent_frames_.front() < now - kRateWindow) {
    recent_frames_.pop_front();
  }
  return static_cast<double>(recent_frames_.size()) / kRateWindow.count();
}

void AppendMetricHeader(std::string* out, std::string_view name, std::string_view type,
                        std::string_view help) {
  *out += "# HELP " + std::string(name) + " " + std::string(help) + "\n";
  *out += "# TYPE " + std::string(name) + " " + std::string(type) + "\n";
}

std::string EscapeLabelValue(std::string_view value) {
  std::string out;
  for (char c : value) {
    if (c == '\\')
      out += "\\\\";
    else if (c == '"')
      out += "\\\"";
    else if (c == '\n')
      out += "\\n";
    else
      out += c;
  }
  return out;
}

std::string ServerMetrics::PrometheusText() const {
  constexpr protocol::FrameTier kTiers[] = {
      protocol::FrameTier::kInteractive, protocol::FrameTier::kRefining,
      protocol::FrameTier::kFinal, protocol::FrameTier::kScreenshot};
  std::string out;
  AppendMetricHeader(&out, "octoscope_sessions", "gauge", "Open WebSocket sessions.");
  out += "octoscope_sessions " + std::to_string(sessions()) + "\n";
  AppendMetricHeader(&out, "octoscope_frames_sent_total", "counter", "Frames sent, by tier.");
  for (auto tier : kTiers) {
    out += "octoscope_frames_sent_total{tier=\"" + std::string(protocol::FrameTierName(tier)) +
           "\"} " + std::to_string(frames_sent(tier)) + "\n";
  }
  AppendMetricHeader(&out, "octoscope_frames_dropped_total", "counter",
                     "Frames replaced by newer ones before sending (stale).");
  out += "octoscope_frames_dropped_total " + std::to_string(frames_dropped_.load()) + "\n";
  AppendMetricHeader(&out, "octoscope_bytes_sent_total", "counter", "Frame bytes sent.");
  out += "octoscope_bytes_sent_total " + std::to_string(bytes_sent_.load()) + "\n";
  AppendMetricHeader(&out, "octoscope_frames_per_second", "gauge",
                     "Frames sent over the last 5 s, per second.");
  out += "octoscope_frames_per_second " + Number(FramesPerSecond()) + "\n";
  AppendMetricHeader(&out, "octoscope_bricks_uploaded_total", "counter",
                     "Bricks uploaded to the device for frames.");
  out += "octoscope_bricks_uploaded_total " + std::to_string(bricks_uploaded_.load()) + "\n";
  std::lock_guard<std::mutex> lock(mu_);
  AppendMetricHeader(&out, "octoscope_render_ms", "histogram", "Render time per frame, ms.");
  for (auto tier : kTiers) {
    render_ms_[static_cast<size_t>(tier)].Append(
        &out, "octoscope_render_ms", "tier=\"" + std::string(protocol::FrameTierName(tier)) + "\"");
  }
  AppendMetricHeader(&out, "octoscope_encode_ms", "histogram", "Encode time per frame, ms.");
  encode_ms_[0].Append(&out, "octoscope_encode_ms", "format=\"jpeg\"");
  encode_ms_[1].Append(&out, "octoscope_encode_ms", "format=\"png\"");
  AppendMetricHeader(&out, "octoscope_http_requests_total", "counter",
                     "HTTP responses, by status code.");
  for (const auto& [code, n] : http_counts_ ? http_counts_() : HttpCounts::result_type{}) {
    out += "octoscope_http_requests_total{code=\"" + std::to_string(code) + "\"} " +
           std::to_string(n) + "\n";
  }
  return out;
}

}  // namespace octoscope::session
