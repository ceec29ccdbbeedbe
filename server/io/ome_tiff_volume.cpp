#include "io/ome_tiff_volume.h"

#include <algorithm>
#include <map>
#include <optional>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "io/file_gate.h"
#include "io/ome_xml.h"
#include "io/spacing.h"
#include "io/tiff_file.h"
#include "io/tiff_file_cache.h"
#include "io/tiff_stack_volume.h"
#include "util/checked_math.h"
#include "util/strings.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

// Planes (z, c, t) one series may declare: bounds the work of walking TiffData at open (a few
// seconds at worst). Real series have at most millions of planes.
constexpr uint64_t kMaxPlanesPerSeries = uint64_t{1} << 28;
// Planes (z, c) of one time point: bounds the plane table (8 bytes each) built at open.
constexpr uint64_t kMaxPlanesPerTimePoint = uint64_t{1} << 22;

// The largest TIFF page index accepted (TiffFile refuses far fewer IFDs anyway).
constexpr int64_t kMaxIfdIndex = (int64_t{1} << 31) - 1;

std::string Quote(const fs::path& path) { return path.string(); }

// ----------------------------------------------------------------------------------------------
// Plane order.

// The three non-XY dimensions of `order` from fastest to slowest, as 0 = Z, 1 = C, 2 = T.
std::array<int, 3> AxisOrder(DimensionOrder order) {
  std::string_view name = DimensionOrderName(order);
  std::array<int, 3> axes{};
  for (int k = 0; k < 3; ++k) {
    char letter = name[2 + k];
    axes[k] = letter == 'Z' ? 0 : letter == 'C' ? 1 : 2;
  }
  return axes;
}

// Converts between a plane index and (z, c, t) for one DimensionOrder and extent.
class PlaneOrder {
 public:
  PlaneOrder(DimensionOrder order, std::array<int64_t, 3> sizes_zct)
      : axes_(AxisOrder(order)), sizes_(sizes_zct) {}

  // REQUIRES: 0 <= zct[i] < sizes[i].
  uint64_t Index(std::array<int64_t, 3> zct) const {
    uint64_t index = 0;
    for (int k = 2; k >= 0; --k) {
      index =
          index * static_cast<uint64_t>(sizes_[axes_[k]]) + static_cast<uint64_t>(zct[axes_[k]]);
    }
    return index;
  }

  // REQUIRES: index < product of sizes.
  std::array<int64_t, 3> Coordinates(uint64_t index) const {
    std::array<int64_t, 3> zct{};
    for (int k = 0; k < 3; ++k) {
      uint64_t size = static_cast<uint64_t>(sizes_[axes_[k]]);
      zct[axes_[k]] = static_cast<int64_t>(index % size);
      index /= size;
    }
    return zct;
  }

 private:
  std::array<int, 3> axes_;
  std::array<int64_t, 3> sizes_;
};

// ----------------------------------------------------------------------------------------------
// Open files.

// ----------------------------------------------------------------------------------------------
// The source.

// Where one plane of one channel group lives.
struct PlaneRef {
  int file = -1;  // Index into OmeTiffVolume::files_; -1: not mapped.
  int ifd = 0;
};

// A run of C indices stored together: one OME Channel (samples_per_pixel > 1 for RGB-style).
struct ChannelGroup {
  int samples_per_pixel = 1;
  std::string name;
  std::optional<volume::Rgba> color;
};

class OmeTiffVolume final : public VolumeSource {
 public:
  // `name`: the file the user opened, for messages.
  OmeTiffVolume(std::string name, volume::VolumeInfo info, std::vector<fs::path> files,
                std::vector<PlaneRef> planes, std::vector<std::pair<int, int>> channel_map,
                std::shared_ptr<TiffFileCache> cache)
      : name_(std::move(name)),
        info_(std::move(info)),
        files_(std::move(files)),
        planes_(std::move(planes)),
        channel_map_(std::move(channel_map)),
        cache_(std::move(cache)) {}

