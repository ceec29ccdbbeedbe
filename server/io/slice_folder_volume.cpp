#include "io/slice_folder_volume.h"

#include <algorithm>
#include <array>
#include <cstdint>
#include <map>
#include <set>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "io/file_gate.h"
#include "io/slice_names.h"
#include "io/spacing.h"
#include "io/tiff_file.h"
#include "io/tiff_file_cache.h"
#include "io/tiff_stack_volume.h"
#include "util/checked_math.h"
#include "util/strings.h"

namespace octoscope::io {
namespace {

// One channel as the folder lays it out: a name and its slice files in z order.
struct FolderChannel {
  std::string name;
  std::vector<std::filesystem::path> files;
};

// The visible TIFF files and sub-folders directly inside `dir`.
struct Listing {
  std::vector<std::filesystem::path> tiffs;
  std::vector<std::filesystem::path> folders;
  // Links a confined gate does not let be looked at as channel sub-folders.
  std::vector<std::filesystem::path> outside_links;
  // Links with a TIFF name that lead out of the folder: slices the folder may not read.
  std::vector<std::filesystem::path> outside_tiffs;
};

// Lists `dir` through `gate`. Under a confined gate a symbolic link is classified through the gate
// too, and only where it may matter: a link with a TIFF name is a slice (one leading out of the
// folder is listed in outside_tiffs, whether its target exists or not); with `want_folders`, when
// `dir` holds no TIFF, any other link may be a channel sub-folder (one leading out of the folder is
// not looked at, and listed in outside_links).
Result<Listing> ListFolder(const std::filesystem::path& dir, const FileGate& gate,
                           bool want_folders) {
  Listing listing;
  std::vector<std::filesystem::path> links;
  OCTO_ASSIGN_OR_RETURN(const std::filesystem::path real, gate.Resolve(dir));
  std::error_code ec;
  std::filesystem::directory_iterator it(real, ec);
  if (ec) return IoError(dir.string() + ": cannot list folder: " + ec.message());
  for (; it != std::filesystem::directory_iterator(); it.increment(ec)) {
    if (ec) return IoError(dir.string() + ": cannot list folder: " + ec.message());
    const std::string name = it->path().filename().string();
    if (name.empty() || name[0] == '.') continue;  // Hidden (also macOS "._x.tif" sidecars).
    const std::filesystem::path path = dir / name;
    std::error_code type_ec;
    if (gate.confined() && it->is_symlink(type_ec)) {
      links.push_back(path);
    } else if (it->is_directory(type_ec)) {
      listing.folders.push_back(path);
    } else if (it->is_regular_file(type_ec) && IsTiffName(name)) {
      listing.tiffs.push_back(path);
    }
  }
  if (ec) return IoError(dir.string() + ": cannot list folder: " + ec.message());
  std::stable_partition(links.begin(), links.end(), [](const std::filesystem::path& p) {
    return IsTiffName(p.filename().string());
  });
  for (const std::filesystem::path& link : links) {
    const bool tiff_name = IsTiffName(link.filename().string());
    if (!tiff_name && !(want_folders && listing.tiffs.empty())) break;
    Result<std::filesystem::file_type> linked = gate.Type(link);
    if (IsOutsideFolderError(linked.status())) {
      (tiff_name ? listing.outside_tiffs : listing.outside_links).push_back(link);
      continue;
    }
    OCTO_ASSIGN_OR_RETURN(const std::filesystem::file_type type, std::move(linked));
    if (type == std::filesystem::file_type::directory) {
      listing.folders.push_back(link);
    } else if (type == std::filesystem::file_type::regular && tiff_name) {
      listing.tiffs.push_back(link);
    }
  }
  auto by_name = [](const std::filesystem::path& a, const std::filesystem::path& b) {
    return NaturalLess(a.filename().string(), b.filename().string());
  };
  std::sort(listing.tiffs.begin(), listing.tiffs.end(), by_name);
  std::sort(listing.folders.begin(), listing.folders.end(), by_name);
  std::sort(listing.outside_tiffs.begin(), listing.outside_tiffs.end(), by_name);
  return listing;
}

// The slices of a listing by name, those leading out included (they take their place in the
// numbering; they are refused when opened).
std::vector<std::filesystem::path> AllSlices(const Listing& listing) {
  std::vector<std::filesystem::path> all = listing.tiffs;
  all.insert(all.end(), listing.outside_tiffs.begin(), listing.outside_tiffs.end());
  std::sort(all.begin(), all.end(), [](const auto& a, const auto& b) {
    return NaturalLess(a.filename().string(), b.filename().string());
  });
  return all;
}

// Tries token position `p` as the channel token of `files` (whose stems are `tokens`). Returns
// nullopt when the token does not number channels: it takes a single value, or every value names
// a single file (then it numbers the slices). Errors when it numbers channels whose names do not
// line up: every channel must hold the same names once the token is blanked out.
Result<std::optional<std::vector<FolderChannel>>> GroupByToken(
    const std::filesystem::path& dir, const std::vector<std::filesystem::path>& files,
    const std::vector<std::vector<NameToken>>& tokens, size_t p) {
  using Grouping = std::optional<std::vector<FolderChannel>>;
  // value -> (key -> file); key is the stem with token p replaced by a placeholder.
  std::map<uint64_t, std::map<std::string, std::filesystem::path>> groups;
  std::map<uint64_t, std::string> names;
  std::optional<std::pair<std::filesystem::path, std::filesystem::path>> duplicate;
  for (size_t f = 0; f < files.size(); ++f) {
    std::string key;
    for (size_t t = 0; t < tokens[f].size(); ++t) key += t == p ? "\x01" : tokens[f][t].text;
    const uint64_t value = DigitValue(tokens[f][p].text);
    auto [it, inserted] = groups[value].emplace(key, files[f]);
    if (!inserted && !duplicate) duplicate.emplace(it->second, files[f]);  // "c1" and "c01".
    names.emplace(value, ChannelMarker(tokens[f][p - 1].text) + tokens[f][p].text);
  }
  if (groups.size() < 2) return Grouping();
  if (std::all_of(groups.begin(), groups.end(),
                  [](const auto& g) { return g.second.size() == 1; })) {
    return Grouping();
  }
  if (duplicate) {
    return CorruptError(dir.string() + ": " + duplicate->first.filename().string() + " and " +
                        duplicate->second.filename().string() +
                        " are the same slice of the same channel");
  }
  // Every name (with the token blanked) must occur in every channel.
  std::vector<std::pair<std::string, const std::filesystem::path*>> keys;
  for (const auto& [value, members] : groups) {
    for (const auto& member : members) {
      // Not a structured binding: clang 14 (the fuzz build) cannot capture one in a lambda.
      const std::string& key = member.first;
      if (std::none_of(keys.begin(), keys.end(), [&](const auto& k) { return k.first == key; })) {
        keys.emplace_back(key, &member.second);
      }
    }
  }
  std::sort(keys.begin(), keys.end(),
            [](const auto& a, const auto& b) { return NaturalLess(a.first, b.first); });
  std::vector<FolderChannel> channels;
  for (const auto& [value, members] : groups) {
    FolderChannel channel{names[value], {}};
    for (const auto& [key, example] : keys) {
      auto it = members.find(key);
      if (it == members.end()) {
        return CorruptError(example->string() + ": no matching slice in channel \"" + names[value] +
                            "\" (channels are told apart by the \"" + names[value] +
                            "\" token in the file names; every channel needs the "
                            "same slices)");
      }
      channel.files.push_back(it->second);
    }
    channels.push_back(std::move(channel));
  }
  return Grouping(std::move(channels));
}

// Splits a flat folder's files (natural order) into channels by a channel token in the names
// (see slice_folder_volume.h), or returns them as one unnamed channel.
Result<std::vector<FolderChannel>> SplitFlatFolder(
    const std::filesystem::path& dir, const std::vector<std::filesystem::path>& files) {
  std::vector<std::vector<NameToken>> tokens;
  for (const auto& f : files) tokens.push_back(TokenizeName(f.stem().string()));
  std::vector<std::vector<FolderChannel>> found;
  std::vector<std::string> found_tokens;
  const size_t n = tokens[0].size();
  const bool uniform = std::all_of(tokens.begin(), tokens.end(),
                                   [n](const std::vector<NameToken>& t) { return t.size() == n; });
  for (size_t p = 1; uniform && p < n; ++p) {
    bool candidate = true;
    for (const auto& t : tokens) {
      if (!t[p].digits || ChannelMarker(t[p - 1].text).empty() ||
          !EqualsIgnoreCase(t[p - 1].text, tokens[0][p - 1].text)) {
        candidate = false;
        break;
      }
    }
    if (!candidate) continue;
    OCTO_ASSIGN_OR_RETURN(std::optional<std::vector<FolderChannel>> channels,
                          GroupByToken(dir, files, tokens, p));
    if (channels) {
      found.push_back(std::move(*channels));
      found_tokens.push_back(tokens[0][p - 1].text + tokens[0][p].text);
    }
  }
  if (found.size() > 1) {
    return UnsupportedError(dir.string() + ": ambiguous channel tokens in the file names (\"" +
                            Printable(found_tokens[0]) + "\" and \"" + Printable(found_tokens[1]) +
                            "\" both vary); put each channel in its own sub-folder");
  }
  if (found.size() == 1) return std::move(found[0]);
  return std::vector<FolderChannel>{{"", files}};
}

// Spacing from one slice's tags, by the TIFF page rules of io/spacing.h (ImageJ's unit= and
// spacing=, else a centimetre resolution). `description`: the slice page's ImageDescription.
std::array<std::optional<double>, 3> SpacingFromSlice(const TiffIfd& ifd,
                                                      std::string_view description) {
  const std::optional<ImageJDescription> ij = ParseImageJDescription(description);
  return TiffPageSpacing(ifd, ij ? &*ij : nullptr);
}

// The one full-resolution IFD of a slice file (reduced-resolution copies such as thumbnails are
// ignored); nullopt when there is not exactly one.
std::optional<int> SliceIfd(const TiffFile& file) {
  std::optional<int> found;
  for (int i = 0; i < file.ifd_count(); ++i) {
    if ((file.ifd(i).subfile_type & 1) != 0) continue;
    if (found) return std::nullopt;
    found = i;
  }
  return found;
}

bool SameSliceLayout(const TiffIfd& a, const TiffIfd& b) {
  return a.width == b.width && a.height == b.height && a.dtype == b.dtype &&
         a.samples_per_pixel == b.samples_per_pixel;
}

class SliceFolderVolume final : public VolumeSource {
 public:
  // REQUIRES: every file of `channels` was checked to have first_ifd's layout; channels non-empty,
  // all with the same number of files.
  SliceFolderVolume(std::string name, volume::VolumeInfo info, std::vector<FolderChannel> channels,
                    const TiffIfd& first_ifd, TiffFile::Limits limits, const FileGate& gate)
      : name_(std::move(name)),
        info_(std::move(info)),
        channels_(std::move(channels)),
        layout_(first_ifd),
        cache_(limits, kMaxOpenSliceFiles, gate) {}

