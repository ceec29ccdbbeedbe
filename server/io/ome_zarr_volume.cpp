#include "io/ome_zarr_volume.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <optional>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "io/chunked_volume.h"
#include "io/file_gate.h"
#include "io/ome_xml.h"
#include "io/spacing.h"
#include "io/zarr_array.h"
#include "util/checked_math.h"
#include "util/strings.h"
#include "volume/volume_info.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

constexpr int kMaxSeriesScan = 1 << 20;   // bioformats2raw series folders counted at most.
constexpr int kParentLevelsSearched = 3;  // An array path may be this deep inside its image.

std::string Num(int64_t v) { return std::to_string(v); }

// Whether anything is at `p` (as `gate` lets it be seen).
Result<bool> Exists(const FileGate& gate, const fs::path& p) {
  OCTO_ASSIGN_OR_RETURN(const fs::file_type type, gate.Type(p));
  return type != fs::file_type::not_found;
}

// What a Zarr node (group or array folder) says about itself.
struct Node {
  bool is_array = false;
  NgffAttributes attrs;
};

Result<NgffAttributes> ParseAttributesFile(const fs::path& file, const OpenOptions& options) {
  OCTO_ASSIGN_OR_RETURN(std::string text, options.file_gate.ReadSmallFile(file, kMaxZarrJsonBytes));
  Result<NgffAttributes> attrs = options.zarr_json.attributes(text);
  if (!attrs.ok()) return attrs.status().WithContext(file.string());
  return attrs;
}

// Reads the node at `dir`: v3 `zarr.json`, or v2 `.zarray` / `.zgroup` / `.zattrs`. NotFound when
// `dir` holds none of them.
Result<Node> ReadNode(const fs::path& dir, const OpenOptions& options) {
  const FileGate& gate = options.file_gate;
  Node node;
  OCTO_ASSIGN_OR_RETURN(const bool v3, Exists(gate, dir / "zarr.json"));
  if (v3) {
    OCTO_ASSIGN_OR_RETURN(node.attrs, ParseAttributesFile(dir / "zarr.json", options));
    node.is_array = node.attrs.node_type == "array";
    return node;
  }
  OCTO_ASSIGN_OR_RETURN(node.is_array, Exists(gate, dir / ".zarray"));
  OCTO_ASSIGN_OR_RETURN(const bool has_attrs, Exists(gate, dir / ".zattrs"));
  OCTO_ASSIGN_OR_RETURN(const bool has_group, Exists(gate, dir / ".zgroup"));
  if (has_attrs) {
    OCTO_ASSIGN_OR_RETURN(node.attrs, ParseAttributesFile(dir / ".zattrs", options));
  } else if (!node.is_array && !has_group) {
    return NotFoundError(dir.string() +
                         ": not a Zarr group or array (no zarr.json, .zgroup, .zattrs or .zarray)");
  }
  return node;
}

// A dataset path must stay inside the image group: relative, without "." or ".." components.
Result<fs::path> DatasetDir(const fs::path& group, const std::string& path,
                            const std::string& where) {
  if (path.empty() || path.front() == '/' || path.find('\0') != std::string::npos) {
    return CorruptError(where + ": dataset path \"" + Printable(path) + "\" is not relative");
  }
  for (std::string_view part : Split(path, '/')) {
    if (part.empty() || part == "." || part == "..") {
      return CorruptError(where + ": dataset path \"" + Printable(path) +
                          "\" leaves the image group or has empty parts");
    }
  }
  return group / path;
}

// The image to read: its group, multiscale entry and level, or a bare array.
struct Selection {
  fs::path group;  // The image group (or the bare array's folder).
  NgffMultiscale multiscale;
  std::vector<OmeroChannel> omero;
  bool has_omero = false;
  int series = 0, series_count = 1;
  int level = 0;
  fs::path array_dir;
  bool bare = false;  // No NGFF metadata.
};

Status FillImage(const fs::path& group, const NgffAttributes& attrs, int multiscale,
                 Selection& sel) {
  sel.group = group;
  sel.multiscale = attrs.multiscales[static_cast<size_t>(multiscale)];
  sel.omero = attrs.omero_channels;
  sel.has_omero = attrs.has_omero;
  if (sel.multiscale.datasets.empty()) {
    return CorruptError(group.string() + ": multiscales[" + Num(multiscale) + "] has no datasets");
  }
  return Status::Ok();
}

