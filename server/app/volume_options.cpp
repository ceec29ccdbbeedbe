#include "app/volume_options.h"

#include <cmath>
#include <cstdio>
#include <string>

#include "protocol/raw_sidecar.h"
#include "protocol/zarr_json.h"
#include "util/strings.h"

namespace octoscope::app {

void AddVolumeFlags(Flags& flags) {
  flags.AddValue("series", "N", "which image/series of a multi-series file", "0");
  flags.AddValue("time", "T", "which time point", "0");
  flags.AddValue("level", "N",
                 "which resolution level of a multiscale file (OME-Zarr, Imaris; 0 = finest)", "0");
  flags.AddValue("decode-threads", "N",
                 "threads decoding compressed chunks of OME-Zarr/Imaris (default: all cores)");
  flags.AddValue("spacing", "X,Y,Z",
                 "override the voxel spacing in micrometres (use '-' to keep an axis, e.g. -,-,5)");
}

io::OpenOptions DefaultOpenOptions() {
  io::OpenOptions options;
  options.parse_raw_sidecar = protocol::ParseRawSidecarFile;
  options.zarr_json = protocol::MakeZarrJsonParsers();
  return options;
}

Result<io::OpenOptions> VolumeOptionsFromFlags(const Flags& flags) {
  io::OpenOptions options = DefaultOpenOptions();
  OCTO_ASSIGN_OR_RETURN(int64_t series, flags.GetInt("series", 0, 0, 1 << 30));
  OCTO_ASSIGN_OR_RETURN(int64_t time, flags.GetInt("time", 0, 0, 1 << 30));
  OCTO_ASSIGN_OR_RETURN(int64_t level, flags.GetInt("level", 0, 0, 1 << 30));
  options.series = static_cast<int>(series);
  options.time = static_cast<int>(time);
  options.level = static_cast<int>(level);
  OCTO_ASSIGN_OR_RETURN(int64_t decode_threads, flags.GetInt("decode-threads", 0, 1, 256));
  options.decode_threads = static_cast<int>(decode_threads);
  if (auto text = flags.Get("spacing")) {
    auto parts = Split(*text, ',');
    if (parts.size() != 3) return InvalidArgumentError("--spacing: expected X,Y,Z");
    for (int a = 0; a < 3; ++a) {
      if (TrimWhitespace(parts[a]) == "-") continue;
      auto v = ParseDouble(parts[a]);
      if (!v || !std::isfinite(*v) || *v <= 0) {
        return InvalidArgumentError("--spacing: '" + Printable(parts[a]) +
                                    "' is not a positive number");
      }
      options.spacing_um[a] = *v;
    }
  }
  // Each warning is one line on stderr as soon as the input is open (docs/cli.md).
  options.on_warning = [command = flags.command()](const std::string& warning) {
    std::string line = warning;
    for (char& c : line) {
      if (c == '\n' || c == '\r') c = ' ';
    }
    std::fprintf(stderr, "%s: warning: %s\n", command.c_str(), line.c_str());
  };
  return options;
}

}  // namespace octoscope::app
