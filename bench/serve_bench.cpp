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
// against that final frame says what the speed costs. The first 3 s of each client are a warm-up
// (not counted); KB/frame counts interactive frames only.
//
// Fairness (--heavy 1): the same interactive clients, plus two heavy clients that stay idle
// (connected, dataset open, no viewport) for the first --seconds and then load the device for
// the next --seconds: one takes 4K screenshots back to back (a 1920x1080 viewport, scale 2:
// 3840x2160 PNG), the other keeps triggering refinements at a 1920x1080 viewport (a new camera as
// soon as the final frame of the previous one arrived). Each interactive client's cameras/s and
// latency are reported for both phases of the same run (one row per client).
//
// Usage: serve_bench --port P --token T --datasets ID[,ID] [--clients N] [--seconds S]
//                    [--viewport WxH] [--heavy 0|1]   (the server must be running)
#include <turbojpeg.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <numeric>
#include <optional>
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
constexpr std::chrono::seconds kWarmUp{3};

// The measured time windows of a run: latencies count in the phase their camera was sent in
// (cameras sent between phases, e.g. during the warm-up, are not counted).
struct Phases {
  std::vector<Clock::time_point> begin, end;
  size_t Of(Clock::time_point t) const {
    for (size_t k = 0; k < begin.size(); ++k) {
      if (t >= begin[k] && t < end[k]) return k;
    }
    return begin.size();
  }
  double Seconds(size_t k) const {
    return std::chrono::duration<double>(end[k] - begin[k]).count();
  }
};

struct PhaseResult {
  std::vector<double> latency_ms;
  uint64_t frames = 0;  // Interactive frames received.
  uint64_t bytes = 0;
  uint64_t pixels = 0;  // Of the interactive frames (width x height).
};

struct ClientResult {
  std::vector<PhaseResult> phases;
  uint64_t sent = 0, dropped = 0;  // From the server's last stats event.
  double psnr = NAN;
  std::string error;
};

// What a heavy client got done in its phase.
struct HeavyResult {
  int done = 0;        // Screenshots received / refinements finished.
  double seconds = 0;  // The time they took together.
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
                       int width, int height, const Phases& phases, int index) {
  ClientResult r;
  r.phases.resize(phases.begin.size());
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
  const auto end = phases.end.back();
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
    auto m = ws.Read(std::chrono::seconds(120));
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
    if (const size_t k = phases.Of(Clock::now());
        k < r.phases.size() && header->tier == octoscope::protocol::FrameTier::kInteractive) {
      ++r.phases[k].frames;
      r.phases[k].bytes += m.data.size();
      r.phases[k].pixels += uint64_t{header->width} * header->height;
    }
    newest_version = std::max(newest_version, header->state_version);
    if (header->tier == octoscope::protocol::FrameTier::kInteractive) {
      last_interactive.assign(bytes.begin() + octoscope::protocol::kFrameHeaderBytes, bytes.end());
    }
    if (waiting && header->state_version > version_at_send) {
      // The first seconds (the first frames of every client, cold caches) are a warm-up.
      if (const size_t k = phases.Of(sent_at); k < r.phases.size()) {
        r.phases[k].latency_ms.push_back(
            std::chrono::duration<double, std::milli>(Clock::now() - sent_at).count());
      }
      waiting = false;
    }
  }
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

// Reads one message; acknowledges a frame and returns its header (nullopt for events).
std::optional<octoscope::protocol::FrameHeader> ReadAcked(WsClient& ws, std::string* error,
                                                         Clock::time_point deadline) {
  auto m = ws.Read(deadline - Clock::now());
  if (!m.ok) {
    *error = "read: " + m.error.message();
    return std::nullopt;
  }
  if (!m.binary) return std::nullopt;
  std::span<const uint8_t> bytes(reinterpret_cast<const uint8_t*>(m.data.data()), m.data.size());
  auto header = octoscope::protocol::DecodeFrameHeader(bytes);
  if (!header.ok()) {
    *error = header.status().ToString();
    return std::nullopt;
  }
  ws.Send(json{{"type", "ack"}, {"frame", header->frame_id}}.dump());
  return *header;
}

