// The 64-byte OCTF frame header of docs/protocol.md: byte offsets checked against a hand-written
// little-endian layout (not against the encoder itself), round trips, and refusals.
#include "protocol/frame_header.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <vector>

namespace octoscope::protocol {
namespace {

FrameHeader Sample() {
  FrameHeader h;
  h.frame_id = 0x0102030405060708ull;
  h.state_version = 0x1112131415161718ull;
  h.view = ViewId::kY;
  h.tier = FrameTier::kScreenshot;
  h.format = ImageFormat::kPng;
  h.final = true;
  h.lossless = true;
  h.width = 0x1234;
  h.height = 0x0567;
  h.progress = 1.0f;
  h.render_ms = 12.5f;
  h.encode_ms = 3.25f;
  h.lod_bias = -1.0f;
  h.screenshot_id = 0xA1B2C3D4u;
  return h;
}

TEST(FrameHeaderTest, LayoutMatchesTheSpecification) {
  const std::vector<uint8_t> image = {0xFF, 0xD8, 0xFF, 0xD9, 0x00};
  Result<std::vector<uint8_t>> message = BuildFrameMessage(Sample(), image);
  ASSERT_TRUE(message.ok()) << message.status().ToString();
  ASSERT_EQ(message->size(), 64u + image.size());
  const uint8_t* p = message->data();
  // Expected bytes, little-endian, written out by hand from the table in docs/protocol.md.
  const uint8_t expected[64] = {
      'O',  'C',  'T',  'F',                           // 0 magic
      1,    0,                                         // 4 version
      64,   0,                                         // 6 header bytes
      0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01,  // 8 frame id
      0x18, 0x17, 0x16, 0x15, 0x14, 0x13, 0x12, 0x11,  // 16 state version
      2,                                               // 24 view y
      3,                                               // 25 tier screenshot
      1,                                               // 26 format PNG
      3,                                               // 27 flags final | lossless
      0x34, 0x12,                                      // 28 width
      0x67, 0x05,                                      // 30 height
      0x00, 0x00, 0x80, 0x3F,                          // 32 progress 1.0f
      0x00, 0x00, 0x48, 0x41,                          // 36 render ms 12.5f
      0x00, 0x00, 0x50, 0x40,                          // 40 encode ms 3.25f
      0x00, 0x00, 0x80, 0xBF,                          // 44 lod bias -1.0f
      0xD4, 0xC3, 0xB2, 0xA1,                          // 48 screenshot id
      5,    0,    0,    0,                             // 52 image bytes
      0,    0,    0,    0,    0,    0,    0,    0,     // 56 reserved
  };
  for (size_t i = 0; i < 64; ++i) EXPECT_EQ(p[i], expected[i]) << "byte " << i;
  EXPECT_EQ(std::memcmp(p + 64, image.data(), image.size()), 0);
}

TEST(FrameHeaderTest, RoundTrips) {
  for (FrameTier tier : {FrameTier::kInteractive, FrameTier::kRefining, FrameTier::kFinal}) {
    FrameHeader h = Sample();
    h.tier = tier;
    h.screenshot_id = 0;
    h.progress = 0.375f;
    const std::vector<uint8_t> image(1000, 7);
    Result<std::vector<uint8_t>> message = BuildFrameMessage(h, image);
    ASSERT_TRUE(message.ok()) << message.status().ToString();
    Result<FrameHeader> back = DecodeFrameHeader(*message);
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    EXPECT_EQ(back->frame_id, h.frame_id);
    EXPECT_EQ(back->state_version, h.state_version);
    EXPECT_EQ(back->view, h.view);
    EXPECT_EQ(back->tier, tier);
    EXPECT_EQ(back->format, h.format);
    EXPECT_EQ(back->final, h.final);
    EXPECT_EQ(back->lossless, h.lossless);
    EXPECT_EQ(back->width, h.width);
    EXPECT_EQ(back->height, h.height);
    EXPECT_EQ(back->progress, 0.375f);
    EXPECT_EQ(back->render_ms, h.render_ms);
    EXPECT_EQ(back->encode_ms, h.encode_ms);
    EXPECT_EQ(back->lod_bias, h.lod_bias);
    EXPECT_EQ(back->image_bytes, 1000u);
  }
  EXPECT_EQ(FrameTierName(FrameTier::kRefining), "refining");
}

TEST(FrameHeaderTest, InvalidHeadersAreNotWritten) {
  auto refused = [](auto mutate) {
    FrameHeader h = Sample();
    mutate(h);
    std::vector<uint8_t> out(64, 0xEE);
    Status s = EncodeFrameHeader(h, std::span<uint8_t, 64>(out.data(), 64));
    return !s.ok() && out == std::vector<uint8_t>(64, 0xEE);
  };
  EXPECT_TRUE(refused([](FrameHeader& h) { h.progress = 1.5f; }));
  EXPECT_TRUE(refused([](FrameHeader& h) { h.progress = std::nanf(""); }));
  EXPECT_TRUE(refused([](FrameHeader& h) { h.render_ms = -1; }));
  EXPECT_TRUE(refused([](FrameHeader& h) { h.encode_ms = INFINITY; }));
  EXPECT_TRUE(refused([](FrameHeader& h) { h.lod_bias = NAN; }));
  EXPECT_TRUE(refused([](FrameHeader& h) { h.view = static_cast<ViewId>(4); }));
  EXPECT_TRUE(refused([](FrameHeader& h) { h.tier = static_cast<FrameTier>(4); }));
  EXPECT_TRUE(refused([](FrameHeader& h) { h.format = static_cast<ImageFormat>(2); }));
  EXPECT_TRUE(refused([](FrameHeader& h) {
    h.tier = FrameTier::kFinal;  // A screenshot id on a frame that is no screenshot.
  }));
}

TEST(FrameHeaderTest, MalformedMessagesAreRefused) {
  Result<std::vector<uint8_t>> good = BuildFrameMessage(Sample(), std::vector<uint8_t>(10, 1));
  ASSERT_TRUE(good.ok());
  auto decode_with = [&](size_t offset, uint8_t value) {
    std::vector<uint8_t> m = *good;
    m[offset] = value;
    return DecodeFrameHeader(m);
  };
  EXPECT_FALSE(DecodeFrameHeader(std::span(good->data(), 63)).ok());
  EXPECT_FALSE(decode_with(0, 'X').ok());    // Magic.
  EXPECT_FALSE(decode_with(4, 2).ok());      // Version.
  EXPECT_FALSE(decode_with(6, 32).ok());     // Header shorter than 64.
  EXPECT_FALSE(decode_with(24, 4).ok());     // View.
  EXPECT_FALSE(decode_with(25, 9).ok());     // Tier.
  EXPECT_FALSE(decode_with(26, 2).ok());     // Format.
  EXPECT_FALSE(decode_with(27, 4).ok());     // Unknown flag.
  EXPECT_FALSE(decode_with(35, 0x7F).ok());  // Progress NaN.
  EXPECT_FALSE(decode_with(52, 11).ok());    // Image size disagrees with the message.
  std::vector<uint8_t> truncated = *good;
  truncated.pop_back();
  EXPECT_FALSE(DecodeFrameHeader(truncated).ok());

  // A later version's longer header is skipped by its declared size.
  std::vector<uint8_t> longer = *good;
  longer[6] = 80;
  longer.insert(longer.begin() + 64, 16, 0xAB);
  Result<FrameHeader> skipped = DecodeFrameHeader(longer);
  ASSERT_TRUE(skipped.ok()) << skipped.status().ToString();
  EXPECT_EQ(skipped->image_bytes, 10u);
}

}  // namespace
}  // namespace octoscope::protocol