  const volume::VolumeInfo& info() const override { return info_; }

  TiffFileCache& cache() { return cache_; }

  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    OCTO_RETURN_IF_ERROR(CheckSlabRequest(info_, channel, z0, nz, out.size()).WithContext(name_));
    const int samples = layout_.samples_per_pixel;
    const size_t folder_channel = static_cast<size_t>(channel / samples);
    const int sample = channel % samples;
    const size_t plane_bytes = static_cast<size_t>(SlabBytes(1));
    for (int64_t i = 0; i < nz; ++i) {
      const size_t z = static_cast<size_t>(z0 + i);
      const std::filesystem::path& path = channels_[folder_channel].files[z];
      OCTO_ASSIGN_OR_RETURN(std::shared_ptr<TiffFile> file, cache_.Get(path));
      // The file may have been replaced since we opened the folder; never decode a plane into a
      // buffer sized for another layout.
      std::optional<int> index = SliceIfd(*file);
      if (!index || !SameSliceLayout(file->ifd(*index), layout_)) {
        return CorruptError(path.string() + ": slice changed since the folder was opened");
      }
      OCTO_RETURN_IF_ERROR(file->ReadPlane(
          *index, sample, out.subspan(static_cast<size_t>(i) * plane_bytes, plane_bytes)));
    }
    return Status::Ok();
  }

