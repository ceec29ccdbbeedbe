#include "io/tiff_stack_volume.h"

#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "util/checked_math.h"
#include "util/strings.h"

namespace octoscope::io {
namespace {

// Where the pages of a file sit along channel, z and time:
//   page = c + C * ((t % F) + F * z + P * (t / F))
// C: channels stored as pages (1 when the samples of a pixel are the channels); F: frames per
// slice (consecutive time points at one z, as ScanImage records them; 1 for ImageJ); P: pages per
// volume per channel (>= F * Z; more when a recorder keeps fly-back frames).
struct PageLayout {
  int64_t page_channels = 1;
  int64_t z = 1;
  int64_t frames_per_slice = 1;
  int64_t pages_per_volume = 1;
  int64_t time_points = 1;

  int64_t Page(int64_t c, int64_t zi, int64_t t) const {
    return c + page_channels * ((t % frames_per_slice) + frames_per_slice * zi +
                                pages_per_volume * (t / frames_per_slice));
  }
};

void ByteSwap(std::span<std::byte> data, size_t bytes) {
  std::byte* p = data.data();
  const size_t n = data.size() / bytes;
  switch (bytes) {
    case 2:
      for (size_t i = 0; i < n; ++i, p += 2) {
        uint16_t v;
        std::memcpy(&v, p, 2);
        v = __builtin_bswap16(v);
        std::memcpy(p, &v, 2);
      }
      break;
    case 4:
      for (size_t i = 0; i < n; ++i, p += 4) {
        uint32_t v;
        std::memcpy(&v, p, 4);
        v = __builtin_bswap32(v);
        std::memcpy(p, &v, 4);
      }
      break;
    case 8:
      for (size_t i = 0; i < n; ++i, p += 8) {
        uint64_t v;
        std::memcpy(&v, p, 8);
        v = __builtin_bswap64(v);
        std::memcpy(p, &v, 8);
      }
      break;
    default:
      break;
  }
}

// A TIFF stack of the selected time point. Planes are either IFDs decoded by TiffFile, or (ImageJ
// > 4 GB) raw images at data_offset + image * plane_bytes.
class TiffStackSource : public VolumeSource {
 public:
  TiffStackSource(std::unique_ptr<TiffFile> file, volume::VolumeInfo info,
                  std::vector<int64_t> planes, bool samples_are_channels,
                  std::optional<uint64_t> data_offset)
      : file_(std::move(file)),
        info_(std::move(info)),
        planes_(std::move(planes)),
        samples_are_channels_(samples_are_channels),
        data_offset_(data_offset) {}

  const volume::VolumeInfo& info() const override { return info_; }

  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    OCTO_RETURN_IF_ERROR(
        CheckSlabRequest(info_, channel, z0, nz, out.size()).WithContext(file_->path().string()));
    const size_t bytes = volume::BytesPerSample(info_.dtype);
    const uint64_t plane_bytes = info_.PlaneVoxels() * bytes;
    const bool swap = file_->big_endian() != (std::endian::native == std::endian::big);
    for (int64_t k = 0; k < nz; ++k) {
      const int64_t z = z0 + k;
      std::span<std::byte> plane = out.subspan(static_cast<size_t>(k) * plane_bytes, plane_bytes);
      const int64_t id =
          samples_are_channels_ ? planes_[z] : planes_[z * info_.channel_count() + channel];
      if (data_offset_) {
        // Checked at open: every image lies inside the file.
        OCTO_RETURN_IF_ERROR(
            file_->ReadBytes(*data_offset_ + static_cast<uint64_t>(id) * plane_bytes, plane));
        if (swap && bytes > 1) ByteSwap(plane, bytes);
      } else {
        OCTO_RETURN_IF_ERROR(
            file_->ReadPlane(static_cast<int>(id), samples_are_channels_ ? channel : 0, plane));
      }
    }
    return Status::Ok();
  }

