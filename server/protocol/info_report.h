// InfoReport: the JSON document `octoscope info --json` prints, one object per volume. Field
// meanings are specified in docs/cli.md; numbers are in the file's own units.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_INFO_REPORT_H_
#define OCTOSCOPE_PROTOCOL_INFO_REPORT_H_

#include <optional>
#include <string>

#include "io/volume_stats.h"
#include "volume/volume_info.h"

namespace octoscope::protocol {

// One-line JSON object: format, size [x,y,z], channels, channel_names, channel_colors,
// channel_windows ({start, end, min, max} or null), dtype, stored_dtype, spacing [x,y,z] (µm, null
// where unknown), bytes, series, series_count, time, time_points, level, level_count, warnings
// (strings, [] when none); with stats also min, max, mean (one entry per channel) and nan_count.
std::string InfoReportJson(const volume::VolumeInfo& info,
                           const std::optional<io::VolumeStats>& stats);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_INFO_REPORT_H_