  const volume::VolumeInfo& info() const override { return info_; }

  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    OCTO_RETURN_IF_ERROR(CheckSlabRequest(info_, channel, z0, nz, out.size()).WithContext(name_));
    const auto [group, sample] = channel_map_[channel];
    const size_t plane_bytes = info_.PlaneVoxels() * volume::BytesPerSample(info_.dtype);
    for (int64_t k = 0; k < nz; ++k) {
      const int64_t z = z0 + k;
      const PlaneRef& ref = planes_[static_cast<size_t>(group) * info_.size[2] + z];
      const fs::path& path = files_[ref.file];
      Result<std::shared_ptr<TiffFile>> file = cache_->Get(path);
      if (!file.ok()) return file.status();
      // An evicted file is reopened here: re-check the page in case the file changed on disk.
      if (ref.ifd >= (*file)->ifd_count() || (*file)->ifd(ref.ifd).width != info_.size[0] ||
          (*file)->ifd(ref.ifd).height != info_.size[1] ||
          (*file)->ifd(ref.ifd).dtype != info_.dtype) {
        return CorruptError(Quote(path) + ": IFD " + std::to_string(ref.ifd) +
                            " no longer matches the OME-XML (file changed since it was opened)");
      }
      Status status = (*file)->ReadPlane(
          ref.ifd, sample, out.subspan(static_cast<size_t>(k) * plane_bytes, plane_bytes));
      if (!status.ok()) {
        // ReadPlane's message already starts with "<file>: IFD <n>"; add where the plane belongs.
        return Status(status.code(), status.message() + " (plane z " + std::to_string(z) +
                                         ", channel " + std::to_string(channel) + ")");
      }
    }
    return Status::Ok();
  }

  std::optional<StoredPlane> FindStoredPlane(int channel, int64_t z) const override {
    if (channel < 0 || channel >= info_.channel_count() || z < 0 || z >= info_.size[2]) {
      return std::nullopt;
    }
    const auto [group, sample] = channel_map_[channel];
    const PlaneRef& ref = planes_[static_cast<size_t>(group) * info_.size[2] + z];
    // The returned plane holds the file open, so the cache may close its own handle meanwhile.
    Result<std::shared_ptr<TiffFile>> file = cache_->Get(files_[ref.file]);
    if (!file.ok()) return std::nullopt;
    // As in ReadSlab: a reopened file must still match the OME-XML.
    if (ref.ifd >= (*file)->ifd_count() || (*file)->ifd(ref.ifd).width != info_.size[0] ||
        (*file)->ifd(ref.ifd).height != info_.size[1] ||
        (*file)->ifd(ref.ifd).dtype != info_.dtype) {
      return std::nullopt;
    }
    std::optional<uint64_t> offset = (*file)->StoredPlaneOffset(ref.ifd, sample);
    if (!offset) return std::nullopt;
    return StoredPlane{*std::move(file), *offset};
  }

 private:
  const std::string name_;
  const volume::VolumeInfo info_;
  const std::vector<fs::path> files_;
  // planes_[group * size_z + z] for the selected series and time point; every entry mapped.
  const std::vector<PlaneRef> planes_;
  // channel -> (group, sample within the group's pages).
  const std::vector<std::pair<int, int>> channel_map_;
  const std::shared_ptr<TiffFileCache> cache_;
};

// ----------------------------------------------------------------------------------------------
// Opening.

// Where the OME-XML came from: a TIFF's first ImageDescription or a companion XML file.
struct XmlDocument {
  OmeMetadata metadata;
  fs::path source;  // The file holding the XML.
  bool in_tiff = false;
};

