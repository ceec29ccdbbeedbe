#include "io/tiff_file.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <list>
#include <string_view>
#include <system_error>
#include <unordered_map>
#include <unordered_set>
#include <utility>

#include "io/volume_source.h"
#include "util/byte_swap.h"
#include "util/checked_math.h"
#include "util/file_reading.h"

namespace octoscope::io {
namespace {

constexpr size_t kMaxKeptMessages = 8;
// Pages whose decoding failure a TiffFile remembers (each holds one message).
constexpr size_t kMaxRememberedFailures = 1024;

// Collects libtiff's messages for one handle. libtiff calls the handlers below with this object as
// user data, so no global state is involved; access is serialized by TiffFile's mutex (or happens
// during Open, before the handle is shared).
struct MessageSink {
  std::vector<std::string> errors;
  std::vector<std::string> warnings;

  void Clear() {
    errors.clear();
    warnings.clear();
  }

  // "libtiff: <first error>; <second error>" or "" when libtiff said nothing.
  std::string Describe() const {
    const std::vector<std::string>& list = errors.empty() ? warnings : errors;
    std::string text;
    for (const std::string& message : list) {
      text += text.empty() ? "libtiff: " : "; ";
      text += message;
    }
    return text;
  }
};

std::string FormatMessage(const char* module, const char* fmt, va_list ap) {
  char buffer[512];
  va_list copy;
  va_copy(copy, ap);
  std::vsnprintf(buffer, sizeof(buffer), fmt, copy);
  va_end(copy);
  std::string text;
  if (module != nullptr && *module != '\0') {
    text += module;
    text += ": ";
  }
  text += buffer;
  return text;
}

int OnTiffError(TIFF*, void* user_data, const char* module, const char* fmt, va_list ap) {
  auto* sink = static_cast<MessageSink*>(user_data);
  if (sink->errors.size() < kMaxKeptMessages)
    sink->errors.push_back(FormatMessage(module, fmt, ap));
  return 1;  // Handled: keeps libtiff from also calling its global (stderr) handler.
}

int OnTiffWarning(TIFF*, void* user_data, const char* module, const char* fmt, va_list ap) {
  auto* sink = static_cast<MessageSink*>(user_data);
  // Private tags (ImageJ, Micro-Manager, ScanImage …) produce "unknown field" warnings on every
  // IFD; they say nothing about the pixels.
  if (std::strstr(fmt, "Unknown field") != nullptr) return 1;
  if (sink->warnings.size() < kMaxKeptMessages) {
    sink->warnings.push_back(FormatMessage(module, fmt, ap));
  }
  return 1;
}

std::string Join(const std::string& a, const std::string& b) {
  if (b.empty()) return a;
  return a + " (" + b + ")";
}

std::optional<volume::DataType> DataTypeOf(uint16_t bits, uint16_t format) {
  using volume::DataType;
  switch (format) {
    case SAMPLEFORMAT_UINT:
    case SAMPLEFORMAT_VOID:  // "Untyped": read as unsigned, as most readers do.
      if (bits == 8) return DataType::kUint8;
      if (bits == 16) return DataType::kUint16;
      if (bits == 32) return DataType::kUint32;
      return std::nullopt;
    case SAMPLEFORMAT_INT:
      if (bits == 8) return DataType::kInt8;
      if (bits == 16) return DataType::kInt16;
      if (bits == 32) return DataType::kInt32;
      return std::nullopt;
    case SAMPLEFORMAT_IEEEFP:
      if (bits == 32) return DataType::kFloat32;
      if (bits == 64) return DataType::kFloat64;
      return std::nullopt;
    default:
      return std::nullopt;
  }
}

uint16_t Load16(const std::byte* p, bool big_endian) {
  auto b = [&](int i) { return static_cast<uint16_t>(p[i]); };
  return big_endian ? static_cast<uint16_t>((b(0) << 8) | b(1))
                    : static_cast<uint16_t>((b(1) << 8) | b(0));
}

uint64_t LoadN(const std::byte* p, int n, bool big_endian) {
  uint64_t v = 0;
  for (int i = 0; i < n; ++i) {
    int at = big_endian ? i : n - 1 - i;
    v = (v << 8) | static_cast<uint64_t>(p[at]);
  }
  return v;
}

// Copies sample `sample` of `count` chunky pixels of `spp` samples each.
template <size_t kBytes>
void ExtractSampleFixed(const std::byte* src, int spp, int sample, size_t count, std::byte* dst) {
  const std::byte* s = src + static_cast<size_t>(sample) * kBytes;
  const size_t stride = static_cast<size_t>(spp) * kBytes;
  for (size_t i = 0; i < count; ++i, s += stride, dst += kBytes) std::memcpy(dst, s, kBytes);
}

void ExtractSample(const std::byte* src, int spp, int sample, size_t bytes, size_t count,
                   std::byte* dst) {
  switch (bytes) {
    case 1:
      ExtractSampleFixed<1>(src, spp, sample, count, dst);
      break;
    case 2:
      ExtractSampleFixed<2>(src, spp, sample, count, dst);
      break;
    case 4:
      ExtractSampleFixed<4>(src, spp, sample, count, dst);
      break;
    default:
      ExtractSampleFixed<8>(src, spp, sample, count, dst);
      break;
  }
}

// Everything ReadPlane needs to know about one request, worked out once.
struct PlaneJob {
  const std::string& name;  // The file, for messages.
  int index;                // The IFD.
  const TiffIfd& ifd;
  int sample;                // The sample wanted; -1: all samples of chunky pixels.
  std::span<std::byte> out;  // width * height pixels of `out_pixel_bytes` each.
  uint64_t bytes;            // Bytes per sample.
  bool chunky;               // Each pixel holds all its samples (spp > 1, contiguous).
  uint64_t pixel_bytes;      // Bytes of one decoded pixel: bytes * (chunky ? spp : 1).
  uint16_t plane_sample;     // The separate plane holding `sample` (0 when chunky).
  uint64_t file_size;        // As sized at Open.
  int fd;                    // The file's descriptor (for a truncation check after an error).

