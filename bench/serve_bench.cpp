// serve_bench: what a browser user of `octoscope serve` gets — camera message → frame latency,
// frames per second, bytes per frame and the fraction of frames dropped as stale — with N
// concurrent clients dragging the camera of one or of different datasets, on the real server
// binary over loopback WebSocket (run by bench/serve.sh; docs/benchmarks.md).
//
// Each client: hello, open its dataset, a viewport, interaction on; then for --seconds it sends a
// camera (an orbit step) as soon as the frame answering its previous camera arrived (a user who
// drags as fast as frames come), acknowledging every frame. Latency = camera sent → first frame
// of that (or a newer) state received. At the end each client stops interacting and waits for
// the final frame of its last camera (lossless PNG): the PSNR of its last interactive frame
// against that final frame says what the speed costs.
//
// Usage: serve_bench --binary PATH --data DIR --datasets ID[,ID] [--clients N] [--seconds S]
//                    [--viewport WxH] [--token T] [--port P]   (the server must be running)
#include <turbojpeg.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <numeric>
#include <string>
#include <thread>
#include <vector>

#include "encode/png_test_decoder.h"
#include "net/net_test_client.h"
#include "protocol/frame_header.h"

namespace {

using json = nlohmann::json;
using octoscope::net::testing::WsClient;
using Clock = std::chrono::steady_clock;

struct ClientResult {
  std::vector<double> latency_ms;
  uint64_t frames = 0;
  uint64_t bytes = 0;
  uint64_t sent = 0, dropped = 0;  // From the server's last stats event.
  double seconds = 0;
  double psnr = NAN;
  std::string error;
};

std::vector<uint8_t> DecodeJpegRgb(const std::vector<uint8_t>& jpeg, int* w, int* h) {
  tjhandle tj = tjInitDecompress();
  int sub = 0, space = 0;
  std::vector<uint8_t> rgb;
  if (tjDecompressHeader3(tj, jpeg.data(), jpeg.size(), w, h, &sub, &space) == 0) {
    rgb.resize(static_cast<size_t>(*w) * *h * 3);
    if (tjDecompress2(tj, jpeg.data(), jpeg.size(), rgb.data(), *w, 0, *h, TJPF_RGB, 0) != 0) {
      rgb.clear();
    }
  }
  tjDestroy(tj);
  return rgb;
}

// PSNR (peak 255) of an interactive frame (possibly smaller: sampled at the nearest pixel, as the
// browser's canvas scaling shows it) against the final frame.
double Psnr(const std::vector<uint8_t>& rgb, int w, int h,
            const octoscope::testing::DecodedPng& ref) {
  double se = 0;
  for (int y = 0; y < ref.height; ++y) {
    for (int x = 0; x < ref.width; ++x) {
      const int sx = std::min(w - 1, x * w / ref.width);
      const int sy = std::min(h - 1, y * h / ref.height);
      for (int c = 0; c < 3; ++c) {
        const double d = rgb[(static_cast<size_t>(sy) * w + sx) * 3 + c] - ref.At(x, y, c);
        se += d * d;
      }
    }
  }
  const double mse = se / (3.0 * ref.width * ref.height);
  return mse <= 0 ? 99 : std::min(99.0, 10 * std::log10(255.0 * 255.0 / mse));
}

json OrbitCamera(const json& base, double angle) {
  // Rotate the opening camera's position about the vertical axis through its target.
  json camera = base;
  const auto& p = base["position"];
  const auto& t = base["target"];
  const double dx = p[0].get<double>() - t[0].get<double>();
  const double dz = p[2].get<double>() - t[2].get<double>();
  camera["position"][0] = t[0].get<double>() + dx * std::cos(angle) - dz * std::sin(angle);
  camera["position"][2] = t[2].get<double>() + dx * std::sin(angle) + dz * std::cos(angle);
  return camera;
}

ClientResult RunClient(uint16_t port, const std::string& token, const std::string& dataset,
                       int width, int height, double seconds, int index) {
  ClientResult r;
  WsClient ws;
  if (std::string e = ws.Connect(port, "/ws?token=" + token); !e.empty()) {
    r.error = "connect: " + e;
    return r;
  }
  ws.Send(json{{"type", "hello"}, {"client", "serve_bench"}, {"protocol", 1}}.dump());
  ws.Send(json{{"type", "quality"}, {"lossless_final", true}}.dump());
  ws.Send(json{{"type", "open"}, {"dataset", dataset}}.dump());
  json camera;
  for (;;) {
    auto m = ws.Read(std::chrono::seconds(60));
    if (!m.ok) {
      r.error = "no 'opened' event";
      return r;
    }
    if (m.binary) continue;
    json event = json::parse(m.data);
    if (event["type"] == "opened") {
      camera = event["state"]["camera"];
      break;
    }
    if (event["type"] == "error") {
      r.error = event.dump();
      return r;
    }
  }
  ws.Send(
      json{{"type", "viewport"}, {"view", "3d"}, {"width", width}, {"height", height}, {"dpr", 1}}
          .dump());
  ws.Send(json{{"type", "interaction"}, {"active", true}}.dump());
  // The state version of our n-th camera is not known to us; frames carry the server's version,
  // which grows with every state change, so "a frame newer than any seen before our camera"
  // answers it.
  uint64_t newest_version = 0;
  std::vector<uint8_t> last_interactive;
  const auto start = Clock::now();
  const auto end = start + std::chrono::duration<double>(seconds);
  int step = 0;
  bool waiting = false;
  Clock::time_point sent_at;
  uint64_t version_at_send = 0;
  while (Clock::now() < end) {
    if (!waiting) {
      ws.Send(
          json{{"type", "camera"}, {"camera", OrbitCamera(camera, 0.05 * ++step + index)}}.dump());
      sent_at = Clock::now();
      version_at_send = newest_version;
      waiting = true;
    }
    auto m = ws.Read(std::chrono::seconds(30));
    if (!m.ok) {
      r.error = "read: " + m.error.message();
      break;
    }
    if (!m.binary) {
      json event = json::parse(m.data);
      if (event["type"] == "stats") {
        r.sent = event["frames_sent"];
        r.dropped = event["frames_dropped"];
      }
      continue;
    }
    std::span<const uint8_t> bytes(reinterpret_cast<const uint8_t*>(m.data.data()), m.data.size());
    auto header = octoscope::protocol::DecodeFrameHeader(bytes);
    if (!header.ok()) {
      r.error = header.status().ToString();
      break;
    }
    ws.Send(json{{"type", "ack"}, {"frame", header->frame_id}}.dump());
    ++r.frames;
    r.bytes += m.data.size();
    newest_version = std::max(newest_version, header->state_version);
    if (header->tier == octoscope::protocol::FrameTier::kInteractive) {
      last_interactive.assign(bytes.begin() + octoscope::protocol::kFrameHeaderBytes, bytes.end());
    }
    if (waiting && header->state_version > version_at_send) {
      r.latency_ms.push_back(
          std::chrono::duration<double, std::milli>(Clock::now() - sent_at).count());
      waiting = false;
    }
  }
  r.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  // What the speed cost: the last interactive frame against the final one of the same state.
  ws.Send(json{{"type", "interaction"}, {"active", false}}.dump());
  const uint64_t last_version = newest_version;
  for (int i = 0; i < 200 && r.error.empty(); ++i) {
    auto m = ws.Read(std::chrono::seconds(60));
    if (!m.ok) break;
    if (!m.binary) continue;
    std::span<const uint8_t> bytes(reinterpret_cast<const uint8_t*>(m.data.data()), m.data.size());
    auto header = octoscope::protocol::DecodeFrameHeader(bytes);
    if (!header.ok()) break;
    ws.Send(json{{"type", "ack"}, {"frame", header->frame_id}}.dump());
    if (header->tier == octoscope::protocol::FrameTier::kInteractive &&
        header->state_version >= last_version) {
      last_interactive.assign(bytes.begin() + octoscope::protocol::kFrameHeaderBytes, bytes.end());
    }
    if (header->final && header->format == octoscope::protocol::ImageFormat::kPng) {
      auto ref = octoscope::testing::DecodeTestPng(std::vector<uint8_t>(
          bytes.begin() + octoscope::protocol::kFrameHeaderBytes, bytes.end()));
      int w = 0, h = 0;
      auto rgb = DecodeJpegRgb(last_interactive, &w, &h);
      if (ref.ok && !rgb.empty()) r.psnr = Psnr(rgb, w, h, ref);
      break;
    }
  }
  ws.Close();
  return r;
}

// Opens the dataset (which starts its build on first use) and waits until it is ready, so that
// the measurement sees a finished octree.
bool WaitReady(uint16_t port, const std::string& token, const std::string& dataset) {
  WsClient ws;
  if (!ws.Connect(port, "/ws?token=" + token).empty()) return false;
  ws.Send(json{{"type", "open"}, {"dataset", dataset}}.dump());
  const auto deadline = Clock::now() + std::chrono::minutes(10);
  while (Clock::now() < deadline) {
    auto m = ws.Read(std::chrono::seconds(60));
    if (!m.ok) return false;
    if (m.binary) continue;
    json event = json::parse(m.data);
    const json* d = event.contains("dataset") ? &event["dataset"] : nullptr;
    if (d != nullptr && d->is_object()) {
      if ((*d)["state"] == "ready") return true;
      if ((*d)["state"] == "error") return false;
    }
  }
  return false;
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(p * (v.size() - 1) + 0.5))];
}

}  // namespace

