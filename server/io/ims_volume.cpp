#include "io/ims_volume.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "io/chunk_codecs.h"
#include "io/chunked_volume.h"
#include "io/file_gate.h"
#include "io/hdf5_call.h"
#include "io/ome_xml.h"
#include "io/spacing.h"
#include "util/byte_swap.h"
#include "util/checked_math.h"
#include "util/file_reading.h"
#include "util/strings.h"
#include "util/uninitialized_bytes.h"
#include "volume/volume_info.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

constexpr int kMaxLevels = 64;
constexpr int64_t kMaxTimePoints = int64_t{1} << 24;
constexpr int64_t kMaxAttributeElements = 1 << 16;
constexpr uint64_t kMaxAttributeBytes = uint64_t{1} << 20;
// Contiguous (unchunked) datasets are read in virtual chunks of whole planes, about this large.
constexpr uint64_t kContiguousChunkBytes = uint64_t{16} << 20;
constexpr H5Z_filter_t kLz4Filter = 32004;  // The HDF5 LZ4 plugin's registered id.

std::string Num(int64_t v) { return std::to_string(v); }

// How the reader follows paths inside the file. Confined (a dataset's FileGate), a path through an
// external link — which would open another file — fails and refused() says so; else HDF5's
// defaults. Datasets stored in other files (external storage, virtual datasets) are refused when
// confined too (OpenChannel).
class LinkAccess {
 public:
  static Result<LinkAccess> Make(bool confined) {
    LinkAccess access;
    if (!confined) return access;
    const std::pair<hid_t, Hdf5Id*> lists[] = {{H5P_LINK_ACCESS, &access.links_},
                                               {H5P_GROUP_ACCESS, &access.groups_},
                                               {H5P_DATASET_ACCESS, &access.datasets_}};
    for (const auto& [kind, list] : lists) {
      OCTO_ASSIGN_OR_RETURN(hid_t id, OCTO_H5(H5Pcreate(kind)));
      *list = Hdf5Id(id);
      OCTO_RETURN_IF_ERROR(
          OCTO_H5(H5Pset_elink_cb(id, &RefuseExternal, access.refused_.get())).status());
    }
    return access;
  }

  bool confined() const { return links_.valid(); }
  // Property lists for H5Lexists / H5A*_by_name, H5Gopen2, H5Dopen2.
  hid_t links() const { return confined() ? links_.get() : H5P_DEFAULT; }
  hid_t groups() const { return confined() ? groups_.get() : H5P_DEFAULT; }
  hid_t datasets() const { return confined() ? datasets_.get() : H5P_DEFAULT; }
  // An external link was met (and not followed).
  bool refused() const { return *refused_; }

 private:
  static herr_t RefuseExternal(const char*, const char*, const char*, const char*, unsigned*, hid_t,
                               void* refused) {
    *static_cast<bool*>(refused) = true;
    return -1;
  }

  Hdf5Id links_, groups_, datasets_;
  std::unique_ptr<bool> refused_ = std::make_unique<bool>(false);  // The callbacks' target.
};

bool LinkExists(hid_t loc, const std::string& path, const LinkAccess& access) {
  const htri_t r = H5Lexists(loc, path.c_str(), access.links());
  if (r < 0) H5Eclear2(H5E_DEFAULT);
  return r > 0;
}

// Clears the error stack a failed attribute lookup left; the attribute counts as absent.
std::optional<std::string> NoAttribute() {
  H5Eclear2(H5E_DEFAULT);
  return std::nullopt;
}

