#include "octree/octree_builder.h"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <string>
#include <system_error>
#include <thread>

namespace octoscope::octree {
namespace {

// True when ConvertToStored would copy the bytes unchanged.
bool IsIdentity(const volume::ValueMap& map) {
  return map.file_type == map.stored_type && map.offset == 0 && map.scale == 1;
}

}  // namespace

BuildBudget SplitBuildBudget(const volume::VolumeInfo& info, const Vec3& brick_size,
                             int bytes_per_stored_sample, uint64_t ram_bytes) {
  const int64_t brick_height = brick_size[1], brick_depth = brick_size[2];
  BuildBudget b;
  b.slab_bytes = std::min<uint64_t>(ram_bytes / 16, uint64_t{64} << 20);
  const uint64_t layer = info.PlaneVoxels() * static_cast<uint64_t>(info.channel_count()) *
                         static_cast<uint64_t>(std::min<int64_t>(brick_depth, info.size[2])) *
                         static_cast<uint64_t>(bytes_per_stored_sample);
  if (2 * layer <= ram_bytes / 2) {
    b.staging_bytes = 2 * layer;
  } else if (layer <= ram_bytes / 4) {
    b.staging_bytes = layer;
  }
  // Layers staged in scratch files are read back one brick row at a time: that row's buffers.
  const uint64_t row = layer / static_cast<uint64_t>(std::max<int64_t>(1, info.size[1])) *
                       static_cast<uint64_t>(std::min<int64_t>(brick_height, info.size[1]));
  const uint64_t reserved = b.slab_bytes + (b.staging_bytes > 0 ? b.staging_bytes : row);
  b.page_bytes = ram_bytes > reserved ? ram_bytes - reserved : 0;
  const auto bricks_across = [&](int a) {
    return static_cast<uint64_t>((info.size[a] + brick_size[a] - 1) / brick_size[a]);
  };
  const uint64_t stored_brick = static_cast<uint64_t>((brick_size[0] + 2) * (brick_size[1] + 2) *
                                                      (brick_size[2] + 2)) *
                                static_cast<uint64_t>(info.channel_count()) *
                                static_cast<uint64_t>(bytes_per_stored_sample);
  b.working_set_bytes = bricks_across(0) * bricks_across(1) * stored_brick * 4 / 3;
  return b;
}

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
  const int64_t nz = options.slab_planes > 0 ? std::min(options.slab_planes, info.size[2])
                                             : SlabPlanes(info, geometry.brick_size()[2], threads,
                                                          options.slab_budget_bytes);
  const int64_t slabs_per_channel = (info.size[2] + nz - 1) / nz;
  const int64_t items = slabs_per_channel * channels;
  const size_t file_bytes = volume::BytesPerSample(info.dtype);
  const size_t stored_bytes = static_cast<size_t>(geometry.bytes_per_sample());