Result<Selection> SelectLevel(Selection sel, const OpenOptions& options) {
  const int levels = static_cast<int>(sel.multiscale.datasets.size());
  if (options.level < 0 || options.level >= levels) {
    return OutOfRangeError(sel.group.string() + ": resolution level " + Num(options.level) +
                           " asked for, the image has " + Num(levels) + " (0 .. " +
                           Num(levels - 1) + ")");
  }
  sel.level = options.level;
  OCTO_ASSIGN_OR_RETURN(
      sel.array_dir,
      DatasetDir(sel.group, sel.multiscale.datasets[sel.level].path, sel.group.string()));
  return sel;
}

// An array folder the user named directly: a level of an image above it, or a bare array. The
// search never looks beyond what the gate admits (a dataset's own folder): the array is then read
// as a bare array.
Result<Selection> SelectFromArray(const fs::path& dir, const OpenOptions& options) {
  const FileGate& gate = options.file_gate;
  std::error_code ec;
  // Where a path leads: resolved by the gate, then made canonical (a no-op when confined).
  auto real = [&](const fs::path& p) -> std::optional<fs::path> {
    Result<fs::path> resolved = gate.Resolve(p);
    if (!resolved.ok()) return std::nullopt;
    fs::path canonical = fs::weakly_canonical(*resolved, ec);
    if (ec) return std::nullopt;
    return canonical;
  };
  const std::optional<fs::path> self = real(dir);
  fs::path up = dir;
  for (int i = 0; i < kParentLevelsSearched && self; ++i) {
    const std::optional<fs::path> parent = real(up / "..");
    if (!parent) break;
    up = *parent;
    Result<Node> node = ReadNode(up, options);
    if (!node.ok()) continue;  // Not a group (or unreadable): keep looking further up.
    const std::vector<NgffMultiscale>& ms = node->attrs.multiscales;
    for (size_t m = 0; m < ms.size(); ++m) {
      for (size_t d = 0; d < ms[m].datasets.size(); ++d) {
        Result<fs::path> level_dir = DatasetDir(up, ms[m].datasets[d].path, up.string());
        if (!level_dir.ok() || real(*level_dir) != self) continue;
        if (options.level != 0 && options.level != static_cast<int>(d)) {
          return InvalidArgumentError(dir.string() + " is resolution level " + Num(d) +
                                      " of the image " + up.string() + "; open the image to " +
                                      "choose a level with --level");
        }
        Selection sel;
        OCTO_RETURN_IF_ERROR(FillImage(up, node->attrs, static_cast<int>(m), sel));
        sel.series = static_cast<int>(m);
        sel.series_count = static_cast<int>(ms.size());
        OpenOptions at_level = options;
        at_level.level = static_cast<int>(d);
        return SelectLevel(std::move(sel), at_level);
      }
    }
  }
  if (options.level != 0) {
    return OutOfRangeError(dir.string() + ": a single Zarr array has one resolution level");
  }
  Selection sel;
  sel.group = dir;
  sel.array_dir = dir;
  sel.bare = true;
  return sel;
}

Result<Selection> Select(const fs::path& root, const OpenOptions& options) {
  OCTO_ASSIGN_OR_RETURN(Node node, ReadNode(root, options));
  if (node.is_array) {
    if (options.series != 0) {
      return OutOfRangeError(root.string() + ": a Zarr array holds one series (asked for " +
                             Num(options.series) + ")");
    }
    return SelectFromArray(root, options);
  }
  Selection sel;
  const NgffAttributes& attrs = node.attrs;
  if (!attrs.multiscales.empty()) {
    const int count = static_cast<int>(attrs.multiscales.size());
    if (options.series >= count) {
      return OutOfRangeError(root.string() + ": series " + Num(options.series) +
                             " asked for, the image group has " + Num(count));
    }
    OCTO_RETURN_IF_ERROR(FillImage(root, attrs, options.series, sel));
    sel.series = options.series;
    sel.series_count = count;
    return SelectLevel(std::move(sel), options);
  }
  if (attrs.bioformats2raw_layout) {
    if (*attrs.bioformats2raw_layout != 3) {
      return UnsupportedError(root.string() + ": bioformats2raw.layout " +
                              Num(*attrs.bioformats2raw_layout) + " (only layout 3 is known)");
    }
    // Series are the sub-groups "0", "1", … (the layout's definition).
    int count = 0;
    for (; count < kMaxSeriesScan; ++count) {
      OCTO_ASSIGN_OR_RETURN(const bool exists,
                            Exists(options.file_gate, root / std::to_string(count)));
      if (!exists) break;
    }
    if (options.series >= count) {
      return OutOfRangeError(root.string() + ": series " + Num(options.series) +
                             " asked for, the bioformats2raw group has " + Num(count));
    }
    const fs::path group = root / std::to_string(options.series);
    OCTO_ASSIGN_OR_RETURN(Node image, ReadNode(group, options));
    if (image.attrs.multiscales.empty()) {
      return CorruptError(group.string() + ": series group without multiscales metadata");
    }
    OCTO_RETURN_IF_ERROR(FillImage(group, image.attrs, 0, sel));
    sel.series = options.series;
    sel.series_count = count;
    return SelectLevel(std::move(sel), options);
  }
  if (attrs.is_plate) {
    return UnsupportedError(root.string() +
                            ": an OME-Zarr plate or well (HCS) is not an image; open one field "
                            "of view, e.g. PLATE.zarr/A/1/0");
  }
  return UnsupportedError(root.string() +
                          ": a Zarr group without OME-NGFF multiscales metadata (open one of "
                          "its arrays)");
}

