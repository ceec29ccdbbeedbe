// `octoscope build INPUT --cache DIR`: builds (or reuses) the octree of a scan in a cache
// directory.
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "app/commands.h"
#include "app/octree_loading.h"
#include "app/volume_options.h"
#include "dataset/cache_setup.h"
#include "io/open_volume.h"
#include "octree/octree_builder.h"
#include "octree/octree_cache.h"
#include "protocol/build_report.h"
#include "util/strings.h"

namespace octoscope::app {
namespace {

constexpr const char* kCommand = "octoscope build";

int Fail(const std::string& input, const Status& status) {
  return ReportBadInput(kCommand, input, status);
}

int Usage(const std::string& message, const Flags& flags) {
  std::fprintf(stderr, "%s: %s\n\n%s", kCommand, message.c_str(), flags.Help().c_str());
  return kExitUsage;
}

double PeakRssMb() {
  struct rusage usage;
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux.
}

Result<octree::Vec3> ParseBrick(const std::string& text) {
  auto parts = Split(text, ',');
  if (parts.size() != 1 && parts.size() != 3) return InvalidArgumentError("--brick: N or X,Y,Z");
  octree::Vec3 brick{};
  for (int a = 0; a < 3; ++a) {
    auto v = ParseInt64(parts[parts.size() == 1 ? 0 : a]);
    if (!v || *v < 2 || *v > octree::kMaxBrickAxis || *v % 2 != 0) {
      return InvalidArgumentError("--brick: each size must be an even number in 2.." +
                                  std::to_string(octree::kMaxBrickAxis));
    }
    brick[a] = *v;
  }
  return brick;
}

// Test hook (tests/app/build_command_test.cpp): OCTOSCOPE_TEST_KILL_AFTER_PLANES=N makes the
// process SIGKILL itself after N planes were inserted, a deterministic crash point.
int64_t TestKillAfterPlanes() {
  const char* text = std::getenv("OCTOSCOPE_TEST_KILL_AFTER_PLANES");
  if (!text) return -1;
  return ParseInt64(text).value_or(-1);
}

}  // namespace

int RunBuild(std::span<const std::string> args) {
  const auto start = std::chrono::steady_clock::now();
  Flags flags(
      "octoscope build INPUT --cache DIR [options]",
      "Builds the multi-resolution octree of INPUT (any format of 'octoscope info') into the\n"
      "cache directory DIR, slab by slab, within a RAM budget; reuses DIR when it already\n"
      "holds a complete octree of the same scan built with the same parameters. Prints one\n"
      "JSON line at the end (fields in docs/cli.md).");
  flags.SetPositionals("INPUT", 1, 1);
  flags.AddValue("cache", "DIR", "cache directory (created if missing)");
  flags.AddValue("brick", "N|X,Y,Z",
                 "brick size in voxels, even (auto: <= 64 per axis, the least padding;\n"
                 "                            thin stacks get shallow bricks)",
                 "auto");
  flags.AddValue(
      "threshold", "F",
      "LOSSY pruning: also replace bricks whose values vary by at most F times the channel's\n"
      "                            data range by their average (the report states the error)",
      "0: lossless, only exactly constant bricks");
  flags.AddValue("slab-planes", "N", "planes per read (1: as a live acquisition delivers them)",
                 "from the budget");
  flags.AddValue("ram-mb", "N", "RAM budget in MiB for pages and slabs",
                 "a quarter of RAM, <= 4096");
  flags.AddValue("threads", "N", "reader threads", "one per channel, at least 2");
  AddVolumeFlags(flags);
  if (Status s = flags.Parse(args); !s.ok()) return Usage(s.message(), flags);
  if (flags.help_requested()) {
    std::printf("%s", flags.Help().c_str());
    return kExitOk;
  }
  auto cache_dir = flags.Get("cache");
  if (!cache_dir || cache_dir->empty()) return Usage("--cache DIR is required", flags);
  octree::Vec3 brick{0, 0, 0};  // Auto.
  if (auto text = flags.Get("brick"); text && *text != "auto") {
    auto parsed = ParseBrick(*text);
    if (!parsed.ok()) return Usage(parsed.status().message(), flags);
    brick = *parsed;
  }
  auto threshold = flags.GetDouble("threshold", 0.0);
  if (!threshold.ok()) return Usage(threshold.status().message(), flags);
  if (!(*threshold >= 0 && *threshold <= 1)) return Usage("--threshold must be in [0, 1]", flags);
  auto ram_mb = flags.GetInt("ram-mb", DefaultRamMb(), 16, int64_t{1} << 22);
  if (!ram_mb.ok()) return Usage(ram_mb.status().message(), flags);
  auto threads = flags.GetInt("threads", 0, 0, 256);
  if (!threads.ok()) return Usage(threads.status().message(), flags);
  auto slab_planes = flags.GetInt("slab-planes", 0, 0, octree::kMaxBrickAxis);
  if (!slab_planes.ok()) return Usage(slab_planes.status().message(), flags);
  auto options = VolumeOptionsFromFlags(flags);
  if (!options.ok()) return Usage(options.status().message(), flags);

  const std::string& input = flags.positionals()[0];
  auto source = io::OpenVolume(input, *options);
  if (!source.ok()) return Fail(input, source.status());
  const volume::VolumeInfo& info = (*source)->info();
  auto identity = octree::ComputeSourceIdentity(input);
  if (!identity.ok()) return Fail(input, identity.status());

  brick = dataset::BrickSizeFor(info, brick);
  const uint64_t ram_bytes = static_cast<uint64_t>(*ram_mb) << 20;
  const octree::BuildBudget budget = dataset::BuildBudgetFor(info, brick, ram_bytes);

  octree::CacheParams params;
  params.info = info;
  params.brick_size = brick;
  params.threshold = *threshold;
  auto cache = octree::OctreeCache::Open(*cache_dir, *identity, params, budget.page_bytes,
                                         [&] { return DeriveMapping(**source, *threshold); });
  if (!cache.ok()) return Fail(input, cache.status());

  if (!(*cache)->reused()) {
    if (budget.page_bytes < budget.working_set_bytes) {
      std::fprintf(stderr,
                   "%s: warning: --ram-mb %lld leaves %llu MiB for brick pages, less than "
                   "construction's working set of about %llu MiB (one brick layer and its "
                   "parents): pages will be written and read back (same octree, slower)\n",
                   kCommand, static_cast<long long>(*ram_mb),
                   static_cast<unsigned long long>(budget.page_bytes >> 20),
                   static_cast<unsigned long long>(budget.working_set_bytes >> 20));
    }
    const int64_t kill_after = TestKillAfterPlanes();
    BuildRun run;
    run.budget = budget;
    run.scratch_dir = *cache_dir;
    run.threads = static_cast<int>(*threads);
    run.slab_planes = *slab_planes;
    run.on_progress = [&](const octree::BuildProgress& p) {
      if (kill_after >= 0 && p.planes_done >= static_cast<uint64_t>(kill_after)) raise(SIGKILL);
    };
    dataset::HistogramAccumulator histogram;  // For the display defaults (histogram.bin).
    run.histogram = &histogram;
    Status built =
        BuildWithProgress(**source, (*cache)->mapping().value_maps, (*cache)->octree(), run);
    if (!built.ok()) return Fail(input, built);
    if (Status s =
            dataset::WriteHistogramFile(*cache_dir, histogram.Snapshot(), (*cache)->source());
        !s.ok()) {
      return Fail(*cache_dir, s);
    }
    if (kill_after == static_cast<int64_t>(info.size[2]) * info.channel_count() + 1) raise(SIGKILL);
    if (Status s = (*cache)->Commit(); !s.ok()) return Fail(*cache_dir, s);
  }

  protocol::BuildReport report;
  report.stats = (*cache)->octree().stats();
  report.input_bytes = info.VoxelBytes();
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  report.mb_per_s = report.seconds > 0 ? report.input_bytes / report.seconds / 1e6 : 0;
  report.peak_rss_mb = PeakRssMb();
  report.ram_budget_mb = static_cast<double>(*ram_mb);
  report.reused = (*cache)->reused();
  report.rebuild_reason = (*cache)->rebuild_reason();
  report.levels = (*cache)->octree().geometry().level_count();
  report.cache_dir = *cache_dir;
  report.threshold = *threshold;
  const std::vector<uint32_t> error = (*cache)->octree().PruningError();
  for (size_t c = 0; c < error.size(); ++c) {
    // file = offset + scale * stored: an error of e stored units is scale * e in the file's.
    report.pruning_error.push_back(error[c] * (*cache)->mapping().value_maps[c].scale);
  }
  const paging::PageCacheStats pages = (*cache)->page_cache().stats();
  // Pages never written before are zero-filled without a read (PageCache): every read is a page
  // that construction needed again after it had left RAM.
  report.pages_reread_mb = static_cast<double>(pages.bytes_read) / 1e6;
  report.pages_written_mb = static_cast<double>(pages.bytes_written) / 1e6;
  const octree::Vec3 used = (*cache)->octree().geometry().brick_size();
  report.brick_size.assign(used.begin(), used.end());
  std::printf("%s\n", protocol::BuildReportJson(report).c_str());
  return kExitOk;
}

}  // namespace octoscope::app