  bool all_samples() const { return sample < 0; }
  // Bytes of one pixel of `out`: the whole decoded pixel, or one sample.
  uint64_t out_pixel_bytes() const { return all_samples() ? pixel_bytes : bytes; }
  // Whether decoded blocks go through scratch memory to have one sample picked out.
  bool extracts() const { return chunky && !all_samples(); }
};

// One pread of the direct path: `bytes` file bytes at `file_offset` into the plane at `out_offset`.
struct ReadRun {
  uint64_t file_offset;
  uint64_t out_offset;
  uint64_t bytes;
};

// How the current IFD's plane is cut into strips. All arithmetic is 64-bit: heights reach
// 2^32 - 1, and RowsPerStrip 2^32 - 1 (or 0, or > height) means "one strip"; in 32 bits the strip
// count of such a plane wraps to 0.
struct StripLayout {
  uint64_t height = 0;
  uint64_t rows_per_strip = 0;
  uint64_t strips_per_plane = 0;
  uint64_t sample_planes = 1;  // Planar configuration: one run of strips per sample.
  uint64_t strips = 0;         // TIFFNumberOfStrips: must equal strips_per_plane * sample_planes.
  bool consistent() const { return strips_per_plane * sample_planes == strips; }
};

// REQUIRES: `tif` is positioned on the IFD `ifd` describes.
StripLayout StripLayoutOf(TIFF* tif, const TiffIfd& ifd) {
  StripLayout layout;
  uint32_t rows_per_strip_tag = 0;
  TIFFGetFieldDefaulted(tif, TIFFTAG_ROWSPERSTRIP, &rows_per_strip_tag);
  layout.height = ifd.height;
  layout.rows_per_strip = (rows_per_strip_tag == 0 || rows_per_strip_tag > layout.height)
                              ? layout.height
                              : rows_per_strip_tag;
  layout.strips_per_plane = (layout.height + layout.rows_per_strip - 1) / layout.rows_per_strip;
  layout.sample_planes = ifd.planar_config == PLANARCONFIG_SEPARATE ? ifd.samples_per_pixel : 1;
  layout.strips = TIFFNumberOfStrips(tif);
  // Both factors are < 2^32 and < 2^16: the product cannot overflow.
  return layout;
}

}  // namespace

struct TiffFile::Impl {
  // Owned by libtiff once `tif` is open (TIFFClose closes it); closed by us otherwise. Never
  // changes after Open, so positioned reads on it need no lock.
  int fd = -1;
  TIFF* tif = nullptr;
  MessageSink sink;
  // The IFD libtiff has loaded and set up for decoding (SelectIfd); -1: none or unknown (after an
  // error, and after Open, which leaves libtiff on the last IFD without codec set-up).
  int current_ifd = -1;
  uint64_t opened_size = 0;  // The file's size at Open.
  // The largest strip or tile ReadPlane decodes into `scratch` (Limits::max_plane_bytes).
  uint64_t max_block_bytes = 0;
  // Scratch for one decoded strip or tile when it cannot be decoded straight into the caller's
  // buffer; freed after a read when large, so an idle file holds little memory.
  std::vector<std::byte> scratch;
  // StoredPlaneOffset's answers, keyed by IFD index << 16 | sample: the plane's file offset, or
  // nullopt when it is not stored as decoded. Strip tables never change: each page is examined
  // once.
  std::unordered_map<uint64_t, std::optional<uint64_t>> stored_offsets;
  // Decoded chunky pages (all samples), most recently used first; their bytes sum to
  // cached_bytes <= max_cached_bytes.
  struct CachedPage {
    int index;
    std::vector<std::byte> pixels;
  };
  std::list<CachedPage> cached_pages;
  uint64_t cached_bytes = 0;
  uint64_t max_cached_bytes = 0;
  // Pages (keyed like stored_offsets, by the sample plane read) that failed to decode in a way
  // that does not change between reads (corrupt, unsupported, over a limit): the same read fails
  // again at once. At most kMaxRememberedFailures are kept.
  std::unordered_map<uint64_t, Status> failed_planes;
  uint64_t blocks_decoded = 0;

  // Drops the least recently used cached pages until `incoming` more bytes fit the budget.
  void MakeRoom(uint64_t incoming) {
    while (!cached_pages.empty() && cached_bytes + incoming > max_cached_bytes) {
      cached_bytes -= cached_pages.back().pixels.size();
      cached_pages.pop_back();
    }
  }

  ~Impl() {
    if (tif != nullptr) {
      TIFFClose(tif);
    } else if (fd >= 0) {
      ::close(fd);
    }
  }

  // Makes IFD `index` libtiff's current directory, set up for decoding the way ReadPlane expects.
  // Every access to per-IFD libtiff state goes through here.
  Status SelectIfd(const std::string& name, int index, const TiffIfd& ifd);
  // The strip and tile readers of ReadPlane. ReadStrips may release `lock` (the direct path reads
  // with pread only); `swap`: the file's byte order is not the machine's.
  Status ReadStrips(const PlaneJob& job, std::unique_lock<std::mutex>& lock, bool swap);
  Status ReadDirectStrips(const PlaneJob& job, uint64_t rows_per_strip, uint64_t strips,
                          uint64_t first, std::unique_lock<std::mutex>& lock, bool swap);
  Status DecodeStrips(const PlaneJob& job, uint64_t rows_per_strip, uint64_t strips,
                      uint64_t first);
  Status ReadTiles(const PlaneJob& job);
  // The file offset of sample `sample` of IFD `index` when its strips hold exactly the decoded
  // plane, contiguous in strip order (see TiffFile::StoredPlaneOffset); nullopt otherwise.
  std::optional<uint64_t> ContiguousPlaneOffset(const std::string& name, int index,
                                                const TiffIfd& ifd, int sample, uint64_t file_size);
};

namespace {

// The bytes of one strip or tile of `ifd` as ReadPlane decodes it into scratch memory (chunky
// pixels, tiles). nullopt: the page decodes straight into the caller's plane (one sample per
// pixel, strips), or declares no usable tile size (ReadPlane reports that); `overflow`: the size
// does not fit 64 bits.
std::optional<uint64_t> ScratchBlockBytes(TIFF* tif, const TiffIfd& ifd, uint64_t sample_bytes,
                                          bool* overflow) {
  *overflow = false;
  const bool chunky = ifd.planar_config != PLANARCONFIG_SEPARATE && ifd.samples_per_pixel > 1;
  const uint64_t per_pixel = chunky ? ifd.samples_per_pixel : 1;
  uint64_t block_width = ifd.width, block_height = 0;
  if (ifd.tiled) {
    uint32_t tile_width = 0, tile_height = 0;
    TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tile_width);
    TIFFGetField(tif, TIFFTAG_TILELENGTH, &tile_height);
    if (tile_width == 0 || tile_height == 0) return std::nullopt;
    block_width = tile_width;
    block_height = tile_height;
  } else {
    if (!chunky) return std::nullopt;
    uint32_t rows_per_strip = 0;
    TIFFGetFieldDefaulted(tif, TIFFTAG_ROWSPERSTRIP, &rows_per_strip);
    block_height =
        (rows_per_strip == 0 || rows_per_strip > ifd.height) ? ifd.height : rows_per_strip;
  }
  std::optional<uint64_t> bytes =
      CheckedProduct({block_width, block_height, per_pixel, sample_bytes});
  if (!bytes) *overflow = true;
  return bytes;
}

// Refuses a page whose decoding would need a scratch block (one strip or tile, with all samples
// of chunky pixels) larger than a plane may be: a 280-byte file must not make us allocate 51 GB.
Status CheckBlockSize(TIFF* tif, const TiffIfd& ifd, const std::string& where,
                      const TiffFile::Limits& limits) {
  bool overflow = false;
  const std::optional<uint64_t> block =
      ScratchBlockBytes(tif, ifd, volume::BytesPerSample(*ifd.dtype), &overflow);
  if (overflow || (block && *block > limits.max_plane_bytes)) {
    return ResourceExhaustedError(where + " stores " + std::to_string(ifd.samples_per_pixel) +
                                  "-sample pixels in " + (ifd.tiled ? "tiles" : "strips") + " of " +
                                  (block ? std::to_string(*block) : std::string("more than 2^64")) +
                                  " bytes, more than the limit of " +
                                  std::to_string(limits.max_plane_bytes) +
                                  " bytes for one decoded block");
  }
  return Status::Ok();
}

}  // namespace

