// Raw sidecar: Octoscope's JSON description of a headerless binary volume ("scan.raw" plus
// "scan.raw.json"). The full field specification, with an example, is in docs/formats.md:
//
//   {"file": "scan.raw", "size": [x, y, z], "channels": 2, "channel_names": ["dapi", "gfp"],
//    "dtype": "uint16", "endianness": "little", "layout": "planar", "header_bytes": 0,
//    "spacing": [0.5, 0.5, 2.0]}
//
// Parsing is strict: unknown keys (typos), wrong types and out-of-range values are errors that
// name the key. Nothing throws out of these functions, whatever the input.
//
// Thread safety: pure functions (LoadRawSidecar reads the file system).
#ifndef OCTOSCOPE_PROTOCOL_RAW_SIDECAR_H_
#define OCTOSCOPE_PROTOCOL_RAW_SIDECAR_H_

#include <filesystem>
#include <string_view>

#include "io/raw_layout.h"
#include "util/result.h"

namespace octoscope::protocol {

// Sidecar files larger than this are refused unread.
inline constexpr uint64_t kMaxRawSidecarBytes = io::kMaxRawSidecarBytes;

// Channels a sidecar may declare (a sanity limit against nonsense headers).
inline constexpr int64_t kMaxRawSidecarChannels = 65536;

// Parses sidecar text. A relative "file" is resolved against `base_dir`. With no sidecar name to
// derive it from, "file" is required here.
Result<io::RawLayout> ParseRawSidecar(std::string_view json_text,
                                      const std::filesystem::path& base_dir);

// Reads and parses `sidecar_path` (at most kMaxRawSidecarBytes). A relative "file" is resolved
// against the sidecar's directory; a missing "file" defaults to the sidecar's name minus ".json"
// ("scan.raw.json" describes "scan.raw"). Errors name the sidecar.
Result<io::RawLayout> LoadRawSidecar(const std::filesystem::path& sidecar_path);
// The same for the sidecar's text, already read (io::OpenOptions::parse_raw_sidecar).
Result<io::RawLayout> ParseRawSidecarFile(std::string_view json_text,
                                          const std::filesystem::path& sidecar_path);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_RAW_SIDECAR_H_