// Where x, y, z, c, t lie among the array's dims.
struct AxisMap {
  int x = -1, y = -1, z = -1, c = -1, t = -1;
};

Result<AxisMap> MapAxes(const Selection& sel, const ZarrArrayMetadata& meta,
                        std::vector<NgffAxis>& axes, const std::string& name) {
  const int dims = static_cast<int>(meta.shape.size());
  axes = sel.multiscale.axes;
  if (axes.empty()) {
    // NGFF 0.1/0.2 images are always 5-D t, c, z, y, x. A bare array: its v3 dimension_names
    // when they are axis letters, else the trailing dims of t, c, z, y, x.
    static const char* kNames[] = {"t", "c", "z", "y", "x"};
    if (!sel.bare && dims != 5) {
      return CorruptError(name + ": NGFF " + sel.multiscale.version +
                          " without axes needs 5 dims (t, c, z, y, x), the array has " + Num(dims));
    }
    if (dims > 5) {
      return UnsupportedError(name + ": a Zarr array of " + Num(dims) +
                              " dims without NGFF axes metadata (at most 5: t, c, z, y, x)");
    }
    if (dims < 2) return UnsupportedError(name + ": a 1-D Zarr array is not an image");
    for (int d = 0; d < dims; ++d) {
      NgffAxis a;
      a.name = kNames[5 - dims + d];
      if (!meta.dimension_names.empty()) a.name = ToLower(meta.dimension_names[d]);
      axes.push_back(a);
    }
  }
  if (static_cast<int>(axes.size()) != dims) {
    return CorruptError(name + ": " + Num(axes.size()) + " axes in multiscales, the array has " +
                        Num(dims) + " dims");
  }
  AxisMap map;
  std::vector<int> other_space;
  auto assign = [&](int& slot, int d) -> Status {
    if (slot >= 0) {
      return CorruptError(name + ": two axes are \"" + Printable(axes[d].name) + "\" (dims " +
                          Num(slot) + " and " + Num(d) + ")");
    }
    slot = d;
    return Status::Ok();
  };
  for (int d = 0; d < dims; ++d) {
    const std::string n = ToLower(axes[d].name);
    const std::string type = ToLower(axes[d].type);
    if (type == "time" || (type.empty() && n == "t")) {
      OCTO_RETURN_IF_ERROR(assign(map.t, d));
    } else if (type == "channel" || (type.empty() && n == "c")) {
      OCTO_RETURN_IF_ERROR(assign(map.c, d));
    } else if (type == "space" || (type.empty() && (n == "x" || n == "y" || n == "z"))) {
      if (n == "x") {
        OCTO_RETURN_IF_ERROR(assign(map.x, d));
      } else if (n == "y") {
        OCTO_RETURN_IF_ERROR(assign(map.y, d));
      } else if (n == "z") {
        OCTO_RETURN_IF_ERROR(assign(map.z, d));
      } else {
        other_space.push_back(d);
      }
    } else if (meta.shape[d] == 1) {
      continue;  // A custom axis of one element changes nothing.
    } else if (map.c < 0) {
      map.c = d;  // NGFF allows a custom axis where the channel axis would be.
    } else {
      return UnsupportedError(name + ": axis \"" + Printable(axes[d].name) + "\" of type \"" +
                              Printable(axes[d].type) + "\" with " + Num(meta.shape[d]) +
                              " elements, besides a channel axis");
    }
  }
  if (!other_space.empty()) {
    // Space axes not called x/y/z: by position, the last is x, then y, then z (NGFF's order).
    if (map.x >= 0 || map.y >= 0 || map.z >= 0 || other_space.size() > 3 ||
        other_space.size() < 2) {
      return UnsupportedError(name + ": space axis \"" + Printable(axes[other_space[0]].name) +
                              "\" is none of x, y, z");
    }
    const size_t n = other_space.size();
    map.x = other_space[n - 1];
    map.y = other_space[n - 2];
    if (n == 3) map.z = other_space[0];
  }
  if (map.x < 0 || map.y < 0) {
    return UnsupportedError(name + ": the image needs an x and a y axis");
  }
  return map;
}