TiffFile::~TiffFile() = default;

Result<std::unique_ptr<TiffFile>> TiffFile::Open(const std::filesystem::path& path,
                                                 const Limits& limits, const FileGate& gate) {
  OCTO_ASSIGN_OR_RETURN(const int fd, gate.OpenForReading(path));
  return OpenDescriptor(fd, path, limits);
}

Result<std::unique_ptr<TiffFile>> TiffFile::OpenMemory(std::span<const std::byte> bytes,
                                                       const std::string& name,
                                                       const Limits& limits) {
  // An anonymous file in RAM: the same indexed, bounded decoding path as a file on disk.
  const int fd = ::memfd_create("octoscope-tiff", MFD_CLOEXEC);
  if (fd < 0) return IoError(name + ": cannot create an in-memory file: " + std::strerror(errno));
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = errno;
      ::close(fd);
      return ResourceExhaustedError(name +
                                    ": cannot hold the TIFF in memory: " + std::strerror(err));
    }
    done += static_cast<size_t>(n);
  }
  // libtiff reads the header from the descriptor's current offset.
  if (::lseek(fd, 0, SEEK_SET) != 0) {
    const int err = errno;
    ::close(fd);
    return IoError(name + ": cannot rewind the in-memory file: " + std::strerror(err));
  }
  return OpenDescriptor(fd, name, limits);
}

