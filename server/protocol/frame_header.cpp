#include "protocol/frame_header.h"

#include <bit>
#include <cmath>
#include <cstring>
#include <string>

namespace octoscope::protocol {
namespace {

// Field offsets of docs/protocol.md.
constexpr size_t kOffMagic = 0, kOffVersion = 4, kOffHeaderBytes = 6, kOffFrameId = 8,
                 kOffStateVersion = 16, kOffView = 24, kOffTier = 25, kOffFormat = 26,
                 kOffFlags = 27, kOffWidth = 28, kOffHeight = 30, kOffProgress = 32,
                 kOffRenderMs = 36, kOffEncodeMs = 40, kOffLodBias = 44, kOffScreenshotId = 48,
                 kOffImageBytes = 52, kOffReserved = 56;
constexpr uint8_t kFlagFinal = 1, kFlagLossless = 2;

template <typename T>
void Put(uint8_t* out, size_t offset, T value) {
  for (size_t i = 0; i < sizeof(T); ++i) {
    out[offset + i] = static_cast<uint8_t>(static_cast<uint64_t>(value) >> (8 * i));
  }
}

template <typename T>
T Get(const uint8_t* in, size_t offset) {
  uint64_t v = 0;
  for (size_t i = 0; i < sizeof(T); ++i) v |= uint64_t{in[offset + i]} << (8 * i);
  return static_cast<T>(v);
}

void PutFloat(uint8_t* out, size_t offset, float value) {
  Put<uint32_t>(out, offset, std::bit_cast<uint32_t>(value));
}
float GetFloat(const uint8_t* in, size_t offset) {
  return std::bit_cast<float>(Get<uint32_t>(in, offset));
}

Status HeaderError(const std::string& problem) {
  return InvalidArgumentError("frame header: " + problem);
}

}  // namespace

std::string_view FrameTierName(FrameTier tier) {
  switch (tier) {
    case FrameTier::kInteractive:
      return "interactive";
    case FrameTier::kRefining:
      return "refining";
    case FrameTier::kFinal:
      return "final";
    case FrameTier::kScreenshot:
      return "screenshot";
  }
  return "?";
}

Status ValidateFrameHeader(const FrameHeader& h) {
  if (static_cast<uint8_t>(h.view) > 3) return HeaderError("unknown view code");
  if (static_cast<uint8_t>(h.tier) > 3) return HeaderError("unknown tier code");
  if (static_cast<uint8_t>(h.format) > 1) return HeaderError("unknown image format code");
  if (!(h.progress >= 0 && h.progress <= 1)) return HeaderError("progress outside [0, 1]");
  if (!(h.render_ms >= 0) || !std::isfinite(h.render_ms)) {
    return HeaderError("render ms negative or not finite");
  }
  if (!(h.encode_ms >= 0) || !std::isfinite(h.encode_ms)) {
    return HeaderError("encode ms negative or not finite");
  }
  if (!std::isfinite(h.lod_bias)) return HeaderError("level-of-detail bias not finite");
  if (h.tier != FrameTier::kScreenshot && h.screenshot_id != 0) {
    return HeaderError("screenshot id on a frame that is not a screenshot");
  }
  return Status::Ok();
}

Status EncodeFrameHeader(const FrameHeader& h, std::span<uint8_t, kFrameHeaderBytes> out) {
  OCTO_RETURN_IF_ERROR(ValidateFrameHeader(h));
  uint8_t* p = out.data();
  std::memset(p, 0, kFrameHeaderBytes);
  std::memcpy(p + kOffMagic, kFrameMagic, 4);
  Put<uint16_t>(p, kOffVersion, kFrameHeaderVersion);
  Put<uint16_t>(p, kOffHeaderBytes, static_cast<uint16_t>(kFrameHeaderBytes));
  Put<uint64_t>(p, kOffFrameId, h.frame_id);
  Put<uint64_t>(p, kOffStateVersion, h.state_version);
  Put<uint8_t>(p, kOffView, static_cast<uint8_t>(h.view));
  Put<uint8_t>(p, kOffTier, static_cast<uint8_t>(h.tier));
  Put<uint8_t>(p, kOffFormat, static_cast<uint8_t>(h.format));
  Put<uint8_t>(p, kOffFlags, (h.final ? kFlagFinal : 0) | (h.lossless ? kFlagLossless : 0));
  Put<uint16_t>(p, kOffWidth, h.width);
  Put<uint16_t>(p, kOffHeight, h.height);
  PutFloat(p, kOffProgress, h.progress);
  PutFloat(p, kOffRenderMs, h.render_ms);
  PutFloat(p, kOffEncodeMs, h.encode_ms);
  PutFloat(p, kOffLodBias, h.lod_bias);
  Put<uint32_t>(p, kOffScreenshotId, h.screenshot_id);
  Put<uint32_t>(p, kOffImageBytes, h.image_bytes);
  Put<uint64_t>(p, kOffReserved, 0);
  return Status::Ok();
}

Result<std::vector<uint8_t>> BuildFrameMessage(FrameHeader header,
                                               std::span<const uint8_t> image) {
  if (image.size() > UINT32_MAX) return HeaderError("image larger than 4 GiB");
  header.image_bytes = static_cast<uint32_t>(image.size());
  std::vector<uint8_t> message(kFrameHeaderBytes + image.size());
  OCTO_RETURN_IF_ERROR(
      EncodeFrameHeader(header, std::span<uint8_t, kFrameHeaderBytes>(message.data(),
                                                                        kFrameHeaderBytes)));
  if (!image.empty()) std::memcpy(message.data() + kFrameHeaderBytes, image.data(), image.size());
  return message;
}

Result<FrameHeader> DecodeFrameHeader(std::span<const uint8_t> message) {
  if (message.size() < kFrameHeaderBytes) {
    return HeaderError("message of " + std::to_string(message.size()) + " bytes, shorter than " +
                       std::to_string(kFrameHeaderBytes));
  }
  const uint8_t* p = message.data();
  if (std::memcmp(p + kOffMagic, kFrameMagic, 4) != 0) return HeaderError("bad magic");
  const uint16_t version = Get<uint16_t>(p, kOffVersion);
  if (version != kFrameHeaderVersion) {
    return HeaderError("version " + std::to_string(version) + ", this decoder reads " +
                       std::to_string(kFrameHeaderVersion));
  }
  const uint16_t header_bytes = Get<uint16_t>(p, kOffHeaderBytes);
  if (header_bytes < kFrameHeaderBytes) {
    return HeaderError("header size " + std::to_string(header_bytes) + " below " +
                       std::to_string(kFrameHeaderBytes));
  }
  FrameHeader h;
  h.frame_id = Get<uint64_t>(p, kOffFrameId);
  h.state_version = Get<uint64_t>(p, kOffStateVersion);
  const uint8_t view = Get<uint8_t>(p, kOffView), tier = Get<uint8_t>(p, kOffTier),
                format = Get<uint8_t>(p, kOffFormat), flags = Get<uint8_t>(p, kOffFlags);
  if (view > 3 || tier > 3 || format > 1) return HeaderError("unknown view, tier or format code");
  if ((flags & ~(kFlagFinal | kFlagLossless)) != 0) return HeaderError("unknown flag bits");
  h.view = static_cast<ViewId>(view);
  h.tier = static_cast<FrameTier>(tier);
  h.format = static_cast<ImageFormat>(format);
  h.final = (flags & kFlagFinal) != 0;
  h.lossless = (flags & kFlagLossless) != 0;
  h.width = Get<uint16_t>(p, kOffWidth);
  h.height = Get<uint16_t>(p, kOffHeight);
  h.progress = GetFloat(p, kOffProgress);
  h.render_ms = GetFloat(p, kOffRenderMs);
  h.encode_ms = GetFloat(p, kOffEncodeMs);
  h.lod_bias = GetFloat(p, kOffLodBias);
  h.screenshot_id = Get<uint32_t>(p, kOffScreenshotId);
  h.image_bytes = Get<uint32_t>(p, kOffImageBytes);
  OCTO_RETURN_IF_ERROR(ValidateFrameHeader(h));
  if (message.size() < header_bytes) return HeaderError("message shorter than its header");
  if (message.size() - header_bytes != h.image_bytes) {
    return HeaderError("image of " + std::to_string(message.size() - header_bytes) +
                       " bytes, header says " + std::to_string(h.image_bytes));
  }
  return h;
}

}  // namespace octoscope::protocol