// Loads the OME-XML held by `path` (a TIFF or an XML file) without following references. Sets
// `*malformed_in_tiff` (when given) if `path` is a TIFF whose own OME-XML does not parse. Files
// are read through the cache's gate.
Result<XmlDocument> LoadXml(const fs::path& path, TiffFileCache& cache,
                            bool* malformed_in_tiff = nullptr) {
  const FileGate& gate = cache.gate();
  OCTO_ASSIGN_OR_RETURN(const fs::file_type type, gate.Type(path));
  if (type != fs::file_type::regular) return NotFoundError(Quote(path) + ": no such file");
  XmlDocument doc;
  doc.source = path;
  std::string xml;
  if (HasTiffSignature(path, gate)) {
    doc.in_tiff = true;
    OCTO_ASSIGN_OR_RETURN(std::shared_ptr<TiffFile> file, cache.Get(path));
    if (file->ifd_count() < 1) return CorruptError(Quote(path) + ": TIFF without pages");
    xml = file->ifd(0).description;
    if (!LooksLikeOmeXml(xml)) {
      return UnsupportedError(Quote(path) + ": not an OME-TIFF (no OME-XML in ImageDescription)");
    }
  } else {
    OCTO_ASSIGN_OR_RETURN(xml, gate.ReadSmallFile(path, kMaxOmeXmlBytes));
    if (!LooksLikeOmeXml(xml)) {
      return UnsupportedError(Quote(path) + ": neither a TIFF nor an OME-XML document");
    }
  }
  Result<OmeMetadata> metadata = ParseOmeXml(xml, Quote(path));
  if (!metadata.ok()) {
    if (doc.in_tiff && malformed_in_tiff != nullptr &&
        metadata.status().code() == StatusCode::kCorrupt) {
      *malformed_in_tiff = true;
    }
    return metadata.status();
  }
  doc.metadata = *std::move(metadata);
  return doc;
}

// Loads the document with the full metadata for `path`, following a BinaryOnly reference once.
// Sets `*malformed_in_tiff` when `path` itself is a TIFF whose own OME-XML does not parse (not
// when a document it refers to is malformed: that one is reported as an error).
Result<XmlDocument> LoadMetadata(const fs::path& path, TiffFileCache& cache,
                                 bool* malformed_in_tiff) {
  OCTO_ASSIGN_OR_RETURN(XmlDocument doc, LoadXml(path, cache, malformed_in_tiff));
  if (!doc.metadata.binary_only) return doc;
  fs::path master =
      (path.parent_path() / doc.metadata.binary_only->metadata_file).lexically_normal();
  Result<XmlDocument> followed = LoadXml(master, cache);
  if (!followed.ok()) {
    return followed.status().WithContext(Quote(path) + ": metadata file named by BinaryOnly");
  }
  if (followed->metadata.binary_only) {
    return CorruptError(Quote(master) + ": BinaryOnly metadata file " + Quote(path) +
                        " points to is itself only a reference");
  }
  return followed;
}

// Resolves TiffData elements to files, deduplicated.
class FileResolver {
 public:
  FileResolver(const XmlDocument& doc, const OmePixels& pixels) : doc_(doc) {
    // UUIDs named together with a FileName anywhere in the image let bare UUIDs be resolved.
    for (const OmeTiffData& td : pixels.tiff_data) {
      if (!td.uuid.empty() && !td.file_name.empty()) {
        uuid_files_.emplace(td.uuid, td.file_name);
      }
    }
  }

  // The index into files() of the file holding `td`'s planes.
  Result<int> Resolve(const OmeTiffData& td) {
    const bool own_uuid = !td.uuid.empty() && td.uuid == doc_.metadata.uuid;
    if (doc_.in_tiff && (own_uuid || (td.uuid.empty() && td.file_name.empty()))) {
      // The file holding the XML (robust against the file having been renamed).
      return Add(doc_.source);
    }
    std::string name = td.file_name;
    if (name.empty() && !td.uuid.empty()) {
      auto it = uuid_files_.find(td.uuid);
      if (it == uuid_files_.end()) {
        return NotFoundError(Quote(doc_.source) + ": TiffData UUID " + Printable(td.uuid) +
                             " names no known file");
      }
      name = it->second;
    }
    if (name.empty()) {
      return CorruptError(Quote(doc_.source) + ": TiffData names no file (no UUID/FileName)");
    }
    return Add((doc_.source.parent_path() / name).lexically_normal());
  }

  const std::vector<fs::path>& files() const { return files_; }

