#include "io/tiff_planes.h"

#include <algorithm>
#include <memory>

#include "io/tiff_file.h"
#include "util/checked_math.h"

namespace octoscope::io {
Result<DecodedPlanes> DecodeTiffPlanes(std::span<const std::byte> tiff, const std::string& name,
                                       const PlaneExpectation& expect) {
  if (expect.width < 1 || expect.height < 1 || expect.max_planes < 1 || expect.planes < 0 ||
      expect.planes > expect.max_planes) {
    return InvalidArgumentError(name + ": invalid plane expectation");
  }
  const uint64_t sample_bytes = volume::BytesPerSample(expect.dtype);
  const std::optional<uint64_t> plane_bytes = CheckedProduct(
      {static_cast<uint64_t>(expect.width), static_cast<uint64_t>(expect.height), sample_bytes});
  if (!plane_bytes || *plane_bytes > expect.max_bytes) {
    return ResourceExhaustedError(name + ": one plane is larger than the limit of " +
                                  std::to_string(expect.max_bytes) + " bytes");
  }
  // Limits from the expectation: one plane per decoded block, a few thumbnails per plane.
  TiffFile::Limits limits;
  limits.max_plane_bytes = *plane_bytes;
  limits.max_ifds = static_cast<uint32_t>(
      std::min<int64_t>(2 * std::min<int64_t>(expect.max_planes, 1 << 19) + 8, 1 << 20));
  limits.max_cached_bytes = 0;
  auto opened = TiffFile::OpenMemory(tiff, name, limits);
  if (opened.status().code() == StatusCode::kResourceExhausted) {
    // A page or block larger than the expected plane (the limit is exactly one plane).
    return InvalidArgumentError(opened.status().message() + " (expected " +
                                std::to_string(expect.width) + "x" + std::to_string(expect.height) +
                                " " + std::string(volume::NumpyName(expect.dtype)) + " planes)");
  }
  if (!opened.ok()) return opened.status();
  std::unique_ptr<TiffFile> file = std::move(*opened);

  // 1. Check every page before allocating anything.
  std::vector<int> pages;
  for (int i = 0; i < file->ifd_count(); ++i) {
    const TiffIfd& ifd = file->ifd(i);
    if ((ifd.subfile_type & 1) != 0) continue;  // A reduced-resolution copy.
    if (ifd.width != expect.width || ifd.height != expect.height || ifd.samples_per_pixel != 1 ||
        ifd.dtype != expect.dtype) {
      return InvalidArgumentError(
          name + ": page " + std::to_string(i) + " is " + DescribePage(ifd) + ", expected " +
          std::to_string(expect.width) + "x" + std::to_string(expect.height) + " " +
          std::string(volume::NumpyName(expect.dtype)) + " with one sample per pixel");
    }
    pages.push_back(i);
  }
  const int64_t count = static_cast<int64_t>(pages.size());
  if (count == 0) return InvalidArgumentError(name + ": the TIFF holds no full-resolution page");
  if (expect.planes > 0 && count != expect.planes) {
    return InvalidArgumentError(name + ": the TIFF holds " + std::to_string(count) +
                                " planes, expected " + std::to_string(expect.planes));
  }
  if (count > expect.max_planes) {
    return InvalidArgumentError(name + ": the TIFF holds " + std::to_string(count) +
                                " planes, at most " + std::to_string(expect.max_planes) +
                                " fit here");
  }
  const std::optional<uint64_t> total = CheckedMul(*plane_bytes, static_cast<uint64_t>(count));
  if (!total || *total > expect.max_bytes) {
    return ResourceExhaustedError(name + ": " + std::to_string(count) +
                                  " planes are more than the limit of " +
                                  std::to_string(expect.max_bytes) + " bytes");
  }

  // 2. Decode page by page into the planes.
  DecodedPlanes out;
  out.count = count;
  out.samples.resize(*total);
  for (int64_t p = 0; p < count; ++p) {
    const std::span<std::byte> plane(out.samples.data() + static_cast<uint64_t>(p) * *plane_bytes,
                                     *plane_bytes);
    OCTO_RETURN_IF_ERROR(file->ReadPlane(pages[static_cast<size_t>(p)], 0, plane));
  }
  return out;
}

}  // namespace octoscope::io
