// Helpers of the end-to-end serve tests: the streamed test volume with known voxels, and a
// WebSocket client's view of the protocol (frames decoded, events read, frames acknowledged).
#ifndef OCTOSCOPE_TESTS_APP_WS_FRAMES_H_
#define OCTOSCOPE_TESTS_APP_WS_FRAMES_H_

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "net/net_test_client.h"
#include "protocol/frame_header.h"

namespace octoscope::testing {

using json = nlohmann::json;
using net::testing::WsClient;
using std::chrono::seconds;

struct Frame {
  protocol::FrameHeader header;
  std::vector<uint8_t> image;
};

// A streamed test volume: channel 0 holds a dim pattern plus a few bright voxels, channel 1 noise.
struct TestVolume {
  int64_t sx = 40, sy = 30, sz = 20;
  std::vector<std::vector<uint16_t>> data;  // [c][(z * sy + y) * sx + x]
  TestVolume() {
    std::mt19937 rng(7);
    data.assign(2, std::vector<uint16_t>(sx * sy * sz));
    for (int64_t z = 0; z < sz; ++z) {
      for (int64_t y = 0; y < sy; ++y) {
        for (int64_t x = 0; x < sx; ++x) {
          const size_t i = (z * sy + y) * sx + x;
          data[0][i] = static_cast<uint16_t>((x * 7 + y * 3 + z * 11) % 251);  // Dim structure.
          data[1][i] = static_cast<uint16_t>(rng() % 4096);
        }
      }
    }
    data[0][(5 * sy + 10) * sx + 20] = 3000;  // Bright spots.
    data[0][(17 * sy + 2) * sx + 33] = 4000;
  }
  std::string Planes(int c, int64_t z0, int64_t nz) const {
    const size_t plane = sx * sy;
    std::string bytes(plane * nz * 2, '\0');
    for (size_t i = 0; i < plane * nz; ++i) {
      const uint16_t v = data[c][z0 * plane + i];
      bytes[2 * i] = static_cast<char>(v & 0xff);
      bytes[2 * i + 1] = static_cast<char>(v >> 8);
    }
    return bytes;
  }
  uint16_t ColumnMax(int c, int64_t x, int64_t y) const {
    uint16_t m = 0;
    for (int64_t z = 0; z < sz; ++z) m = std::max(m, data[c][(z * sy + y) * sx + x]);
    return m;
  }
};

inline std::optional<Frame> DecodeFrame(const std::string& data) {
  std::span<const uint8_t> bytes(reinterpret_cast<const uint8_t*>(data.data()), data.size());
  auto header = protocol::DecodeFrameHeader(bytes);
  EXPECT_TRUE(header.ok()) << header.status().ToString();
  if (!header.ok()) return std::nullopt;
  Frame f{*header, std::vector<uint8_t>(bytes.begin() + protocol::kFrameHeaderBytes, bytes.end())};
  return f;
}

inline void Ack(WsClient& ws, uint64_t id) { ws.Send(json{{"type", "ack"}, {"frame", id}}.dump()); }

// Reads until a text event of `type`; frames on the way are acknowledged and kept in *frames.
inline std::optional<json> ReadEvent(WsClient& ws, const std::string& type,
                                     std::vector<Frame>* frames = nullptr,
                                     seconds timeout = seconds(30)) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    auto m = ws.Read(timeout);
    if (!m.ok) return std::nullopt;
    if (m.binary) {
      auto frame = DecodeFrame(m.data);
      if (frame) {
        Ack(ws, frame->header.frame_id);
        if (frames) frames->push_back(std::move(*frame));
      }
      continue;
    }
    json event = json::parse(m.data);
    if (event.value("type", "") == type) return event;
  }
  return std::nullopt;
}

// Reads frames (acknowledging them) until `done(frame)` holds; events are skipped.
inline std::optional<Frame> ReadFrameUntil(WsClient& ws,
                                           const std::function<bool(const Frame&)>& done,
                                           seconds timeout = seconds(60)) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    auto m = ws.Read(timeout);
    if (!m.ok) return std::nullopt;
    if (!m.binary) continue;
    auto frame = DecodeFrame(m.data);
    EXPECT_TRUE(frame.has_value());
    if (!frame) return std::nullopt;
    Ack(ws, frame->header.frame_id);
    if (done(*frame)) return frame;
  }
  return std::nullopt;
}

}  // namespace octoscope::testing

#endif  // OCTOSCOPE_TESTS_APP_WS_FRAMES_H_
