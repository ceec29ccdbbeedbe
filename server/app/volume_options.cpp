#include "app/volume_options.h"

#include <cmath>
#include <cstdio>
#include <string>

#include "protocol/raw_sidecar.h"
#include "util/strings.h"

namespace octoscope::app {

void AddVolumeFlags(Flags& flags) {
  flags.AddValue("series", "N", "which image/series of a multi-series file", "0");
  flags.AddValue("time", "T", "which time point", "0");
  flags.AddValue("spacing", "X,Y,Z",
                 "override the voxel spacing in micrometres (use '-' to keep an axis, e.g. -,-,5)");
}

Result<io::OpenOptions> VolumeOptionsFromFlags(const Flags& flags) {
  io::OpenOptions options;
  OCTO_ASSIGN_OR_RETURN(int64_t series, flags.GetInt("series", 0, 0, 1 << 30));
  OCTO_ASSIGN_OR_RETURN(int64_t time, flags.GetInt("time", 0, 0, 1 << 30));
  options.series = static_cast<int>(series);
  options.time = static_cast<int>(time);
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
  options.load_raw_sidecar = protocol::LoadRawSidecar;
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