 private:
  int Add(const fs::path& path) {
    auto [it, inserted] = index_.emplace(path.string(), static_cast<int>(files_.size()));
    if (inserted) files_.push_back(path);
    return it->second;
  }

  const XmlDocument& doc_;
  std::map<std::string, std::string> uuid_files_;
  std::map<std::string, int> index_;
  std::vector<fs::path> files_;
};

// One TiffData resolved: planes [start, start + count) of the series lie in IFDs
// [ifd, ifd + count) of files[file].
struct PlaneRun {
  int file = 0;
  int64_t ifd = 0;
  uint64_t start = 0;
  uint64_t count = 0;
};

std::string ZctName(const std::array<int64_t, 3>& zct) {
  return "z " + std::to_string(zct[0]) + ", c " + std::to_string(zct[1]) + ", t " +
         std::to_string(zct[2]);
}

// Builds the channel groups: one per Channel when their SamplesPerPixel add up to SizeC, else
// groups of the sample count of the first page (or single samples).
std::vector<ChannelGroup> MakeChannelGroups(const OmePixels& pixels, int first_page_samples) {
  std::vector<ChannelGroup> groups;
  int64_t sum = 0;
  for (const OmeChannel& ch : pixels.channels) sum += ch.samples_per_pixel.value_or(1);
  if (!pixels.channels.empty() && sum == pixels.size_c) {
    for (const OmeChannel& ch : pixels.channels) {
      groups.push_back({ch.samples_per_pixel.value_or(1), ch.name, ch.color});
    }
    return groups;
  }
  int spp =
      (first_page_samples > 1 && pixels.size_c % first_page_samples == 0) ? first_page_samples : 1;
  for (int64_t c = 0; c < pixels.size_c / spp; ++c) {
    ChannelGroup group;
    group.samples_per_pixel = spp;
    if (static_cast<size_t>(c) < pixels.channels.size()) {
      group.name = pixels.channels[c].name;
      group.color = pixels.channels[c].color;
    }
    groups.push_back(std::move(group));
  }
  return groups;
}

// The steps of Open: check the selected series -> resolve files -> build runs -> plane table ->
// verify pages -> build info. Each takes `source` (the file holding the XML) for its messages.

// Checks the series' sizes against the limits before any table is sized by them.
Status CheckPixels(const std::string& source, const OmePixels& pixels, const OpenOptions& options) {
  const size_t bytes_per_sample = volume::BytesPerSample(pixels.type);
  std::optional<uint64_t> plane_bytes =
      CheckedProduct({static_cast<uint64_t>(pixels.size_x), static_cast<uint64_t>(pixels.size_y),
                      bytes_per_sample});
  if (!plane_bytes || *plane_bytes > options.max_plane_bytes) {
    return ResourceExhaustedError(source + ": a " + std::to_string(pixels.size_x) + "x" +
                                  std::to_string(pixels.size_y) + " plane exceeds the limit of " +
                                  std::to_string(options.max_plane_bytes) + " bytes");
  }
  if (pixels.tiff_data.empty()) {
    if (pixels.has_bin_data) {
      return UnsupportedError(source + ": pixels embedded as BinData (pure OME-XML), not OME-TIFF");
    }
    return CorruptError(source + ": image " + std::to_string(options.series) +
                        " has no TiffData: no planes are stored");
  }
  // Bound the tables built later (SizeC sizes the channel list; Z x C the plane table; Z x C x T
  // the walk over TiffData).
  OCTO_RETURN_IF_ERROR(volume::CheckChannelCount(pixels.size_c)
                           .WithContext(source + ": series " + std::to_string(options.series) +
                                        " declares SizeC=" + std::to_string(pixels.size_c)));
  std::optional<uint64_t> declared_planes =
      CheckedProduct({static_cast<uint64_t>(pixels.size_z), static_cast<uint64_t>(pixels.size_c),
                      static_cast<uint64_t>(pixels.size_time)});
  if (static_cast<uint64_t>(pixels.size_z) * static_cast<uint64_t>(pixels.size_c) >
          kMaxPlanesPerTimePoint ||
      !declared_planes || *declared_planes > kMaxPlanesPerSeries) {
    return ResourceExhaustedError(
        source + ": series " + std::to_string(options.series) + " declares " +
        std::to_string(pixels.size_z) + " z x " + std::to_string(pixels.size_c) + " c x " +
        std::to_string(pixels.size_time) + " t planes, more than supported (" +
        std::to_string(kMaxPlanesPerTimePoint) + " planes per time point, " +
        std::to_string(kMaxPlanesPerSeries) + " in all)");
  }
  return Status::Ok();
}