// The text of attribute `attr` of the object at `object` (relative to `loc`): char arrays are
// joined (Imaris's "array of single characters"), fixed and variable-length strings read as such,
// a single number formatted. nullopt when absent, empty-typed, oversized or of another kind.
std::optional<std::string> TextAttribute(hid_t loc, const std::string& object, const char* attr,
                                         const LinkAccess& access) {
  if (!LinkExists(loc, object, access) && object != ".") return std::nullopt;
  const htri_t exists = H5Aexists_by_name(loc, object.c_str(), attr, access.links());
  if (exists <= 0) return NoAttribute();
  Hdf5Id a(H5Aopen_by_name(loc, object.c_str(), attr, H5P_DEFAULT, access.links()));
  if (!a.valid()) return NoAttribute();
  Hdf5Id type(H5Aget_type(a.get()));
  Hdf5Id space(H5Aget_space(a.get()));
  if (!type.valid() || !space.valid()) return NoAttribute();
  const hssize_t n = H5Sget_simple_extent_npoints(space.get());
  if (n < 1 || n > kMaxAttributeElements) return NoAttribute();
  const H5T_class_t cls = H5Tget_class(type.get());
  if (cls == H5T_STRING) {
    if (H5Tis_variable_str(type.get()) > 0) {
      if (n != 1) return std::nullopt;
      Hdf5Id mem(H5Tcopy(H5T_C_S1));
      char* text = nullptr;
      // The memory type takes the file's character set (HDF5 converts none between them).
      if (!mem.valid() || H5Tset_size(mem.get(), H5T_VARIABLE) < 0 ||
          H5Tset_cset(mem.get(), H5Tget_cset(type.get())) < 0 ||
          H5Aread(a.get(), mem.get(), &text) < 0) {
        return NoAttribute();
      }
      std::string out = text != nullptr ? std::string(text) : std::string();
      H5free_memory(text);
      return out;
    }
    const size_t size = H5Tget_size(type.get());
    if (size == 0 ||
        CheckedMul(size, static_cast<uint64_t>(n)).value_or(UINT64_MAX) > kMaxAttributeBytes) {
      return std::nullopt;
    }
    // Read with the file's own type (no conversion): each element's bytes up to its first NUL.
    std::vector<char> bytes(size * static_cast<size_t>(n));
    if (H5Aread(a.get(), type.get(), bytes.data()) < 0) return NoAttribute();
    std::string out;
    for (hssize_t i = 0; i < n; ++i) {
      const char* e = bytes.data() + static_cast<size_t>(i) * size;
      out.append(e, strnlen(e, size));
    }
    return out;
  }
  if ((cls == H5T_INTEGER || cls == H5T_FLOAT) && n == 1) {
    double v = 0;
    if (H5Aread(a.get(), H5T_NATIVE_DOUBLE, &v) < 0) return NoAttribute();
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return std::string(buf);
  }
  return std::nullopt;
}

std::optional<double> NumberAttribute(hid_t loc, const std::string& object, const char* attr,
                                      const LinkAccess& access) {
  std::optional<std::string> text = TextAttribute(loc, object, attr, access);
  if (!text) return std::nullopt;
  std::optional<double> v = ParseDouble(TrimWhitespace(*text));
  if (v && !std::isfinite(*v)) return std::nullopt;
  return v;
}

// Whitespace-separated numbers ("1.000 0.000 0.000", "0 247").
std::vector<double> NumberList(std::string_view text) {
  std::vector<double> out;
  for (std::string_view part : Split(text, ' ')) {
    part = TrimWhitespace(part);
    if (part.empty()) continue;
    std::optional<double> v = ParseDouble(part);
    if (!v || !std::isfinite(*v)) return {};
    out.push_back(*v);
  }
  return out;
}

// Counts "<prefix>0", "<prefix>1", … under `group` (at most the group's link count).
int64_t CountNumbered(hid_t file, const std::string& group, const std::string& prefix,
                      int64_t limit, const LinkAccess& access) {
  Hdf5Id g(H5Gopen2(file, group.c_str(), access.groups()));
  H5G_info_t info;
  if (!g.valid() || H5Gget_info(g.get(), &info) < 0) {
    H5Eclear2(H5E_DEFAULT);  // A missing group holds nothing.
    return 0;
  }
  const int64_t links = static_cast<int64_t>(std::min<hsize_t>(info.nlinks, limit + 1));
  int64_t n = 0;
  while (n < links && LinkExists(g.get(), prefix + std::to_string(n), access)) ++n;
  return n;
}

