// Overflow-checked integer arithmetic for sizes read from untrusted headers. Every size that a
// file declares goes through these before it is used to allocate or to index.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_UTIL_CHECKED_MATH_H_
#define OCTOSCOPE_UTIL_CHECKED_MATH_H_

#include <cstdint>
#include <initializer_list>
#include <optional>

namespace octoscope {

// a * b, or nullopt on overflow. REQUIRES: a >= 0, b >= 0.
inline std::optional<uint64_t> CheckedMul(uint64_t a, uint64_t b) {
  uint64_t r;
  if (__builtin_mul_overflow(a, b, &r)) return std::nullopt;
  return r;
}

// The product of all factors, or nullopt on overflow.
inline std::optional<uint64_t> CheckedProduct(std::initializer_list<uint64_t> factors) {
  uint64_t r = 1;
  for (uint64_t f : factors) {
    if (__builtin_mul_overflow(r, f, &r)) return std::nullopt;
  }
  return r;
}

inline std::optional<uint64_t> CheckedAdd(uint64_t a, uint64_t b) {
  uint64_t r;
  if (__builtin_add_overflow(a, b, &r)) return std::nullopt;
  return r;
}

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_CHECKED_MATH_H_
