// Test helper: page contents that encode their page id and a version, so a test can tell from
// the bytes alone which write of which page it is looking at (and whether the page is torn).
// Layout: bytes 0..7 page id (little endian), 8..15 version, the rest a pattern of both.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_TESTS_PAGING_PAGE_PATTERN_H_
#define OCTOSCOPE_TESTS_PAGING_PAGE_PATTERN_H_

#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace octoscope::paging::testing {

inline constexpr size_t kPatternHeaderBytes = 16;

inline std::byte PatternByte(uint64_t page, uint64_t version, size_t i) {
  const uint64_t x = page * 0x9E3779B97F4A7C15ull + version * 0xC2B2AE3D27D4EB4Full + i * 131;
  return static_cast<std::byte>((x >> 29) ^ (x >> 7) ^ i);
}

// REQUIRES: out.size() >= kPatternHeaderBytes.
inline void FillPage(std::span<std::byte> out, uint64_t page, uint64_t version) {
  for (size_t i = 0; i < 8; ++i) {
    out[i] = static_cast<std::byte>(page >> (8 * i));
    out[8 + i] = static_cast<std::byte>(version >> (8 * i));
  }
  for (size_t i = kPatternHeaderBytes; i < out.size(); ++i) out[i] = PatternByte(page, version, i);
}

inline std::vector<std::byte> PageBytes(size_t size, uint64_t page, uint64_t version) {
  std::vector<std::byte> bytes(size);
  FillPage(bytes, page, version);
  return bytes;
}

inline uint64_t ReadLe64(std::span<const std::byte> bytes, size_t at) {
  uint64_t v = 0;
  for (size_t i = 0; i < 8; ++i) v |= static_cast<uint64_t>(bytes[at + i]) << (8 * i);
  return v;
}

// The version a page holds, without checking the rest.
inline uint64_t PageVersion(std::span<const std::byte> bytes) { return ReadLe64(bytes, 8); }

// Success when `bytes` is exactly FillPage(page, version).
inline ::testing::AssertionResult PageIs(std::span<const std::byte> bytes, uint64_t page,
                                         uint64_t version) {
  if (ReadLe64(bytes, 0) != page || ReadLe64(bytes, 8) != version) {
    return ::testing::AssertionFailure()
           << "header says page " << ReadLe64(bytes, 0) << " version " << ReadLe64(bytes, 8)
           << ", expected page " << page << " version " << version;
  }
  for (size_t i = kPatternHeaderBytes; i < bytes.size(); ++i) {
    if (bytes[i] != PatternByte(page, version, i)) {
      return ::testing::AssertionFailure()
             << "page " << page << " version " << version << ": byte " << i << " is "
             << static_cast<int>(bytes[i]) << ", expected "
             << static_cast<int>(PatternByte(page, version, i)) << " (torn or mixed page)";
    }
  }
  return ::testing::AssertionSuccess();
}

// Success when every byte is zero.
inline ::testing::AssertionResult PageIsZero(std::span<const std::byte> bytes) {
  for (size_t i = 0; i < bytes.size(); ++i) {
    if (bytes[i] != std::byte{0}) {
      return ::testing::AssertionFailure() << "byte " << i << " is " << static_cast<int>(bytes[i]);
    }
  }
  return ::testing::AssertionSuccess();
}

}  // namespace octoscope::paging::testing

#endif  // OCTOSCOPE_TESTS_PAGING_PAGE_PATTERN_H_