// The spacing (µm) of dim `d`: the level's scale times the multiscale's, in the axis unit.
std::optional<double> SpacingOf(const Selection& sel, const NgffAxis& axis, int d) {
  if (sel.bare || axis.unit.empty()) return std::nullopt;
  const std::optional<double> um = MicrometresPerNgffUnit(axis.unit);
  if (!um) return std::nullopt;
  const std::vector<double>& scale = sel.multiscale.datasets[sel.level].transform.scale;
  const std::vector<double>& global = sel.multiscale.transform.scale;
  if (scale.empty()) return std::nullopt;
  double s = scale[static_cast<size_t>(d)];
  if (!global.empty()) s *= global[static_cast<size_t>(d)];
  return PositiveOrNone(s * *um);
}

Status CheckTransform(const NgffTransform& t, size_t dims, const std::string& where) {
  if ((!t.scale.empty() && t.scale.size() != dims) ||
      (!t.translation.empty() && t.translation.size() != dims)) {
    return CorruptError(where + ": coordinateTransformations of " +
                        Num(std::max(t.scale.size(), t.translation.size())) +
                        " values for an array of " + Num(dims) + " dims");
  }
  return Status::Ok();
}

}  // namespace

std::optional<double> MicrometresPerNgffUnit(std::string_view unit) {
  struct Entry {
    std::string_view name;
    double um;
  };
  // The NGFF specification's length units (UDUNITS-2 names).
  static constexpr Entry kUnits[] = {
      {"angstrom", 1e-4},    {"attometer", 1e-12},  {"centimeter", 1e4},
      {"decimeter", 1e5},    {"exameter", 1e24},    {"femtometer", 1e-9},
      {"foot", 304800},      {"gigameter", 1e15},   {"hectometer", 1e8},
      {"inch", 25400},       {"kilometer", 1e9},    {"megameter", 1e12},
      {"meter", 1e6},        {"micrometer", 1},     {"mile", 1609344000},
      {"millimeter", 1e3},   {"nanometer", 1e-3},   {"parsec", 3.0856775814913673e22},
      {"petameter", 1e21},   {"picometer", 1e-6},   {"terameter", 1e18},
      {"yard", 914400},      {"yoctometer", 1e-18}, {"yottameter", 1e30},
      {"zeptometer", 1e-15}, {"zettameter", 1e27},
  };
  for (const Entry& e : kUnits) {
    if (unit == e.name) return e.um;
  }
  if (std::optional<double> um = MicrometresPerLengthUnit(unit)) return um;
  return MicrometresPerUnit(unit);
}

Result<bool> LooksLikeZarr(const fs::path& path, const FileGate& gate) {
  OCTO_ASSIGN_OR_RETURN(const fs::file_type type, gate.Type(path));
  if (type == fs::file_type::directory) {
    for (const char* f : {".zgroup", ".zattrs", ".zarray", "zarr.json"}) {
      OCTO_ASSIGN_OR_RETURN(const bool exists, Exists(gate, path / f));
      if (exists) return true;
    }
    return false;
  }
  const std::string name = path.filename().string();
  return name == ".zgroup" || name == ".zattrs" || name == ".zarray" || name == "zarr.json" ||
         name == ".zmetadata";
}

