#include "io/tiff_stack_volume.h"

#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "io/spacing.h"
#include "util/byte_swap.h"
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
        if (swap) SwapBytesInPlace(plane, bytes);
      } else {
        OCTO_RETURN_IF_ERROR(
            file_->ReadPlane(static_cast<int>(id), samples_are_channels_ ? channel : 0, plane));
      }
    }
    return Status::Ok();
  }

  std::optional<StoredPlane> FindStoredPlane(int channel, int64_t z) const override {
    if (channel < 0 || channel >= info_.channel_count() || z < 0 || z >= info_.size[2]) {
      return std::nullopt;
    }
    const int64_t id =
        samples_are_channels_ ? planes_[z] : planes_[z * info_.channel_count() + channel];
    if (data_offset_) {
      // ImageJ > 4 GB: the images are raw runs of the file, in the file's byte order.
      const size_t bytes = volume::BytesPerSample(info_.dtype);
      if (bytes > 1 && file_->big_endian() != (std::endian::native == std::endian::big)) {
        return std::nullopt;
      }
      return StoredPlane{file_, *data_offset_ + static_cast<uint64_t>(id) * SlabBytes(1)};
    }
    std::optional<uint64_t> offset =
        file_->StoredPlaneOffset(static_cast<int>(id), samples_are_channels_ ? channel : 0);
    if (!offset) return std::nullopt;
    return StoredPlane{file_, *offset};
  }

 private:
  const std::shared_ptr<TiffFile> file_;
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

// A page whose samples become channels must not declare more than a volume may have.
Status CheckSampleChannels(const std::string& name, int64_t index, const TiffIfd& page) {
  return volume::CheckChannelCount(page.samples_per_pixel)
      .WithContext(name + ": IFD " + std::to_string(index) + " has " +
                   std::to_string(page.samples_per_pixel) +
                   " samples per pixel, each of which would be a channel");
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
// not fit the file (then the file opens as a plain stack). Every count is bounded by `pages`
// before it is multiplied: a product that overflows or needs more pages than the file has means
// the metadata does not describe this file.
std::optional<ScanImageLayout> ScanImageLayoutOf(std::string_view metadata, int64_t pages) {
  const auto keys = ParseScanImageKeys(metadata);
  auto save = keys.find("SI.hChannels.channelSave");
  if (save == keys.end()) return std::nullopt;
  const int64_t channels = static_cast<int64_t>(ParseMatlabNumbers(save->second).size());
  if (channels < 1 || channels > pages) return std::nullopt;

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
  // Both factors are < 1e9, so the product fits; more pages per volume than the file has is no fit.
  int64_t per_volume = frames * slices;
  if (per_volume > pages) return std::nullopt;
  if (fast_z && !ScanImageTrue(keys, "SI.hFastZ.discardFlybackFrames")) {
    // Fly-back frames are stored after the slices of each volume.
    std::optional<double> with_flyback =
        ScanImageNumber(keys, "SI.hStackManager.numFramesPerVolumeWithFlyback");
    if (with_flyback && *with_flyback > static_cast<double>(per_volume) && *with_flyback < 1e9) {
      per_volume = static_cast<int64_t>(*with_flyback);
    }
  }
  const std::optional<uint64_t> pages_per_volume =
      CheckedProduct({static_cast<uint64_t>(channels), static_cast<uint64_t>(per_volume)});
  if (!pages_per_volume || *pages_per_volume == 0 ||
      *pages_per_volume > static_cast<uint64_t>(pages)) {
    return std::nullopt;
  }
  const int64_t volumes = pages / static_cast<int64_t>(*pages_per_volume);  // >= 1.

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
  // Channels size a table: bound them before anything else.
  if (ij.channels > 0) {
    OCTO_RETURN_IF_ERROR(volume::CheckChannelCount(ij.channels)
                             .WithContext(name + ": ImageJ description declares channels=" +
                                          std::to_string(ij.channels)));
  }
  int64_t c = std::max<int64_t>(1, ij.channels);
  int64_t z = std::max<int64_t>(1, ij.slices);
  int64_t t = std::max<int64_t>(1, ij.frames);
  const std::optional<uint64_t> product = CheckedProduct(
      {static_cast<uint64_t>(c), static_cast<uint64_t>(z), static_cast<uint64_t>(t)});
  const int64_t images = ij.images > 0 ? ij.images : static_cast<int64_t>(product.value_or(0));
  // The most images the file can hold, worked out before the description sizes anything: one per
  // IFD, or (a single IFD: ImageJ's > 4 GB layout) as many whole planes as fit in the file.
  const uint64_t page_bytes = uint64_t{first.width} * first.height * first.samples_per_pixel *
                              volume::BytesPerSample(*first.dtype);  // Checked at Open.
  const uint64_t capacity = file->ifd_count() > 1
                                ? static_cast<uint64_t>(file->ifd_count())
                                : std::max<uint64_t>(1, file->file_size() / page_bytes);
  if (!product || *product > capacity || static_cast<uint64_t>(images) > capacity) {
    return CorruptError(name + ": ImageJ description declares images=" + std::to_string(images) +
                        " (channels x slices x frames = " +
                        (product ? std::to_string(*product) : std::string("overflow")) +
                        "), but the file can hold at most " + std::to_string(capacity) + " images");
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
  OCTO_RETURN_IF_ERROR(CheckSampleChannels(name, 0, first));
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
  info.spacing_um = TiffPageSpacing(first, &ij);

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
  info.spacing_um = TiffPageSpacing(first, nullptr);
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
  OCTO_RETURN_IF_ERROR(CheckSampleChannels(name, planes[0], first));
  for (int64_t p : planes) {
    OCTO_RETURN_IF_ERROR(CheckSamePage(*file, static_cast<int>(planes[0]), static_cast<int>(p)));
  }
  OCTO_RETURN_IF_ERROR(CheckTime(name, options.time, 1));
  volume::VolumeInfo info;
  info.format = "tiff";
  info.size = {first.width, first.height, static_cast<int64_t>(planes.size())};
  info.channels.resize(first.samples_per_pixel);
  info.dtype = *first.dtype;
  info.spacing_um = TiffPageSpacing(first, nullptr);
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
  const std::string metadata = first.software + "\n" + first.description;
  const bool scanimage = ParseScanImageKeys(metadata).contains("SI.hChannels.channelSave");
  if (scanimage && first.dtype && first.samples_per_pixel == 1) {
    if (std::optional<ScanImageLayout> si = ScanImageLayoutOf(metadata, file->ifd_count())) {
      return OpenScanImage(std::move(file), *si, options);
    }
  }
  if (!scanimage) return OpenPlain(std::move(file), options);
  // ScanImage metadata that does not describe this file: say so rather than reinterpret quietly.
  const std::string warning =
      name + ": its ScanImage metadata does not fit the file (" +
      std::to_string(file->ifd_count()) + " pages of " + std::to_string(first.samples_per_pixel) +
      " samples); read as a plain TIFF stack instead: each page is a z plane";
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<VolumeSource> plain, OpenPlain(std::move(file), options));
  return WithWarnings(std::move(plain), {warning});
}

Result<std::unique_ptr<VolumeSource>> OpenTiffStack(const std::filesystem::path& path,
                                                    const OpenOptions& options) {
  TiffFile::Limits limits;
  limits.max_plane_bytes = options.max_plane_bytes;
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<TiffFile> file,
                        TiffFile::Open(path, limits, options.file_gate));
  return OpenTiffStack(std::move(file), options);
}

}  // namespace octoscope::io