// The files a series' TiffData name, opened on demand through the cache; remembers the IFD count
// of each file opened so far.
class PageFiles {
 public:
  PageFiles(std::string source, std::vector<fs::path> files, TiffFileCache& cache)
      : source_(std::move(source)),
        files_(std::move(files)),
        cache_(cache),
        ifd_counts_(files_.size()) {}

  const std::vector<fs::path>& files() const { return files_; }
  // nullopt until file `index` was opened.
  std::optional<int> ifd_count(int index) const { return ifd_counts_[index]; }

  // Opens file `index` (checking existence first, for a clear message).
  Result<std::shared_ptr<TiffFile>> Open(int index) {
    OCTO_ASSIGN_OR_RETURN(const fs::file_type type, cache_.gate().Type(files_[index]));
    if (type != fs::file_type::regular) {
      return NotFoundError(source_ + ": OME-XML references " + Quote(files_[index]) +
                           ", which does not exist");
    }
    OCTO_ASSIGN_OR_RETURN(std::shared_ptr<TiffFile> file, cache_.Get(files_[index]));
    ifd_counts_[index] = file->ifd_count();
    return file;
  }

 private:
  const std::string source_;
  const std::vector<fs::path> files_;
  TiffFileCache& cache_;
  std::vector<std::optional<int>> ifd_counts_;
};

// Step 2: each TiffData becomes a run of planes in consecutive IFDs of one file.
Result<std::vector<PlaneRun>> BuildRuns(const std::string& source, const OmePixels& pixels,
                                        const std::vector<int>& td_files, const PlaneOrder& order,
                                        uint64_t total_planes, int64_t group_count,
                                        PageFiles& files) {
  std::vector<PlaneRun> runs;
  uint64_t mapped_total = 0;
  for (size_t i = 0; i < pixels.tiff_data.size(); ++i) {
    const OmeTiffData& td = pixels.tiff_data[i];
    const std::string what = source + ": TiffData " + std::to_string(i);
    if (td.first_c >= group_count) {
      return CorruptError(what + ": FirstC " + std::to_string(td.first_c) + " exceeds the " +
                          std::to_string(group_count) + " channels stored as pages");
    }
    PlaneRun run;
    run.file = td_files[i];
    run.ifd = td.ifd.value_or(0);
    run.start = order.Index({td.first_z, td.first_c, td.first_t});
    const uint64_t remaining_planes = total_planes - run.start;
    if (td.plane_count) {
      run.count = static_cast<uint64_t>(*td.plane_count);
    } else if (td.ifd) {
      run.count = 1;
    } else if (pixels.tiff_data.size() == 1) {
      run.count = remaining_planes;  // The sole TiffData: every plane, in order.
    } else {
      // All remaining pages of the file.
      if (!files.ifd_count(run.file)) {
        Result<std::shared_ptr<TiffFile>> opened = files.Open(run.file);
        if (!opened.ok()) return opened.status();
      }
      run.count = std::min<uint64_t>(
          remaining_planes, static_cast<uint64_t>(std::max(0, *files.ifd_count(run.file))));
    }
    if (run.count > remaining_planes) {
      return CorruptError(what + ": PlaneCount " + std::to_string(run.count) + " from plane " +
                          std::to_string(run.start) + " runs past the image's " +
                          std::to_string(total_planes) + " planes");
    }
    if (run.count > 0 &&
        static_cast<uint64_t>(run.ifd) + run.count - 1 > static_cast<uint64_t>(kMaxIfdIndex)) {
      return CorruptError(what + ": IFD index beyond 2^31");
    }
    mapped_total += run.count;
    if (mapped_total > total_planes) {
      return CorruptError(source + ": TiffData elements map more planes than the image's " +
                          std::to_string(total_planes));
    }
    runs.push_back(run);
  }
  return runs;
}

