// `octoscope bench upload CACHE_DIR`: brick upload throughput from resident pages
// (docs/benchmarks.md, "Brick uploads"), against baselines measured in the same run on the same
// bytes: a plain memcpy into warm memory, one blocking clEnqueueWriteBuffer of one big buffer,
// and the previous upload path (ReadBrick into a buffer, then one blocking write per brick).
//
// Flow: open the cache, list its bricked nodes coarse first (breadth first, so every node's
// ancestors come before it), keep an even number n of them (--mb), read each once so that their
// pages are resident, then mirror the tree with a brick buffer of n / 2 slots and upload the two
// halves in turn (--rounds): each Upload brings in n / 2 bricks and evicts the other half. Round 1
// writes into fresh device memory (first touch), the later ones into slots written before.
//
// Thread safety: runs on the command's thread only.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "app/commands.h"
#include "app/flags.h"
#include "app/octree_loading.h"
#include "octree/node_encoding.h"
#include "render/cl_call.h"
#include "render/device.h"
#include "render/device_octree.h"

namespace octoscope::app {
namespace {

constexpr const char* kCommand = "octoscope bench upload";

double MsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

double MbPerS(uint64_t bytes, double ms) { return ms > 0 ? bytes / 1e6 / (ms / 1e3) : 0; }

// Bricked node ids, breadth first from the root (coarse first; ancestors before descendants).
std::vector<uint32_t> BrickedBreadthFirst(const octree::Octree& tree) {
  std::vector<uint32_t> queue = {0};
  std::vector<uint32_t> out;
  for (size_t i = 0; i < queue.size(); ++i) {
    std::optional<octree::NodeSnapshot> snap = tree.GetNode(queue[i]);
    if (!snap.has_value()) continue;
    if (snap->has_brick()) out.push_back(snap->id);
    if (snap->has_children()) {
      for (uint32_t o = 0; o < 8; ++o) queue.push_back(snap->child_group * 8 + o);
    }
  }
  return out;
}

struct Row {
  std::string what;
  double mb_per_s;
};

struct Settings {
  std::string dir;
  std::string device;
  render::UploadPath path = render::UploadPath::kAuto;
  int64_t mb = 256;
  int64_t rounds = 7;
};

// The flags' values; a bad one is a usage error.
Result<Settings> ParseSettings(const Flags& flags) {
  Settings s;
  s.dir = flags.positionals()[0];
  s.device = flags.Get("device").value_or("auto");
  OCTO_ASSIGN_OR_RETURN(s.mb, flags.GetInt("mb", 256, 16, 1 << 20));
  OCTO_ASSIGN_OR_RETURN(s.rounds, flags.GetInt("rounds", 7, 2, 1000));
  const std::string path = flags.Get("path").value_or("auto");
  if (path == "mapped") {
    s.path = render::UploadPath::kMapped;
  } else if (path == "staged") {
    s.path = render::UploadPath::kStaged;
  } else if (path != "auto") {
    return InvalidArgumentError("--path must be auto, mapped or staged");
  }
  return s;
}

Status Run(const Settings& settings) {
  const std::string& dir = settings.dir;
  const int64_t mb = settings.mb;
  const int64_t rounds = settings.rounds;
  const render::UploadPath path = settings.path;
  const uint64_t ram_bytes = static_cast<uint64_t>(DefaultRamMb()) << 20;
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<LoadedOctree> loaded, OpenCacheDirectory(dir, ram_bytes));
  octree::Octree& tree = loaded->octree();
  const octree::BrickGeometry& geometry = tree.geometry();
  if (geometry.bytes_per_sample() != 2) {
    return InvalidArgumentError("bench upload measures uint16 caches (this one stores uint8)");
  }
  const uint64_t brick_bytes = geometry.brick_bytes();

