// TiffFile: one open TIFF or BigTIFF file (either byte order) with an index of all its IFDs,
// built once at open, so any plane can be decoded without walking the IFD chain again (OME-TIFF
// writers such as Micro-Manager put IFDs anywhere in the file). The only class that talks to
// libtiff; libtiff's error and warning handlers are routed into the Status of the failing call.
//
// Decoding supports strips and tiles, every compression this libtiff decodes, chunky and planar
// samples, and the sample types of volume::DataType. Sizes declared by the file are checked
// against Limits and the file size before anything is allocated (a plane of one sample, and one
// decoded strip or tile, which chunky pixels decode with all their samples, must each fit
// Limits::max_plane_bytes); IFD loops are refused.
//
// Pages of chunky (interleaved) samples decode all samples at once; the decoded page is kept
// (up to Limits::max_cached_bytes, least recently used dropped first), so reading each of its
// samples in turn (one channel after another) decodes it once. A page that fails to decode fails
// again at once for its other samples, without touching libtiff.
//
// Planes stored exactly as decoded (uncompressed, native byte order, contiguous strips) can also
// be located (StoredPlaneOffset) and read with positioned reads (ReadBytes). The file is never
// memory-mapped: a file truncated while open gives errors, not SIGBUS.
//
// Thread safety: thread-safe. Decoding calls are serialized by an internal mutex (a libtiff
// handle is not reentrant); the index is immutable after Open; ReadBytes needs no lock.
#ifndef OCTOSCOPE_IO_TIFF_FILE_H_
#define OCTOSCOPE_IO_TIFF_FILE_H_

#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "io/file_gate.h"
#include "io/volume_source.h"
#include "util/result.h"
#include "volume/data_type.h"

namespace octoscope::io {

// What Octoscope needs to know about one IFD (one page of the file).
struct TiffIfd {
  uint64_t offset = 0;  // Byte offset of the IFD in the file.
  uint32_t width = 0;
  uint32_t height = 0;
  uint16_t samples_per_pixel = 1;
  uint16_t bits_per_sample = 8;
  uint16_t sample_format = 1;  // SAMPLEFORMAT_UINT etc.
  uint16_t planar_config = 1;  // 1 chunky (contiguous), 2 planar (separate).
  uint16_t compression = 1;    // COMPRESSION_*.
  uint16_t photometric = 1;
  bool tiled = false;
  std::optional<volume::DataType> dtype;  // nullopt: a sample layout we cannot decode.
  // ImageDescription of IFD 0 only ("" elsewhere and when absent): writers repeat up to megabytes
  // of metadata in every IFD, which must not be multiplied by the page count in the index. Use
  // TiffFile::Description() for another page's.
  std::string description;
  // XResolution / YResolution (pixels per unit) and ResolutionUnit (1 none, 2 inch, 3 cm).
  std::optional<double> x_resolution;
  std::optional<double> y_resolution;
  uint16_t resolution_unit = 2;
  // Software tag of IFD 0 only ("" elsewhere and when absent): ScanImage stores its metadata there
  // and repeats kilobytes of it in every IFD, which would bloat the index of a long recording.
  std::string software;
  // NewSubfileType bits (bit 0: a reduced-resolution copy of another page, e.g. a thumbnail).
  uint32_t subfile_type = 0;
};

class TiffFile final : public PositionedFile {
 public:
  struct Limits {
    // One decoded plane of one sample; also one decoded strip or tile (all samples of chunky
    // pixels), which ReadPlane holds in scratch memory.
    uint64_t max_plane_bytes = uint64_t{4} << 30;
    uint32_t max_ifds = 1u << 20;
    // Decoded chunky pages (all samples) kept for reading their other samples; a page larger
    // than this is decoded again for each sample. 0 keeps none.
    uint64_t max_cached_bytes = uint64_t{64} << 20;
  };

