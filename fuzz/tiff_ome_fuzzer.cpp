// libFuzzer harness over the TIFF + OME-XML reading path: the bytes become a file that
// OpenVolume opens (TIFF/BigTIFF/ImageJ/OME-TIFF detection, IFD indexing, OME-XML parsing and
// plane mapping), then every slab of every channel is read. The OME-XML parser is also fed the
// raw bytes directly, and the in-memory plane decoder of slab uploads (DecodeTiffPlanes) gets
// them against the layout of their own first page (so valid inputs decode) and a fixed one.
// Nothing may crash, hang, leak or allocate unboundedly: errors are fine.
#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "io/ome_xml.h"
#include "io/open_volume.h"
#include "io/tiff_file.h"
#include "io/tiff_planes.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::string_view bytes(reinterpret_cast<const char*>(data), size);
  (void)octoscope::io::ParseOmeXml(bytes, "fuzz-input");

  const std::span<const std::byte> raw(reinterpret_cast<const std::byte*>(data), size);
  octoscope::io::PlaneExpectation expect;
  expect.width = 64;
  expect.height = 64;
  expect.max_planes = 64;
  expect.max_bytes = 16 << 20;
  octoscope::io::TiffFile::Limits limits;
  limits.max_plane_bytes = 16 << 20;
  if (auto file = octoscope::io::TiffFile::OpenMemory(raw, "fuzz-input", limits);
      file.ok() && (*file)->ifd(0).dtype) {
    const octoscope::io::TiffIfd& first = (*file)->ifd(0);
    expect.width = first.width;
    expect.height = first.height;
    expect.dtype = *first.dtype;
  }
  (void)octoscope::io::DecodeTiffPlanes(raw, "fuzz-input", expect);

  // An anonymous in-memory file: no disk traffic, unique per run.
  int fd = memfd_create("fuzz-input", MFD_CLOEXEC);
  if (fd < 0) return 0;
  if (size > 0 && write(fd, data, size) != static_cast<ssize_t>(size)) {
    close(fd);
    return 0;
  }
  std::string path = "/proc/self/fd/" + std::to_string(fd);

  octoscope::io::OpenOptions options;
  options.max_plane_bytes = 16 << 20;  // Keep each run small; real limits are far larger.
  auto source = octoscope::io::OpenVolume(path, options);
  if (source.ok()) {
    const auto& info = (*source)->info();
    // Read everything when it is small enough to be quick.
    if (info.VoxelBytes() <= (64u << 20)) {
      std::vector<std::byte> slab((*source)->SlabBytes(1));
      for (int c = 0; c < info.channel_count(); ++c) {
        for (int64_t z = 0; z < info.size[2]; ++z) {
          if (!(*source)->ReadSlab(c, z, 1, slab).ok()) break;
        }
      }
    }
  }
  close(fd);
  return 0;
}
