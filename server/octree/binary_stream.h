// Little-endian binary helpers for the octree's persistence (docs/octree_format.md, "Node
// table"): fixed-width unsigned integers written byte by byte, so files are portable between
// hosts, and a reader that remembers the first failure instead of throwing.
//
// Thread safety: a BinaryReader is used by one thread; the free functions are reentrant.
#ifndef OCTOSCOPE_OCTREE_BINARY_STREAM_H_
#define OCTOSCOPE_OCTREE_BINARY_STREAM_H_

#include <array>
#include <cstdint>
#include <istream>
#include <ostream>
#include <type_traits>

namespace octoscope::octree {

template <typename T>
inline void PutLe(std::ostream& out, T value) {
  static_assert(std::is_unsigned_v<T>);
  std::array<char, sizeof(T)> bytes;
  for (size_t i = 0; i < sizeof(T); ++i) bytes[i] = static_cast<char>((value >> (8 * i)) & 0xff);
  out.write(bytes.data(), sizeof(T));
}

// Reads little-endian integers; after the first short read every Get returns 0 and ok() is false.
class BinaryReader {
 public:
  explicit BinaryReader(std::istream& in) : in_(in) {}

  template <typename T>
  T Get() {
    static_assert(std::is_unsigned_v<T>);
    if (!ok_) return 0;
    std::array<unsigned char, sizeof(T)> bytes;
    in_.read(reinterpret_cast<char*>(bytes.data()), sizeof(T));
    if (in_.gcount() != static_cast<std::streamsize>(sizeof(T))) {
      ok_ = false;
      return 0;
    }
    T value = 0;
    for (size_t i = 0; i < sizeof(T); ++i) value |= static_cast<T>(T{bytes[i]} << (8 * i));
    return value;
  }

  bool ok() const { return ok_; }

 private:
  std::istream& in_;
  bool ok_ = true;
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_BINARY_STREAM_H_