Result<volume::DataType> SampleTypeOf(hid_t type, const std::string& where, bool& big_endian) {
  const H5T_class_t cls = H5Tget_class(type);
  const size_t size = H5Tget_size(type);
  big_endian = H5Tget_order(type) == H5T_ORDER_BE;
  if (cls == H5T_INTEGER) {
    const bool is_signed = H5Tget_sign(type) == H5T_SGN_2;
    if (size == 1) return is_signed ? volume::DataType::kInt8 : volume::DataType::kUint8;
    if (size == 2) return is_signed ? volume::DataType::kInt16 : volume::DataType::kUint16;
    if (size == 4) return is_signed ? volume::DataType::kInt32 : volume::DataType::kUint32;
  } else if (cls == H5T_FLOAT) {
    if (size == 4) return volume::DataType::kFloat32;
    if (size == 8) return volume::DataType::kFloat64;
  }
  H5Eclear2(H5E_DEFAULT);
  return UnsupportedError(where + ": sample type of class " + Num(cls) + ", " + Num(size) +
                          " bytes (supported: 8/16/32-bit integers, 32/64-bit floats)");
}

hid_t NativeType(volume::DataType t) {
  switch (t) {
    case volume::DataType::kUint8:
      return H5T_NATIVE_UINT8;
    case volume::DataType::kInt8:
      return H5T_NATIVE_INT8;
    case volume::DataType::kUint16:
      return H5T_NATIVE_UINT16;
    case volume::DataType::kInt16:
      return H5T_NATIVE_INT16;
    case volume::DataType::kUint32:
      return H5T_NATIVE_UINT32;
    case volume::DataType::kInt32:
      return H5T_NATIVE_INT32;
    case volume::DataType::kFloat32:
      return H5T_NATIVE_FLOAT;
    case volume::DataType::kFloat64:
      return H5T_NATIVE_DOUBLE;
  }
  return H5T_NATIVE_UINT8;
}

// One channel's dataset at the selected level and time point.
struct ChannelData {
  Hdf5Id dataset;
  std::array<hsize_t, 3> dims{};       // z, y, x of the stored (possibly padded) array.
  bool direct = false;                 // Raw chunk reads + our decoders.
  std::vector<H5Z_filter_t> filters;   // Pipeline order (encoding order).
  std::vector<unsigned> shuffle_size;  // Shuffle element size per filter (0 for others).
};

class ImarisChunkReader final : public ChunkReader {
 public:
  ImarisChunkReader(std::string name, Hdf5Id file, std::vector<ChannelData> channels,
                    std::array<hsize_t, 3> chunk, volume::DataType dtype, bool big_endian)
      : name_(std::move(name)),
        file_(std::move(file)),
        channels_(std::move(channels)),
        chunk_(chunk),
        dtype_(dtype),
        big_endian_(big_endian) {}

  ~ImarisChunkReader() override {
    Hdf5Quiet();
    channels_.clear();  // Datasets before the file.
  }

  Result<bool> ReadChunk(std::span<const int64_t> index, std::span<std::byte> out) override {
    Hdf5Quiet();
    const ChannelData& ch = channels_[static_cast<size_t>(index[0])];
    const std::array<hsize_t, 3> offset = {static_cast<hsize_t>(index[1]) * chunk_[0],
                                           static_cast<hsize_t>(index[2]) * chunk_[1],
                                           static_cast<hsize_t>(index[3]) * chunk_[2]};
    const std::string where = name_ + ": channel " + Num(index[0]) + " chunk at z " +
                              Num(static_cast<int64_t>(offset[0])) + ", y " +
                              Num(static_cast<int64_t>(offset[1])) + ", x " +
                              Num(static_cast<int64_t>(offset[2]));
    if (ch.direct) return ReadDirect(ch, offset, out, where);
    OCTO_RETURN_IF_ERROR(ReadThroughHdf5(ch, offset, out).WithContext(where));
    return true;
  }

