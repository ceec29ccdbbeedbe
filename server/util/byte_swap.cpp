#include "util/byte_swap.h"

#include <algorithm>
#include <cstdint>
#include <cstring>

#include "util/target_clones.h"

namespace octoscope {

// Works on 64-bit words (4, 2 or 1 samples at a time): a per-sample rotate in memory runs at a
// fraction of memory speed, while this loop vectorizes.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
OCTO_TARGET_CLONES_AVX2  // Twice the width where the CPU has it.
#endif
    void
    SwapBytesInPlace(std::span<std::byte> data, size_t sample_bytes) {
  if (sample_bytes < 2) return;
  std::byte* p = data.data();
  const size_t words = data.size() / 8;
  for (size_t i = 0; i < words; ++i) {
    uint64_t v;
    std::memcpy(&v, p + i * 8, 8);
    if (sample_bytes == 2) {
      v = ((v & 0x00FF00FF00FF00FFull) << 8) | ((v >> 8) & 0x00FF00FF00FF00FFull);
    } else if (sample_bytes == 4) {
      v = ((v & 0x0000FFFF0000FFFFull) << 16) | ((v >> 16) & 0x0000FFFF0000FFFFull);
      v = ((v & 0x00FF00FF00FF00FFull) << 8) | ((v >> 8) & 0x00FF00FF00FF00FFull);
    } else {
      v = __builtin_bswap64(v);
    }
    std::memcpy(p + i * 8, &v, 8);
  }
  // The tail after the last whole word (only when the size is not a multiple of 8 bytes). Words
  // hold whole samples, so the tail starts on a sample boundary.
  for (size_t at = words * 8; at + sample_bytes <= data.size(); at += sample_bytes) {
    std::reverse(p + at, p + at + sample_bytes);
  }
}

}  // namespace octoscope
