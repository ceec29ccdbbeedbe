// SliceNames: the file-name conventions of folders of 2-D TIFF slices, shared by the slice-folder
// reader (a finished folder, io/slice_folder_volume.h) and the folder watcher of `octoscope serve
// --watch` (a folder an acquisition is writing plane by plane, dataset/folder_watcher.h).
//
//   - Slice files are .tif/.tiff (any case); names starting with '.' are hidden and ignored.
//   - A file stem splits into maximal runs of digits and of non-digits (tokens).
//   - A CHANNEL token is a digit run right after a marker "c", "ch", "channel" or "w" (any case)
//     that starts the stem or follows a non-letter: "img_c0_z12", "ch1-0005", "C01Z005",
//     "scan_w2_z3" ("slow5" has none: its "w" follows a letter).
//   - A Z token (ParsePlaneName only) is a digit run right after a marker "z" (same rule), else
//     the last digit run that is not the channel token: "ch1-0005" is z 5, "C01Z005" is z 5.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_IO_SLICE_NAMES_H_
#define OCTOSCOPE_IO_SLICE_NAMES_H_

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"

namespace octoscope::io {

// True for "*.tif" / "*.tiff", any case.
bool IsTiffName(std::string_view name);

struct NameToken {
  std::string text;
  bool digits = false;
};

// A file stem split into maximal runs of digits and of non-digits.
std::vector<NameToken> TokenizeName(std::string_view stem);

// The channel marker ("channel", "ch", "c", "w", any case) that `token` ends with, as spelled in
// the name, when it starts the token or follows a non-letter; "" otherwise.
std::string ChannelMarker(std::string_view token);

// Numeric value of a digit run, saturating at UINT64_MAX (only compared, never used as a size).
uint64_t DigitValue(std::string_view digits);

// What the name of one plane file of an acquisition says.
struct PlaneName {
  std::optional<uint64_t> channel;  // The channel token's value, when the name has one.
  uint64_t z = 0;                   // The z token's value.
};

// Parses a plane file's stem by the rules above. Errors (kInvalidArgument, naming the stem): no
// digit run that could number the plane, two channel tokens, two z markers.
Result<PlaneName> ParsePlaneName(std::string_view stem);

// The channel number a sub-folder's name carries: its channel token ("ch1", "C2", "w0"), or the
// whole name when it is a plain number ("0", "01"); nullopt otherwise.
std::optional<uint64_t> ChannelFolderNumber(std::string_view folder_name);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_SLICE_NAMES_H_