 private:
  const std::unique_ptr<TiffFile> file_;
  const volume::VolumeInfo info_;
  // The plane id of (z, c) at planes_[z * C + c] (or planes_[z] when the samples are the
  // channels): an IFD index, or an image index when data_offset_ is set.
  const std::vector<int64_t> planes_;
  const bool samples_are_channels_;
  const std::optional<uint64_t> data_offset_;
};

std::string Dtype(const TiffIfd& ifd) {
  if (ifd.dtype) return std::string(volume::NumpyName(*ifd.dtype));
  return std::to_string(ifd.bits_per_sample) + "-bit format " + std::to_string(ifd.sample_format);
}

// Every page of a stack must look like its first.
Status CheckSamePage(const TiffFile& file, int first, int index) {
  const TiffIfd& a = file.ifd(first);
  const TiffIfd& b = file.ifd(index);
  if (a.width == b.width && a.height == b.height && a.dtype == b.dtype &&
      a.samples_per_pixel == b.samples_per_pixel) {
    return Status::Ok();
  }
  auto describe = [](const TiffIfd& i) {
    return std::to_string(i.width) + "x" + std::to_string(i.height) + " " + Dtype(i) + " x" +
           std::to_string(i.samples_per_pixel) + " samples";
  };
  return UnsupportedError(file.path().string() + ": pages differ: IFD " + std::to_string(index) +
                          " is " + describe(b) + ", IFD " + std::to_string(first) + " is " +
                          describe(a) + "; a stack needs equal pages");
}

std::optional<double> PositiveOrNone(std::optional<double> v) {
  if (v && std::isfinite(*v) && *v > 0) return v;
  return std::nullopt;
}

// x/y pitch from a resolution tag: only centimetres are trusted (inch is mostly a 72 dpi default).
std::optional<double> SpacingFromResolution(std::optional<double> resolution, uint16_t unit) {
  if (!resolution || unit != 3) return std::nullopt;
  return PositiveOrNone(1e4 / *resolution);
}

Status CheckTime(const std::string& name, int time, int64_t time_points) {
  if (time < 0 || time >= time_points) {
    return OutOfRangeError(name + ": time point " + std::to_string(time) +
                           " requested, the file has " + std::to_string(time_points));
  }
  return Status::Ok();
}

// "SI.hChannels.channelSave = [1;2]" lines of ScanImage metadata, keyed without "scanimage.".
std::map<std::string, std::string, std::less<>> ParseScanImageKeys(std::string_view text) {
  std::map<std::string, std::string, std::less<>> keys;
  for (std::string_view line : Split(text, '\n')) {
    line = TrimWhitespace(line);
    if (line.starts_with("scanimage.")) line.remove_prefix(10);
    if (!line.starts_with("SI.")) continue;
    const size_t eq = line.find(" = ");
    if (eq == std::string_view::npos) continue;
    keys.emplace(std::string(TrimWhitespace(line.substr(0, eq))),
                 std::string(TrimWhitespace(line.substr(eq + 3))));
  }
  return keys;
}

// The numbers of a MATLAB-style value: "[1;2]", "[1 2 3]", "4".
std::vector<double> ParseMatlabNumbers(std::string_view value) {
  std::vector<double> numbers;
  std::string text(value);
  for (char& ch : text) {
    if (ch == '[' || ch == ']' || ch == ';' || ch == ',') ch = ' ';
  }
  for (std::string_view token : Split(text, ' ')) {
    if (token.empty()) continue;
    if (auto v = ParseDouble(token)) numbers.push_back(*v);
  }
  return numbers;
}

std::optional<double> ScanImageNumber(const std::map<std::string, std::string, std::less<>>& keys,
                                      std::string_view key) {
  auto it = keys.find(key);
  if (it == keys.end()) return std::nullopt;
  std::vector<double> numbers = ParseMatlabNumbers(it->second);
  if (numbers.size() != 1) return std::nullopt;
  return numbers[0];
}

bool ScanImageTrue(const std::map<std::string, std::string, std::less<>>& keys,
                   std::string_view key) {
  auto it = keys.find(key);
  return it != keys.end() && (it->second == "true" || it->second == "1");
}

struct ScanImageLayout {
  PageLayout layout;
  std::optional<double> z_step_um;
};

// The page layout ScanImage metadata describes; nullopt when the text is not ScanImage's or does
// not fit the file (then the file opens as a plain stack).
std::optional<ScanImageLayout> ScanImageLayoutOf(std::string_view metadata, int64_t pages) {
  const auto keys = ParseScanImageKeys(metadata);
  auto save = keys.find("SI.hChannels.channelSave");
  if (save == keys.end()) return std::nullopt;
  const int64_t channels = static_cast<int64_t>(ParseMatlabNumbers(save->second).size());
  if (channels < 1) return std::nullopt;

  const bool fast_z = ScanImageTrue(keys, "SI.hFastZ.enable");
  const bool stack = fast_z || ScanImageTrue(keys, "SI.hStackManager.enable");
  int64_t slices = 1;
  if (stack) {
    std::optional<double> n = ScanImageNumber(keys, "SI.hStackManager.actualNumSlices");
    if (!n) n = ScanImageNumber(keys, "SI.hStackManager.numSlices");
    if (n && *n >= 1 && *n < 1e9) slices = static_cast<int64_t>(*n);
  }
  // Frames recorded per slice, after ScanImage's own averaging.
  int64_t frames = 1;
  if (!fast_z) {
    std::optional<double> f = ScanImageNumber(keys, "SI.hStackManager.framesPerSlice");
    std::optional<double> avg = ScanImageNumber(keys, "SI.hScan2D.logAverageFactor");
    if (f && *f >= 1 && *f < 1e9) frames = static_cast<int64_t>(*f);
    if (avg && *avg > 1 && *avg < 1e9 && frames % static_cast<int64_t>(*avg) == 0) {
      frames /= static_cast<int64_t>(*avg);
    }
  }
  int64_t per_volume = frames * slices;
  if (fast_z && !ScanImageTrue(keys, "SI.hFastZ.discardFlybackFrames")) {
    // Fly-back frames are stored after the slices of each volume.
    std::optional<double> with_flyback =
        ScanImageNumber(keys, "SI.hStackManager.numFramesPerVolumeWithFlyback");
    if (with_flyback && *with_flyback > static_cast<double>(per_volume) && *with_flyback < 1e9) {
      per_volume = static_cast<int64_t>(*with_flyback);
    }
  }
  const int64_t volumes = pages / (channels * per_volume);
  if (volumes < 1) return std::nullopt;

  ScanImageLayout result;
  result.layout.page_channels = channels;
  result.layout.z = slices;
  result.layout.frames_per_slice = frames;
  result.layout.pages_per_volume = per_volume;
  result.layout.time_points = frames * volumes;
  if (slices > 1) {
    std::optional<double> step = ScanImageNumber(keys, "SI.hStackManager.actualStackZStepSize");
    if (!step) step = ScanImageNumber(keys, "SI.hStackManager.stackZStepSize");
    if (step) result.z_step_um = PositiveOrNone(std::fabs(*step));
  }
  return result;
}

void ApplySpacingOverrides(volume::VolumeInfo& info, const OpenOptions& options) {
  for (int a = 0; a < 3; ++a) {
    if (options.spacing_um[a]) info.spacing_um[a] = options.spacing_um[a];
  }
}

Result<std::unique_ptr<VolumeSource>> Finish(std::unique_ptr<TiffFile> file,
                                             volume::VolumeInfo info, const OpenOptions& options,
                                             std::vector<int64_t> planes, bool samples_are_channels,
                                             std::optional<uint64_t> data_offset) {
  ApplySpacingOverrides(info, options);
  OCTO_RETURN_IF_ERROR(info.Validate().WithContext(file->path().string()));
  return std::unique_ptr<VolumeSource>(new TiffStackSource(
      std::move(file), std::move(info), std::move(planes), samples_are_channels, data_offset));
}

Result<std::unique_ptr<VolumeSource>> OpenImageJ(std::unique_ptr<TiffFile> file,
                                                 const ImageJDescription& ij,
                                                 const OpenOptions& options) {
  const std::string name = file->path().string();
  const TiffIfd& first = file->ifd(0);
  if (ij.images < 0 || ij.channels < 0 || ij.slices < 0 || ij.frames < 0) {
    return CorruptError(name + ": ImageJ description has negative counts");
  }
  int64_t c = std::max<int64_t>(1, ij.channels);
  int64_t z = std::max<int64_t>(1, ij.slices);
  int64_t t = std::max<int64_t>(1, ij.frames);
  const std::optional<uint64_t> product = CheckedProduct(
      {static_cast<uint64_t>(c), static_cast<uint64_t>(z), static_cast<uint64_t>(t)});
  int64_t images = ij.images > 0 ? ij.images : static_cast<int64_t>(product.value_or(0));
  if (!product || *product > (uint64_t{1} << 40) || images > (int64_t{1} << 40)) {
    return CorruptError(name + ": ImageJ description declares an absurd number of images");
  }
  if (static_cast<uint64_t>(images) != *product) {
    if (ij.channels == 0 && ij.slices == 0 && ij.frames == 0) {
      z = images;  // "images=N" alone: a plain z stack.
    } else {
      return CorruptError(name + ": ImageJ description says images=" + std::to_string(images) +
                          " but channels*slices*frames = " + std::to_string(*product));
    }
  }
  const bool samples_are_channels = first.samples_per_pixel > 1;
  if (samples_are_channels && c > 1) {
    return UnsupportedError(name + ": ImageJ stack with both channels=" + std::to_string(c) +
                            " and " + std::to_string(first.samples_per_pixel) +
                            " samples per pixel");
  }
  OCTO_RETURN_IF_ERROR(CheckTime(name, options.time, t));

  volume::VolumeInfo info;
  info.format = "imagej-tiff";
  info.size = {first.width, first.height, z};
  info.channels.resize(samples_are_channels ? first.samples_per_pixel : c);
  info.dtype = *first.dtype;
  info.time_points = static_cast<int>(std::min<int64_t>(t, INT32_MAX));
  info.time = options.time;
  if (std::optional<double> um = MicrometresPerUnit(ij.unit)) {
    if (first.x_resolution) info.spacing_um[0] = PositiveOrNone(*um / *first.x_resolution);
    if (first.y_resolution) info.spacing_um[1] = PositiveOrNone(*um / *first.y_resolution);
    if (ij.spacing) info.spacing_um[2] = PositiveOrNone(*um * std::fabs(*ij.spacing));
  }

  PageLayout layout;
  layout.page_channels = samples_are_channels ? 1 : c;
  layout.z = z;
  layout.pages_per_volume = z;
  layout.time_points = t;
  std::vector<int64_t> planes;
  planes.reserve(static_cast<size_t>(z * layout.page_channels));
  for (int64_t zi = 0; zi < z; ++zi) {
    for (int64_t ci = 0; ci < layout.page_channels; ++ci) {
      planes.push_back(layout.Page(ci, zi, options.time));
    }
  }

  if (file->ifd_count() >= images) {
    for (int i = 1; i < images; ++i) OCTO_RETURN_IF_ERROR(CheckSamePage(*file, 0, i));
    return Finish(std::move(file), std::move(info), options, std::move(planes),
                  samples_are_channels, std::nullopt);
  }
  if (file->ifd_count() > 1) {
    return CorruptError(name + ": ImageJ description says images=" + std::to_string(images) +
                        " but the file has " + std::to_string(file->ifd_count()) + " IFDs");
  }
  // One IFD for many images: ImageJ's > 4 GB layout, images stored back to back after the first.
  if (samples_are_channels) {
    return UnsupportedError(name + ": single-IFD ImageJ file with " +
                            std::to_string(first.samples_per_pixel) + " samples per pixel");
  }
  Result<uint64_t> offset = file->ContiguousDataOffset(0);
  if (!offset.ok()) {
    return CorruptError(name + ": ImageJ description says images=" + std::to_string(images) +
                        " but the file has one IFD whose data is not contiguous (" +
                        offset.status().message() + ")");
  }
  const uint64_t plane_bytes =
      uint64_t{first.width} * first.height * volume::BytesPerSample(info.dtype);
  const std::optional<uint64_t> all = CheckedMul(plane_bytes, static_cast<uint64_t>(images));
  const std::optional<uint64_t> end = all ? CheckedAdd(*offset, *all) : std::nullopt;
  if (!end || *end > file->file_size()) {
    return CorruptError(name + ": ImageJ description says images=" + std::to_string(images) +
                        ", stored contiguously from offset " + std::to_string(*offset) +
                        ", but the file is only " + std::to_string(file->file_size()) +
                        " bytes: the file is truncated");
  }
  return Finish(std::move(file), std::move(info), options, std::move(planes), false, *offset);
}

Result<std::unique_ptr<VolumeSource>> OpenScanImage(std::unique_ptr<TiffFile> file,
                                                    const ScanImageLayout& si,
                                                    const OpenOptions& options) {
  const std::string name = file->path().string();
  const TiffIfd& first = file->ifd(0);
  const PageLayout& layout = si.layout;
  OCTO_RETURN_IF_ERROR(CheckTime(name, options.time, layout.time_points));
  const int64_t used = layout.page_channels * layout.pages_per_volume *
                       (layout.time_points / layout.frames_per_slice);
  for (int64_t i = 1; i < used; ++i) {
    OCTO_RETURN_IF_ERROR(CheckSamePage(*file, 0, static_cast<int>(i)));
  }
  volume::VolumeInfo info;
  info.format = "tiff";
  info.size = {first.width, first.height, layout.z};
  info.channels.resize(layout.page_channels);
  info.dtype = *first.dtype;
  info.time_points = static_cast<int>(std::min<int64_t>(layout.time_points, INT32_MAX));
  info.time = options.time;
  info.spacing_um[0] = SpacingFromResolution(first.x_resolution, first.resolution_unit);
  info.spacing_um[1] = SpacingFromResolution(first.y_resolution, first.resolution_unit);
  info.spacing_um[2] = si.z_step_um;
  std::vector<int64_t> planes;
  for (int64_t zi = 0; zi < layout.z; ++zi) {
    for (int64_t ci = 0; ci < layout.page_channels; ++ci) {
      planes.push_back(layout.Page(ci, zi, options.time));
    }
  }
  return Finish(std::move(file), std::move(info), options, std::move(planes), false, std::nullopt);
}

Result<std::unique_ptr<VolumeSource>> OpenPlain(std::unique_ptr<TiffFile> file,
                                                const OpenOptions& options) {
  const std::string name = file->path().string();
  // Pages are the full-resolution IFDs; reduced-resolution copies (thumbnails) are skipped.
  std::vector<int64_t> planes;
  for (int i = 0; i < file->ifd_count(); ++i) {
    if ((file->ifd(i).subfile_type & 1) == 0) planes.push_back(i);
  }
  if (planes.empty()) return CorruptError(name + ": no full-resolution page");
  const TiffIfd& first = file->ifd(static_cast<int>(planes[0]));
  if (!first.dtype) {
    return UnsupportedError(name + ": IFD " + std::to_string(planes[0]) + " has " + Dtype(first) +
                            " samples, which Octoscope cannot read");
  }
  for (int64_t p : planes) {
    OCTO_RETURN_IF_ERROR(CheckSamePage(*file, static_cast<int>(planes[0]), static_cast<int>(p)));
  }
  OCTO_RETURN_IF_ERROR(CheckTime(name, options.time, 1));
  volume::VolumeInfo info;
  info.format = "tiff";
  info.size = {first.width, first.height, static_cast<int64_t>(planes.size())};
  info.channels.resize(first.samples_per_pixel);
  info.dtype = *first.dtype;
  info.spacing_um[0] = SpacingFromResolution(first.x_resolution, first.resolution_unit);
  info.spacing_um[1] = SpacingFromResolution(first.y_resolution, first.resolution_unit);
  const bool samples_are_channels = true;  // One page per z; channel = sample.
  return Finish(std::move(file), std::move(info), options, std::move(planes), samples_are_channels,
                std::nullopt);
}

// Decodes ImageJ's "\uXXXX" escapes (it writes "unit=\u00B5m") to UTF-8.
std::string DecodeUnicodeEscapes(std::string_view text) {
  std::string out;
  for (size_t i = 0; i < text.size(); ++i) {
    if (text[i] == '\\' && i + 5 < text.size() && text[i + 1] == 'u') {
      uint32_t code = 0;
      bool ok = true;
      for (size_t k = 2; k < 6; ++k) {
        char ch = text[i + k];
        code <<= 4;
        if (ch >= '0' && ch <= '9')
          code |= static_cast<uint32_t>(ch - '0');
        else if (ch >= 'a' && ch <= 'f')
          code |= static_cast<uint32_t>(ch - 'a' + 10);
        else if (ch >= 'A' && ch <= 'F')
          code |= static_cast<uint32_t>(ch - 'A' + 10);
        else
          ok = false;
      }
      if (ok) {
        if (code < 0x80) {
          out += static_cast<char>(code);
        } else if (code < 0x800) {
          out += static_cast<char>(0xC0 | (code >> 6));
          out += static_cast<char>(0x80 | (code & 0x3F));
        } else {
          out += static_cast<char>(0xE0 | (code >> 12));
          out += static_cast<char>(0x80 | ((code >> 6) & 0x3F));
          out += static_cast<char>(0x80 | (code & 0x3F));
        }
        i += 5;
        continue;
      }
    }
    out += text[i];
  }
  return out;
}

}  // namespace