Result<std::unique_ptr<VolumeSource>> OpenOmeZarr(const fs::path& path,
                                                  const OpenOptions& options) {
  OCTO_ASSIGN_OR_RETURN(const fs::file_type type, options.file_gate.Type(path));
  const fs::path root = type == fs::file_type::directory ? path : path.parent_path();
  if (!options.zarr_json.array || !options.zarr_json.attributes) {
    return UnsupportedError(root.string() + ": Zarr metadata parsing is not enabled");
  }
  OCTO_ASSIGN_OR_RETURN(Selection sel, Select(root, options));
  OCTO_ASSIGN_OR_RETURN(
      ZarrArrayMetadata meta,
      LoadZarrArray(sel.array_dir, options.zarr_json, options.max_chunk_bytes, options.file_gate));
  const std::string name = sel.array_dir.string();
  const size_t dims = meta.shape.size();
  if (!sel.bare) {
    OCTO_RETURN_IF_ERROR(CheckTransform(sel.multiscale.transform, dims, sel.group.string()));
    OCTO_RETURN_IF_ERROR(CheckTransform(sel.multiscale.datasets[sel.level].transform, dims,
                                        sel.group.string() + ": datasets[" + Num(sel.level) + "]"));
  }
  std::vector<NgffAxis> axes;
  OCTO_ASSIGN_OR_RETURN(AxisMap map, MapAxes(sel, meta, axes, name));

  auto extent = [&](int d) -> int64_t { return d >= 0 ? meta.shape[static_cast<size_t>(d)] : 1; };
  volume::VolumeInfo info;
  info.format = sel.bare ? "zarr" : "ome-zarr";
  info.size = {extent(map.x), extent(map.y), extent(map.z)};
  info.dtype = meta.dtype;
  for (int64_t s : meta.shape) {
    if (s == 0) return CorruptError(name + ": the array is empty (a dimension of size 0)");
  }
  const int64_t channels = extent(map.c);
  const int64_t times = extent(map.t);
  // Channels size tables: bound them before anything else.
  OCTO_RETURN_IF_ERROR(volume::CheckChannelCount(channels).WithContext(name));
  if (times > INT_MAX) return ResourceExhaustedError(name + ": " + Num(times) + " time points");
  const std::optional<uint64_t> plane_bytes =
      CheckedProduct({static_cast<uint64_t>(info.size[0]), static_cast<uint64_t>(info.size[1]),
                      volume::BytesPerSample(info.dtype)});
  if (!plane_bytes || *plane_bytes > options.max_plane_bytes) {
    return ResourceExhaustedError(
        name + ": one plane is " + (plane_bytes ? std::to_string(*plane_bytes) : "over 2^64") +
        " bytes, more than the limit of " + std::to_string(options.max_plane_bytes));
  }
  info.time_points = static_cast<int>(times);
  if (options.time < 0 || options.time >= info.time_points) {
    return OutOfRangeError(name + ": time point " + Num(options.time) +
                           " asked for, the image has " + Num(info.time_points));
  }
  info.time = options.time;
  info.series = sel.series;
  info.series_count = sel.series_count;
  info.level = sel.level;
  info.level_count = sel.bare ? 1 : static_cast<int>(sel.multiscale.datasets.size());
  info.channels.resize(static_cast<size_t>(channels));
  if (sel.has_omero && sel.omero.size() == info.channels.size()) {
    for (size_t c = 0; c < info.channels.size(); ++c) {
      info.channels[c].name = sel.omero[c].label;
      info.channels[c].color = sel.omero[c].color;
      info.channels[c].window = sel.omero[c].window;
    }
  } else if (sel.has_omero) {
    info.warnings.push_back(name + ": \"omero\" lists " +
                            Num(static_cast<int64_t>(sel.omero.size())) +
                            " channels, the image has " + Num(channels) +
                            "; its channel names, colours and windows are ignored");
  }
  const int space[3] = {map.x, map.y, map.z};
  for (int a = 0; a < 3; ++a) {
    if (space[a] >= 0) info.spacing_um[a] = SpacingOf(sel, axes[space[a]], space[a]);
  }
  ApplySpacingOverrides(info, options);
  if (Status s = info.Validate(); !s.ok()) return s.WithContext(name);

  ChunkLayout layout;
  layout.shape = meta.shape;
  layout.chunk = ReadChunkShape(meta);
  layout.strides = ReadChunkStrides(meta);
  layout.x_dim = map.x;
  layout.y_dim = map.y;
  layout.z_dim = map.z;
  layout.channel_dim = map.c;
  layout.time_dim = map.t;
  // Chunk files are many: resolved from the store's folder held open.
  OCTO_ASSIGN_OR_RETURN(FileGate chunks, options.file_gate.Pinned());
  ChunkedVolumeOptions chunked;
  chunked.name = name;
  chunked.fill_value = meta.fill_value.value_or(0);
  chunked.cache_bytes = options.chunk_cache_bytes;
  chunked.threads = options.decode_threads;
  return MakeChunkedVolume(std::move(info), std::move(layout),
                           MakeZarrChunkReader(sel.array_dir, std::move(meta), std::move(chunks)),
                           chunked);
}

}  // namespace octoscope::io
