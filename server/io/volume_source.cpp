#include "io/volume_source.h"

#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <string>

namespace octoscope::io {

uint64_t VolumeSource::SlabBytes(int64_t nz) const {
  const volume::VolumeInfo& i = info();
  return i.PlaneVoxels() * static_cast<uint64_t>(nz) * volume::BytesPerSample(i.dtype);
}

Status CheckSlabRequest(const volume::VolumeInfo& info, int channel, int64_t z0, int64_t nz,
                        size_t out_size) {
  if (channel < 0 || channel >= info.channel_count()) {
    return OutOfRangeError("channel " + std::to_string(channel) + " of " +
                           std::to_string(info.channel_count()));
  }
  if (z0 < 0 || nz < 1 || z0 > info.size[2] - nz) {
    return OutOfRangeError("slab z " + std::to_string(z0) + "+" + std::to_string(nz) +
                           " outside 0.." + std::to_string(info.size[2]));
  }
  uint64_t want =
      info.PlaneVoxels() * static_cast<uint64_t>(nz) * volume::BytesPerSample(info.dtype);
  if (out_size != want) {
    return InvalidArgumentError("slab buffer holds " + std::to_string(out_size) +
                                " bytes, the slab needs " + std::to_string(want));
  }
  return Status::Ok();
}

LazyFileMapping::~LazyFileMapping() {
  if (base_ != nullptr) {
    ::munmap(const_cast<std::byte*>(base_), static_cast<size_t>(size_));
  }
}

std::optional<std::span<const std::byte>> LazyFileMapping::View(uint64_t offset,
                                                                uint64_t length) const {
  if (offset > size_ || length > size_ - offset) return std::nullopt;
  std::call_once(once_, [this] {
    // An empty file cannot be mapped, nor one larger than the address space.
    if (size_ == 0 || size_ > SIZE_MAX) return;
    void* base = ::mmap(nullptr, static_cast<size_t>(size_), PROT_READ, MAP_SHARED, fd_, 0);
    if (base != MAP_FAILED) base_ = static_cast<const std::byte*>(base);
  });
  if (base_ == nullptr) return std::nullopt;
  if (length > 0) {
    // Start reading the range in (a no-op for pages already cached). madvise wants a page-aligned
    // start; the hint is best effort, so its result is ignored.
    const uint64_t page = static_cast<uint64_t>(::sysconf(_SC_PAGESIZE));
    const uint64_t start = offset / page * page;
    (void)::madvise(const_cast<std::byte*>(base_) + start,
                    static_cast<size_t>(offset + length - start), MADV_WILLNEED);
  }
  return std::span<const std::byte>(base_ + offset, static_cast<size_t>(length));
}

}  // namespace octoscope::io
