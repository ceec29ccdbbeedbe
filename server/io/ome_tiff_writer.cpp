#include "io/ome_tiff_writer.h"

#include <tiffio.h>

#include <algorithm>
#include <bit>
#include <charconv>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <future>
#include <memory>
#include <pugixml.hpp>
#include <random>
#include <sstream>
#include <system_error>
#include <utility>
#include <vector>

#include "util/checked_math.h"
#include "util/strings.h"

namespace octoscope::io {
namespace {

// Above this many bytes of pixel data a classic TIFF (32-bit offsets) risks overflowing.
constexpr uint64_t kBigTiffThreshold = 3'900'000'000;
constexpr uint64_t kStripTargetBytes = 256 << 10;

// Collects libtiff's messages for one handle (the first error wins: later ones are consequences).
struct TiffMessages {
  std::string error;
};

int OnTiffError(TIFF*, void* user_data, const char* module, const char* fmt, va_list ap) {
  auto* messages = static_cast<TiffMessages*>(user_data);
  if (messages->error.empty()) {
    char buffer[512];
    std::vsnprintf(buffer, sizeof(buffer), fmt, ap);
    messages->error = (module && *module ? std::string(module) + ": " : std::string()) + buffer;
  }
  return 1;  // Handled: keep libtiff's global handler quiet.
}

int OnTiffWarning(TIFF*, void*, const char*, const char*, va_list) { return 1; }

struct TiffCloser {
  void operator()(TIFF* tif) const { TIFFClose(tif); }
};

std::string_view OmeTypeName(volume::DataType type) {
  switch (type) {
    case volume::DataType::kFloat32:
      return "float";
    case volume::DataType::kFloat64:
      return "double";
    default:
      return volume::NumpyName(type);
  }
}

uint16_t SampleFormatOf(volume::DataType type) {
  if (volume::IsFloat(type)) return SAMPLEFORMAT_IEEEFP;
  return volume::IsSigned(type) ? SAMPLEFORMAT_INT : SAMPLEFORMAT_UINT;
}

uint16_t CompressionTag(TiffCompression compression) {
  switch (compression) {
    case TiffCompression::kNone:
      return COMPRESSION_NONE;
    case TiffCompression::kDeflate:
      return COMPRESSION_ADOBE_DEFLATE;
    case TiffCompression::kZstd:
      return COMPRESSION_ZSTD;
    case TiffCompression::kLzw:
      return COMPRESSION_LZW;
  }
  return COMPRESSION_NONE;
}

std::string FormatDouble(double value) {
  char buffer[64];
  auto [end, ec] = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return ec == std::errc() ? std::string(buffer, end) : std::to_string(value);
}

// A random (version 4) UUID as "urn:uuid:...".
std::string NewUuid() {
  std::random_device device;
  std::mt19937_64 rng((static_cast<uint64_t>(device()) << 32) ^ device());
  uint64_t hi = rng(), lo = rng();
  hi = (hi & ~uint64_t{0xF000}) | 0x4000;                      // Version 4.
  lo = (lo & ~(uint64_t{0xC} << 60)) | (uint64_t{0x8} << 60);  // Variant 10xx.
  char text[64];
  std::snprintf(text, sizeof(text), "urn:uuid:%08x-%04x-%04x-%04x-%012llx",
                static_cast<unsigned>(hi >> 32), static_cast<unsigned>((hi >> 16) & 0xFFFF),
                static_cast<unsigned>(hi & 0xFFFF), static_cast<unsigned>(lo >> 48),
                static_cast<unsigned long long>(lo & 0xFFFFFFFFFFFFull));
  return text;
}

// Control characters are not allowed in XML 1.0 even escaped; replace them.
std::string XmlSafe(std::string_view text) {
  std::string out(text);
  for (char& ch : out) {
    if (static_cast<unsigned char>(ch) < 0x20 && ch != '\t' && ch != '\n' && ch != '\r') ch = ' ';
  }
  return out;
}

std::string DefaultImageName(const std::filesystem::path& path) {
  std::string name = path.filename().string();
  for (std::string_view suffix : {".ome.tiff", ".ome.tif", ".tiff", ".tif"}) {
    if (EndsWithIgnoreCase(name, suffix) && name.size() > suffix.size()) {
      name.resize(name.size() - suffix.size());
      break;
    }
  }
  return name;
}

std::string BuildOmeXml(const volume::VolumeInfo& info, const std::string& image_name,
                        const std::string& file_name, const std::string& uuid) {
  pugi::xml_document doc;
  pugi::xml_node decl = doc.append_child(pugi::node_declaration);
  decl.append_attribute("version") = "1.0";
  decl.append_attribute("encoding") = "UTF-8";
  pugi::xml_node ome = doc.append_child("OME");
  ome.append_attribute("xmlns") = "http://www.openmicroscopy.org/Schemas/OME/2016-06";
  ome.append_attribute("xmlns:xsi") = "http://www.w3.org/2001/XMLSchema-instance";
  ome.append_attribute("xsi:schemaLocation") =
      "http://www.openmicroscopy.org/Schemas/OME/2016-06 "
      "http://www.openmicroscopy.org/Schemas/OME/2016-06/ome.xsd";
  ome.append_attribute("UUID") = uuid.c_str();
  ome.append_attribute("Creator") = "Octoscope";

  pugi::xml_node image = ome.append_child("Image");
  image.append_attribute("ID") = "Image:0";
  image.append_attribute("Name") = XmlSafe(image_name).c_str();
  pugi::xml_node pixels = image.append_child("Pixels");
  pixels.append_attribute("ID") = "Pixels:0";
  pixels.append_attribute("DimensionOrder") = "XYZCT";
  pixels.append_attribute("Type") = std::string(OmeTypeName(info.dtype)).c_str();
  pixels.append_attribute("BigEndian") = std::endian::native == std::endian::big ? "true" : "false";
  pixels.append_attribute("Interleaved") = "false";
  pixels.append_attribute("SizeX") = std::to_string(info.size[0]).c_str();
  pixels.append_attribute("SizeY") = std::to_string(info.size[1]).c_str();
  pixels.append_attribute("SizeZ") = std::to_string(info.size[2]).c_str();
  pixels.append_attribute("SizeC") = std::to_string(info.channel_count()).c_str();
  pixels.append_attribute("SizeT") = "1";
  static constexpr const char* kPhysical[3] = {"PhysicalSizeX", "PhysicalSizeY", "PhysicalSizeZ"};
  for (int a = 0; a < 3; ++a) {
    if (!info.spacing_um[a]) continue;
    pixels.append_attribute(kPhysical[a]) = FormatDouble(*info.spacing_um[a]).c_str();
    pixels.append_attribute((std::string(kPhysical[a]) + "Unit").c_str()) = "\xC2\xB5m";  // µm
  }
  for (int c = 0; c < info.channel_count(); ++c) {
    const volume::ChannelInfo& channel = info.channels[c];
    pugi::xml_node node = pixels.append_child("Channel");
    node.append_attribute("ID") = ("Channel:0:" + std::to_string(c)).c_str();
    if (!channel.name.empty()) node.append_attribute("Name") = XmlSafe(channel.name).c_str();
    node.append_attribute("SamplesPerPixel") = "1";
    if (channel.color) {
      const volume::Rgba& k = *channel.color;
      // OME stores RGBA as one signed 32-bit integer.
      const uint32_t packed =
          (uint32_t{k.r} << 24) | (uint32_t{k.g} << 16) | (uint32_t{k.b} << 8) | uint32_t{k.a};
      node.append_attribute("Color") = std::to_string(static_cast<int32_t>(packed)).c_str();
    }
  }
  pugi::xml_node tiff_data = pixels.append_child("TiffData");
  tiff_data.append_attribute("IFD") = "0";
  tiff_data.append_attribute("PlaneCount") =
      std::to_string(info.size[2] * info.channel_count()).c_str();
  pugi::xml_node uuid_node = tiff_data.append_child("UUID");
  uuid_node.append_attribute("FileName") = XmlSafe(file_name).c_str();
  uuid_node.text() = uuid.c_str();

  std::ostringstream out;
  doc.save(out, "", pugi::format_raw | pugi::format_no_declaration);
  return "<?xml version=\"1.0\" encoding=\"UTF-8\"?>" + out.str();
}

struct SlabJob {
  int channel;
  int64_t z0;
  int64_t nz;
};

// Writes one prepared plane (the IFD's tags first, then strips or tiles, then the directory).
class PlaneWriter {
 public:
  PlaneWriter(TIFF* tif, TiffMessages* messages, const volume::VolumeInfo& info,
              const OmeTiffWriteOptions& options, std::string path_text)
      : tif_(tif),
        messages_(messages),
        info_(info),
        options_(options),
        path_text_(std::move(path_text)),
        bytes_per_sample_(volume::BytesPerSample(info.dtype)),
        width_(static_cast<uint32_t>(info.size[0])),
        height_(static_cast<uint32_t>(info.size[1])) {}

