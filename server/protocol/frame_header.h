// FrameHeader: the 64-byte little-endian header in front of every image the server sends over
// the WebSocket (docs/protocol.md, "Server → client: frames"). The server encodes; the decoder,
// which validates everything a client relies on, serves tests, benchmarks and native clients.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_FRAME_HEADER_H_
#define OCTOSCOPE_PROTOCOL_FRAME_HEADER_H_

#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

#include "protocol/view_id.h"
#include "util/result.h"

namespace octoscope::protocol {

inline constexpr size_t kFrameHeaderBytes = 64;
inline constexpr uint16_t kFrameHeaderVersion = 1;
inline constexpr char kFrameMagic[4] = {'O', 'C', 'T', 'F'};

enum class FrameTier : uint8_t { kInteractive = 0, kRefining = 1, kFinal = 2, kScreenshot = 3 };
enum class ImageFormat : uint8_t { kJpeg = 0, kPng = 1 };

std::string_view FrameTierName(FrameTier tier);  // "interactive", "refining", ...

struct FrameHeader {
  uint64_t frame_id = 0;       // Per connection, increasing from 1.
  uint64_t state_version = 0;  // The session state version the frame shows.
  ViewId view = ViewId::k3d;
  FrameTier tier = FrameTier::kInteractive;
  ImageFormat format = ImageFormat::kJpeg;
  bool final = false;     // No better frame of this state follows.
  bool lossless = false;  // The image holds the rendered pixels exactly (PNG).
  uint16_t width = 0;     // Pixels.
  uint16_t height = 0;
  float progress = 0;       // Fraction of rays finished, [0, 1].
  float render_ms = 0;      // >= 0.
  float encode_ms = 0;      // >= 0.
  float lod_bias = 0;       // Finite.
  uint32_t screenshot_id = 0;  // Tier kScreenshot only, else 0.
  uint32_t image_bytes = 0;    // Bytes of the image after the header.
};

// Checks the invariants above (enum values, ranges, finiteness, screenshot id only on
// screenshots).
Status ValidateFrameHeader(const FrameHeader& header);

// Writes `header` into `out`. Errors (nothing written) when it fails ValidateFrameHeader.
Status EncodeFrameHeader(const FrameHeader& header, std::span<uint8_t, kFrameHeaderBytes> out);

// A whole binary message: the header (image_bytes set from `image`) followed by `image`.
Result<std::vector<uint8_t>> BuildFrameMessage(FrameHeader header, std::span<const uint8_t> image);

// Decodes the header of a binary message and checks it against the message: magic, version,
// header size (at least 64; larger headers of later versions are skipped), field values, and
// that exactly image_bytes follow the header.
Result<FrameHeader> DecodeFrameHeader(std::span<const uint8_t> message);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_FRAME_HEADER_H_