 private:
  // The stored chunk, fetched raw and decoded here (on the calling thread, outside HDF5's lock).
  Result<bool> ReadDirect(const ChannelData& ch, const std::array<hsize_t, 3>& offset,
                          std::span<std::byte> out, const std::string& where) {
    hsize_t stored = 0;
    if (H5Dget_chunk_storage_size(ch.dataset.get(), offset.data(), &stored) < 0) {
      // HDF5 1.10 reports a chunk that was never written as an error here: it reads as fill.
      H5Eclear2(H5E_DEFAULT);
      return false;
    }
    if (stored == 0) return false;
    if (stored > out.size() + out.size() / 16 + 4096) {
      return CorruptError(where + ": stored chunk of " + Num(static_cast<int64_t>(stored)) +
                          " bytes, far more than its " + Num(static_cast<int64_t>(out.size())) +
                          " decoded bytes");
    }
    UninitializedBytes raw(static_cast<size_t>(stored));
    uint32_t skipped = 0;  // Bit i set: filter i was not applied to this chunk.
    OCTO_RETURN_IF_ERROR(
        OCTO_H5(H5Dread_chunk(ch.dataset.get(), H5P_DEFAULT, offset.data(), &skipped, raw.data()))
            .status()
            .WithContext(where));
    UninitializedBytes scratch;
    std::span<const std::byte> cur = raw;
    for (size_t k = ch.filters.size(); k-- > 0;) {
      if (skipped & (1u << k)) continue;
      // Every supported filter decodes to the chunk's full size.
      UninitializedBytes next(out.size());
      Status s;
      if (ch.filters[k] == H5Z_FILTER_DEFLATE) {
        s = DecodeChunk(ChunkCodec::kZlib, cur, next);
      } else if (ch.filters[k] == kLz4Filter) {
        s = DecodeChunk(ChunkCodec::kHdf5Lz4, cur, next);
      } else {  // H5Z_FILTER_SHUFFLE
        if (cur.size() != next.size()) {
          s = CorruptError("shuffled chunk holds " + Num(static_cast<int64_t>(cur.size())) +
                           " bytes, expected " + Num(static_cast<int64_t>(next.size())));
        } else {
          Unshuffle(cur, std::max(1u, ch.shuffle_size[k]), next);
        }
      }
      if (!s.ok()) return s.WithContext(where);
      scratch = std::move(next);
      cur = scratch;
    }
    if (cur.size() != out.size()) {
      return CorruptError(where + ": chunk holds " + Num(static_cast<int64_t>(cur.size())) +
                          " bytes, expected " + Num(static_cast<int64_t>(out.size())));
    }
    std::memcpy(out.data(), cur.data(), out.size());
    if (big_endian_ != (std::endian::native == std::endian::big)) {
      SwapBytesInPlace(out, volume::BytesPerSample(dtype_));
    }
    return true;
  }

  // Any other pipeline (and contiguous data): HDF5 reads and decodes the chunk's region of the
  // stored array (clipped to it) into the chunk-shaped buffer, converting to native order.
  Status ReadThroughHdf5(const ChannelData& ch, const std::array<hsize_t, 3>& offset,
                         std::span<std::byte> out) {
    std::array<hsize_t, 3> count;
    for (int d = 0; d < 3; ++d) count[d] = std::min(chunk_[d], ch.dims[d] - offset[d]);
    const std::array<hsize_t, 3> zero = {0, 0, 0};
    OCTO_ASSIGN_OR_RETURN(hid_t fs, OCTO_H5(H5Dget_space(ch.dataset.get())));
    Hdf5Id file_space(fs);
    OCTO_RETURN_IF_ERROR(OCTO_H5(H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET,
                                                     offset.data(), nullptr, count.data(), nullptr))
                             .status());
    OCTO_ASSIGN_OR_RETURN(hid_t ms, OCTO_H5(H5Screate_simple(3, chunk_.data(), nullptr)));
    Hdf5Id mem_space(ms);
    OCTO_RETURN_IF_ERROR(OCTO_H5(H5Sselect_hyperslab(mem_space.get(), H5S_SELECT_SET, zero.data(),
                                                     nullptr, count.data(), nullptr))
                             .status());
    return OCTO_H5(H5Dread(ch.dataset.get(), NativeType(dtype_), mem_space.get(), file_space.get(),
                           H5P_DEFAULT, out.data()))
        .status();
  }

  const std::string name_;
  Hdf5Id file_;
  std::vector<ChannelData> channels_;
  const std::array<hsize_t, 3> chunk_;  // z, y, x.
  const volume::DataType dtype_;
  const bool big_endian_;
};

