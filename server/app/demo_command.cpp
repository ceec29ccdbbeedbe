// `octoscope demo`: writes the built-in synthetic embryo as an OME-TIFF, so a user (or a test)
// has a realistic multi-channel volume to open without downloading anything.
#include <array>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

#include "app/commands.h"
#include "app/flags.h"
#include "io/ome_tiff_writer.h"
#include "io/synthetic_embryo.h"
#include "io/volume_stats.h"
#include "protocol/info_report.h"
#include "util/progress.h"
#include "util/strings.h"

namespace octoscope::app {
namespace {

constexpr const char* kCommand = "octoscope demo";

// "X,Y,Z" with each value in 1..kMaxSize.
Result<std::array<int64_t, 3>> ParseSize(const std::string& text) {
  std::vector<std::string_view> parts = Split(text, ',');
  if (parts.size() != 3) {
    return InvalidArgumentError("--size: '" + Printable(text) + "' is not X,Y,Z");
  }
  std::array<int64_t, 3> size{};
  for (int a = 0; a < 3; ++a) {
    std::optional<int64_t> value = ParseInt64(parts[a]);
    if (!value || *value < 1 || *value > io::SyntheticEmbryo::kMaxSize) {
      return InvalidArgumentError("--size: '" + Printable(parts[a]) +
                                  "' must be an integer in 1.." +
                                  std::to_string(io::SyntheticEmbryo::kMaxSize));
    }
    size[a] = *value;
  }
  return size;
}

// A plain file name: no directories, nothing that escapes --out.
bool IsPlainName(const std::string& name) {
  return !name.empty() && name != "." && name != ".." && name.find('/') == std::string::npos &&
         name.find('\0') == std::string::npos;
}

int UsageError(const std::string& message, const Flags& flags) {
  std::fprintf(stderr, "%s: %s\n\n%s", kCommand, message.c_str(), flags.Help().c_str());
  return kExitUsage;
}

}  // namespace

int RunDemo(std::span<const std::string> args) {
  Flags flags("octoscope demo --out DIR [options]",
              "Writes the built-in demo specimen, a synthetic fluorescently labelled embryo\n"
              "(channels: nuclei, membranes, spots, reporter), as DIR/NAME.ome.tif and prints\n"
              "the file's path. The same size, channels and seed always give the same voxels.");
  flags.AddValue("out", "DIR", "output directory (created if missing)");
  flags.AddValue("size", "X,Y,Z", "volume size in voxels", "256,256,128");
  flags.AddValue("channels", "N", "number of channels, 1..4", "3");
  flags.AddValue("seed", "S", "random seed", "42");
  flags.AddValue("compression", "C", "none, deflate, zstd or lzw", "deflate");
  flags.AddValue("name", "NAME", "file name without .ome.tif", "demo-embryo");
  flags.AddValue("embryo-percent", "P",
                 "how much of the box the embryo spans per axis, 1..100 (small: a sparse scan)",
                 "92");
  flags.AddValue(
      "stats-json", "FILE",
      "also write `info --json --stats` of the generated voxels (computed from the\n"
      "                            generator, not the file: a reference for tests and benchmarks)");
  if (Status s = flags.Parse(args); !s.ok()) return UsageError(s.message(), flags);
  if (flags.help_requested()) {
    std::printf("%s", flags.Help().c_str());
    return kExitOk;
  }

  std::optional<std::string> out_dir = flags.Get("out");
  if (!out_dir || out_dir->empty()) return UsageError("--out DIR is required", flags);
  io::SyntheticEmbryoOptions embryo_options;
  if (std::optional<std::string> size_text = flags.Get("size")) {
    Result<std::array<int64_t, 3>> size = ParseSize(*size_text);
    if (!size.ok()) return UsageError(size.status().message(), flags);
    embryo_options.size = *size;
  }
  Result<int64_t> channels = flags.GetInt("channels", 3, 1, io::SyntheticEmbryo::kMaxChannels);
  if (!channels.ok()) return UsageError(channels.status().message(), flags);
  embryo_options.channels = static_cast<int>(*channels);
  Result<int64_t> seed = flags.GetInt("seed", 42, 0, INT64_MAX);
  if (!seed.ok()) return UsageError(seed.status().message(), flags);
  embryo_options.seed = static_cast<uint64_t>(*seed);
  Result<int64_t> percent = flags.GetInt("embryo-percent", 92, 1, 100);
  if (!percent.ok()) return UsageError(percent.status().message(), flags);
  embryo_options.embryo_percent = static_cast<int>(*percent);
  io::OmeTiffWriteOptions write_options;
  const std::string compression_name = flags.Get("compression").value_or("deflate");
  std::optional<io::TiffCompression> compression = io::TiffCompressionFromName(compression_name);
  if (!compression) {
    return UsageError("--compression: '" + Printable(compression_name) +
                          "' is not one of none, deflate, zstd, lzw",
                      flags);
  }
  write_options.compression = *compression;
  const std::string name = flags.Get("name").value_or("demo-embryo");
  if (!IsPlainName(name)) {
    return UsageError("--name: '" + Printable(name) + "' is not a plain file name", flags);
  }
  write_options.image_name = name;

  Result<std::unique_ptr<io::SyntheticEmbryo>> embryo = io::SyntheticEmbryo::Create(embryo_options);
  if (!embryo.ok()) return UsageError(embryo.status().message(), flags);

  const std::filesystem::path dir(*out_dir);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) {
    std::fprintf(stderr, "%s: cannot create directory %s: %s\n", kCommand, dir.string().c_str(),
                 ec.message().c_str());
    return kExitBadInput;
  }
  const std::filesystem::path path = dir / (name + ".ome.tif");

  const volume::VolumeInfo& info = (*embryo)->info();
  const uint64_t total_planes = static_cast<uint64_t>(info.size[2]) * info.channel_count();
  ProgressBar progress(stderr, "planes", total_planes,
                       static_cast<double>(info.PlaneVoxels() * sizeof(uint16_t)));
  write_options.progress = [&progress](uint64_t done, uint64_t) { progress.Update(done); };
  Status status = io::WriteOmeTiff(**embryo, path, write_options);
  progress.Finish();  // Ends the progress line before anything else is printed.
  if (!status.ok()) {
    std::fprintf(stderr, "%s: %s\n", kCommand, status.message().c_str());
    return kExitBadInput;
  }
  if (std::optional<std::string> stats_path = flags.Get("stats-json")) {
    // Statistics straight from the generator: independent of every reader.
    Result<io::VolumeStats> stats = io::ComputeVolumeStats(**embryo, {});
    if (!stats.ok()) {
      std::fprintf(stderr, "%s: %s\n", kCommand, stats.status().message().c_str());
      return kExitBadInput;
    }
    volume::VolumeInfo file_info = info;
    file_info.format = "ome-tiff";
    std::ofstream out(*stats_path, std::ios::trunc);
    out << protocol::InfoReportJson(file_info, *stats) << "\n";
    if (!out.flush()) {
      std::fprintf(stderr, "%s: cannot write %s\n", kCommand, stats_path->c_str());
      return kExitBadInput;
    }
  }
  std::printf("%s\n", path.string().c_str());
  return kExitOk;
}

}  // namespace octoscope::app