  const int insert_threads =
      options.insert_threads > 0
          ? options.insert_threads
          : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  WorkerPool workers(insert_threads);
  IngestOptions ingest_options;
  ingest_options.staging_bytes = options.staging_bytes;
  ingest_options.scratch_dir = options.scratch_dir;
  ingest_options.workers = &workers;
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<SlabIngest> ingest,
                        SlabIngest::Create(&octree, ingest_options));

  std::mutex mutex;
  std::condition_variable cv;
  int64_t next_item = 0;    // GUARDED_BY(mutex): next work item to read.
  int64_t items_read = 0;   // GUARDED_BY(mutex)
  int readers_running = 0;  // GUARDED_BY(mutex)
  bool stop = false;        // GUARDED_BY(mutex): an error or a cancellation ended the build.
  Status first_error;       // GUARDED_BY(mutex)

  auto fail = [&](Status s) {
    std::lock_guard lock(mutex);
    if (first_error.ok()) first_error = std::move(s);
    stop = true;
    cv.notify_all();
  };

  auto reader = [&] {
    std::vector<std::byte> raw, stored;
    while (true) {
      int64_t item;
      {
        std::lock_guard lock(mutex);
        if (stop || next_item >= items) break;
        if (options.stop.stop_requested()) {
          if (first_error.ok()) first_error = CancelledError("build cancelled");
          stop = true;
          cv.notify_all();
          break;
        }
        item = next_item++;
      }
      const int channel = static_cast<int>(item % channels);
      const int64_t z0 = (item / channels) * nz;
      const int64_t depth = std::min(nz, info.size[2] - z0);
      raw.resize(source.SlabBytes(depth));
      Status s = source.ReadSlab(channel, z0, depth, raw);
      if (s.ok()) {
        std::span<const std::byte> slab = raw;
        if (!(IsIdentity(maps[channel]) && file_bytes == stored_bytes)) {
          stored.resize(raw.size() / file_bytes * stored_bytes);
          volume::ConvertToStored(maps[channel], raw, stored);
          slab = stored;
        }
        s = ingest->Add(channel, z0, depth, slab);
        if (s.ok() && options.on_slab) options.on_slab(channel, z0, depth, slab);
      }
      if (!s.ok()) {
        fail(std::move(s));
        break;
      }
      std::lock_guard lock(mutex);
      ++items_read;
      cv.notify_all();
    }
  };
  // Exceptions (allocation failures) must not cross the thread boundary.
  auto guarded_reader = [&] {
    try {
      reader();
    } catch (const std::exception& e) {
      fail(ResourceExhaustedError(std::string("reading a slab: ") + e.what()));
    } catch (...) {
      fail(InternalError("reading a slab: an unknown exception"));
    }
    std::lock_guard lock(mutex);
    --readers_running;
    cv.notify_all();
  };

  std::vector<std::thread> pool;
  pool.reserve(threads);
  for (int t = 0; t < threads; ++t) {
    {
      std::lock_guard lock(mutex);
      ++readers_running;
    }
    try {
      pool.emplace_back(guarded_reader);
    } catch (const std::system_error&) {
      std::lock_guard lock(mutex);
      --readers_running;
      break;  // Run with the readers that started (or none: see below).
    }
  }
  if (pool.empty()) {
    // Not even one thread: read on this one.
    {
      std::lock_guard lock(mutex);
      ++readers_running;
    }
    guarded_reader();
  }

  BuildProgress progress;
  progress.planes_total = static_cast<uint64_t>(info.size[2]) * channels;
  const uint64_t plane_file_bytes = info.PlaneVoxels() * file_bytes;
  auto report = [&](int64_t read) {
    const IngestProgress ip = ingest->progress();
    progress.planes_done = ip.planes_inserted;
    progress.planes_read = static_cast<uint64_t>(std::min(read * nz, info.size[2])) * channels;
    progress.planes_read = std::min(progress.planes_read, progress.planes_total);
    progress.source_bytes_done = ip.planes_inserted * plane_file_bytes;
    if (!options.progress) return;
    try {
      options.progress(progress);
    } catch (const std::exception& e) {
      fail(InternalError(std::string("build progress callback: ") + e.what()));
    } catch (...) {
      fail(InternalError("build progress callback threw"));
    }
  };
  {
    std::unique_lock lock(mutex);
    int64_t reported = -1;
    while (readers_running > 0) {
      cv.wait_for(lock, std::chrono::milliseconds(100));
      if (options.stop.stop_requested() && !stop) {
        if (first_error.ok()) first_error = CancelledError("build cancelled");
        stop = true;
      }
      if (items_read != reported) {
        reported = items_read;
        lock.unlock();
        report(reported);
        lock.lock();
      }
    }
  }
  for (std::thread& t : pool) t.join();
  Status status;
  {
    std::lock_guard lock(mutex);
    status = first_error;
  }
  if (status.ok()) status = ingest->Flush();
  if (status.ok() && !ingest->complete()) {
    status = InternalError("build ended with planes missing from the octree");
  }
  if (status.ok()) {
    report(items);  // A callback that throws now still fails the build.
    std::lock_guard lock(mutex);
    status = first_error;
  }
  return status;
}

}  // namespace octoscope::octree