// Opens and checks one channel's dataset; fills `dtype`, `chunk` on the first channel and checks
// the others against them.
Status OpenChannel(hid_t file, const std::string& path, const std::string& name, ChannelData& ch,
                   volume::DataType& dtype, bool& big_endian, std::array<hsize_t, 3>& chunk,
                   bool first, const LinkAccess& access) {
  const std::string where = name + ": " + path;
  if (!LinkExists(file, path, access)) return CorruptError(where + ": dataset missing");
  OCTO_ASSIGN_OR_RETURN(hid_t ds, OCTO_H5(H5Dopen2(file, path.c_str(), access.datasets())));
  ch.dataset = Hdf5Id(ds);
  OCTO_ASSIGN_OR_RETURN(hid_t pl, OCTO_H5(H5Dget_create_plist(ds)));
  Hdf5Id dcpl(pl);
  const H5D_layout_t layout = H5Pget_layout(dcpl.get());
  // Data kept in other files (external storage, a virtual dataset's sources), refused before
  // anything (such as its extent) could make HDF5 open them.
  if (access.confined() && (layout == H5D_VIRTUAL || H5Pget_external_count(dcpl.get()) != 0)) {
    H5Eclear2(H5E_DEFAULT);
    return OutsideFolderError();
  }
  OCTO_ASSIGN_OR_RETURN(hid_t sp, OCTO_H5(H5Dget_space(ds)));
  Hdf5Id space(sp);
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank != 3) {
    H5Eclear2(H5E_DEFAULT);
    return CorruptError(where + ": a " + Num(rank) + "-D dataset, Imaris data is 3-D (z, y, x)");
  }
  OCTO_RETURN_IF_ERROR(
      OCTO_H5(H5Sget_simple_extent_dims(space.get(), ch.dims.data(), nullptr)).status());
  OCTO_ASSIGN_OR_RETURN(hid_t ty, OCTO_H5(H5Dget_type(ds)));
  Hdf5Id type(ty);
  bool be = false;
  OCTO_ASSIGN_OR_RETURN(volume::DataType t, SampleTypeOf(type.get(), where, be));
  std::array<hsize_t, 3> ch_chunk;
  if (layout == H5D_CHUNKED) {
    if (H5Pget_chunk(dcpl.get(), 3, ch_chunk.data()) != 3) {
      H5Eclear2(H5E_DEFAULT);
      return CorruptError(where + ": chunk dims are not 3-D");
    }
    const int n = H5Pget_nfilters(dcpl.get());
    bool direct = n >= 0;
    for (int i = 0; i < n; ++i) {
      unsigned flags = 0, config = 0;
      size_t nvalues = 4;
      unsigned values[4] = {0, 0, 0, 0};
      const H5Z_filter_t id = H5Pget_filter2(dcpl.get(), static_cast<unsigned>(i), &flags, &nvalues,
                                             values, 0, nullptr, &config);
      ch.filters.push_back(id);
      ch.shuffle_size.push_back(id == H5Z_FILTER_SHUFFLE && nvalues >= 1 ? values[0] : 0);
      direct = direct && (id == H5Z_FILTER_DEFLATE || id == H5Z_FILTER_SHUFFLE || id == kLz4Filter);
    }
    if (n < 0) H5Eclear2(H5E_DEFAULT);
    ch.direct = direct && ch.filters.size() <= 32;
  } else {
    // Contiguous or compact: virtual chunks of whole planes.
    const uint64_t plane = ch.dims[1] * ch.dims[2] * volume::BytesPerSample(t);
    ch_chunk = {std::clamp<hsize_t>(kContiguousChunkBytes / std::max<uint64_t>(plane, 1), 1,
                                    std::max<hsize_t>(ch.dims[0], 1)),
                ch.dims[1], ch.dims[2]};
    ch.direct = false;
  }
  for (hsize_t c : ch_chunk) {
    if (c == 0) return CorruptError(where + ": a chunk dimension is 0");
  }
  if (first) {
    dtype = t;
    big_endian = be;
    chunk = ch_chunk;
  } else if (t != dtype || ch_chunk != chunk) {
    return UnsupportedError(where + ": channels differ in sample type or chunk shape");
  }
  return Status::Ok();
}

