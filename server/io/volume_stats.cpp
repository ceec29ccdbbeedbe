#include "io/volume_stats.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <limits>
#include <mutex>
#include <optional>
#include <thread>
#include <type_traits>
#include <vector>

#include "util/target_clones.h"
#include "util/uninitialized_bytes.h"

namespace octoscope::io {
namespace {

using volume::DataType;
// Integer sums of up to 2^64 voxels of 32-bit values need more than 64 bits.
__extension__ typedef __int128 Int128;

// Running sums for one channel. Integer types sum exactly in 128 bits; floats use Neumaier's
// compensated sum so a long run of small values after a large one is not lost.
struct Accumulator {
  double min = std::numeric_limits<double>::infinity();
  double max = -std::numeric_limits<double>::infinity();
  Int128 int_sum = 0;
  double float_sum = 0;
  double float_comp = 0;
  uint64_t count = 0;
  uint64_t nan_count = 0;
};

// The widest partial sum that cannot overflow over one chunk: 32 bits for 8/16-bit samples (the
// fast path, which vectorises well), 64 bits for 32-bit samples.
template <typename T>
using ChunkSum =
    std::conditional_t<(sizeof(T) <= 2), std::conditional_t<std::is_signed_v<T>, int32_t, uint32_t>,
                       int64_t>;

// Integer samples: chunks small enough that the partial sum cannot overflow, so the inner loop is
// plain adds/min/max over one type, which the compiler vectorises.
template <typename T>
[[gnu::always_inline]] inline void AccumulateInts(const std::byte* data, size_t n,
                                                  Accumulator& acc) {
  const T* v = reinterpret_cast<const T*>(data);
  // (Hot path for uint16: see AccumulateUint16 below, cloned for AVX2.)
  constexpr size_t kChunk = 1 << 15;  // 2^15 * 2^16 < 2^31: safe for int32 and uint32 sums.
  for (size_t start = 0; start < n; start += kChunk) {
    const size_t count = std::min(n - start, kChunk);
    const T* p = v + start;
    T lo = p[0], hi = p[0];
    ChunkSum<T> sum = 0;
    for (size_t i = 0; i < count; ++i) {
      const T x = p[i];
      lo = x < lo ? x : lo;
      hi = x > hi ? x : hi;
      sum += x;
    }
    acc.min = std::min(acc.min, static_cast<double>(lo));
    acc.max = std::max(acc.max, static_cast<double>(hi));
    acc.int_sum += sum;
  }
  acc.count += n;
}

template <typename T>
void AccumulateFloats(const std::byte* data, size_t n, Accumulator& acc) {
  const T* v = reinterpret_cast<const T*>(data);
  for (size_t i = 0; i < n; ++i) {
    double x = static_cast<double>(v[i]);
    if (std::isnan(x)) {
      ++acc.nan_count;
      continue;
    }
    acc.min = std::min(acc.min, x);
    acc.max = std::max(acc.max, x);
    // Neumaier: keep the low-order bits that the addition loses.
    double t = acc.float_sum + x;
    if (std::fabs(acc.float_sum) >= std::fabs(x)) {
      acc.float_comp += (acc.float_sum - t) + x;
    } else {
      acc.float_comp += (x - t) + acc.float_sum;
    }
    acc.float_sum = t;
    ++acc.count;
  }
}

// The common microscopy type gets an AVX2 clone picked at load time (GCC function multiversioning):
// unsigned 16-bit min/max are single instructions there, and twice as wide.
OCTO_TARGET_CLONES_AVX2 void AccumulateUint16(const std::byte* data, size_t n, Accumulator& acc) {
  AccumulateInts<uint16_t>(data, n, acc);
}

void Accumulate(DataType type, const std::byte* data, size_t n, Accumulator& acc) {
  switch (type) {
    case DataType::kUint8:
      return AccumulateInts<uint8_t>(data, n, acc);
    case DataType::kInt8:
      return AccumulateInts<int8_t>(data, n, acc);
    case DataType::kUint16:
      return AccumulateUint16(data, n, acc);
    case DataType::kInt16:
      return AccumulateInts<int16_t>(data, n, acc);
    case DataType::kUint32:
      return AccumulateInts<uint32_t>(data, n, acc);
    case DataType::kInt32:
      return AccumulateInts<int32_t>(data, n, acc);
    case DataType::kFloat32:
      return AccumulateFloats<float>(data, n, acc);
    case DataType::kFloat64:
      return AccumulateFloats<double>(data, n, acc);
  }
}

// One slab read by the reader thread, handed to the accumulating thread.
struct Slab {
  int channel = 0;
  int64_t z0 = 0;
  int64_t nz = 0;
  UninitializedBytes data;  // Overwritten by each read: never zero-filled.
};

// Adds the sums of `from` into `into`. Integer sums add exactly; compensated float sums add their
// sums with the same Neumaier step (its rounding error joins the compensations).
void Merge(const Accumulator& from, Accumulator& into) {
  into.min = std::min(into.min, from.min);
  into.max = std::max(into.max, from.max);
  into.int_sum += from.int_sum;
  const double t = into.float_sum + from.float_sum;
  const double lost = std::fabs(into.float_sum) >= std::fabs(from.float_sum)
                          ? (into.float_sum - t) + from.float_sum
                          : (from.float_sum - t) + into.float_sum;
  into.float_comp += from.float_comp + lost;
  into.float_sum = t;
  into.count += from.count;
  into.nan_count += from.nan_count;
}

VolumeStats Finish(DataType dtype, const std::vector<Accumulator>& acc) {
  VolumeStats stats;
  for (const Accumulator& a : acc) {
    ChannelStats c;
    c.count = a.count;
    c.nan_count = a.nan_count;
    if (a.count > 0) {
      c.min = a.min;
      c.max = a.max;
      c.mean = volume::IsFloat(dtype)
                   ? (a.float_sum + a.float_comp) / static_cast<double>(a.count)
                   // Exact integer sum, one rounding in the division (long double keeps 64 bits).
                   : static_cast<double>(static_cast<long double>(a.int_sum) /
                                         static_cast<long double>(a.count));
    } else {
      c.min = c.max = c.mean = std::numeric_limits<double>::quiet_NaN();
    }
    stats.channels.push_back(c);
  }
  return stats;
}

// Direct path: the (z, c) planes, in z-major order (sequential in channel-interleaved files), are
// cut into one contiguous share per thread, so each thread walks the file forward and the result
// depends only on the thread count. A plane the file stores as is is read piece by piece into a
// small per-thread buffer that stays in cache while it is summed (what `cat` does); any other
// plane is read whole with ReadSlab into a per-thread plane buffer.
Result<VolumeStats> ComputeDirectStats(VolumeSource& source, const StatsOptions& options,
                                       int threads) {
  const volume::VolumeInfo& info = source.info();
  const int channels = info.channel_count();
  const uint64_t total_planes = static_cast<uint64_t>(info.size[2]) * channels;
  const uint64_t plane_bytes = source.SlabBytes(1);
  const uint64_t sample_bytes = volume::BytesPerSample(info.dtype);
  // Whole samples per piece, at least one.
  const uint64_t piece_bytes =
      std::max<uint64_t>(sample_bytes, options.piece_bytes / sample_bytes * sample_bytes);
  const int workers =
      static_cast<int>(std::clamp<uint64_t>(static_cast<uint64_t>(threads), 1, total_planes));

  struct Worker {
    std::vector<Accumulator> acc;
    Status status;
  };
  std::vector<Worker> work(static_cast<size_t>(workers));
  std::atomic<uint64_t> planes_done{0};
  std::atomic<bool> stop{false};  // Set on the first error: the others give up early.
  uint64_t reported = 0;          // The last progress reported (by the calling thread only).

  // Sums planes [begin, end) of the z-major order into `w`. Errors (exceptions included) end up
  // in w.status; only the progress callback, called when `report`, may throw.
  auto run = [&](Worker& w, uint64_t begin, uint64_t end, bool report) {
    std::vector<std::byte> buffer;  // One piece of a stored plane, or a whole other plane.
    for (uint64_t i = begin; i < end && !stop.load(std::memory_order_relaxed); ++i) {
      try {
        if (w.acc.empty()) w.acc.assign(static_cast<size_t>(channels), Accumulator{});
        const int c = static_cast<int>(i % static_cast<uint64_t>(channels));
        const int64_t z = static_cast<int64_t>(i / static_cast<uint64_t>(channels));
        // (The kernel's read-ahead follows each thread's forward run through the shared
        // descriptor; an explicit fadvise(WILLNEED) per plane measured no faster, cold or warm.)
        std::optional<StoredPlane> stored = source.FindStoredPlane(c, z);
        if (stored) {
          buffer.resize(static_cast<size_t>(std::min(piece_bytes, plane_bytes)));
          for (uint64_t done = 0; done < plane_bytes && w.status.ok();) {
            const uint64_t n = std::min(piece_bytes, plane_bytes - done);
            std::span<std::byte> piece(buffer.data(), static_cast<size_t>(n));
            w.status = stored->file->ReadBytes(stored->offset + done, piece);
            if (w.status.ok()) {
              Accumulate(info.dtype, piece.data(), static_cast<size_t>(n / sample_bytes),
                         w.acc[static_cast<size_t>(c)]);
            }
            done += n;
          }
        } else {
          buffer.resize(static_cast<size_t>(plane_bytes));
          w.status = source.ReadSlab(c, z, 1, buffer);
          if (w.status.ok()) {
            Accumulate(info.dtype, buffer.data(), static_cast<size_t>(info.PlaneVoxels()),
                       w.acc[static_cast<size_t>(c)]);
          }
        }
      } catch (const std::bad_alloc&) {
        w.status = ResourceExhaustedError("out of memory reading a plane of " +
                                          std::to_string(plane_bytes) + " bytes");
      } catch (const std::exception& e) {
        w.status = InternalError(std::string("summing planes: ") + e.what());
      }
      if (!w.status.ok()) {
        stop = true;
        return;
      }
      const uint64_t done = planes_done.fetch_add(1, std::memory_order_relaxed) + 1;
      if (report && options.progress) {
        reported = done;
        options.progress(done, total_planes);
      }
    }
  };
  auto share = [&](int k) { return total_planes * static_cast<uint64_t>(k) / workers; };

  std::vector<std::thread> helpers;
  // Whatever happens on this thread (a throwing progress callback, a failed thread start), stop
  // and join the helpers before the shared state above goes out of scope.
  struct JoinGuard {
    std::atomic<bool>& stop;
    std::vector<std::thread>& helpers;
    ~JoinGuard() {
      stop = true;
      for (std::thread& t : helpers) {
        if (t.joinable()) t.join();
      }
    }
  } join_guard{stop, helpers};
  for (int k = 1; k < workers; ++k) {
    helpers.emplace_back([&, k] { run(work[k], share(k), share(k + 1), false); });
  }
  // The calling thread sums the first share and is the only one to report progress; the helpers'
  // last planes are reported once they are joined.
  run(work[0], share(0), share(1), true);
  for (std::thread& t : helpers) t.join();
  for (const Worker& w : work) {
    if (!w.status.ok()) return w.status;
  }
  if (options.progress && reported < total_planes) options.progress(total_planes, total_planes);

  std::vector<Accumulator> acc(static_cast<size_t>(channels));
  for (const Worker& w : work) {
    // Every share holds at least one plane (workers <= planes), so every acc is sized.
    for (int c = 0; c < channels && !w.acc.empty(); ++c) Merge(w.acc[c], acc[c]);
  }
  return Finish(info.dtype, acc);
}

}  // namespace

Result<VolumeStats> ComputeVolumeStats(VolumeSource& source, const StatsOptions& options) {
  const volume::VolumeInfo& info = source.info();
  if (options.direct && info.size[2] > 0 && info.channel_count() > 0 &&
      source.FindStoredPlane(0, 0)) {
    int threads = options.threads;
    if (threads <= 0) {
      threads = static_cast<int>(std::clamp(std::thread::hardware_concurrency(), 1u, 4u));
    }
    return ComputeDirectStats(source, options, threads);
  }
  const uint64_t plane_bytes = source.SlabBytes(1);
  int64_t planes_per_slab = static_cast<int64_t>(
      std::clamp<uint64_t>(options.slab_bytes / std::max<uint64_t>(plane_bytes, 1), 1,
                           static_cast<uint64_t>(info.size[2])));
  // Chunked sources decode whole chunks: slabs of whole chunk depths decode each chunk once.
  const int64_t align = source.PreferredSlabPlanes();
  if (align > 1 && static_cast<uint64_t>(align) * plane_bytes <= options.max_aligned_slab_bytes) {
    planes_per_slab = std::max<int64_t>(1, planes_per_slab / align) * align;
  }
  const int channels = info.channel_count();
  const uint64_t total_planes = static_cast<uint64_t>(info.size[2]) * channels;

  // Two buffers in flight: the reader fills one while this thread sums the other.
  std::mutex mutex;
  std::condition_variable cv;
  std::optional<Slab> full;    // GUARDED_BY(mutex): ready for summing.
  std::vector<Slab> empty(2);  // GUARDED_BY(mutex): free buffers.
  bool reader_done = false;    // GUARDED_BY(mutex)
  bool stop = false;           // GUARDED_BY(mutex): set when the consumer gives up.
  Status read_status;          // GUARDED_BY(mutex)

  // Ends the reader with `status`; called at most once, from the reader thread.
  auto finish_reader = [&](Status status) {
    std::lock_guard lock(mutex);
    read_status = std::move(status);
    reader_done = true;
    cv.notify_all();
  };

  auto read_all = [&] {
    // z-major order keeps channel-interleaved files (one IFD per z and channel) sequential.
    for (int64_t z0 = 0; z0 < info.size[2]; z0 += planes_per_slab) {
      int64_t nz = std::min(planes_per_slab, info.size[2] - z0);
      for (int c = 0; c < channels; ++c) {
        Slab slab;
        {
          std::unique_lock lock(mutex);
          cv.wait(lock, [&] { return !empty.empty() || stop; });
          if (stop) return;
          slab = std::move(empty.back());
          empty.pop_back();
        }
        slab.channel = c;
        slab.z0 = z0;
        slab.nz = nz;
        slab.data.resize(source.SlabBytes(nz));
        Status s = source.ReadSlab(c, z0, nz, slab.data);
        if (!s.ok()) return finish_reader(std::move(s));
        std::unique_lock lock(mutex);
        cv.wait(lock, [&] { return !full.has_value() || stop; });
        if (stop) return;
        full = std::move(slab);
        cv.notify_all();
      }
    }
    finish_reader(Status::Ok());
  };

  std::thread reader([&] {
    // Exceptions must not cross the thread boundary (std::terminate): turn them into a Status.
    try {
      read_all();
    } catch (const std::bad_alloc&) {
      finish_reader(ResourceExhaustedError("out of memory reading a slab of " +
                                           std::to_string(planes_per_slab) + " planes"));
    } catch (const std::exception& e) {
      finish_reader(InternalError(std::string("reading slabs: ") + e.what()));
    }
  });
  // Whatever happens on this thread (an error, a throwing progress callback), stop and join the
  // reader before the shared state above goes out of scope.
  struct JoinGuard {
    std::function<void()> stop_and_join;
    ~JoinGuard() { stop_and_join(); }
  } join_guard{[&] {
    {
      std::lock_guard lock(mutex);
      stop = true;
      cv.notify_all();
    }
    if (reader.joinable()) reader.join();
  }};

  std::vector<Accumulator> acc(channels);
  uint64_t planes_done = 0;
  Status status;
  while (true) {
    Slab slab;
    {
      std::unique_lock lock(mutex);
      cv.wait(lock, [&] { return full.has_value() || reader_done; });
      if (!full.has_value()) {
        status = read_status;
        break;
      }
      slab = std::move(*full);
      full.reset();
      cv.notify_all();
    }
    Accumulate(info.dtype, slab.data.data(), slab.data.size() / volume::BytesPerSample(info.dtype),
               acc[slab.channel]);
    planes_done += slab.nz;
    if (options.progress) options.progress(planes_done, total_planes);
    std::lock_guard lock(mutex);
    empty.push_back(std::move(slab));
    cv.notify_all();
  }
  join_guard.stop_and_join();
  if (!status.ok()) return status;
  return Finish(info.dtype, acc);
}

}  // namespace octoscope::io
