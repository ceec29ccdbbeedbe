#include "octree/octree_builder.h"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>

namespace octoscope::octree {
namespace {

// One slab of one channel, converted to the stored type, waiting to be inserted.
struct ReadySlab {
  int channel = 0;
  int64_t z0 = 0;
  int64_t nz = 0;
  std::vector<std::byte> stored;
};

// True when ConvertToStored would copy the bytes unchanged.
bool IsIdentity(const volume::ValueMap& map) {
  return map.file_type == map.stored_type && map.offset == 0 && map.scale == 1;
}

}  // namespace

int64_t SlabPlanes(const volume::VolumeInfo& info, int64_t brick_depth, int threads,
                   uint64_t slab_budget_bytes) {
  const uint64_t plane_bytes = info.PlaneVoxels() * volume::BytesPerSample(info.dtype);
  const uint64_t per_slab = slab_budget_bytes / (2 * static_cast<uint64_t>(std::max(threads, 1)));
  int64_t best = 1;
  for (int64_t n = 1; n <= brick_depth; ++n) {
    if (brick_depth % n == 0 && n * plane_bytes <= per_slab) best = n;
  }
  return std::min(best, info.size[2]);
}

Status BuildOctree(io::VolumeSource& source, const std::vector<volume::ValueMap>& maps,
                   Octree& octree, const BuildOptions& options) {
  const volume::VolumeInfo& info = source.info();
  const BrickGeometry& geometry = octree.geometry();
  const int channels = info.channel_count();
  if (geometry.volume_size() != Vec3{info.size[0], info.size[1], info.size[2]} ||
      geometry.channels() != channels || static_cast<int>(maps.size()) != channels) {
    return InvalidArgumentError("octree geometry does not match the source " + info.ToString());
  }
  const int threads = options.threads > 0 ? options.threads : std::max(2, channels);
  const int64_t nz = SlabPlanes(info, geometry.brick_size()[2], threads, options.slab_budget_bytes);
  const int64_t slabs_per_channel = (info.size[2] + nz - 1) / nz;
  const int64_t items = slabs_per_channel * channels;
  const size_t stored_bytes = static_cast<size_t>(geometry.bytes_per_sample());

  std::mutex mutex;
  std::condition_variable cv;
  int64_t next_item = 0;          // GUARDED_BY(mutex): next work item to read.
  std::deque<ReadySlab> ready;    // GUARDED_BY(mutex): read, waiting for insertion.
  int readers_running = threads;  // GUARDED_BY(mutex)
  bool stop = false;              // GUARDED_BY(mutex): an error ended the build.
  Status first_error;             // GUARDED_BY(mutex)
  const size_t max_ready = static_cast<size_t>(threads);
  // Slab buffers are recycled: a fresh 10-100 MB buffer costs a page fault per 4 KiB and a
  // zero fill, more than copying the slab. Bounded by the slabs in flight.
  std::vector<std::vector<std::byte>> spare;  // GUARDED_BY(mutex)
  auto take_spare = [&] {
    std::lock_guard lock(mutex);
    if (spare.empty()) return std::vector<std::byte>();
    std::vector<std::byte> buffer = std::move(spare.back());
    spare.pop_back();
    return buffer;
  };

  auto fail = [&](Status s) {
    std::lock_guard lock(mutex);
    if (first_error.ok()) first_error = std::move(s);
    stop = true;
    cv.notify_all();
  };

  auto reader = [&] {
    std::vector<std::byte> raw;
    while (true) {
      int64_t item;
      {
        std::unique_lock lock(mutex);
        if (stop || next_item >= items) break;
        item = next_item++;
      }
      // z-major: all channels of a slab before the next slab, so files stored plane-interleaved
      // are read nearly sequentially.
      ReadySlab slab;
      slab.channel = static_cast<int>(item % channels);
      slab.z0 = (item / channels) * nz;
      slab.nz = std::min(nz, info.size[2] - slab.z0);
      raw.resize(source.SlabBytes(slab.nz));
      Status s = source.ReadSlab(slab.channel, slab.z0, slab.nz, raw);
      if (!s.ok()) {
        fail(std::move(s));
        break;
      }
      if (IsIdentity(maps[slab.channel]) && volume::BytesPerSample(info.dtype) == stored_bytes) {
        // Nothing to convert: the slab as read is the stored slab.
        slab.stored = std::move(raw);
        raw = take_spare();
      } else {
        slab.stored = take_spare();
        slab.stored.resize(raw.size() / volume::BytesPerSample(info.dtype) * stored_bytes);
        volume::ConvertToStored(maps[slab.channel], raw, slab.stored);
      }
      std::unique_lock lock(mutex);
      cv.wait(lock, [&] { return stop || ready.size() < max_ready; });
      if (stop) break;
      ready.push_back(std::move(slab));
      cv.notify_all();
    }
    std::lock_guard lock(mutex);
    --readers_running;
    cv.notify_all();
  };

  std::vector<std::thread> pool;
  pool.reserve(threads);
  for (int t = 0; t < threads; ++t) {
    pool.emplace_back([&] {
      // Exceptions (allocation failures) must not cross the thread boundary.
      try {
        reader();
      } catch (const std::exception& e) {
        fail(ResourceExhaustedError(std::string("reading a slab: ") + e.what()));
        std::lock_guard lock(mutex);
        --readers_running;
        cv.notify_all();
      }
    });
  }

  BuildProgress progress;
  progress.planes_total = static_cast<uint64_t>(info.size[2]) * channels;
  const uint64_t plane_file_bytes = info.PlaneVoxels() * volume::BytesPerSample(info.dtype);
  Status status;
  while (true) {
    ReadySlab slab;
    {
      std::unique_lock lock(mutex);
      cv.wait(lock, [&] { return !ready.empty() || readers_running == 0 || stop; });
      if (stop) break;
      if (ready.empty()) break;  // All readers finished and everything is inserted.
      slab = std::move(ready.front());
      ready.pop_front();
      cv.notify_all();
    }
    Box box{{0, 0, slab.z0}, {info.size[0], info.size[1], slab.z0 + slab.nz}};
    status = octree.Insert(slab.channel, box, slab.stored);
    if (!status.ok()) {
      fail(status);
      break;
    }
    {
      std::lock_guard lock(mutex);
      spare.push_back(std::move(slab.stored));
    }
    progress.planes_done += static_cast<uint64_t>(slab.nz);
    progress.source_bytes_done += static_cast<uint64_t>(slab.nz) * plane_file_bytes;
    if (options.progress) options.progress(progress);
  }
  {
    std::lock_guard lock(mutex);
    stop = true;
    cv.notify_all();
  }
  for (std::thread& t : pool) t.join();
  std::lock_guard lock(mutex);
  return first_error;
}

}  // namespace octoscope::octree