// Step 3: the plane table of the selected time point (planes[group * size_z + z]); marks in
// `needed` the files it uses. Errors when a plane is not mapped.
Result<std::vector<PlaneRef>> BuildPlaneTable(const std::string& source,
                                              const std::vector<PlaneRun>& runs,
                                              const PlaneOrder& order, int64_t size_z,
                                              int64_t group_count, const OpenOptions& options,
                                              std::vector<bool>& needed) {
  std::vector<PlaneRef> planes(static_cast<size_t>(group_count * size_z));
  for (const PlaneRun& run : runs) {
    for (uint64_t k = 0; k < run.count; ++k) {
      std::array<int64_t, 3> zct = order.Coordinates(run.start + k);
      if (zct[2] != options.time) continue;
      PlaneRef& ref = planes[static_cast<size_t>(zct[1] * size_z + zct[0])];
      if (ref.file >= 0) continue;  // Mapped twice: the first TiffData wins.
      ref.file = run.file;
      ref.ifd = static_cast<int>(run.ifd + static_cast<int64_t>(k));
      needed[run.file] = true;
    }
  }
  for (int64_t g = 0; g < group_count; ++g) {
    for (int64_t z = 0; z < size_z; ++z) {
      if (planes[static_cast<size_t>(g * size_z + z)].file < 0) {
        return CorruptError(source + ": plane (" + ZctName({z, g, options.time}) + ") of series " +
                            std::to_string(options.series) +
                            " is not stored in any TIFF page (no TiffData maps it)");
      }
    }
  }
  return planes;
}

// Step 4: verifies the pages of the runs. Files the selected time point needs are opened; runs
// in files opened anyway are checked too, so an XML claiming more pages than a file holds is
// caught early.
Status VerifyPages(const std::string& source, const OmePixels& pixels,
                   const std::vector<PlaneRun>& runs, const PlaneOrder& order,
                   const std::vector<ChannelGroup>& groups, const std::vector<bool>& needed,
                   PageFiles& files) {
  for (size_t f = 0; f < files.files().size(); ++f) {
    if (!needed[f] && !files.ifd_count(static_cast<int>(f))) continue;
    OCTO_ASSIGN_OR_RETURN(std::shared_ptr<TiffFile> file, files.Open(static_cast<int>(f)));
    const std::string name = Quote(files.files()[f]);
    for (const PlaneRun& run : runs) {
      if (run.file != static_cast<int>(f) || run.count == 0) continue;
      const uint64_t last = static_cast<uint64_t>(run.ifd) + run.count - 1;
      if (last >= static_cast<uint64_t>(file->ifd_count())) {
        const std::string xml_where = name == source ? "" : " in " + source;
        return CorruptError(name + ": OME-XML" + xml_where + " maps planes to IFDs " +
                            std::to_string(run.ifd) + ".." + std::to_string(last) +
                            ", but the file has only " + std::to_string(file->ifd_count()) +
                            " IFDs");
      }
      for (uint64_t k = 0; k < run.count; ++k) {
        const int index = static_cast<int>(run.ifd + static_cast<int64_t>(k));
        const TiffIfd& ifd = file->ifd(index);
        const std::string page = name + ": IFD " + std::to_string(index);
        if (ifd.width != pixels.size_x || ifd.height != pixels.size_y) {
          return CorruptError(page + " is " + std::to_string(ifd.width) + "x" +
                              std::to_string(ifd.height) + ", OME-XML Pixels says " +
                              std::to_string(pixels.size_x) + "x" + std::to_string(pixels.size_y));
        }
        if (!ifd.dtype) {
          return UnsupportedError(page + ": sample layout (" + std::to_string(ifd.bits_per_sample) +
                                  " bits, format " + std::to_string(ifd.sample_format) +
                                  ") is not supported");
        }
        if (*ifd.dtype != pixels.type) {
          return CorruptError(page + " holds " + std::string(volume::NumpyName(*ifd.dtype)) +
                              " samples, OME-XML Pixels@Type says " +
                              std::string(volume::NumpyName(pixels.type)));
        }
        const std::array<int64_t, 3> zct = order.Coordinates(run.start + k);
        const int want_samples = groups[static_cast<size_t>(zct[1])].samples_per_pixel;
        if (ifd.samples_per_pixel != want_samples) {
          return CorruptError(page + " has " + std::to_string(ifd.samples_per_pixel) +
                              " samples per pixel, OME-XML expects " +
                              std::to_string(want_samples) + " for channel group " +
                              std::to_string(zct[1]));
        }
      }
    }
  }
  return Status::Ok();
}

