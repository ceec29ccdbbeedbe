// Byte-order conversion of sample arrays: reverses the bytes of every 2-, 4- or 8-byte sample of a
// buffer in place (big-endian file data on a little-endian machine and vice versa). One fast
// implementation for every reader: it works on 64-bit words so the compiler vectorizes it, and
// runs near memory speed.
//
// Thread safety: a pure function of its buffer; concurrent calls on disjoint buffers are safe.
#ifndef OCTOSCOPE_UTIL_BYTE_SWAP_H_
#define OCTOSCOPE_UTIL_BYTE_SWAP_H_

#include <cstddef>
#include <span>

namespace octoscope {

// Reverses the byte order of each `sample_bytes`-wide sample of `data`, in place. Samples start at
// data[0]; a tail shorter than one sample is left alone. sample_bytes 0 or 1: nothing to do.
// REQUIRES: sample_bytes is 0, 1, 2, 4 or 8.
void SwapBytesInPlace(std::span<std::byte> data, size_t sample_bytes);

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_BYTE_SWAP_H_