std::optional<volume::Rgba> ImarisColor(std::string_view text) {
  std::vector<double> rgb = NumberList(text);
  if (rgb.size() < 3) return std::nullopt;
  // Imaris writes fractions 0..1; tolerate 0..255.
  const bool fractions = std::max({rgb[0], rgb[1], rgb[2]}) <= 1.0;
  volume::Rgba c;
  uint8_t* parts[3] = {&c.r, &c.g, &c.b};
  for (int k = 0; k < 3; ++k) {
    const double v = fractions ? rgb[k] * 255.0 : rgb[k];
    if (v < 0 || v > 255) return std::nullopt;
    *parts[k] = static_cast<uint8_t>(std::lround(v));
  }
  return c;
}

// The HDF5 signature at byte 0 or after a user block of 512, 1024, 2048, … bytes of `fd`.
bool HasHdf5SignatureAt(int fd) {
  static constexpr unsigned char kSignature[8] = {0x89, 'H', 'D', 'F', '\r', '\n', 0x1a, '\n'};
  bool found = false;
  for (off_t at = 0; at <= (off_t{1} << 16) && !found; at = at == 0 ? 512 : at * 2) {
    unsigned char buf[8];
    if (::pread(fd, buf, 8, at) != 8) break;
    found = std::memcmp(buf, kSignature, 8) == 0;
  }
  return found;
}