// Step 5: the volume's info (channels expanded from the groups, spacing with the overrides) and
// the map channel -> (group, sample).
volume::VolumeInfo BuildInfo(const OmePixels& pixels, const std::vector<ChannelGroup>& groups,
                             const OpenOptions& options, int series_count,
                             std::vector<std::pair<int, int>>& channel_map) {
  volume::VolumeInfo info;
  info.format = "ome-tiff";
  info.size = {pixels.size_x, pixels.size_y, pixels.size_z};
  info.dtype = pixels.type;
  for (size_t g = 0; g < groups.size(); ++g) {
    const ChannelGroup& group = groups[g];
    static constexpr volume::Rgba kRgb[3] = {{255, 0, 0, 255}, {0, 255, 0, 255}, {0, 0, 255, 255}};
    for (int s = 0; s < group.samples_per_pixel; ++s) {
      volume::ChannelInfo channel;
      channel.name = group.name;
      channel.color = group.color;
      // RGB pages without a colour: show them as red, green and blue.
      if (!channel.color && group.samples_per_pixel == 3) channel.color = kRgb[s];
      info.channels.push_back(std::move(channel));
      channel_map.emplace_back(static_cast<int>(g), s);
    }
  }
  info.spacing_um = pixels.physical_size_um;
  ApplySpacingOverrides(info, options);
  info.series_count = series_count;
  info.series = options.series;
  info.time_points = static_cast<int>(pixels.size_time);  // <= kMaxPlanesPerSeries < 2^31.
  info.time = options.time;
  return info;
}

// A TIFF whose own OME-XML is malformed is read as what it also is, a plain TIFF stack, as
// tifffile does, never silently: the source carries a warning that names the file and the XML's
// problem. When the pages do not form a stack either, the XML's error is returned with that.
Result<std::unique_ptr<VolumeSource>> OpenAsPlainTiff(const fs::path& path,
                                                      const OpenOptions& options,
                                                      const Status& xml_error) {
  Result<std::unique_ptr<VolumeSource>> plain = OpenTiffStack(path, options);
  if (!plain.ok()) {
    return Status(xml_error.code(), xml_error.message() +
                                        "; nor can the file be read as a plain TIFF stack: " +
                                        plain.status().message());
  }
  return WithWarnings(std::move(*plain),
                      {xml_error.message() +
                       "; read as a plain TIFF instead: each page is a z plane and each sample a "
                       "channel, and the OME-XML's dimensions, channels and spacing are ignored"});
}