 private:
  const std::string name_;  // The folder, for messages.
  const volume::VolumeInfo info_;
  const std::vector<FolderChannel> channels_;
  const TiffIfd layout_;
  TiffFileCache cache_;
};

}  // namespace

Result<std::unique_ptr<VolumeSource>> OpenSliceFolder(const std::filesystem::path& dir,
                                                      const OpenOptions& options) {
  const std::string name = dir.string();
  const FileGate& gate = options.file_gate;
  OCTO_ASSIGN_OR_RETURN(const std::filesystem::file_type type, gate.Type(dir));
  if (type == std::filesystem::file_type::not_found)
    return NotFoundError(name + ": no such folder");
  if (type != std::filesystem::file_type::directory) {
    return InvalidArgumentError(name + ": not a folder");
  }
  if (options.series != 0 || options.time != 0) {
    return OutOfRangeError(name +
                           ": a slice folder holds one series and one time point (asked "
                           "for series " +
                           std::to_string(options.series) + ", time " +
                           std::to_string(options.time) + ")");
  }

  // Slices that lead out of the folder refuse it — but only a folder that is a slice folder
  // otherwise: one whose TIFFs all lead out is not one (a container of links, each of which is
  // refused on its own), and the slices inside are checked first (a folder of multi-page files
  // is no slice folder either, whatever else it holds).
  OCTO_ASSIGN_OR_RETURN(Listing top, ListFolder(dir, gate, true));
  std::vector<FolderChannel> channels;
  std::set<std::filesystem::path> outside(top.outside_tiffs.begin(), top.outside_tiffs.end());
  if (!top.tiffs.empty()) {
    OCTO_ASSIGN_OR_RETURN(channels, SplitFlatFolder(dir, AllSlices(top)));
  } else {
    for (const auto& sub : top.folders) {
      OCTO_ASSIGN_OR_RETURN(Listing inner, ListFolder(sub, gate, false));
      if (inner.tiffs.empty()) continue;
      outside.insert(inner.outside_tiffs.begin(), inner.outside_tiffs.end());
      channels.push_back({sub.filename().string(), AllSlices(inner)});
    }
  }
  if (channels.empty()) {
    return NotFoundError(name + ": no TIFF slices (.tif/.tiff) in the folder or its sub-folders");
  }
  for (const FolderChannel& c : channels) {
    if (c.files.size() != channels[0].files.size()) {
      return CorruptError(name + ": channel \"" + c.name + "\" has " +
                          std::to_string(c.files.size()) + " slices, channel \"" +
                          channels[0].name + "\" has " + std::to_string(channels[0].files.size()));
    }
  }

  // Open every slice once: all must agree with the first. (Opened as the cache would open them:
  // the first ones are handed to it.)
  TiffFile::Limits limits;
  limits.max_plane_bytes = options.max_plane_bytes;
  const TiffFile::Limits file_limits = TiffFileCache::PerFileLimits(limits, kMaxOpenSliceFiles);
  std::optional<TiffIfd> first;
  std::string first_description;  // The first slice page's ImageDescription (for its spacing).
  // Handles to keep cached.
  std::vector<std::pair<std::filesystem::path, std::shared_ptr<TiffFile>>> warm;
  const size_t slices = channels[0].files.size();
  bool refers_outside = false;
  for (size_t c = 0; c < channels.size(); ++c) {
    for (size_t z = 0; z < slices; ++z) {
      const std::filesystem::path& path = channels[c].files[z];
      if (outside.count(path) != 0) {
        refers_outside = true;
        continue;
      }
      OCTO_ASSIGN_OR_RETURN(std::unique_ptr<TiffFile> file,
                            TiffFile::Open(path, file_limits, gate));
      std::optional<int> index = SliceIfd(*file);
      if (!index) {
        return UnsupportedError(path.string() + ": has " + std::to_string(file->ifd_count()) +
                                " full-resolution pages; a slice folder holds one 2-D image per "
                                "file (open a multi-page file on its own)");
      }
      const TiffIfd& ifd = file->ifd(*index);
      if (!first) {
        if (!ifd.dtype) {
          return UnsupportedError(path.string() + ": sample layout not supported (" +
                                  std::to_string(ifd.bits_per_sample) + " bits, format " +
                                  std::to_string(ifd.sample_format) + ")");
        }
        first = ifd;
        // The index keeps IFD 0's description only; a slice after a thumbnail is read here.
        OCTO_ASSIGN_OR_RETURN(first_description, file->Description(*index));
      } else if (!SameSliceLayout(ifd, *first)) {
        return CorruptError(path.string() + ": slice is " + DescribePage(ifd) + ", but " +
                            channels[0].files[0].filename().string() + " is " +
                            DescribePage(*first) + "; all slices must match");
      }
      if (warm.size() < static_cast<size_t>(kMaxOpenSliceFiles)) {
        warm.emplace_back(path, std::shared_ptr<TiffFile>(std::move(file)));
      }
    }
  }

  if (refers_outside) return OutsideFolderError();

  volume::VolumeInfo info;
  info.format = "slice-folder";
  if (top.tiffs.empty()) {
    for (const std::filesystem::path& link : top.outside_links) {
      info.warnings.push_back(name + ": " + link.filename().string() +
                              " is not read as a channel: it leads outside the folder");
    }
  }
  info.size = {first->width, first->height, static_cast<int64_t>(slices)};
  info.dtype = *first->dtype;
  const int samples = first->samples_per_pixel;
  for (const FolderChannel& c : channels) {
    for (int s = 0; s < samples; ++s) {
      std::string channel_name = c.name;
      if (samples > 1) {
        channel_name += (channel_name.empty() ? "s" : " s") + std::to_string(s);
      }
      info.channels.push_back({channel_name, std::nullopt});
    }
  }
  info.spacing_um = SpacingFromSlice(*first, first_description);
  ApplySpacingOverrides(info, options);
  if (Status s = info.Validate(); !s.ok()) return s.WithContext(name);

  auto volume = std::make_unique<SliceFolderVolume>(name, std::move(info), std::move(channels),
                                                    *first, limits, gate);
  for (auto& [key, file] : warm) volume->cache().Put(key, std::move(file));
  return std::unique_ptr<VolumeSource>(std::move(volume));
}

}  // namespace octoscope::io