Result<std::unique_ptr<TiffFile>> TiffFile::OpenDescriptor(int fd,
                                                           const std::filesystem::path& path,
                                                           const Limits& limits) {
  const std::string name = path.string();
  std::unique_ptr<TiffFile> file(new TiffFile());
  file->path_ = path;
  file->impl_ = std::make_unique<Impl>();
  Impl& impl = *file->impl_;
  impl.fd = fd;  // Closed by Impl from here on.
  struct stat st;
  if (::fstat(impl.fd, &st) != 0) return IoError(name + ": cannot stat: " + std::strerror(errno));
  file->file_size_ = static_cast<uint64_t>(st.st_size);
  if (file->file_size_ == 0) return CorruptError(name + ": empty file, not a TIFF");

  std::byte header[16] = {};
  const size_t header_size = static_cast<size_t>(std::min<uint64_t>(16, file->file_size_));
  OCTO_RETURN_IF_ERROR(ReadFully(impl.fd, 0, std::span<std::byte>(header, header_size), name));
  const bool little =
      header_size >= 4 && header[0] == std::byte{'I'} && header[1] == std::byte{'I'};
  const bool big = header_size >= 4 && header[0] == std::byte{'M'} && header[1] == std::byte{'M'};
  const uint16_t magic = (little || big) ? Load16(header + 2, big) : 0;
  if (magic != 42 && magic != 43) {
    return UnsupportedError(name + ": not a TIFF file (no TIFF signature at the start)");
  }
  file->big_endian_ = big;
  file->big_tiff_ = magic == 43;
  if (file->file_size_ < (file->big_tiff_ ? 16u : 8u)) {
    return CorruptError(name + ": truncated TIFF header (" + std::to_string(file->file_size_) +
                        " bytes)");
  }

  TIFFOpenOptions* options = TIFFOpenOptionsAlloc();
  if (options == nullptr) return ResourceExhaustedError(name + ": out of memory");
  TIFFOpenOptionsSetErrorHandlerExtR(options, OnTiffError, &impl.sink);
  TIFFOpenOptionsSetWarningHandlerExtR(options, OnTiffWarning, &impl.sink);
  // libtiff's own single allocations (strile arrays, compressed strips, tag data) must not exceed
  // what a legitimate plane of all samples could need.
  uint64_t alloc_cap = CheckedMul(limits.max_plane_bytes, 4).value_or(UINT64_MAX);
  alloc_cap = std::clamp<uint64_t>(alloc_cap, uint64_t{256} << 20, uint64_t{INT64_MAX});
  TIFFOpenOptionsSetMaxSingleMemAlloc(options, static_cast<tmsize_t>(alloc_cap));
  // r: read only; m: no memory mapping, so uncompressed strips are read() straight into the
  // caller's buffer; c: no "strip chopping" of single-strip images into 8 KiB pieces;
  // O: strip offsets/byte counts loaded on demand (files with millions of strips open fast).
  impl.tif = TIFFFdOpenExt(impl.fd, name.c_str(), "rmcO", options);
  TIFFOpenOptionsFree(options);
  if (impl.tif == nullptr) {
    return CorruptError(Join(name + ": cannot read the first IFD", impl.sink.Describe()));
  }

  // Index every IFD. We follow the chain ourselves too (one small pread per IFD) so that a loop is
  // an error whatever libtiff makes of it, and so that the end of the chain is told apart from a
  // directory libtiff failed to read.
  std::unordered_set<uint64_t> seen;
  const int entry_size = file->big_tiff_ ? 20 : 12;
  const int count_size = file->big_tiff_ ? 8 : 2;
  const int pointer_size = file->big_tiff_ ? 8 : 4;
  while (true) {
    const int index = static_cast<int>(file->ifds_.size());
    if (file->ifds_.size() >= limits.max_ifds) {
      return ResourceExhaustedError(name + ": more than " + std::to_string(limits.max_ifds) +
                                    " IFDs");
    }
    TiffIfd ifd;
    TIFF* tif = impl.tif;
    ifd.offset = TIFFCurrentDirOffset(tif);
    seen.insert(ifd.offset);
    TIFFGetFieldDefaulted(tif, TIFFTAG_IMAGEWIDTH, &ifd.width);
    TIFFGetFieldDefaulted(tif, TIFFTAG_IMAGELENGTH, &ifd.height);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &ifd.samples_per_pixel);
    TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &ifd.bits_per_sample);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &ifd.sample_format);
    TIFFGetFieldDefaulted(tif, TIFFTAG_PLANARCONFIG, &ifd.planar_config);
    TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &ifd.compression);
    if (!TIFFGetField(tif, TIFFTAG_PHOTOMETRIC, &ifd.photometric)) ifd.photometric = 1;
    TIFFGetFieldDefaulted(tif, TIFFTAG_SUBFILETYPE, &ifd.subfile_type);
    ifd.tiled = TIFFIsTiled(tif) != 0;
    // Texts of IFD 0 only: writers repeat (up to megabytes of) metadata in every IFD, which must
    // not be multiplied by the page count in the index. Description() reads any other page's.
    const char* text = nullptr;
    if (index == 0 && TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &text) && text != nullptr) {
      ifd.description = text;
    }
    if (index == 0 && TIFFGetField(tif, TIFFTAG_SOFTWARE, &text) && text != nullptr) {
      ifd.software = text;
    }
    float resolution = 0;
    if (TIFFGetField(tif, TIFFTAG_XRESOLUTION, &resolution) && resolution > 0) {
      ifd.x_resolution = resolution;
    }
    if (TIFFGetField(tif, TIFFTAG_YRESOLUTION, &resolution) && resolution > 0) {
      ifd.y_resolution = resolution;
    }
    TIFFGetFieldDefaulted(tif, TIFFTAG_RESOLUTIONUNIT, &ifd.resolution_unit);
    ifd.dtype = DataTypeOf(ifd.bits_per_sample, ifd.sample_format);
    if (ifd.photometric == PHOTOMETRIC_YCBCR && ifd.compression != COMPRESSION_JPEG) {
      // Raw subsampled YCbCr has a sample layout of its own; we do not unpack it.
      uint16_t sub_x = 1, sub_y = 1;
      TIFFGetFieldDefaulted(tif, TIFFTAG_YCBCRSUBSAMPLING, &sub_x, &sub_y);
      if (sub_x != 1 || sub_y != 1) ifd.dtype = std::nullopt;
    }

    const std::string where = name + ": IFD " + std::to_string(index);
    if (ifd.width == 0 || ifd.height == 0) {
      return CorruptError(where + " declares " + std::to_string(ifd.width) + "x" +
                          std::to_string(ifd.height) + " pixels");
    }
    if (ifd.samples_per_pixel == 0) return CorruptError(where + " declares 0 samples per pixel");
    const uint64_t sample_bytes = ifd.dtype ? volume::BytesPerSample(*ifd.dtype)
                                            : std::max<uint64_t>(1, (ifd.bits_per_sample + 7) / 8);
    const std::optional<uint64_t> plane_bytes =
        CheckedProduct({ifd.width, ifd.height, sample_bytes});
    const std::string dims = std::to_string(ifd.width) + "x" + std::to_string(ifd.height);
    if (!plane_bytes || *plane_bytes > limits.max_plane_bytes) {
      return ResourceExhaustedError(where + " declares " + dims +
                                    " pixels, a plane larger than the limit of " +
                                    std::to_string(limits.max_plane_bytes) + " bytes");
    }
    if (ifd.compression == COMPRESSION_NONE) {
      // Uncompressed pixels occupy their full size in the file.
      std::optional<uint64_t> all = CheckedMul(*plane_bytes, ifd.samples_per_pixel);
      if (!all || *all > file->file_size_) {
        return CorruptError(where + " declares " + dims + " uncompressed pixels, more than the " +
                            std::to_string(file->file_size_) + "-byte file can hold");
      }
    }
    if (ifd.dtype) OCTO_RETURN_IF_ERROR(CheckBlockSize(tif, ifd, where, limits));
    file->ifds_.push_back(std::move(ifd));

    // Find the next IFD offset: after the entry count and the entries.
    const uint64_t at = file->ifds_.back().offset;
    std::byte count_bytes[8];
    if (!ReadFully(impl.fd, at, std::span<std::byte>(count_bytes, count_size), name).ok()) {
      return CorruptError(where + " at offset " + std::to_string(at) + " is truncated");
    }
    const uint64_t entries = LoadN(count_bytes, count_size, big);
    const std::optional<uint64_t> next_at =
        CheckedAdd(at + count_size, CheckedMul(entries, entry_size).value_or(UINT64_MAX));
    std::byte next_bytes[8];
    if (!next_at ||
        !ReadFully(impl.fd, *next_at, std::span<std::byte>(next_bytes, pointer_size), name).ok()) {
      return CorruptError(where + ": the pointer to the next IFD lies beyond the end of the file");
    }
    const uint64_t next = LoadN(next_bytes, pointer_size, big);
    if (next == 0) break;
    if (seen.count(next) != 0) {
      return CorruptError(where + " links back to the IFD at offset " + std::to_string(next) +
                          " (an IFD loop)");
    }
    if (next >= file->file_size_) {
      return CorruptError(where + " points to a next IFD at offset " + std::to_string(next) +
                          ", beyond the end of the file (" + std::to_string(file->file_size_) +
                          " bytes)");
    }
    impl.sink.Clear();
    if (!TIFFReadDirectory(impl.tif)) {
      return CorruptError(Join(name + ": cannot read IFD " + std::to_string(index + 1) +
                                   " at offset " + std::to_string(next),
                               impl.sink.Describe()));
    }
    if (TIFFCurrentDirOffset(impl.tif) != next) {
      return InternalError(name + ": libtiff read IFD " + std::to_string(index + 1) +
                           " at an unexpected offset");
    }
  }
  // libtiff is left on the last IFD, but without the codec set-up of SelectIfd: make the first
  // read of any IFD (the last one included) select it properly.
  impl.current_ifd = -1;
  impl.max_block_bytes = limits.max_plane_bytes;
  impl.max_cached_bytes = limits.max_cached_bytes;
  impl.opened_size = file->file_size_;
  impl.sink.Clear();
  return file;
}