  Status Write(const std::byte* plane, uint64_t ifd_index, const std::string* description) {
    const uint16_t compression = CompressionTag(options_.compression);
    bool ok =
        TIFFSetField(tif_, TIFFTAG_IMAGEWIDTH, width_) &&
        TIFFSetField(tif_, TIFFTAG_IMAGELENGTH, height_) &&
        TIFFSetField(tif_, TIFFTAG_BITSPERSAMPLE, static_cast<uint16_t>(8 * bytes_per_sample_)) &&
        TIFFSetField(tif_, TIFFTAG_SAMPLEFORMAT, SampleFormatOf(info_.dtype)) &&
        TIFFSetField(tif_, TIFFTAG_SAMPLESPERPIXEL, uint16_t{1}) &&
        TIFFSetField(tif_, TIFFTAG_PHOTOMETRIC, uint16_t{PHOTOMETRIC_MINISBLACK}) &&
        TIFFSetField(tif_, TIFFTAG_PLANARCONFIG, uint16_t{PLANARCONFIG_CONTIG}) &&
        TIFFSetField(tif_, TIFFTAG_COMPRESSION, compression) &&
        TIFFSetField(tif_, TIFFTAG_SOFTWARE, "Octoscope");
    if (ok && compression != COMPRESSION_NONE && !volume::IsFloat(info_.dtype)) {
      // Differencing neighbours makes smooth integer images compress far better.
      ok = TIFFSetField(tif_, TIFFTAG_PREDICTOR, uint16_t{PREDICTOR_HORIZONTAL});
    }
    if (ok && compression == COMPRESSION_ADOBE_DEFLATE)
      ok = TIFFSetField(tif_, TIFFTAG_ZIPQUALITY, 4);
    if (ok && compression == COMPRESSION_ZSTD) ok = TIFFSetField(tif_, TIFFTAG_ZSTD_LEVEL, 5);
    if (ok && info_.spacing_um[0] && info_.spacing_um[1]) {
      // Also tell plain TIFF readers the pixel size: pixels per centimetre.
      ok =
          TIFFSetField(tif_, TIFFTAG_RESOLUTIONUNIT, uint16_t{RESUNIT_CENTIMETER}) &&
          TIFFSetField(tif_, TIFFTAG_XRESOLUTION, static_cast<float>(1e4 / *info_.spacing_um[0])) &&
          TIFFSetField(tif_, TIFFTAG_YRESOLUTION, static_cast<float>(1e4 / *info_.spacing_um[1]));
    }
    if (ok && description) ok = TIFFSetField(tif_, TIFFTAG_IMAGEDESCRIPTION, description->c_str());
    const uint64_t row_bytes = uint64_t{width_} * bytes_per_sample_;
    if (ok && options_.tile_size == 0) {
      rows_per_strip_ = static_cast<uint32_t>(
          std::clamp<uint64_t>(kStripTargetBytes / std::max<uint64_t>(row_bytes, 1), 1, height_));
      ok = TIFFSetField(tif_, TIFFTAG_ROWSPERSTRIP, rows_per_strip_);
    } else if (ok) {
      ok = TIFFSetField(tif_, TIFFTAG_TILEWIDTH, options_.tile_size) &&
           TIFFSetField(tif_, TIFFTAG_TILELENGTH, options_.tile_size);
    }
    if (!ok) return Failure("cannot set the tags of IFD " + std::to_string(ifd_index));

    if (options_.tile_size == 0) {
      for (uint32_t row = 0, strip = 0; row < height_; row += rows_per_strip_, ++strip) {
        const uint32_t rows = std::min(rows_per_strip_, height_ - row);
        // libtiff copies before predicting or swapping, so the const_cast never lets it write.
        void* data = const_cast<std::byte*>(plane + row * row_bytes);
        if (TIFFWriteEncodedStrip(tif_, strip, data, static_cast<tmsize_t>(rows * row_bytes)) < 0) {
          return Failure("cannot write strip " + std::to_string(strip) + " of IFD " +
                         std::to_string(ifd_index));
        }
      }
    } else {
      const uint32_t t = options_.tile_size;
      const uint64_t tile_row_bytes = uint64_t{t} * bytes_per_sample_;
      tile_.resize(tile_row_bytes * t);
      for (uint32_t y0 = 0; y0 < height_; y0 += t) {
        for (uint32_t x0 = 0; x0 < width_; x0 += t) {
          // Edge tiles are padded with zeros (TIFF tiles always have the full size).
          std::fill(tile_.begin(), tile_.end(), std::byte{0});
          const uint32_t w = std::min(t, width_ - x0), h = std::min(t, height_ - y0);
          for (uint32_t y = 0; y < h; ++y) {
            std::memcpy(tile_.data() + y * tile_row_bytes,
                        plane + (uint64_t{y0} + y) * row_bytes + uint64_t{x0} * bytes_per_sample_,
                        w * bytes_per_sample_);
          }
          const uint32_t tile = TIFFComputeTile(tif_, x0, y0, 0, 0);
          if (TIFFWriteEncodedTile(tif_, tile, tile_.data(), static_cast<tmsize_t>(tile_.size())) <
              0) {
            return Failure("cannot write tile " + std::to_string(tile) + " of IFD " +
                           std::to_string(ifd_index));
          }
        }
      }
    }
    if (!TIFFWriteDirectory(tif_)) return Failure("cannot write IFD " + std::to_string(ifd_index));
    return Status::Ok();
  }

