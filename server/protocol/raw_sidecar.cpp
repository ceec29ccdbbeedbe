#include "protocol/raw_sidecar.h"

#include <cmath>
#include <cstdint>
#include <exception>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "util/checked_math.h"
#include "util/file_reading.h"
#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using nlohmann::json;

constexpr const char* kKnownKeys[] = {"file",          "size",         "channels",
                                      "channel_names", "dtype",        "endianness",
                                      "layout",        "header_bytes", "spacing"};

Status KeyError(std::string_view key, std::string_view problem) {
  return CorruptError("raw sidecar: \"" + std::string(key) + "\" " + std::string(problem));
}

std::string TypeOf(const json& j) { return std::string(j.type_name()); }

// An integer in [lo, hi] (JSON floats such as 3.0 are refused: sizes are counts).
Result<int64_t> GetInteger(const json& j, std::string_view key, int64_t lo, int64_t hi) {
  if (!j.is_number_integer()) {
    return KeyError(key, "must be an integer, got " + TypeOf(j) +
                             (j.is_number_float() ? " " + Printable(j.dump()) : ""));
  }
  if (j.is_number_unsigned() && j.get<uint64_t>() > static_cast<uint64_t>(INT64_MAX)) {
    return KeyError(key, "is " + j.dump() + ", too large");
  }
  const int64_t v = j.get<int64_t>();
  if (v < lo || v > hi) {
    return KeyError(key, "is " + std::to_string(v) + ", must be in " + std::to_string(lo) + ".." +
                             std::to_string(hi));
  }
  return v;
}

Result<std::string> GetString(const json& j, std::string_view key) {
  if (!j.is_string()) return KeyError(key, "must be a string, got " + TypeOf(j));
  return j.get<std::string>();
}

Status CheckArray(const json& j, std::string_view key, size_t length) {
  if (!j.is_array()) return KeyError(key, "must be an array, got " + TypeOf(j));
  if (j.size() != length) {
    return KeyError(
        key, "must have " + std::to_string(length) + " elements, has " + std::to_string(j.size()));
  }
  return Status::Ok();
}