namespace {

// Checks that strile (strip or tile) `strile` lies inside the file. Sets `sparse` when the file
// leaves it out on purpose (offset and byte count 0, GDAL's convention for an all-zero block).
Status CheckStrile(TIFF* tif, const PlaneJob& job, const char* kind, uint32_t strile,
                   uint64_t min_bytes, bool* sparse, uint64_t* offset_out = nullptr) {
  int err = 0;
  const uint64_t offset = TIFFGetStrileOffsetWithErr(tif, strile, &err);
  if (offset_out != nullptr) *offset_out = offset;
  const uint64_t bytes = err ? 0 : TIFFGetStrileByteCountWithErr(tif, strile, &err);
  const std::string where =
      job.name + ": IFD " + std::to_string(job.index) + " " + kind + " " + std::to_string(strile);
  if (err) return CorruptError(where + ": cannot read its offset or byte count");
  *sparse = offset == 0 && bytes == 0;
  if (*sparse) return Status::Ok();
  if (bytes == 0) return CorruptError(where + " is empty (byte count 0)");
  if (offset > job.file_size || bytes > job.file_size - offset) {
    return CorruptError(where + " (bytes " + std::to_string(offset) + ".." +
                        std::to_string(offset + bytes) + ") extends beyond the end of the file (" +
                        std::to_string(job.file_size) + " bytes): the file is truncated");
  }
  if (bytes < min_bytes) {
    return CorruptError(where + " holds " + std::to_string(bytes) +
                        " bytes of uncompressed data, " + std::to_string(min_bytes) + " needed");
  }
  return Status::Ok();
}

// "; the file is truncated: ..." when the file behind `fd` is now shorter than the `opened_size`
// bytes it had at Open (a writer cut it short: libtiff's own messages do not say so); "" otherwise.
std::string TruncationNote(uint64_t opened_size, int fd) {
  struct stat st;
  if (::fstat(fd, &st) != 0 || static_cast<uint64_t>(st.st_size) >= opened_size) return "";
  return "; the file is truncated: it has " + std::to_string(st.st_size) + " bytes, " +
         std::to_string(opened_size) + " when it was opened";
}

Status DecodeError(const PlaneJob& job, const char* kind, uint32_t strile, tmsize_t got,
                   uint64_t want, const MessageSink& sink) {
  std::string message =
      job.name + ": IFD " + std::to_string(job.index) + " " + kind + " " + std::to_string(strile);
  if (got < 0) {
    message += ": decoding failed";
  } else if (static_cast<uint64_t>(got) == want) {
    message += ": decoding reported errors";
  } else {
    message +=
        " decoded to " + std::to_string(got) + " bytes, " + std::to_string(want) + " expected";
  }
  return CorruptError(Join(message, sink.Describe()) + TruncationNote(job.file_size, job.fd));
}

// Zeroes columns [x0, x0 + cols) of rows [y0, y0 + rows) of the plane (a sparse strip or tile).
void ZeroRect(const PlaneJob& job, uint64_t x0, uint64_t y0, uint64_t cols, uint64_t rows) {
  const uint64_t width = job.ifd.width;
  const uint64_t bytes = job.out_pixel_bytes();
  if (x0 == 0 && cols == width) {  // Whole rows: one contiguous run.
    std::memset(job.out.data() + y0 * width * bytes, 0, rows * width * bytes);
    return;
  }
  for (uint64_t y = 0; y < rows; ++y) {
    std::memset(job.out.data() + ((y0 + y) * width + x0) * bytes, 0, cols * bytes);
  }
}

}  // namespace

Status TiffFile::Impl::SelectIfd(const std::string& name, int index, const TiffIfd& ifd) {
  if (current_ifd == index) return Status::Ok();
  current_ifd = -1;
  if (!TIFFSetSubDirectory(tif, ifd.offset)) {
    return CorruptError(
        Join(name + ": cannot reload IFD " + std::to_string(index), sink.Describe()) +
        TruncationNote(opened_size, fd));
  }
  if (ifd.compression == COMPRESSION_JPEG && ifd.photometric == PHOTOMETRIC_YCBCR) {
    // Let libjpeg convert to RGB instead of handing out subsampled YCbCr. A pseudo-tag of the
    // codec: libtiff resets it whenever it loads the directory, so it is set on every selection.
    TIFFSetField(tif, TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB);
  }
  current_ifd = index;
  return Status::Ok();
}

Status TiffFile::Impl::ReadStrips(const PlaneJob& job, std::unique_lock<std::mutex>& lock,
                                  bool swap) {
  const TiffIfd& ifd = job.ifd;
  const StripLayout layout = StripLayoutOf(tif, ifd);
  const uint64_t height = layout.height, rows_per_strip = layout.rows_per_strip;
  const uint64_t strips_per_plane = layout.strips_per_plane;
  const uint64_t sample_planes = layout.sample_planes, strips = layout.strips;
  if (!layout.consistent()) {
    return CorruptError(job.name + ": IFD " + std::to_string(job.index) + " has " +
                        std::to_string(strips) + " strips, but " + std::to_string(height) +
                        " rows in strips of " + std::to_string(rows_per_strip) + " rows (x " +
                        std::to_string(sample_planes) + " sample planes) make " +
                        std::to_string(strips_per_plane * sample_planes));
  }
  const uint64_t first = job.plane_sample * strips_per_plane;
  uint16_t fill_order = FILLORDER_MSB2LSB;
  TIFFGetFieldDefaulted(tif, TIFFTAG_FILLORDER, &fill_order);
  if (ifd.compression == COMPRESSION_NONE && !job.chunky && fill_order == FILLORDER_MSB2LSB) {
    return ReadDirectStrips(job, rows_per_strip, strips_per_plane, first, lock, swap);
  }
  return DecodeStrips(job, rows_per_strip, strips_per_plane, first);
}

// Direct path: pread the strips straight into `out`, merging strips that follow each other in the
// file into one read, then swap bytes if needed. Only the strip table needs libtiff, so the lock
// is released before the (possibly long) reads.
Status TiffFile::Impl::ReadDirectStrips(const PlaneJob& job, uint64_t rows_per_strip,
                                        uint64_t strips, uint64_t first,
                                        std::unique_lock<std::mutex>& lock, bool swap) {
  const uint64_t height = job.ifd.height;
  const uint64_t row_bytes = uint64_t{job.ifd.width} * job.pixel_bytes;
  std::vector<ReadRun> runs;
  for (uint64_t s = 0; s < strips; ++s) {
    const uint32_t strip = static_cast<uint32_t>(first + s);  // < TIFFNumberOfStrips.
    const uint64_t y0 = s * rows_per_strip;
    const uint64_t want = std::min(rows_per_strip, height - y0) * row_bytes;
    const uint64_t at = y0 * row_bytes;
    bool sparse = false;
    uint64_t offset = 0;
    OCTO_RETURN_IF_ERROR(CheckStrile(tif, job, "strip", strip, want, &sparse, &offset));
    if (sparse) {
      std::memset(job.out.data() + at, 0, want);
    } else if (!runs.empty() && runs.back().file_offset + runs.back().bytes == offset &&
               runs.back().out_offset + runs.back().bytes == at) {
      runs.back().bytes += want;
    } else {
      runs.push_back({offset, at, want});
    }
  }
  lock.unlock();
  // When swapping, read 1 MiB at a time and swap it while it is still in cache.
  const uint64_t chunk = swap ? uint64_t{1} << 20 : UINT64_MAX;
  for (const ReadRun& run : runs) {
    for (uint64_t done = 0; done < run.bytes; done += std::min(chunk, run.bytes - done)) {
      std::span<std::byte> piece =
          job.out.subspan(run.out_offset + done, std::min(chunk, run.bytes - done));
      // CheckStrile put every run inside the file; a read past its end means it shrank since.
      OCTO_RETURN_IF_ERROR(ReadFully(fd, run.file_offset + done, piece, job.name));
      if (swap) SwapBytesInPlace(piece, job.bytes);
    }
  }
  return Status::Ok();
}