std::optional<ImageJDescription> ParseImageJDescription(std::string_view text) {
  if (!text.starts_with("ImageJ=")) return std::nullopt;
  ImageJDescription d;
  for (std::string_view line : Split(text, '\n')) {
    line = TrimWhitespace(line);
    const size_t eq = line.find('=');
    if (eq == std::string_view::npos) continue;
    const std::string_view key = TrimWhitespace(line.substr(0, eq));
    const std::string_view value = TrimWhitespace(line.substr(eq + 1));
    auto count = [&](int64_t& field) {
      if (auto v = ParseInt64(value)) field = *v;
    };
    if (key == "images")
      count(d.images);
    else if (key == "channels")
      count(d.channels);
    else if (key == "slices")
      count(d.slices);
    else if (key == "frames")
      count(d.frames);
    else if (key == "hyperstack")
      d.hyperstack = value == "true";
    else if (key == "spacing")
      d.spacing = ParseDouble(value);
    else if (key == "finterval")
      d.finterval = ParseDouble(value);
    else if (key == "unit")
      d.unit = DecodeUnicodeEscapes(value);
  }
  return d;
}

std::optional<double> MicrometresPerUnit(std::string_view unit) {
  const std::string u = ToLower(TrimWhitespace(unit));
  if (u == "micron" || u == "microns" || u == "um" || u == "\xC2\xB5m" || u == "\xCE\xBCm" ||
      u == "micrometer" || u == "micrometre" || u == "micrometers" || u == "micrometres") {
    return 1.0;
  }
  if (u == "nm" || u == "nanometer" || u == "nanometre" || u == "nanometers") return 1e-3;
  if (u == "mm" || u == "millimeter" || u == "millimetre" || u == "millimeters") return 1e3;
  if (u == "cm" || u == "centimeter" || u == "centimetre" || u == "centimeters") return 1e4;
  if (u == "m" || u == "meter" || u == "metre" || u == "meters") return 1e6;
  if (u == "inch" || u == "inches" || u == "in") return 25400.0;
  if (u == "angstrom" || u == "\xC3\x85") return 1e-4;
  return std::nullopt;
}