  // 1. The bricks: an even count within --mb and the page cache, their pages made resident.
  std::vector<uint32_t> ids = BrickedBreadthFirst(tree);
  const uint64_t fit = std::min<uint64_t>(static_cast<uint64_t>(mb) << 20, ram_bytes / 2);
  ids.resize(std::min<size_t>(ids.size(), fit / brick_bytes) & ~size_t{1});
  if (ids.size() < 16) {
    return InvalidArgumentError("the cache has fewer than 16 bricks to upload (" +
                                std::to_string(ids.size()) + ")");
  }
  const size_t half = ids.size() / 2;
  const uint64_t half_bytes = half * brick_bytes;
  std::vector<std::byte> source(half_bytes);  // The first half's bytes, for the baselines.
  std::vector<std::byte> scratch(brick_bytes);
  for (size_t i = 0; i < ids.size(); ++i) {
    OCTO_RETURN_IF_ERROR(tree.ReadBrick(
        ids[i], i < half ? std::span(source).subspan(i * brick_bytes, brick_bytes) : scratch));
  }
  const std::span<const uint32_t> halves[2] = {std::span(ids).first(half),
                                               std::span(ids).subspan(half)};

  // 2. The device and the mirror with n / 2 slots.
  OCTO_ASSIGN_OR_RETURN(render::DeviceInfo device, render::ChooseDevice(settings.device));
  OCTO_ASSIGN_OR_RETURN(render::ComputeContext context, render::ComputeContext::Create(device));
  render::DeviceOctreeOptions options;
  options.brick_buffer_bytes = half * geometry.brick_samples() * 2;
  options.upload_path = path;
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<render::DeviceOctree> mirror,
                        render::DeviceOctree::Create(&context, &tree, options));
  if (mirror->slot_count() != half) {
    return InternalError("bench upload: the mirror has " + std::to_string(mirror->slot_count()) +
                         " slots, wanted " + std::to_string(half));
  }

  // 3. Rounds of Upload, alternating the halves (each evicts the other).
  std::vector<double> upload_ms;
  double first_ms = 0;
  for (int64_t r = 0; r < rounds; ++r) {
    render::UploadStats stats;
    // No frame ran (every stamp is 0): protect_frame 1 lets each round evict the other half.
    OCTO_RETURN_IF_ERROR(mirror->UploadAll(halves[r % 2], 1, &stats));
    if (stats.uploaded != half) {
      return InternalError("bench upload: round " + std::to_string(r) + " uploaded " +
                           std::to_string(stats.uploaded) + " bricks, wanted " +
                           std::to_string(half));
    }
    (r == 0 ? first_ms : upload_ms.emplace_back()) = stats.ms;
  }

  // 4. Baselines on the same bytes, each repeated as often.
  const size_t repeats = upload_ms.size();
  std::vector<double> memcpy_ms, write_ms, per_brick_ms;
  std::vector<std::byte> warm(half_bytes);
  std::memcpy(warm.data(), source.data(), half_bytes);  // Touched once: warm.
  for (size_t r = 0; r < repeats; ++r) {
    const auto start = std::chrono::steady_clock::now();
    std::memcpy(warm.data(), source.data(), half_bytes);
    memcpy_ms.push_back(MsSince(start));
  }
  double fresh_memcpy_ms = 0;
  {
    // Fresh (never touched) memory: what a first fill pays for page faults.
    std::unique_ptr<std::byte[]> fresh(new std::byte[half_bytes]);
    const auto start = std::chrono::steady_clock::now();
    std::memcpy(fresh.get(), source.data(), half_bytes);
    fresh_memcpy_ms = MsSince(start);
  }
  {
    OCTO_ASSIGN_OR_RETURN(render::ClMem big, context.CreateBuffer(CL_MEM_READ_ONLY, half_bytes));
    OCTO_RETURN_IF_ERROR(context.WriteBuffer(big, 0, half_bytes, source.data()));
    for (size_t r = 0; r < repeats; ++r) {
      const auto start = std::chrono::steady_clock::now();
      OCTO_RETURN_IF_ERROR(context.WriteBuffer(big, 0, half_bytes, source.data()));
      write_ms.push_back(MsSince(start));
    }
    // The previous path: ReadBrick into one brick buffer, then a blocking write per brick.
    std::vector<std::byte> raw(brick_bytes);
    for (size_t r = 0; r < repeats; ++r) {
      const auto start = std::chrono::steady_clock::now();
      for (size_t i = 0; i < half; ++i) {
        OCTO_RETURN_IF_ERROR(tree.ReadBrick(halves[r % 2][i], raw));
        OCTO_RETURN_IF_ERROR(context.WriteBuffer(big, i * brick_bytes, brick_bytes, raw.data()));
      }
      per_brick_ms.push_back(MsSince(start));
    }
  }