Result<std::unique_ptr<VolumeSource>> Open(const fs::path& input, const OpenOptions& options) {
  std::error_code ec;
  const fs::path absolute = fs::absolute(input, ec);
  if (ec) return IoError(Quote(input) + ": cannot resolve the path: " + ec.message());
  const fs::path path = absolute.lexically_normal();
  TiffFile::Limits limits;
  limits.max_plane_bytes = options.max_plane_bytes;
  auto cache = std::make_shared<TiffFileCache>(limits, kMaxOpenOmeTiffFiles, options.file_gate);

  bool malformed = false;
  Result<XmlDocument> loaded = LoadMetadata(path, *cache, &malformed);
  if (!loaded.ok()) {
    if (malformed) return OpenAsPlainTiff(path, options, loaded.status());
    return loaded.status();
  }
  XmlDocument doc = *std::move(loaded);
  const std::string source = Quote(doc.source);
  const std::vector<OmeImage>& images = doc.metadata.images;
  const int series_count = static_cast<int>(std::min<size_t>(images.size(), INT32_MAX));
  if (options.series < 0 || options.series >= series_count) {
    return OutOfRangeError(source + ": series " + std::to_string(options.series) +
                           " requested, the file has " + std::to_string(series_count) +
                           " series (OME Images)");
  }
  const OmePixels& pixels = images[options.series].pixels;
  if (options.time < 0 || options.time >= pixels.size_time) {
    return OutOfRangeError(source + ": time point " + std::to_string(options.time) +
                           " requested, series " + std::to_string(options.series) + " has " +
                           std::to_string(pixels.size_time) + " (SizeT)");
  }
  OCTO_RETURN_IF_ERROR(CheckPixels(source, pixels, options));

  // Step 1: resolve files; learn the first page's sample count (needed when Channel elements are
  // absent).
  FileResolver resolver(doc, pixels);
  std::vector<int> td_files;
  for (const OmeTiffData& td : pixels.tiff_data) {
    OCTO_ASSIGN_OR_RETURN(int file, resolver.Resolve(td));
    td_files.push_back(file);
  }
  PageFiles files(source, resolver.files(), *cache);
  int first_page_samples = 1;
  {
    OCTO_ASSIGN_OR_RETURN(std::shared_ptr<TiffFile> first, files.Open(td_files[0]));
    int64_t ifd = pixels.tiff_data[0].ifd.value_or(0);
    if (ifd < first->ifd_count()) {
      first_page_samples = first->ifd(static_cast<int>(ifd)).samples_per_pixel;
    }
  }
  const std::vector<ChannelGroup> groups = MakeChannelGroups(pixels, first_page_samples);
  const int64_t group_count = static_cast<int64_t>(groups.size());
  const std::array<int64_t, 3> sizes_zct{pixels.size_z, group_count, pixels.size_time};
  std::optional<uint64_t> total_planes =
      CheckedProduct({static_cast<uint64_t>(sizes_zct[0]), static_cast<uint64_t>(sizes_zct[1]),
                      static_cast<uint64_t>(sizes_zct[2])});
  if (!total_planes || *total_planes > kMaxPlanesPerSeries) {  // Cannot happen: C_eff <= SizeC.
    return InternalError(source + ": plane count check failed");
  }
  const PlaneOrder order(pixels.dimension_order, sizes_zct);

  OCTO_ASSIGN_OR_RETURN(std::vector<PlaneRun> runs, BuildRuns(source, pixels, td_files, order,
                                                              *total_planes, group_count, files));
  std::vector<bool> needed(files.files().size(), false);
  OCTO_ASSIGN_OR_RETURN(
      std::vector<PlaneRef> planes,
      BuildPlaneTable(source, runs, order, pixels.size_z, group_count, options, needed));
  OCTO_RETURN_IF_ERROR(VerifyPages(source, pixels, runs, order, groups, needed, files));

  std::vector<std::pair<int, int>> channel_map;
  volume::VolumeInfo info = BuildInfo(pixels, groups, options, series_count, channel_map);
  Status valid = info.Validate();
  if (!valid.ok()) return valid.WithContext(source);

  return std::unique_ptr<VolumeSource>(
      std::make_unique<OmeTiffVolume>(path.string(), std::move(info), files.files(),
                                      std::move(planes), std::move(channel_map), std::move(cache)));
}

}  // namespace

Result<std::unique_ptr<VolumeSource>> OpenOmeTiff(const std::filesystem::path& path,
                                                  const OpenOptions& options) {
  return Open(path, options);
}

}  // namespace octoscope::io