Result<std::unique_ptr<VolumeSource>> OpenTiffStack(std::unique_ptr<TiffFile> file,
                                                    const OpenOptions& options) {
  const std::string name = file->path().string();
  if (options.series != 0) {
    return OutOfRangeError(name + ": series " + std::to_string(options.series) +
                           " requested, a TIFF stack has 1 series");
  }
  const TiffIfd& first = file->ifd(0);
  if (std::optional<ImageJDescription> ij = ParseImageJDescription(first.description)) {
    if (!first.dtype) {
      return UnsupportedError(name + ": IFD 0 has " + Dtype(first) +
                              " samples, which Octoscope cannot read");
    }
    return OpenImageJ(std::move(file), *ij, options);
  }
  if (first.dtype && first.samples_per_pixel == 1) {
    const std::string metadata = first.software + "\n" + first.description;
    if (std::optional<ScanImageLayout> si = ScanImageLayoutOf(metadata, file->ifd_count())) {
      return OpenScanImage(std::move(file), *si, options);
    }
  }
  return OpenPlain(std::move(file), options);
}

Result<std::unique_ptr<VolumeSource>> OpenTiffStack(const std::filesystem::path& path,
                                                    const OpenOptions& options) {
  TiffFile::Limits limits;
  limits.max_plane_bytes = options.max_plane_bytes;
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<TiffFile> file, TiffFile::Open(path, limits));
  return OpenTiffStack(std::move(file), options);
}

}  // namespace octoscope::io