// Decoded path: libtiff decodes each strip (decompressing, undoing predictors and byte order).
// One sample per pixel decodes straight into the caller's buffer; chunky pixels go through
// scratch, from which the wanted sample is picked.
Status TiffFile::Impl::DecodeStrips(const PlaneJob& job, uint64_t rows_per_strip, uint64_t strips,
                                    uint64_t first) {
  const uint64_t width = job.ifd.width;
  const uint64_t height = job.ifd.height;
  const uint64_t row_bytes = width * job.pixel_bytes;
  const bool uncompressed = job.ifd.compression == COMPRESSION_NONE;
  if (job.extracts()) {
    const uint64_t block = rows_per_strip * row_bytes;  // <= max_block_bytes, checked at Open.
    if (block > max_block_bytes) {
      return ResourceExhaustedError(
          job.name + ": IFD " + std::to_string(job.index) + " strips of " + std::to_string(block) +
          " bytes exceed the limit of " + std::to_string(max_block_bytes));
    }
    scratch.resize(block);
  }
  for (uint64_t s = 0; s < strips; ++s) {
    const uint32_t strip = static_cast<uint32_t>(first + s);  // < TIFFNumberOfStrips.
    const uint64_t y0 = s * rows_per_strip;
    const uint64_t rows = std::min(rows_per_strip, height - y0);
    const uint64_t want = rows * row_bytes;
    std::byte* dst = job.out.data() + y0 * width * job.out_pixel_bytes();
    bool sparse = false;
    OCTO_RETURN_IF_ERROR(CheckStrile(tif, job, "strip", strip, uncompressed ? want : 0, &sparse));
    if (sparse) {
      ZeroRect(job, 0, y0, width, rows);
      continue;
    }
    // For uncompressed data libtiff read()s the strip straight into `target`, with no copy.
    std::byte* target = job.extracts() ? scratch.data() : dst;
    ++blocks_decoded;
    const tmsize_t got = TIFFReadEncodedStrip(tif, strip, target, static_cast<tmsize_t>(want));
    if (got != static_cast<tmsize_t>(want) || !sink.errors.empty()) {
      return DecodeError(job, "strip", strip, got, want, sink);
    }
    if (job.extracts()) {
      ExtractSample(target, job.ifd.samples_per_pixel, job.sample, job.bytes, rows * width, dst);
    }
  }
  return Status::Ok();
}

Status TiffFile::Impl::ReadTiles(const PlaneJob& job) {
  const TiffIfd& ifd = job.ifd;
  uint32_t tile_width = 0, tile_height = 0;
  TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tile_width);
  TIFFGetField(tif, TIFFTAG_TILELENGTH, &tile_height);
  const std::string where = job.name + ": IFD " + std::to_string(job.index);
  const std::string tiles = std::to_string(tile_width) + "x" + std::to_string(tile_height);
  if (tile_width == 0 || tile_height == 0) {
    return CorruptError(where + " declares " + tiles + " tiles");
  }
  // A tile may be wider or taller than the image (one 1024x1024 tile for a 1000x10 image is
  // legitimate), so its size is bounded only by the scratch limit, as checked at Open.
  const std::optional<uint64_t> tile_bytes =
      CheckedProduct({tile_width, tile_height, job.pixel_bytes});
  if (!tile_bytes || *tile_bytes > max_block_bytes) {
    return ResourceExhaustedError(where + " declares " + tiles + " tiles of " +
                                  (tile_bytes ? std::to_string(*tile_bytes) : "> 2^64") +
                                  " bytes, more than the limit of " +
                                  std::to_string(max_block_bytes));
  }
  if (static_cast<uint64_t>(TIFFTileSize64(tif)) != *tile_bytes) {
    return UnsupportedError(where + ": tile layout not understood (libtiff tile size " +
                            std::to_string(TIFFTileSize64(tif)) + " bytes, expected " +
                            std::to_string(*tile_bytes) + ")");
  }
  scratch.resize(*tile_bytes);
  const bool uncompressed = ifd.compression == COMPRESSION_NONE;
  const uint64_t width = ifd.width;
  const uint64_t height = ifd.height;
  const uint64_t tile_row_bytes = uint64_t{tile_width} * job.pixel_bytes;
  // 64-bit loop counters: with 32 bits, ty += tile_height wraps past 2^32 and never ends.
  for (uint64_t ty = 0; ty < height; ty += tile_height) {
    for (uint64_t tx = 0; tx < width; tx += tile_width) {
      const uint32_t tile = TIFFComputeTile(tif, static_cast<uint32_t>(tx),
                                            static_cast<uint32_t>(ty), 0, job.plane_sample);
      const uint64_t rows = std::min<uint64_t>(tile_height, height - ty);
      const uint64_t cols = std::min<uint64_t>(tile_width, width - tx);
      bool sparse = false;
      OCTO_RETURN_IF_ERROR(
          CheckStrile(tif, job, "tile", tile, uncompressed ? *tile_bytes : 0, &sparse));
      if (sparse) {
        ZeroRect(job, tx, ty, cols, rows);
        continue;
      }
      ++blocks_decoded;
      const tmsize_t got =
          TIFFReadEncodedTile(tif, tile, scratch.data(), static_cast<tmsize_t>(*tile_bytes));
      if (got != static_cast<tmsize_t>(*tile_bytes) || !sink.errors.empty()) {
        return DecodeError(job, "tile", tile, got, *tile_bytes, sink);
      }
      // Crop the tile at the right and bottom edges of the image.
      for (uint64_t y = 0; y < rows; ++y) {
        const std::byte* src = scratch.data() + y * tile_row_bytes;
        std::byte* dst = job.out.data() + ((ty + y) * width + tx) * job.out_pixel_bytes();
        if (job.extracts()) {
          ExtractSample(src, ifd.samples_per_pixel, job.sample, job.bytes, cols, dst);
        } else {
          std::memcpy(dst, src, cols * job.out_pixel_bytes());
        }
      }
    }
  }
  return Status::Ok();
}

