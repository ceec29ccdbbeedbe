// UninitializedBytes: a byte vector whose resize() leaves new bytes uninitialised, for buffers
// that are completely overwritten right away (decoded chunks, file reads): zero-filling them
// first would cost a pass over memory for nothing.
//
// Thread safety: as std::vector.
#ifndef OCTOSCOPE_UTIL_UNINITIALIZED_BYTES_H_
#define OCTOSCOPE_UTIL_UNINITIALIZED_BYTES_H_

#include <cstddef>
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

namespace octoscope {

// std::allocator, except that value-initialisation (what resize() asks for) default-initialises.
template <typename T>
struct DefaultInitAllocator : std::allocator<T> {
  template <typename U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <typename U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}  // NOLINT

  template <typename U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <typename U, typename... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

using UninitializedBytes = std::vector<std::byte, DefaultInitAllocator<std::byte>>;

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_UNINITIALIZED_BYTES_H_