  Status Failure(const std::string& what) const {
    return IoError(path_text_ + ": " + what +
                   (messages_->error.empty() ? std::string() : " (" + messages_->error + ")"));
  }

 private:
  TIFF* tif_;
  TiffMessages* messages_;
  const volume::VolumeInfo& info_;
  const OmeTiffWriteOptions& options_;
  std::string path_text_;
  size_t bytes_per_sample_;
  uint32_t width_, height_;
  uint32_t rows_per_strip_ = 1;
  std::vector<std::byte> tile_;
};

Status WriteToTemporary(VolumeSource& source, const std::filesystem::path& temporary,
                        const std::filesystem::path& final_path, const OmeTiffWriteOptions& options,
                        bool big_tiff, uint64_t plane_bytes) {
  const volume::VolumeInfo& info = source.info();
  const std::string path_text = final_path.string();
  const std::string image_name =
      options.image_name.empty() ? DefaultImageName(final_path) : options.image_name;
  const std::string description =
      BuildOmeXml(info, image_name, final_path.filename().string(), NewUuid());

  TiffMessages messages;
  TIFFOpenOptions* open_options = TIFFOpenOptionsAlloc();
  TIFFOpenOptionsSetErrorHandlerExtR(open_options, OnTiffError, &messages);
  TIFFOpenOptionsSetWarningHandlerExtR(open_options, OnTiffWarning, &messages);
  std::unique_ptr<TIFF, TiffCloser> tif(
      TIFFOpenExt(temporary.c_str(), big_tiff ? "w8" : "w", open_options));
  TIFFOpenOptionsFree(open_options);
  if (!tif) {
    return IoError(path_text + ": cannot create " + temporary.string() +
                   (messages.error.empty() ? "" : " (" + messages.error + ")"));
  }

  // Slabs in file order: channel-major, z within.
  const int64_t size_z = info.size[2];
  const int64_t planes_per_slab = static_cast<int64_t>(
      std::clamp<uint64_t>(options.slab_bytes / plane_bytes, 1, static_cast<uint64_t>(size_z)));
  std::vector<SlabJob> jobs;
  for (int c = 0; c < info.channel_count(); ++c) {
    for (int64_t z0 = 0; z0 < size_z; z0 += planes_per_slab) {
      jobs.push_back({c, z0, std::min(planes_per_slab, size_z - z0)});
    }
  }
  const uint64_t total_planes = static_cast<uint64_t>(size_z) * info.channel_count();
  std::vector<std::byte> current(plane_bytes * planes_per_slab);
  std::vector<std::byte> next(current.size());
  auto read = [&source, plane_bytes](const SlabJob& job, std::vector<std::byte>& buffer) {
    return source.ReadSlab(job.channel, job.z0, job.nz,
                           std::span<std::byte>(buffer.data(), plane_bytes * job.nz));
  };

  PlaneWriter writer(tif.get(), &messages, info, options, path_text);
  Status status = read(jobs[0], current);
  uint64_t planes_done = 0;
  for (size_t j = 0; j < jobs.size() && status.ok(); ++j) {
    // Read the next slab on a helper thread while this one is compressed and written.
    std::future<Status> pending;
    if (j + 1 < jobs.size()) {
      pending = std::async(std::launch::async, read, std::cref(jobs[j + 1]), std::ref(next));
    }
    for (int64_t p = 0; p < jobs[j].nz && status.ok(); ++p) {
      status = writer.Write(current.data() + p * plane_bytes, planes_done,
                            planes_done == 0 ? &description : nullptr);
      if (!status.ok()) break;
      ++planes_done;
      if (options.progress) options.progress(planes_done, total_planes);
    }
    if (pending.valid()) {
      Status read_status = pending.get();  // Always join before leaving the loop.
      if (status.ok()) status = read_status;
    }
    std::swap(current, next);
  }
  if (status.ok() && !TIFFFlush(tif.get())) status = writer.Failure("cannot flush the file");
  tif.reset();  // Closes the file.
  if (status.ok() && !messages.error.empty()) status = writer.Failure("libtiff reported an error");
  return status;
}

}  // namespace

std::optional<TiffCompression> TiffCompressionFromName(std::string_view name) {
  for (TiffCompression c : {TiffCompression::kNone, TiffCompression::kDeflate,
                            TiffCompression::kZstd, TiffCompression::kLzw}) {
    if (EqualsIgnoreCase(name, TiffCompressionName(c))) return c;
  }
  return std::nullopt;
}

std::string_view TiffCompressionName(TiffCompression compression) {
  switch (compression) {
    case TiffCompression::kNone:
      return "none";
    case TiffCompression::kDeflate:
      return "deflate";
    case TiffCompression::kZstd:
      return "zstd";
    case TiffCompression::kLzw:
      return "lzw";
  }
  return "none";
}

Status WriteOmeTiff(VolumeSource& source, const std::filesystem::path& path,
                    const OmeTiffWriteOptions& options) {
  const volume::VolumeInfo& info = source.info();
  const std::string path_text = path.string();
  if (Status s = info.Validate(); !s.ok()) return s.WithContext(path_text + ": cannot write");
  if (info.size[0] > UINT32_MAX || info.size[1] > UINT32_MAX) {
    return InvalidArgumentError(path_text + ": a plane of " + std::to_string(info.size[0]) + "x" +
                                std::to_string(info.size[1]) + " is too large for TIFF");
  }
  if (options.tile_size % 16 != 0) {
    return InvalidArgumentError(path_text + ": tile size " + std::to_string(options.tile_size) +
                                " is not a multiple of 16");
  }
  const uint16_t compression = CompressionTag(options.compression);
  if (!TIFFIsCODECConfigured(compression)) {
    return UnsupportedError(path_text + ": this libtiff cannot write " +
                            std::string(TiffCompressionName(options.compression)) + " compression");
  }
  const std::optional<uint64_t> plane_bytes =
      CheckedProduct({info.PlaneVoxels(), volume::BytesPerSample(info.dtype)});
  if (!plane_bytes || *plane_bytes > (uint64_t{1} << 40)) {
    return ResourceExhaustedError(path_text + ": one plane of " + std::to_string(info.size[0]) +
                                  "x" + std::to_string(info.size[1]) + " is too large");
  }
  const uint64_t planes = static_cast<uint64_t>(info.size[2]) * info.channel_count();
  const uint64_t overhead = planes * 512 + (uint64_t{1} << 20);  // IFDs, tags, XML (generous).
  const bool big_tiff =
      options.big_tiff == BigTiffMode::kAlways ||
      (options.big_tiff == BigTiffMode::kAuto && info.VoxelBytes() + overhead > kBigTiffThreshold);

  std::filesystem::path temporary = path;
  temporary += ".tmp";
  Status status = WriteToTemporary(source, temporary, path, options, big_tiff, *plane_bytes);
  std::error_code ec;
  if (status.ok()) {
    std::filesystem::rename(temporary, path, ec);
    if (ec)
      status = IoError(path_text + ": cannot rename " + temporary.string() + ": " + ec.message());
  }
  if (!status.ok()) std::filesystem::remove(temporary, ec);  // Best effort.
  return status;
}

}  // namespace octoscope::io