  // 5. The table.
  const double memcpy_mb = MbPerS(half_bytes, Median(memcpy_ms));
  const std::vector<Row> rows = {
      {"memcpy, warm destination (baseline)", memcpy_mb},
      {"one blocking clEnqueueWriteBuffer of one buffer", MbPerS(half_bytes, Median(write_ms))},
      {"previous path: ReadBrick + blocking write per brick",
       MbPerS(half_bytes, Median(per_brick_ms))},
      {std::string("DeviceOctree::Upload (") +
           (mirror->upload_path() == render::UploadPath::kMapped ? "mapped" : "staged") +
           "), slots written before",
       MbPerS(half_bytes, Median(upload_ms))},
      {"memcpy, fresh destination (first touch)", MbPerS(half_bytes, fresh_memcpy_ms)},
      {"DeviceOctree::Upload, first fill of fresh slots", MbPerS(half_bytes, first_ms)},
  };
  std::printf("device: %s\n", device.ToString().c_str());
  std::printf("bricks: %zu per upload of %.1f MB (%llu-byte bricks), %lld rounds (medians)\n\n",
              half, half_bytes / 1e6, static_cast<unsigned long long>(brick_bytes),
              static_cast<long long>(rounds));
  std::printf("| transfer | MB/s | ÷ memcpy |\n|---|---|---|\n");
  for (const Row& row : rows) {
    std::printf("| %s | %.0f | %.2f |\n", row.what.c_str(), row.mb_per_s,
                memcpy_mb > 0 ? row.mb_per_s / memcpy_mb : 0);
  }
  return Status::Ok();
}

}  // namespace

int RunBenchUpload(std::span<const std::string> args) {
  Flags flags("octoscope bench upload CACHE_DIR [options]",
              "Brick upload throughput from resident pages into the device's brick buffer,\n"
              "against memcpy and clEnqueueWriteBuffer of the same bytes (docs/benchmarks.md).");
  flags.SetPositionals("CACHE_DIR", 1, 1);
  flags.AddValue("device", "PREF", "OpenCL device: auto, gpu, cpu, N, P:D or a name", "auto");
  flags.AddValue("path", "auto|mapped|staged", "the transfer DeviceOctree uses", "auto");
  flags.AddValue("mb", "N", "MiB of bricks (two halves uploaded in turn)", "256");
  flags.AddValue("rounds", "N", "uploads of a half (the first fills fresh slots)", "7");
  if (Status s = flags.Parse(args); !s.ok()) {
    std::fprintf(stderr, "%s: %s\n\n%s", kCommand, s.message().c_str(), flags.Help().c_str());
    return kExitUsage;
  }
  if (flags.help_requested()) {
    std::printf("%s", flags.Help().c_str());
    return kExitOk;
  }
  Result<Settings> settings = ParseSettings(flags);
  if (!settings.ok()) {
    std::fprintf(stderr, "%s: %s\n\n%s", kCommand, settings.status().message().c_str(),
                 flags.Help().c_str());
    return kExitUsage;
  }
  if (Status s = Run(*settings); !s.ok()) return ReportBadInput(kCommand, settings->dir, s);
  return kExitOk;
}

}  // namespace octoscope::app