// OpenImaris on the open `file`, followed as `access` says.
Result<std::unique_ptr<VolumeSource>> OpenFile(Hdf5Id file, const std::string& name,
                                               const OpenOptions& options,
                                               const LinkAccess& access) {
  const hid_t f = file.get();
  if (!LinkExists(f, "DataSet", access)) {
    return CorruptError(name + ": an HDF5 file without the Imaris group /DataSet");
  }

  // Levels, time points and channels are numbered groups.
  const int64_t levels = CountNumbered(f, "DataSet", "ResolutionLevel ", kMaxLevels, access);
  if (levels == 0) return CorruptError(name + ": /DataSet holds no \"ResolutionLevel 0\"");
  if (options.level < 0 || options.level >= levels) {
    return OutOfRangeError(name + ": resolution level " + Num(options.level) +
                           " asked for, the file has " + Num(levels) + " (0 .. " + Num(levels - 1) +
                           ")");
  }
  const std::string level = "DataSet/ResolutionLevel " + Num(options.level);
  const int64_t times = CountNumbered(f, level, "TimePoint ", kMaxTimePoints, access);
  if (times == 0) return CorruptError(name + ": /" + level + " holds no \"TimePoint 0\"");
  if (times > kMaxTimePoints) {
    return ResourceExhaustedError(name + ": more than " + Num(kMaxTimePoints) + " time points");
  }
  if (options.time < 0 || options.time >= times) {
    return OutOfRangeError(name + ": time point " + Num(options.time) +
                           " asked for, the file has " + Num(times));
  }
  if (options.series != 0) {
    return OutOfRangeError(name + ": an Imaris file holds one series (asked for " +
                           Num(options.series) + ")");
  }
  const std::string time = level + "/TimePoint " + Num(options.time);
  // Counted up to one past the limit: a file with more channels is refused before they size
  // anything.
  const int64_t channels = CountNumbered(f, time, "Channel ", volume::kMaxChannels, access);
  if (channels == 0) return CorruptError(name + ": /" + time + " holds no \"Channel 0\"");
  if (channels > volume::kMaxChannels) {
    return ResourceExhaustedError(name + ": /" + time + " holds more than " +
                                  Num(volume::kMaxChannels) +
                                  " channels, the most Octoscope supports");
  }

  std::vector<ChannelData> data(static_cast<size_t>(channels));
  volume::DataType dtype = volume::DataType::kUint8;
  bool big_endian = false;
  std::array<hsize_t, 3> chunk{};
  for (int64_t c = 0; c < channels; ++c) {
    OCTO_RETURN_IF_ERROR(OpenChannel(f, time + "/Channel " + Num(c) + "/Data", name,
                                     data[static_cast<size_t>(c)], dtype, big_endian, chunk, c == 0,
                                     access));
    if (data[static_cast<size_t>(c)].dims != data[0].dims) {
      return CorruptError(name + ": channel " + Num(c) +
                          "'s data array differs in size from "
                          "channel 0's");
    }
  }

  // The image size: the level's ImageSize attributes, else (level 0) /DataSetInfo/Image X/Y/Z,
  // else the data array itself. The array may be larger (padding), never smaller.
  volume::VolumeInfo info;
  info.format = "imaris";
  const std::string channel0 = time + "/Channel 0";
  const char* kSizeAttrs[3] = {"ImageSizeX", "ImageSizeY", "ImageSizeZ"};
  const char* kInfoSize[3] = {"X", "Y", "Z"};
  for (int a = 0; a < 3; ++a) {
    const int64_t stored = static_cast<int64_t>(data[0].dims[2 - a]);
    std::optional<double> v = NumberAttribute(f, channel0, kSizeAttrs[a], access);
    if (!v && options.level == 0) v = NumberAttribute(f, "DataSetInfo/Image", kInfoSize[a], access);
    int64_t size = stored;
    if (v) {
      if (*v < 1 || *v != std::floor(*v) || *v > static_cast<double>(stored)) {
        return CorruptError(name + ": image size " + std::string(1, "xyz"[a]) + " = " +
                            std::to_string(*v) + " does not fit the data array of " + Num(stored));
      }
      size = static_cast<int64_t>(*v);
    }
    info.size[a] = size;
  }
  info.dtype = dtype;
  info.time_points = static_cast<int>(times);
  info.time = options.time;
  info.level_count = static_cast<int>(levels);
  info.level = options.level;
  const std::optional<uint64_t> plane_bytes =
      CheckedProduct({static_cast<uint64_t>(info.size[0]), static_cast<uint64_t>(info.size[1]),
                      volume::BytesPerSample(dtype)});
  if (!plane_bytes || *plane_bytes > options.max_plane_bytes) {
    return ResourceExhaustedError(name + ": one plane is more than the limit of " +
                                  std::to_string(options.max_plane_bytes) + " bytes");
  }
  const std::optional<uint64_t> chunk_bytes =
      CheckedProduct({chunk[0], chunk[1], chunk[2], volume::BytesPerSample(dtype)});
  if (!chunk_bytes || *chunk_bytes > options.max_chunk_bytes) {
    return ResourceExhaustedError(name + ": one chunk decodes to more than the limit of " +
                                  std::to_string(options.max_chunk_bytes) + " bytes");
  }

  // Spacing: the physical extent over the level's voxel count, in the file's unit (Imaris's
  // default, micrometres, when it names none).
  const std::string image = "DataSetInfo/Image";
  std::optional<double> um = 1.0;
  if (std::optional<std::string> unit = TextAttribute(f, image, "Unit", access)) {
    um = MicrometresPerUnit(*unit);
    if (!um) um = MicrometresPerLengthUnit(TrimWhitespace(*unit));
  }
  for (int a = 0; a < 3 && um; ++a) {
    const std::string k = std::to_string(a);
    std::optional<double> lo = NumberAttribute(f, image, ("ExtMin" + k).c_str(), access);
    std::optional<double> hi = NumberAttribute(f, image, ("ExtMax" + k).c_str(), access);
    if (lo && hi) info.spacing_um[a] = PositiveOrNone((*hi - *lo) * *um / info.size[a]);
  }

  // Channels: names, colours ("r g b" fractions), display windows ("ColorRange lo hi", the
  // slider range from the level-0 histogram bounds).
  info.channels.resize(static_cast<size_t>(channels));
  for (int64_t c = 0; c < channels; ++c) {
    volume::ChannelInfo& ci = info.channels[static_cast<size_t>(c)];
    const std::string meta = "DataSetInfo/Channel " + Num(c);
    if (std::optional<std::string> n = TextAttribute(f, meta, "Name", access)) ci.name = *n;
    if (std::optional<std::string> col = TextAttribute(f, meta, "Color", access))
      ci.color = ImarisColor(*col);
    if (std::optional<std::string> range = TextAttribute(f, meta, "ColorRange", access)) {
      std::vector<double> lohi = NumberList(*range);
      if (lohi.size() == 2) {
        const std::string hist =
            "DataSet/ResolutionLevel 0/TimePoint " + Num(options.time) + "/Channel " + Num(c);
        ci.window = volume::DisplayWindow{lohi[0], lohi[1],
                                          NumberAttribute(f, hist, "HistogramMin", access),
                                          NumberAttribute(f, hist, "HistogramMax", access)};
      }
    }
  }
  ApplySpacingOverrides(info, options);
  if (Status s = info.Validate(); !s.ok()) return s.WithContext(name);

  // The fill value of chunks never written (HDF5's, default 0).
  double fill = 0;
  {
    Hdf5Id dcpl(H5Dget_create_plist(data[0].dataset.get()));
    if (!dcpl.valid() || H5Pget_fill_value(dcpl.get(), H5T_NATIVE_DOUBLE, &fill) < 0) {
      H5Eclear2(H5E_DEFAULT);
      fill = 0;
    }
  }

  ChunkLayout layout;
  layout.shape = {channels, info.size[2], info.size[1], info.size[0]};
  layout.chunk = {1, static_cast<int64_t>(chunk[0]), static_cast<int64_t>(chunk[1]),
                  static_cast<int64_t>(chunk[2])};
  layout.strides = ChunkLayout::StridesFor(layout.chunk, {});
  layout.channel_dim = 0;
  layout.z_dim = 1;
  layout.y_dim = 2;
  layout.x_dim = 3;
  ChunkedVolumeOptions chunked;
  chunked.name = name;
  chunked.fill_value = fill;
  chunked.cache_bytes = options.chunk_cache_bytes;
  chunked.threads = options.decode_threads;
  auto reader = std::make_unique<ImarisChunkReader>(name, std::move(file), std::move(data), chunk,
                                                    dtype, big_endian);
  return MakeChunkedVolume(std::move(info), std::move(layout), std::move(reader), chunked);
}

}  // namespace