Status TiffFile::ReadPlane(int index, int sample, std::span<std::byte> out) {
  const std::string name = path_.string();
  if (index < 0 || index >= ifd_count()) {
    return OutOfRangeError(name + ": IFD " + std::to_string(index) + " requested, the file has " +
                           std::to_string(ifd_count()));
  }
  const TiffIfd& ifd = ifds_[index];
  if (!ifd.dtype) {
    return UnsupportedError(name + ": IFD " + std::to_string(index) + " has " +
                            std::to_string(ifd.bits_per_sample) + "-bit samples of format " +
                            std::to_string(ifd.sample_format) + " (photometric " +
                            std::to_string(ifd.photometric) + "), which Octoscope cannot decode");
  }
  if (sample < 0 || sample >= ifd.samples_per_pixel) {
    return OutOfRangeError(name + ": IFD " + std::to_string(index) + ": sample " +
                           std::to_string(sample) + " requested, it has " +
                           std::to_string(ifd.samples_per_pixel));
  }
  const uint64_t bytes = volume::BytesPerSample(*ifd.dtype);
  const uint64_t plane_bytes = uint64_t{ifd.width} * ifd.height * bytes;  // Checked at Open.
  if (out.size() != plane_bytes) {
    return InvalidArgumentError(name + ": plane buffer holds " + std::to_string(out.size()) +
                                " bytes, IFD " + std::to_string(index) + " needs " +
                                std::to_string(plane_bytes));
  }

  const bool chunky = ifd.planar_config != PLANARCONFIG_SEPARATE && ifd.samples_per_pixel > 1;
  // The sample plane read: every sample of chunky pixels comes from the same strips or tiles.
  const uint64_t key =
      (static_cast<uint64_t>(index) << 16) | static_cast<uint64_t>(chunky ? 0 : sample);
  const uint64_t pixels = uint64_t{ifd.width} * ifd.height;
  const uint64_t page_bytes = plane_bytes * ifd.samples_per_pixel;  // < 2^32 * 2^16.

  std::unique_lock<std::mutex> lock(mutex_);
  Impl& impl = *impl_;
  // 1. A page that failed before fails the same way now.
  if (auto failed = impl.failed_planes.find(key); failed != impl.failed_planes.end()) {
    return failed->second;
  }
  // 2. Another sample of a chunky page decoded before: pick it out of the kept page.
  const bool keep_page = chunky && page_bytes <= impl.max_cached_bytes;
  if (keep_page) {
    for (auto it = impl.cached_pages.begin(); it != impl.cached_pages.end(); ++it) {
      if (it->index != index) continue;
      impl.cached_pages.splice(impl.cached_pages.begin(), impl.cached_pages, it);
      ExtractSample(it->pixels.data(), ifd.samples_per_pixel, sample, bytes, pixels, out.data());
      return Status::Ok();
    }
  }
  // 3. Decode: a chunky page that can be kept is decoded whole (all samples), else only `sample`.
  std::vector<std::byte> page;
  if (keep_page) {
    impl.MakeRoom(page_bytes);
    page.resize(page_bytes);
  }
  impl.sink.Clear();
  Status result = impl.SelectIfd(name, index, ifd);
  if (result.ok()) {
    uint32_t depth = 1;
    TIFFGetFieldDefaulted(impl.tif, TIFFTAG_IMAGEDEPTH, &depth);
    if (depth > 1) {
      result = UnsupportedError(name + ": IFD " + std::to_string(index) + " is a 3-D (ImageDepth " +
                                std::to_string(depth) + ") image");
    }
  }
  if (result.ok()) {
    const PlaneJob job{name,
                       index,
                       ifd,
                       keep_page ? -1 : sample,
                       keep_page ? std::span<std::byte>(page) : out,
                       bytes,
                       chunky,
                       bytes * (chunky ? ifd.samples_per_pixel : 1),
                       static_cast<uint16_t>(chunky ? 0 : sample),
                       file_size_,
                       impl.fd};
    const bool swap = bytes > 1 && big_endian_ != (std::endian::native == std::endian::big);
    result = ifd.tiled ? impl.ReadTiles(job) : impl.ReadStrips(job, lock, swap);
  }
  // The direct strip path releases the lock for its reads; then libtiff's state was not touched.
  if (lock.owns_lock()) {
    if (impl.scratch.size() > (size_t{64} << 20)) {
      impl.scratch = std::vector<std::byte>();  // Do not keep a huge scratch buffer around.
    }
    if (!result.ok()) {
      // After a failure libtiff's per-directory state may be off; reload the IFD next time.
      impl.current_ifd = -1;
      const StatusCode code = result.code();
      if ((code == StatusCode::kCorrupt || code == StatusCode::kUnsupported ||
           code == StatusCode::kResourceExhausted) &&
          impl.failed_planes.size() < kMaxRememberedFailures) {
        impl.failed_planes.emplace(key, result);
      }
    } else if (keep_page) {
      ExtractSample(page.data(), ifd.samples_per_pixel, sample, bytes, pixels, out.data());
      impl.cached_bytes += page.size();
      impl.cached_pages.push_front({index, std::move(page)});
    }
  }
  return result;
}

uint64_t TiffFile::blocks_decoded() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return impl_->blocks_decoded;
}

std::optional<uint64_t> TiffFile::Impl::ContiguousPlaneOffset(const std::string& name, int index,
                                                              const TiffIfd& ifd, int sample,
                                                              uint64_t file_size) {
  sink.Clear();
  if (!SelectIfd(name, index, ifd).ok()) {
    current_ifd = -1;
    return std::nullopt;
  }
  uint32_t depth = 1;
  TIFFGetFieldDefaulted(tif, TIFFTAG_IMAGEDEPTH, &depth);
  uint16_t fill_order = FILLORDER_MSB2LSB;
  TIFFGetFieldDefaulted(tif, TIFFTAG_FILLORDER, &fill_order);
  if (depth > 1 || fill_order != FILLORDER_MSB2LSB) return std::nullopt;
  // The same strip layout ReadStrips decodes.
  const StripLayout layout = StripLayoutOf(tif, ifd);
  if (!layout.consistent()) return std::nullopt;
  const uint64_t height = layout.height, rows_per_strip = layout.rows_per_strip;
  const uint64_t strips_per_plane = layout.strips_per_plane;
  const uint64_t bytes = volume::BytesPerSample(*ifd.dtype);
  const uint64_t row_bytes = uint64_t{ifd.width} * bytes;
  const uint64_t first = static_cast<uint64_t>(sample) * strips_per_plane;
  uint64_t start = 0;
  for (uint64_t s = 0; s < strips_per_plane; ++s) {
    const uint32_t strip = static_cast<uint32_t>(first + s);  // < TIFFNumberOfStrips.
    const uint64_t y0 = s * rows_per_strip;
    const uint64_t want = std::min(rows_per_strip, height - y0) * row_bytes;
    int err = 0;
    const uint64_t offset = TIFFGetStrileOffsetWithErr(tif, strip, &err);
    const uint64_t count = err ? 0 : TIFFGetStrileByteCountWithErr(tif, strip, &err);
    // A sparse (0, 0) strip reads as zeros, a short one is an error for ReadPlane: not mappable.
    if (err || count < want || offset == 0) return std::nullopt;
    if (s == 0) {
      start = offset;
    } else if (offset != start + y0 * row_bytes) {  // A gap, or strips out of order.
      return std::nullopt;
    }
  }
  const uint64_t plane_bytes = height * row_bytes;  // Checked at Open.
  if (start > file_size || plane_bytes > file_size - start) return std::nullopt;
  return start;
}