  // Opens `path` (through `gate`) and indexes every IFD. Errors: not a TIFF, not a regular file
  // (Unsupported), truncated, IFD loop, more IFDs than Limits allow, a plane or a strip/tile
  // larger than Limits allow; the gate's refusal.
  static Result<std::unique_ptr<TiffFile>> Open(const std::filesystem::path& path,
                                                const Limits& limits,
                                                const FileGate& gate = FileGate());
  static Result<std::unique_ptr<TiffFile>> Open(const std::filesystem::path& path) {
    return Open(path, Limits{});
  }
  // Opens a TIFF held in memory (an upload's body) the same way: the bytes are copied into an
  // anonymous in-memory file (memfd), so decoding and every limit work exactly as for a file.
  // `name` stands for the file in messages and path().
  static Result<std::unique_ptr<TiffFile>> OpenMemory(std::span<const std::byte> bytes,
                                                      const std::string& name,
                                                      const Limits& limits);
  ~TiffFile() override;
  TiffFile(const TiffFile&) = delete;
  TiffFile& operator=(const TiffFile&) = delete;

  const std::filesystem::path& path() const { return path_; }
  bool big_tiff() const { return big_tiff_; }
  bool big_endian() const { return big_endian_; }
  uint64_t file_size() const { return file_size_; }
  int ifd_count() const { return static_cast<int>(ifds_.size()); }
  // REQUIRES: 0 <= index < ifd_count().
  const TiffIfd& ifd(int index) const { return ifds_[index]; }

  // Decodes sample `sample` of IFD `index` into `out`: width*height samples, row-major, in the
  // IFD's dtype and native byte order. Chunky pages are decoded whole and kept (see above).
  // REQUIRES: out.size() == width * height * BytesPerSample(*dtype).
  Status ReadPlane(int index, int sample, std::span<std::byte> out);

  // Strips or tiles decoded by libtiff so far (diagnostics: tests check that reading every sample
  // of a chunky page decodes it once).
  uint64_t blocks_decoded() const;

  // The ImageDescription of IFD `index` ("" when absent), read on demand. ResourceExhausted when
  // it is longer than `max_bytes`.
  Result<std::string> Description(int index, size_t max_bytes = size_t{1} << 20);

  // The file offset of IFD `index`'s pixel data when it is uncompressed, in strips, and stored
  // as one contiguous run of width*height*samples*bytes bytes in strip order (as ImageJ writes
  // it); an Unsupported error otherwise. Lets readers address data that no IFD describes (ImageJ
  // files > 4 GB keep one IFD and store the further images right after the first).
  Result<uint64_t> ContiguousDataOffset(int index);

  // The file offset of sample `sample` of IFD `index` when the file stores exactly the
  // width*height samples ReadPlane would decode as one run: uncompressed strips (not tiles) of one
  // sample per pixel, or planar (separate) samples; whole-byte samples of the IFD's dtype in native
  // byte order (bit fill order MSB first); the plane's strips contiguous in strip order with no gap
  // or sparse strip; the whole plane inside the file (as sized at Open). nullopt otherwise, and
  // for invalid arguments: callers then use ReadPlane. Each page is examined once.
  std::optional<uint64_t> StoredPlaneOffset(int index, int sample = 0);

  // Reads out.size() raw bytes at `offset` (file byte order). Errors when the range does not lie
  // inside the file as sized at Open, or when the file has shrunk since ("the file is truncated").
  // Thread-safe without taking the decoding lock (positioned reads).
  Status ReadBytes(uint64_t offset, std::span<std::byte> out) const override;

 private:
  struct Impl;
  TiffFile() = default;
  // Open's work on an open descriptor, which the returned file (or the error path) closes.
  static Result<std::unique_ptr<TiffFile>> OpenDescriptor(int fd, const std::filesystem::path& path,
                                                          const Limits& limits);

  std::filesystem::path path_;
  bool big_tiff_ = false;
  bool big_endian_ = false;
  uint64_t file_size_ = 0;
  std::vector<TiffIfd> ifds_;
  mutable std::mutex mutex_;
  std::unique_ptr<Impl> impl_;  // GUARDED_BY(mutex_) for decoding.
};

// "WxH dtype[ with N samples per pixel]" ("undecodable" for an unknown sample layout), for
// messages.
std::string DescribePage(const TiffIfd& ifd);

// True when the file starts with a TIFF or BigTIFF signature (either byte order); false also when
// `gate` refuses it.
bool HasTiffSignature(const std::filesystem::path& path, const FileGate& gate = FileGate());

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_TIFF_FILE_H_
