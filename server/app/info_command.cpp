// `octoscope info INPUT [--json] [--stats]`: what a scan is, and optionally its value ranges.
#include <cstdio>
#include <filesystem>
#include <string>

#include "app/commands.h"
#include "app/volume_options.h"
#include "io/open_volume.h"
#include "io/volume_stats.h"
#include "protocol/info_report.h"
#include "util/progress.h"

namespace octoscope::app {
namespace {

// One line on stderr, "<kind>: <file>: <problem>" (docs/cli.md). Readers name the file in their
// messages; where one does not, the input path is added after the kind.
int Fail(const std::string& input, const Status& status) {
  const bool names_file =
      status.message().find(std::filesystem::path(input).filename().string()) != std::string::npos;
  std::string line = names_file ? status.ToString() : status.WithContext(input).ToString();
  // A message must stay one line even when a file name or library text holds a newline.
  for (char& c : line) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  std::fprintf(stderr, "octoscope info: %s\n", line.c_str());
  return kExitBadInput;
}

void PrintHuman(const volume::VolumeInfo& info, const std::optional<io::VolumeStats>& stats) {
  std::printf("format      %s\n", info.format.c_str());
  std::printf("size        %lld x %lld x %lld voxels (x, y, z)\n",
              static_cast<long long>(info.size[0]), static_cast<long long>(info.size[1]),
              static_cast<long long>(info.size[2]));
  std::printf("type        %s\n", std::string(volume::NumpyName(info.dtype)).c_str());
  std::printf("spacing     ");
  for (int a = 0; a < 3; ++a) {
    if (info.spacing_um[a]) {
      std::printf("%g", *info.spacing_um[a]);
    } else {
      std::printf("?");
    }
    std::printf(a < 2 ? " x " : " µm\n");
  }
  std::printf("series      %d of %d\n", info.series, info.series_count);
  std::printf("time point  %d of %d\n", info.time, info.time_points);
  if (info.level_count > 1) std::printf("level       %d of %d\n", info.level, info.level_count);
  std::printf("bytes       %llu\n", static_cast<unsigned long long>(info.VoxelBytes()));
  for (int c = 0; c < info.channel_count(); ++c) {
    const volume::ChannelInfo& ch = info.channels[c];
    std::printf("channel %d   %s", c, ch.name.empty() ? "(unnamed)" : ch.name.c_str());
    if (ch.color) std::printf("  color #%02x%02x%02x", ch.color->r, ch.color->g, ch.color->b);
    if (ch.window) std::printf("  window %.10g..%.10g", ch.window->start, ch.window->end);
    if (stats) {
      const io::ChannelStats& s = stats->channels[c];
      std::printf("  min %.10g  max %.10g  mean %.10g", s.min, s.max, s.mean);
      if (s.nan_count) std::printf("  NaN %llu", static_cast<unsigned long long>(s.nan_count));
    }
    std::printf("\n");
  }
}

}  // namespace

int RunInfo(std::span<const std::string> args) {
  Flags flags(
      "octoscope info INPUT [--json] [--stats] [--series N] [--time T] [--level N]",
      "Prints what INPUT holds: format, size, channels, sample type, spacing. INPUT is an\n"
      "OME-TIFF (single file, any file of a multi-file set, or a .companion.ome), a TIFF or\n"
      "BigTIFF stack, an ImageJ hyperstack, a folder of 2-D slices, an OME-Zarr folder (or\n"
      "one of its arrays), an Imaris .ims file, a raw file with a .json sidecar, or a Voreen\n"
      ".vvd. With --stats every voxel is read, slab by slab.");
  flags.SetPositionals("INPUT", 1, 1);
  flags.AddSwitch("json", "print one JSON object (fields in docs/cli.md)");
  flags.AddSwitch("stats", "read all voxels and add per-channel min, max and mean");
  AddVolumeFlags(flags);
  if (Status s = flags.Parse(args); !s.ok()) {
    std::fprintf(stderr, "octoscope info: %s\n\n%s", s.message().c_str(), flags.Help().c_str());
    return kExitUsage;
  }
  if (flags.help_requested()) {
    std::printf("%s", flags.Help().c_str());
    return kExitOk;
  }
  auto options = VolumeOptionsFromFlags(flags);
  if (!options.ok()) {
    std::fprintf(stderr, "octoscope info: %s\n", options.status().message().c_str());
    return kExitUsage;
  }
  const std::string& input = flags.positionals()[0];
  auto source = io::OpenVolume(input, *options);
  if (!source.ok()) return Fail(input, source.status());
  const volume::VolumeInfo& info = (*source)->info();

  std::optional<io::VolumeStats> stats;
  if (flags.Has("stats")) {
    uint64_t total = static_cast<uint64_t>(info.size[2]) * info.channel_count();
    ProgressBar bar(stderr, "planes", total, static_cast<double>((*source)->SlabBytes(1)));
    io::StatsOptions stats_options;
    stats_options.progress = [&bar](uint64_t done, uint64_t) { bar.Update(done); };
    auto computed = io::ComputeVolumeStats(**source, stats_options);
    bar.Finish();
    if (!computed.ok()) return Fail(input, computed.status());
    stats = std::move(*computed);
  }
  if (flags.Has("json")) {
    std::printf("%s\n", protocol::InfoReportJson(info, stats).c_str());
  } else {
    PrintHuman(info, stats);
  }
  return kExitOk;
}

}  // namespace octoscope::app
