#include "util/byte_swap.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

namespace octoscope {
namespace {

// The buffer 0, 1, 2, … n-1.
std::vector<std::byte> Counting(size_t n) {
  std::vector<std::byte> v(n);
  for (size_t i = 0; i < n; ++i) v[i] = static_cast<std::byte>(i);
  return v;
}

TEST(ByteSwapTest, ReversesEverySampleOfEveryWidth) {
  // Sizes around the 8-byte word, so the word loop and the tail loop both run.
  for (size_t width : {2u, 4u, 8u}) {
    for (size_t samples : {0u, 1u, 3u, 4u, 5u, 17u, 1000u}) {
      SCOPED_TRACE("width " + std::to_string(width) + ", samples " + std::to_string(samples));
      std::vector<std::byte> data = Counting(width * samples);
      SwapBytesInPlace(data, width);
      for (size_t s = 0; s < samples; ++s) {
        for (size_t b = 0; b < width; ++b) {
          ASSERT_EQ(data[s * width + b], static_cast<std::byte>(s * width + (width - 1 - b)))
              << "sample " << s << " byte " << b;
        }
      }
    }
  }
}

TEST(ByteSwapTest, MatchesBuiltinSwaps) {
  const uint16_t a = 0x1234;
  const uint32_t b = 0x89ABCDEFu;
  const uint64_t c = 0x0123456789ABCDEFull;
  std::vector<std::byte> buf(sizeof(a));
  std::memcpy(buf.data(), &a, sizeof(a));
  SwapBytesInPlace(buf, 2);
  uint16_t a2;
  std::memcpy(&a2, buf.data(), 2);
  EXPECT_EQ(a2, __builtin_bswap16(a));
  buf.resize(sizeof(b));
  std::memcpy(buf.data(), &b, sizeof(b));
  SwapBytesInPlace(buf, 4);
  uint32_t b2;
  std::memcpy(&b2, buf.data(), 4);
  EXPECT_EQ(b2, __builtin_bswap32(b));
  buf.resize(sizeof(c));
  std::memcpy(buf.data(), &c, sizeof(c));
  SwapBytesInPlace(buf, 8);
  uint64_t c2;
  std::memcpy(&c2, buf.data(), 8);
  EXPECT_EQ(c2, __builtin_bswap64(c));
}

TEST(ByteSwapTest, SingleBytesAndPartialTailAreUntouched) {
  std::vector<std::byte> data = Counting(11);
  SwapBytesInPlace(data, 1);
  EXPECT_EQ(data, Counting(11));
  // 11 bytes of 4-byte samples: two samples swapped, the 3-byte tail left alone.
  SwapBytesInPlace(data, 4);
  const std::vector<uint8_t> want = {3, 2, 1, 0, 7, 6, 5, 4, 8, 9, 10};
  for (size_t i = 0; i < want.size(); ++i) EXPECT_EQ(data[i], static_cast<std::byte>(want[i]));
}

TEST(ByteSwapTest, SwappingTwiceRestores) {
  std::vector<std::byte> data = Counting(4096 + 6);
  SwapBytesInPlace(data, 2);
  SwapBytesInPlace(data, 2);
  EXPECT_EQ(data, Counting(4096 + 6));
}

}  // namespace
}  // namespace octoscope