std::optional<uint64_t> TiffFile::StoredPlaneOffset(int index, int sample) {
  if (index < 0 || index >= ifd_count()) return std::nullopt;
  const TiffIfd& ifd = ifds_[index];
  if (!ifd.dtype || sample < 0 || sample >= ifd.samples_per_pixel) return std::nullopt;
  if (ifd.compression != COMPRESSION_NONE || ifd.tiled) return std::nullopt;
  // Chunky pixels interleave the samples: one sample's plane is not a run of the file.
  if (ifd.samples_per_pixel > 1 && ifd.planar_config != PLANARCONFIG_SEPARATE) return std::nullopt;
  const uint64_t bytes = volume::BytesPerSample(*ifd.dtype);
  if (ifd.bits_per_sample != bytes * 8) return std::nullopt;
  if (bytes > 1 && big_endian_ != (std::endian::native == std::endian::big)) return std::nullopt;
  const uint64_t key = (static_cast<uint64_t>(index) << 16) | static_cast<uint64_t>(sample);
  std::lock_guard<std::mutex> lock(mutex_);
  Impl& impl = *impl_;
  auto it = impl.stored_offsets.find(key);
  if (it == impl.stored_offsets.end()) {
    it = impl.stored_offsets
             .emplace(key,
                      impl.ContiguousPlaneOffset(path_.string(), index, ifd, sample, file_size_))
             .first;
  }
  return it->second;
}

Result<std::string> TiffFile::Description(int index, size_t max_bytes) {
  const std::string name = path_.string();
  if (index < 0 || index >= ifd_count()) {
    return OutOfRangeError(name + ": IFD " + std::to_string(index) + " requested, the file has " +
                           std::to_string(ifd_count()));
  }
  std::string_view text;
  std::lock_guard<std::mutex> lock(mutex_);
  Impl& impl = *impl_;
  if (index == 0) {
    text = ifds_[0].description;  // Kept in the index.
  } else {
    impl.sink.Clear();
    OCTO_RETURN_IF_ERROR(impl.SelectIfd(name, index, ifds_[index]));
    const char* raw = nullptr;
    if (TIFFGetField(impl.tif, TIFFTAG_IMAGEDESCRIPTION, &raw) && raw != nullptr) {
      text = std::string_view(raw, ::strnlen(raw, max_bytes + 1));
    }
  }
  if (text.size() > max_bytes) {
    return ResourceExhaustedError(name + ": IFD " + std::to_string(index) +
                                  " has an ImageDescription longer than the limit of " +
                                  std::to_string(max_bytes) + " bytes");
  }
  return std::string(text);
}

Result<uint64_t> TiffFile::ContiguousDataOffset(int index) {
  const std::string name = path_.string();
  if (index < 0 || index >= ifd_count()) {
    return OutOfRangeError(name + ": IFD " + std::to_string(index) + " requested, the file has " +
                           std::to_string(ifd_count()));
  }
  const TiffIfd& ifd = ifds_[index];
  const std::string where = name + ": IFD " + std::to_string(index);
  if (!ifd.dtype) return UnsupportedError(where + ": sample type cannot be decoded");
  if (ifd.compression != COMPRESSION_NONE || ifd.tiled) {
    return UnsupportedError(where + " is compressed or tiled, its data is not one contiguous run");
  }
  const uint64_t want = uint64_t{ifd.width} * ifd.height * ifd.samples_per_pixel *
                        volume::BytesPerSample(*ifd.dtype);  // Checked at Open.

  std::lock_guard<std::mutex> lock(mutex_);
  Impl& impl = *impl_;
  impl.sink.Clear();
  OCTO_RETURN_IF_ERROR(impl.SelectIfd(name, index, ifd));
  const uint32_t strips = TIFFNumberOfStrips(impl.tif);
  uint64_t first = 0, end = 0;
  for (uint32_t s = 0; s < strips && end - first < want; ++s) {
    int err = 0;
    const uint64_t offset = TIFFGetStrileOffsetWithErr(impl.tif, s, &err);
    const uint64_t bytes = err ? 0 : TIFFGetStrileByteCountWithErr(impl.tif, s, &err);
    if (err) return CorruptError(where + ": cannot read the offset of strip " + std::to_string(s));
    if (s == 0) {
      first = end = offset;
    } else if (offset != end) {
      return UnsupportedError(where + ": strip " + std::to_string(s) +
                              " does not follow the previous one in the file");
    }
    end = CheckedAdd(end, bytes).value_or(UINT64_MAX);
  }
  if (end - first < want) {
    return CorruptError(where + ": its strips hold " + std::to_string(end - first) + " bytes, " +
                        std::to_string(want) + " needed");
  }
  if (end > file_size_ || first + want > file_size_) {
    return CorruptError(where + ": its pixel data extends beyond the end of the file (" +
                        std::to_string(file_size_) + " bytes): the file is truncated");
  }
  return first;
}

Status TiffFile::ReadBytes(uint64_t offset, std::span<std::byte> out) const {
  const std::string name = path_.string();
  if (offset > file_size_ || out.size() > file_size_ - offset) {
    return CorruptError(name + ": bytes " + std::to_string(offset) + ".." +
                        std::to_string(offset + out.size()) + " lie beyond the end of the file (" +
                        std::to_string(file_size_) + " bytes): the file is truncated");
  }
  return ReadFully(impl_->fd, offset, out, name);
}

std::string DescribePage(const TiffIfd& ifd) {
  return std::to_string(ifd.width) + "x" + std::to_string(ifd.height) + " " +
         (ifd.dtype ? std::string(volume::NumpyName(*ifd.dtype)) : std::string("undecodable")) +
         (ifd.samples_per_pixel > 1
              ? " with " + std::to_string(ifd.samples_per_pixel) + " samples per pixel"
              : std::string());
}

bool HasTiffSignature(const std::filesystem::path& path, const FileGate& gate) {
  Result<int> fd = gate.OpenForReading(path);
  if (!fd.ok()) return false;
  const ScopedFd owned(*fd);
  std::byte head[4] = {};
  if (!ReadFully(*fd, 0, head, path.string()).ok()) return false;
  const std::string_view s(reinterpret_cast<const char*>(head), 4);
  return s == std::string_view("II*\0", 4) || s == std::string_view("MM\0*", 4) ||
         s == std::string_view("II+\0", 4) || s == std::string_view("MM\0+", 4);
}

}  // namespace octoscope::io
