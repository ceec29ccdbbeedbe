#include "io/tiff_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <string_view>
#include <system_error>
#include <unordered_set>
#include <utility>

#include "util/checked_math.h"

namespace octoscope::io {
namespace {

constexpr size_t kMaxKeptMessages = 8;

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

// Reads exactly out.size() bytes at `offset`; false on error or end of file.
bool PreadAll(int fd, uint64_t offset, std::byte* out, size_t size) {
  while (size > 0) {
    ssize_t n =
        ::pread(fd, out, std::min<size_t>(size, size_t{1} << 30), static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    out += n;
    size -= static_cast<size_t>(n);
    offset += static_cast<uint64_t>(n);
  }
  return true;
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

}  // namespace

struct TiffFile::Impl {
  // Owned by libtiff once `tif` is open (TIFFClose closes it); closed by us otherwise.
  int fd = -1;
  TIFF* tif = nullptr;
  MessageSink sink;
  int current_ifd = -1;  // The IFD libtiff has loaded; -1: unknown (after an error).
  // Scratch for one decoded strip or tile when it cannot be decoded straight into the caller's
  // buffer; freed after a read when large, so an idle file holds little memory.
  std::vector<std::byte> scratch;

  ~Impl() {
    if (tif != nullptr) {
      TIFFClose(tif);
    } else if (fd >= 0) {
      ::close(fd);
    }
  }
};

namespace {

// What messages about a strip or tile of one plane need.
struct PlaneContext {
  const std::string& name;
  int index;
  uint64_t file_size;
};

// One pread of the direct path: `bytes` file bytes at `file_offset` into the plane at `out_offset`.
struct ReadRun {
  uint64_t file_offset;
  uint64_t out_offset;
  uint64_t bytes;
};

// Swaps the byte order of every `bytes`-wide sample of `data` in place. Works on 64-bit words
// (4, 2 or 1 samples at a time) so the compiler can vectorize it; a per-sample rotate in memory
// runs at a fraction of memory speed.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("avx2", "default")))  // Twice the width where the CPU has it.
#endif
void SwapSamples(std::span<std::byte> data, size_t bytes) {
  if (bytes < 2) return;
  std::byte* p = data.data();
  const size_t words = data.size() / 8;
  for (size_t i = 0; i < words; ++i) {
    uint64_t v;
    std::memcpy(&v, p + i * 8, 8);
    if (bytes == 2) {
      v = ((v & 0x00FF00FF00FF00FFull) << 8) | ((v >> 8) & 0x00FF00FF00FF00FFull);
    } else if (bytes == 4) {
      v = ((v & 0x0000FFFF0000FFFFull) << 16) | ((v >> 16) & 0x0000FFFF0000FFFFull);
      v = ((v & 0x00FF00FF00FF00FFull) << 8) | ((v >> 8) & 0x00FF00FF00FF00FFull);
    } else {
      v = __builtin_bswap64(v);
    }
    std::memcpy(p + i * 8, &v, 8);
  }
  // A tail shorter than a word (only when the plane size is not a multiple of 8 bytes).
  for (size_t at = words * 8; at + bytes <= data.size(); at += bytes) {
    std::reverse(p + at, p + at + bytes);
  }
}

}  // namespace

TiffFile::~TiffFile() = default;

Result<std::unique_ptr<TiffFile>> TiffFile::Open(const std::filesystem::path& path,
                                                 const Limits& limits) {
  const std::string name = path.string();
  std::error_code ec;
  auto status = std::filesystem::status(path, ec);
  if (ec || !std::filesystem::exists(status)) return NotFoundError(name + ": no such file");
  if (!std::filesystem::is_regular_file(status)) {
    return InvalidArgumentError(name + ": not a regular file");
  }

  std::unique_ptr<TiffFile> file(new TiffFile());
  file->path_ = path;
  file->impl_ = std::make_unique<Impl>();
  Impl& impl = *file->impl_;

  impl.fd = ::open(name.c_str(), O_RDONLY | O_CLOEXEC);
  if (impl.fd < 0) {
    return IoError(name + ": cannot open: " + std::strerror(errno));
  }
  struct stat st;
  if (::fstat(impl.fd, &st) != 0) return IoError(name + ": cannot stat: " + std::strerror(errno));
  file->file_size_ = static_cast<uint64_t>(st.st_size);
  if (file->file_size_ == 0) return CorruptError(name + ": empty file, not a TIFF");

  std::byte header[16] = {};
  const size_t header_size = static_cast<size_t>(std::min<uint64_t>(16, file->file_size_));
  if (!PreadAll(impl.fd, 0, header, header_size)) {
    return IoError(name + ": cannot read the header: " + std::strerror(errno));
  }
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
    const char* text = nullptr;
    if (TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &text) && text != nullptr) {
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
    file->ifds_.push_back(std::move(ifd));

    // Find the next IFD offset: after the entry count and the entries.
    const uint64_t at = file->ifds_.back().offset;
    std::byte count_bytes[8];
    if (!PreadAll(impl.fd, at, count_bytes, count_size)) {
      return CorruptError(where + " at offset " + std::to_string(at) + " is truncated");
    }
    const uint64_t entries = LoadN(count_bytes, count_size, big);
    const std::optional<uint64_t> next_at =
        CheckedAdd(at + count_size, CheckedMul(entries, entry_size).value_or(UINT64_MAX));
    std::byte next_bytes[8];
    if (!next_at || !PreadAll(impl.fd, *next_at, next_bytes, pointer_size)) {
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
  impl.current_ifd = file->ifd_count() - 1;
  impl.sink.Clear();
  return file;
}

namespace {

// Checks that strile (strip or tile) `strile` lies inside the file. Sets `sparse` when the file
// leaves it out on purpose (offset and byte count 0, GDAL's convention for an all-zero block).
Status CheckStrile(TIFF* tif, const PlaneContext& c, const char* kind, uint32_t strile,
                   uint64_t min_bytes, bool* sparse, uint64_t* offset_out = nullptr) {
  int err = 0;
  const uint64_t offset = TIFFGetStrileOffsetWithErr(tif, strile, &err);
  if (offset_out != nullptr) *offset_out = offset;
  const uint64_t bytes = err ? 0 : TIFFGetStrileByteCountWithErr(tif, strile, &err);
  const std::string where =
      c.name + ": IFD " + std::to_string(c.index) + " " + kind + " " + std::to_string(strile);
  if (err) return CorruptError(where + ": cannot read its offset or byte count");
  *sparse = offset == 0 && bytes == 0;
  if (*sparse) return Status::Ok();
  if (bytes == 0) return CorruptError(where + " is empty (byte count 0)");
  if (offset > c.file_size || bytes > c.file_size - offset) {
    return CorruptError(where + " (bytes " + std::to_string(offset) + ".." +
                        std::to_string(offset + bytes) + ") extends beyond the end of the file (" +
                        std::to_string(c.file_size) + " bytes): the file is truncated");
  }
  if (bytes < min_bytes) {
    return CorruptError(where + " holds " + std::to_string(bytes) +
                        " bytes of uncompressed data, " + std::to_string(min_bytes) + " needed");
  }
  return Status::Ok();
}

Status DecodeError(const PlaneContext& c, const char* kind, uint32_t strile, tmsize_t got,
                   uint64_t want, const MessageSink& sink) {
  std::string message =
      c.name + ": IFD " + std::to_string(c.index) + " " + kind + " " + std::to_string(strile);
  if (got < 0) {
    message += ": decoding failed";
  } else if (static_cast<uint64_t>(got) == want) {
    message += ": decoding reported errors";
  } else {
    message +=
        " decoded to " + std::to_string(got) + " bytes, " + std::to_string(want) + " expected";
  }
  return CorruptError(Join(message, sink.Describe()));
}

}  // namespace

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

  std::unique_lock<std::mutex> lock(mutex_);
  Impl& impl = *impl_;
  TIFF* tif = impl.tif;
  impl.sink.Clear();
  const PlaneContext c{name, index, file_size_};
  if (impl.current_ifd != index) {
    impl.current_ifd = -1;
    if (!TIFFSetSubDirectory(tif, ifd.offset)) {
      return CorruptError(
          Join(name + ": cannot reload IFD " + std::to_string(index), impl.sink.Describe()));
    }
    if (ifd.compression == COMPRESSION_JPEG && ifd.photometric == PHOTOMETRIC_YCBCR) {
      // Let libjpeg convert to RGB instead of handing out subsampled YCbCr.
      TIFFSetField(tif, TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB);
    }
    impl.current_ifd = index;
  }
  uint32_t depth = 1;
  TIFFGetFieldDefaulted(tif, TIFFTAG_IMAGEDEPTH, &depth);
  if (depth > 1) {
    return UnsupportedError(name + ": IFD " + std::to_string(index) + " is a 3-D (ImageDepth " +
                            std::to_string(depth) + ") image");
  }

  const bool chunky = ifd.planar_config != PLANARCONFIG_SEPARATE && ifd.samples_per_pixel > 1;
  const int spp = ifd.samples_per_pixel;
  const uint64_t per_pixel = chunky ? static_cast<uint64_t>(spp) : 1;
  const uint64_t pixel_bytes = per_pixel * bytes;
  const uint16_t plane_sample = chunky ? 0 : static_cast<uint16_t>(sample);
  const bool uncompressed = ifd.compression == COMPRESSION_NONE;
  Status result = Status::Ok();

  if (!ifd.tiled) {
    uint32_t rows_per_strip = 0;
    TIFFGetFieldDefaulted(tif, TIFFTAG_ROWSPERSTRIP, &rows_per_strip);
    if (rows_per_strip == 0 || rows_per_strip > ifd.height) rows_per_strip = ifd.height;
    const uint32_t strips_per_plane = (ifd.height + rows_per_strip - 1) / rows_per_strip;
    const uint32_t first = plane_sample * strips_per_plane;
    const uint64_t strips = TIFFNumberOfStrips(tif);
    if (uint64_t{first} + strips_per_plane > strips) {
      return CorruptError(name + ": IFD " + std::to_string(index) + " has " +
                          std::to_string(strips) + " strips, " +
                          std::to_string(uint64_t{first} + strips_per_plane) + " needed");
    }
    const uint64_t row_bytes = uint64_t{ifd.width} * pixel_bytes;
    uint16_t fill_order = FILLORDER_MSB2LSB;
    TIFFGetFieldDefaulted(tif, TIFFTAG_FILLORDER, &fill_order);
    if (uncompressed && !chunky && fill_order == FILLORDER_MSB2LSB) {
      // Direct path: pread the strips straight into `out`, merging strips that follow each other
      // in the file into one read, then swap bytes if needed. Only the strip table needs libtiff,
      // so the lock is released before the (possibly long) reads.
      std::vector<ReadRun> runs;
      for (uint32_t s = 0; s < strips_per_plane; ++s) {
        const uint32_t strip = first + s;
        const uint32_t y0 = s * rows_per_strip;
        const uint64_t want = std::min(rows_per_strip, ifd.height - y0) * row_bytes;
        const uint64_t at = uint64_t{y0} * row_bytes;
        bool sparse = false;
        uint64_t offset = 0;
        Status st = CheckStrile(tif, c, "strip", strip, want, &sparse, &offset);
        if (!st.ok()) {
          impl.current_ifd = -1;
          return st;
        }
        if (sparse) {
          std::memset(out.data() + at, 0, want);
        } else if (!runs.empty() && runs.back().file_offset + runs.back().bytes == offset &&
                   runs.back().out_offset + runs.back().bytes == at) {
          runs.back().bytes += want;
        } else {
          runs.push_back({offset, at, want});
        }
      }
      lock.unlock();
      const bool swap = bytes > 1 && big_endian_ != (std::endian::native == std::endian::big);
      // When swapping, read 1 MiB at a time and swap it while it is still in cache.
      const uint64_t chunk = swap ? uint64_t{1} << 20 : UINT64_MAX;
      for (const ReadRun& run : runs) {
        for (uint64_t done = 0; done < run.bytes; done += chunk) {
          std::span<std::byte> piece =
              out.subspan(run.out_offset + done, std::min(chunk, run.bytes - done));
          OCTO_RETURN_IF_ERROR(ReadBytes(run.file_offset + done, piece));
          if (swap) SwapSamples(piece, bytes);
        }
      }
      return Status::Ok();
    }
    for (uint32_t s = 0; s < strips_per_plane && result.ok(); ++s) {
      const uint32_t strip = first + s;
      const uint32_t y0 = s * rows_per_strip;
      const uint32_t rows = std::min(rows_per_strip, ifd.height - y0);
      const uint64_t want = rows * row_bytes;
      std::byte* dst = out.data() + uint64_t{y0} * ifd.width * bytes;
      bool sparse = false;
      result = CheckStrile(tif, c, "strip", strip, uncompressed ? want : 0, &sparse);
      if (!result.ok()) break;
      if (sparse) {
        std::memset(dst, 0, uint64_t{rows} * ifd.width * bytes);
        continue;
      }
      // One sample per pixel: decode straight into the caller's buffer (for uncompressed data
      // libtiff then read()s the strip there, with no copy at all).
      std::byte* target = dst;
      if (chunky) {
        impl.scratch.resize(want);
        target = impl.scratch.data();
      }
      const tmsize_t got = TIFFReadEncodedStrip(tif, strip, target, static_cast<tmsize_t>(want));
      if (got != static_cast<tmsize_t>(want) || !impl.sink.errors.empty()) {
        result = DecodeError(c, "strip", strip, got, want, impl.sink);
        break;
      }
      if (chunky) {
        ExtractSample(target, spp, sample, bytes, uint64_t{rows} * ifd.width, dst);
      }
    }
  } else {
    uint32_t tile_width = 0, tile_height = 0;
    TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tile_width);
    TIFFGetField(tif, TIFFTAG_TILELENGTH, &tile_height);
    const std::string where = name + ": IFD " + std::to_string(index);
    if (tile_width == 0 || tile_height == 0) {
      return CorruptError(where + " declares " + std::to_string(tile_width) + "x" +
                          std::to_string(tile_height) + " tiles");
    }
    const std::optional<uint64_t> tile_bytes =
        CheckedProduct({tile_width, tile_height, pixel_bytes});
    const uint64_t max_tile = CheckedMul(plane_bytes, per_pixel).value_or(UINT64_MAX);
    // A tile may exceed the plane (edge padding) but not absurdly: cap it at 4 planes + 1 MiB.
    if (!tile_bytes || *tile_bytes > CheckedMul(max_tile, 4).value_or(UINT64_MAX) + (1u << 20)) {
      return CorruptError(where + " declares " + std::to_string(tile_width) + "x" +
                          std::to_string(tile_height) + " tiles, far larger than its image");
    }
    if (static_cast<uint64_t>(TIFFTileSize64(tif)) != *tile_bytes) {
      return UnsupportedError(where + ": tile layout not understood (libtiff tile size " +
                              std::to_string(TIFFTileSize64(tif)) + " bytes, expected " +
                              std::to_string(*tile_bytes) + ")");
    }
    impl.scratch.resize(*tile_bytes);
    const uint64_t tile_row_bytes = uint64_t{tile_width} * pixel_bytes;
    for (uint32_t ty = 0; ty < ifd.height && result.ok(); ty += tile_height) {
      for (uint32_t tx = 0; tx < ifd.width && result.ok(); tx += tile_width) {
        const uint32_t tile = TIFFComputeTile(tif, tx, ty, 0, plane_sample);
        const uint32_t rows = std::min(tile_height, ifd.height - ty);
        const uint32_t cols = std::min(tile_width, ifd.width - tx);
        bool sparse = false;
        result = CheckStrile(tif, c, "tile", tile, uncompressed ? *tile_bytes : 0, &sparse);
        if (!result.ok()) break;
        if (sparse) {
          for (uint32_t y = 0; y < rows; ++y) {
            std::memset(out.data() + ((uint64_t{ty} + y) * ifd.width + tx) * bytes, 0,
                        uint64_t{cols} * bytes);
          }
          continue;
        }
        const tmsize_t got =
            TIFFReadEncodedTile(tif, tile, impl.scratch.data(), static_cast<tmsize_t>(*tile_bytes));
        if (got != static_cast<tmsize_t>(*tile_bytes) || !impl.sink.errors.empty()) {
          result = DecodeError(c, "tile", tile, got, *tile_bytes, impl.sink);
          break;
        }
        // Crop the tile at the right and bottom edges of the image.
        for (uint32_t y = 0; y < rows; ++y) {
          const std::byte* src = impl.scratch.data() + y * tile_row_bytes;
          std::byte* dst = out.data() + ((uint64_t{ty} + y) * ifd.width + tx) * bytes;
          if (chunky) {
            ExtractSample(src, spp, sample, bytes, cols, dst);
          } else {
            std::memcpy(dst, src, uint64_t{cols} * bytes);
          }
        }
      }
    }
  }
  if (impl.scratch.size() > (size_t{64} << 20)) {
    impl.scratch = std::vector<std::byte>();  // Do not keep a huge scratch buffer around.
  }
  // After a failure libtiff's per-directory state may be off; reload the IFD next time.
  if (!result.ok()) impl.current_ifd = -1;
  return result;
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
  if (impl.current_ifd != index) {
    impl.current_ifd = -1;
    if (!TIFFSetSubDirectory(impl.tif, ifd.offset)) {
      return CorruptError(
          Join(name + ": cannot reload IFD " + std::to_string(index), impl.sink.Describe()));
    }
    impl.current_ifd = index;
  }
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
  errno = 0;
  if (!PreadAll(impl_->fd, offset, out.data(), out.size())) {
    return IoError(name + ": read of " + std::to_string(out.size()) + " bytes at offset " +
                   std::to_string(offset) + " failed" +
                   (errno != 0 ? std::string(": ") + std::strerror(errno) : std::string()));
  }
  return Status::Ok();
}

bool HasTiffSignature(const std::filesystem::path& path) {
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  std::byte head[4] = {};
  const bool read = PreadAll(fd, 0, head, sizeof(head));
  ::close(fd);
  if (!read) return false;
  const std::string_view s(reinterpret_cast<const char*>(head), 4);
  return s == std::string_view("II*\0", 4) || s == std::string_view("MM\0*", 4) ||
         s == std::string_view("II+\0", 4) || s == std::string_view("MM\0+", 4);
}

}  // namespace octoscope::io