int main(int argc, char** argv) {
  uint16_t port = 0;
  std::string token;
  std::vector<std::string> datasets;
  int clients = 1, width = 512, height = 512;
  double seconds = 10;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string flag = argv[i], value = argv[i + 1];
    if (flag == "--port")
      port = static_cast<uint16_t>(std::stoi(value));
    else if (flag == "--token")
      token = value;
    else if (flag == "--datasets") {
      size_t start = 0;
      for (size_t comma; (comma = value.find(',', start)) != std::string::npos; start = comma + 1) {
        datasets.push_back(value.substr(start, comma - start));
      }
      datasets.push_back(value.substr(start));
    } else if (flag == "--clients")
      clients = std::stoi(value);
    else if (flag == "--seconds")
      seconds = std::stod(value);
    else if (flag == "--viewport")
      std::sscanf(value.c_str(), "%dx%d", &width, &height);
    else {
      std::fprintf(stderr, "serve_bench: unknown flag %s\n", flag.c_str());
      return 64;
    }
  }
  if (port == 0 || token.empty() || datasets.empty()) {
    std::fprintf(stderr,
                 "usage: serve_bench --port P --token T --datasets ID[,ID] [--clients N] "
                 "[--seconds S] [--viewport WxH]\n");
    return 64;
  }
  for (const std::string& d : datasets) {
    if (!WaitReady(port, token, d)) {
      std::fprintf(stderr, "serve_bench: dataset %s did not become ready\n", d.c_str());
      return 1;
    }
  }
  std::vector<ClientResult> results(clients);
  std::vector<std::thread> threads;
  for (int i = 0; i < clients; ++i) {
    threads.emplace_back([&, i] {
      results[i] = RunClient(port, token, datasets[i % datasets.size()], width, height, seconds, i);
    });
  }
  for (auto& t : threads) t.join();
  std::vector<double> fps, all_latency, psnr;
  uint64_t frames = 0, bytes = 0, sent = 0, dropped = 0;
  for (const ClientResult& r : results) {
    if (!r.error.empty()) {
      std::fprintf(stderr, "serve_bench: client failed: %s\n", r.error.c_str());
      return 1;
    }
    fps.push_back(r.latency_ms.size() / r.seconds);
    all_latency.insert(all_latency.end(), r.latency_ms.begin(), r.latency_ms.end());
    frames += r.frames;
    bytes += r.bytes;
    sent += r.sent;
    dropped += r.dropped;
    if (!std::isnan(r.psnr)) psnr.push_back(r.psnr);
  }
  // One markdown row: clients | datasets | answered cameras/s per client (min, median) | latency
  // p50/p95 | KB per frame | dropped % | PSNR of interactive vs final (median).
  std::printf("| %d | %zu | %dx%d | %.1f | %.1f | %.0f | %.0f | %.1f | %.1f | %.1f |\n", clients,
              datasets.size(), width, height, *std::min_element(fps.begin(), fps.end()),
              Percentile(fps, 0.5), Percentile(all_latency, 0.5), Percentile(all_latency, 0.95),
              frames ? bytes / 1024.0 / frames : 0.0,
              sent + dropped ? 100.0 * dropped / (sent + dropped) : 0.0, Percentile(psnr, 0.5));
  return 0;
}