bool HasHdf5Signature(const fs::path& path, const FileGate& gate) {
  Result<int> fd = gate.OpenForReading(path);
  if (!fd.ok()) return false;
  const ScopedFd owned(*fd);
  return HasHdf5SignatureAt(*fd);
}

Result<std::unique_ptr<VolumeSource>> OpenImaris(const fs::path& path, const OpenOptions& options) {
  Hdf5Quiet();
  const std::string name = path.string();
  const FileGate& gate = options.file_gate;
  Result<int> fd = gate.OpenForReading(path);
  if (!fd.ok() && IsOutsideFolderError(fd.status())) return fd.status();
  const ScopedFd owned(fd.ok() ? *fd : -1);
  if (!fd.ok() || !HasHdf5SignatureAt(*fd)) {
    return CorruptError(name + ": not an HDF5 file (an Imaris .ims file is HDF5)");
  }
  // Confined, HDF5 reads the file the gate opened (not whatever the path leads to by now).
  const std::string file_name = gate.confined() ? "/proc/self/fd/" + std::to_string(*fd) : name;
  // Read without HDF5's file lock: a reader's lock would stop an acquisition from reopening the
  // file for writing (and a writer's lock would refuse us).
  OCTO_ASSIGN_OR_RETURN(hid_t raw_fapl, OCTO_H5(H5Pcreate(H5P_FILE_ACCESS)));
  Hdf5Id fapl(raw_fapl);
  OCTO_RETURN_IF_ERROR(OCTO_H5(H5Pset_file_locking(fapl.get(), false, true)).status());
  OCTO_ASSIGN_OR_RETURN(const LinkAccess access, LinkAccess::Make(gate.confined()));
  Result<hid_t> opened = OCTO_H5(H5Fopen(file_name.c_str(), H5F_ACC_RDONLY, fapl.get()));
  if (!opened.ok()) return opened.status().WithContext(name);
  Result<std::unique_ptr<VolumeSource>> source = OpenFile(Hdf5Id(*opened), name, options, access);
  // An external link met anywhere (its failure may have read as a missing group) refuses it all.
  if (access.refused()) return OutsideFolderError();
  return source;
}

}  // namespace octoscope::io