// The parser proper. `default_file` is used when "file" is absent ("" makes "file" required).
Result<io::RawLayout> Parse(std::string_view text, const std::filesystem::path& base_dir,
                            const std::filesystem::path& default_file) {
  json doc;
  try {
    doc = json::parse(text.begin(), text.end());
  } catch (const json::exception& e) {
    // e.what() names the line and column; it may quote the input, so it is shortened.
    return CorruptError("raw sidecar: not valid JSON: " + Printable(e.what(), 200));
  }
  if (!doc.is_object())
    return CorruptError("raw sidecar: must be a JSON object, got " + TypeOf(doc));

  for (const auto& [key, value] : doc.items()) {
    bool known = false;
    for (const char* k : kKnownKeys) known = known || key == k;
    if (!known) {
      return CorruptError("raw sidecar: unknown key \"" + Printable(key) +
                          "\" (known: file, size, channels, channel_names, dtype, endianness, "
                          "layout, header_bytes, spacing)");
    }
  }

  io::RawLayout layout;
  std::filesystem::path file = default_file;
  if (auto it = doc.find("file"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(std::string name, GetString(*it, "file"));
    if (name.empty() || name.find('\0') != std::string::npos) {
      return KeyError("file", "must be a non-empty file name");
    }
    file = std::filesystem::path(name);
  }
  if (file.empty()) return CorruptError("raw sidecar: missing required key \"file\"");
  layout.data_file = file.is_absolute() ? file : base_dir / file;

  auto size_it = doc.find("size");
  if (size_it == doc.end()) return CorruptError("raw sidecar: missing required key \"size\"");
  OCTO_RETURN_IF_ERROR(CheckArray(*size_it, "size", 3));
  for (int axis = 0; axis < 3; ++axis) {
    OCTO_ASSIGN_OR_RETURN(layout.size[axis], GetInteger((*size_it)[axis], "size", 1, INT64_MAX));
  }

  if (auto it = doc.find("channels"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(int64_t channels, GetInteger(*it, "channels", 1, kMaxRawSidecarChannels));
    layout.channels = static_cast<int>(channels);
  }

  if (auto it = doc.find("channel_names"); it != doc.end()) {
    OCTO_RETURN_IF_ERROR(CheckArray(*it, "channel_names", static_cast<size_t>(layout.channels)));
    for (const json& name : *it) {
      OCTO_ASSIGN_OR_RETURN(std::string s, GetString(name, "channel_names"));
      layout.channel_names.push_back(std::move(s));
    }
  }

  auto dtype_it = doc.find("dtype");
  if (dtype_it == doc.end()) return CorruptError("raw sidecar: missing required key \"dtype\"");
  OCTO_ASSIGN_OR_RETURN(std::string dtype_name, GetString(*dtype_it, "dtype"));
  std::optional<volume::DataType> dtype = volume::DataTypeFromNumpyName(dtype_name);
  if (!dtype) {
    return KeyError("dtype", "is \"" + Printable(dtype_name) +
                                 "\"; expected uint8, int8, uint16, int16, uint32, int32, "
                                 "float32 or float64");
  }
  layout.dtype = *dtype;

  if (auto it = doc.find("endianness"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(std::string e, GetString(*it, "endianness"));
    if (e != "little" && e != "big") {
      return KeyError("endianness", "is \"" + Printable(e) + "\"; expected \"little\" or \"big\"");
    }
    layout.big_endian = e == "big";
  }

  if (auto it = doc.find("layout"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(std::string l, GetString(*it, "layout"));
    if (l != "planar" && l != "interleaved") {
      return KeyError("layout",
                      "is \"" + Printable(l) + "\"; expected \"planar\" or \"interleaved\"");
    }
    layout.interleaved = l == "interleaved";
  }

  if (auto it = doc.find("header_bytes"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(int64_t h, GetInteger(*it, "header_bytes", 0, INT64_MAX));
    layout.header_bytes = static_cast<uint64_t>(h);
  }

  if (auto it = doc.find("spacing"); it != doc.end()) {
    OCTO_RETURN_IF_ERROR(CheckArray(*it, "spacing", 3));
    for (int axis = 0; axis < 3; ++axis) {
      const json& v = (*it)[axis];
      if (v.is_null()) continue;
      if (!v.is_number()) {
        return KeyError("spacing", "elements must be numbers (µm) or null, got " + TypeOf(v));
      }
      const double d = v.get<double>();
      if (!std::isfinite(d) || d <= 0) {
        return KeyError("spacing", "elements must be positive, got " + Printable(v.dump()));
      }
      layout.spacing_um[axis] = d;
    }
  }

  // Refuse layouts whose byte count cannot be represented (the raw reader checks the file).
  std::optional<uint64_t> bytes =
      CheckedProduct({static_cast<uint64_t>(layout.size[0]), static_cast<uint64_t>(layout.size[1]),
                      static_cast<uint64_t>(layout.size[2]), static_cast<uint64_t>(layout.channels),
                      volume::BytesPerSample(layout.dtype)});
  if (!bytes || !CheckedAdd(*bytes, layout.header_bytes) ||
      *CheckedAdd(*bytes, layout.header_bytes) > static_cast<uint64_t>(INT64_MAX)) {
    return CorruptError(
        "raw sidecar: \"size\" x \"channels\" x dtype (+ \"header_bytes\") "
        "overflows a 64-bit byte count");
  }
  return layout;
}

// Runs Parse, turning any exception (a bug, or std::bad_alloc) into a Status.
Result<io::RawLayout> ParseNoThrow(std::string_view text, const std::filesystem::path& base_dir,
                                   const std::filesystem::path& default_file) {
  try {
    return Parse(text, base_dir, default_file);
  } catch (const std::exception& e) {
    return InternalError(std::string("raw sidecar: ") + e.what());
  } catch (...) {
    return InternalError("raw sidecar: unknown exception");
  }
}

}  // namespace

Result<io::RawLayout> ParseRawSidecar(std::string_view json_text,
                                      const std::filesystem::path& base_dir) {
  return ParseNoThrow(json_text, base_dir, {});
}

Result<io::RawLayout> LoadRawSidecar(const std::filesystem::path& sidecar_path) {
  try {
    OCTO_ASSIGN_OR_RETURN(const std::string text, ReadSmallFile(sidecar_path, kMaxRawSidecarBytes));
    return ParseRawSidecarFile(text, sidecar_path);
  } catch (const std::exception& e) {
    return IoError(sidecar_path.string() + ": " + e.what());
  }
}

Result<io::RawLayout> ParseRawSidecarFile(std::string_view json_text,
                                          const std::filesystem::path& sidecar_path) {
  try {
    // "scan.raw.json" describes "scan.raw".
    std::filesystem::path default_file;
    const std::string file_name = sidecar_path.filename().string();
    if (EndsWithIgnoreCase(file_name, ".json") && file_name.size() > 5) {
      default_file = file_name.substr(0, file_name.size() - 5);
    }
    Result<io::RawLayout> layout =
        ParseNoThrow(json_text, sidecar_path.parent_path(), default_file);
    if (!layout.ok()) return layout.status().WithContext(sidecar_path.string());
    return layout;
  } catch (const std::exception& e) {
    return IoError(sidecar_path.string() + ": " + e.what());
  }
}

}  // namespace octoscope::protocol