// A heavy client: idle (dataset open, no viewport) until `begin`, then until `end` either 4K
// screenshots back to back (`screenshots`) or refinements at 1920x1080 (a new camera whenever the
// final frame of the previous one arrived). Closes at `end` (its render work is dropped).
HeavyResult RunHeavy(uint16_t port, const std::string& token, const std::string& dataset,
                     bool screenshots, Clock::time_point begin, Clock::time_point end) {
  HeavyResult r;
  WsClient ws;
  if (std::string e = ws.Connect(port, "/ws?token=" + token); !e.empty()) {
    r.error = "connect: " + e;
    return r;
  }
  ws.Send(json{{"type", "hello"}, {"client", "serve_bench heavy"}, {"protocol", 1}}.dump());
  ws.Send(json{{"type", "open"}, {"dataset", dataset}}.dump());
  json camera;
  while (camera.is_null() && r.error.empty()) {
    auto m = ws.Read(std::chrono::seconds(60));
    if (!m.ok) r.error = "no 'opened' event";
    if (!m.ok || m.binary) continue;
    json event = json::parse(m.data);
    if (event["type"] == "opened") camera = event["state"]["camera"];
  }
  // Idle: connected with the dataset open, nothing to render (the server pings a silent
  // connection only after 30 s).
  std::this_thread::sleep_until(begin);
  if (!r.error.empty()) return r;
  ws.Send(json{{"type", "viewport"}, {"view", "3d"}, {"width", 1920}, {"height", 1080}, {"dpr", 1}}
              .dump());
  uint32_t id = 0;
  int step = 0;
  uint64_t newest_version = 0;
  while (r.error.empty() && Clock::now() < end) {
    const auto t0 = Clock::now();
    const uint64_t version_before = newest_version;
    if (screenshots) {
      ws.Send(json{{"type", "screenshot"}, {"view", "3d"}, {"scale", 2}, {"id", ++id}}.dump());
    } else {
      ws.Send(json{{"type", "camera"}, {"camera", OrbitCamera(camera, 0.3 * ++step)}}.dump());
    }
    for (;;) {
      // What is still unfinished at the end of the phase does not count.
      if (Clock::now() >= end) return r;
      auto header = ReadAcked(ws, &r.error, end);
      // (A read cut off at the end of the phase times out.)
      if (Clock::now() >= end || r.error.find("timed out") != std::string::npos) {
        r.error.clear();
        return r;
      }
      if (!r.error.empty()) break;
      if (!header) continue;
      newest_version = std::max(newest_version, header->state_version);
      const bool done = screenshots
                            ? header->tier == octoscope::protocol::FrameTier::kScreenshot &&
                                  header->screenshot_id == id
                            : header->final && header->state_version > version_before &&
                                  header->tier != octoscope::protocol::FrameTier::kScreenshot;
      if (done) break;
    }
    if (r.error.empty()) {
      ++r.done;
      r.seconds += std::chrono::duration<double>(Clock::now() - t0).count();
    }
  }
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
  int clients = 1, width = 512, height = 512, heavy = 0;
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
    else if (flag == "--heavy")
      heavy = std::stoi(value);
    else {
      std::fprintf(stderr, "serve_bench: unknown flag %s\n", flag.c_str());
      return 64;
    }
  }
  if (port == 0 || token.empty() || datasets.empty() || clients < 1) {
    std::fprintf(stderr,
                 "usage: serve_bench --port P --token T --datasets ID[,ID] [--clients N] "
                 "[--seconds S] [--viewport WxH] [--heavy 0|1]\n");
    return 64;
  }
  for (const std::string& d : datasets) {
    if (!WaitReady(port, token, d)) {
      std::fprintf(stderr, "serve_bench: dataset %s did not become ready\n", d.c_str());
      return 1;
    }
  }
  // Phases: after the warm-up, [baseline] or, with --heavy, [baseline, gap, loaded]: the gap lets
  // the heavy clients' first frames start so that "loaded" measures them running.
  const auto t0 = Clock::now();
  const auto span =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  Phases phases;
  phases.begin.push_back(t0 + kWarmUp);
  phases.end.push_back(t0 + kWarmUp + span);
  constexpr std::chrono::seconds kGap{2};
  if (heavy) {
    phases.begin.push_back(phases.end[0] + kGap);
    phases.end.push_back(phases.begin[1] + span);
  }
  std::vector<ClientResult> results(clients);
  std::vector<HeavyResult> heavy_results(heavy ? 2 : 0);
  std::vector<std::thread> threads;
  for (int i = 0; i < clients; ++i) {
    threads.emplace_back([&, i] {
      results[i] = RunClient(port, token, datasets[i % datasets.size()], width, height, phases, i);
    });
  }
  for (size_t h = 0; h < heavy_results.size(); ++h) {
    // The screenshot client on the first dataset, the refining one on the last.
    threads.emplace_back([&, h] {
      heavy_results[h] = RunHeavy(port, token, h == 0 ? datasets.front() : datasets.back(), h == 0,
                                  phases.end[0], phases.end[1]);
    });
  }
  for (auto& t : threads) t.join();
  for (const ClientResult& r : results) {
    if (!r.error.empty()) {
      std::fprintf(stderr, "serve_bench: client failed: %s\n", r.error.c_str());
      return 1;
    }
  }
  for (const HeavyResult& r : heavy_results) {
    if (!r.error.empty()) {
      std::fprintf(stderr, "serve_bench: heavy client failed: %s\n", r.error.c_str());
      return 1;
    }
  }
  auto fps_of = [&](const ClientResult& r, size_t k) {
    return r.phases[k].latency_ms.size() / phases.Seconds(k);
  };
  if (!heavy) {
    std::vector<double> fps, all_latency, psnr;
    uint64_t frames = 0, bytes = 0, sent = 0, dropped = 0;
    for (const ClientResult& r : results) {
      fps.push_back(fps_of(r, 0));
      all_latency.insert(all_latency.end(), r.phases[0].latency_ms.begin(),
                         r.phases[0].latency_ms.end());
      frames += r.phases[0].frames;
      bytes += r.phases[0].bytes;
      sent += r.sent;
      dropped += r.dropped;
      if (!std::isnan(r.psnr)) psnr.push_back(r.psnr);
    }
    // One markdown row: clients | datasets | answered cameras/s per client (min, median) |
    // latency p50/p95 | KB per frame | dropped % | PSNR of interactive vs final (median).
    std::printf("| %d | %zu | %dx%d | %.1f | %.1f | %.0f | %.0f | %.1f | %.1f | %.1f |\n", clients,
                datasets.size(), width, height, *std::min_element(fps.begin(), fps.end()),
                Percentile(fps, 0.5), Percentile(all_latency, 0.5), Percentile(all_latency, 0.95),
                frames ? bytes / 1024.0 / frames : 0.0,
                sent + dropped ? 100.0 * dropped / (sent + dropped) : 0.0, Percentile(psnr, 0.5));
    return 0;
  }
  // Fairness: one row per interactive client, then all of them together, then the heavy ones.
  std::printf(
      "| client | dataset | cameras/s idle | loaded | ratio | p50 ms idle | loaded | p95 ms idle "
      "| loaded | frame pixels idle | loaded | PSNR vs final (dB) |\n"
      "|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  std::vector<double> lat[2], ratios;
  for (int i = 0; i < clients; ++i) {
    const ClientResult& r = results[i];
    const double f0 = fps_of(r, 0), f1 = fps_of(r, 1);
    ratios.push_back(f0 > 0 ? f1 / f0 : NAN);
    for (size_t k = 0; k < 2; ++k) {
      lat[k].insert(lat[k].end(), r.phases[k].latency_ms.begin(), r.phases[k].latency_ms.end());
    }
    auto px = [&](size_t k) {
      return r.phases[k].frames ? std::sqrt(double(r.phases[k].pixels) / r.phases[k].frames) : 0;
    };
    std::printf(
        "| %d | %zu | %.1f | %.1f | %.2f | %.0f | %.0f | %.0f | %.0f | %.0f² | %.0f² | %.1f |\n",
        i + 1, i % datasets.size() + 1, f0, f1, ratios.back(),
        Percentile(r.phases[0].latency_ms, 0.5), Percentile(r.phases[1].latency_ms, 0.5),
        Percentile(r.phases[0].latency_ms, 0.95), Percentile(r.phases[1].latency_ms, 0.95), px(0),
        px(1), r.psnr);
  }
  std::printf("| all %d | | | | min %.2f, median %.2f | %.0f | %.0f | %.0f | %.0f | | | |\n",
              clients, *std::min_element(ratios.begin(), ratios.end()), Percentile(ratios, 0.5),
              Percentile(lat[0], 0.5), Percentile(lat[1], 0.5), Percentile(lat[0], 0.95),
              Percentile(lat[1], 0.95));
  std::printf(
      "\nHeavy clients in the loaded phase: %d screenshots of 3840x2160 (%.1f s each), %d "
      "refinements of 1920x1080 (%.1f s each).\n",
      heavy_results[0].done,
      heavy_results[0].done ? heavy_results[0].seconds / heavy_results[0].done : NAN,
      heavy_results[1].done,
      heavy_results[1].done ? heavy_results[1].seconds / heavy_results[1].done : NAN);
  return 0;
}
