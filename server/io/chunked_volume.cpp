#include "io/chunked_volume.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <exception>
#include <mutex>
#include <new>
#include <thread>
#include <utility>

#include "io/buffer_pool.h"
#include "io/chunk_cache.h"
#include "util/checked_math.h"

namespace octoscope::io {
namespace {

// One sample of `type` holding `value` (clamped to the type's range, rounded for integers), in
// native byte order.
std::array<std::byte, 8> SampleBytes(volume::DataType type, double value) {
  std::array<std::byte, 8> out{};
  auto put = [&out]<typename T>(T v) { std::memcpy(out.data(), &v, sizeof v); };
  auto integer = [&](double lo, double hi) {
    return std::isnan(value) ? 0.0 : std::clamp(std::nearbyint(value), lo, hi);
  };
  switch (type) {
    case volume::DataType::kUint8:
      put(static_cast<uint8_t>(integer(0, 255)));
      break;
    case volume::DataType::kInt8:
      put(static_cast<int8_t>(integer(-128, 127)));
      break;
    case volume::DataType::kUint16:
      put(static_cast<uint16_t>(integer(0, 65535)));
      break;
    case volume::DataType::kInt16:
      put(static_cast<int16_t>(integer(-32768, 32767)));
      break;
    case volume::DataType::kUint32:
      put(static_cast<uint32_t>(integer(0, 4294967295.0)));
      break;
    case volume::DataType::kInt32:
      put(static_cast<int32_t>(integer(-2147483648.0, 2147483647.0)));
      break;
    case volume::DataType::kFloat32:
      put(static_cast<float>(value));
      break;
    case volume::DataType::kFloat64:
      put(value);
      break;
  }
  return out;
}

int64_t CeilDiv(int64_t a, int64_t b) { return (a + b - 1) / b; }

class ChunkedVolume final : public VolumeSource {
 public:
  ChunkedVolume(volume::VolumeInfo info, ChunkLayout layout, std::unique_ptr<ChunkReader> reader,
                const ChunkedVolumeOptions& options, int threads)
      : info_(std::move(info)),
        layout_(std::move(layout)),
        reader_(std::move(reader)),
        name_(options.name),
        bps_(volume::BytesPerSample(info_.dtype)),
        fill_(SampleBytes(info_.dtype, options.fill_value)),
        chunk_bytes_(layout_.ChunkElements() * bps_),
        cache_(options.cache_bytes),
        buffers_(BufferPool::Create(static_cast<size_t>(threads) + 2)),
        free_helpers_(threads - 1) {
    cx_ = layout_.chunk[layout_.x_dim];
    cy_ = layout_.chunk[layout_.y_dim];
    cz_ = layout_.z_dim >= 0 ? layout_.chunk[layout_.z_dim] : 1;
    cc_ = layout_.channel_dim >= 0 ? layout_.chunk[layout_.channel_dim] : 1;
    ct_ = layout_.time_dim >= 0 ? layout_.chunk[layout_.time_dim] : 1;
    grid_x_ = CeilDiv(info_.size[0], cx_);
    grid_y_ = CeilDiv(info_.size[1], cy_);
    grid_z_ = CeilDiv(info_.size[2], cz_);
    whole_planes_ = WholePlanes();
  }

  const volume::VolumeInfo& info() const override { return info_; }

  int64_t PreferredSlabPlanes() const override { return std::min(cz_, info_.size[2]); }

  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    OCTO_RETURN_IF_ERROR(CheckSlabRequest(info_, channel, z0, nz, out.size()).WithContext(name_));
    const int64_t zc0 = z0 / cz_;
    const int64_t zc1 = (z0 + nz - 1) / cz_;
    const int64_t tasks = (zc1 - zc0 + 1) * grid_y_ * grid_x_;

    std::atomic<int64_t> next{0};
    std::atomic<bool> failed{false};
    std::mutex error_mutex;
    Status first_error;  // GUARDED_BY(error_mutex)
    auto fail = [&](Status s) {
      std::lock_guard lock(error_mutex);
      if (first_error.ok()) first_error = std::move(s);
      failed = true;
    };
    // Each worker takes chunks in grid order (x fastest) until none are left.
    auto work = [&] {
      try {
        for (int64_t i = next++; i < tasks && !failed; i = next++) {
          const int64_t xc = i % grid_x_;
          const int64_t yc = (i / grid_x_) % grid_y_;
          const int64_t zc = zc0 + i / (grid_x_ * grid_y_);
          Status s = CopyChunk(channel, z0, nz, zc, yc, xc, out);
          if (!s.ok()) {
            fail(std::move(s));
            return;
          }
        }
      } catch (const std::bad_alloc&) {
        fail(ResourceExhaustedError(name_ + ": out of memory decoding chunks"));
      } catch (const std::exception& e) {
        fail(InternalError(name_ + ": reading chunks: " + e.what()));
      }
    };

    // Helpers beyond the calling thread, as many as the chunks need and the shared budget of
    // decoding threads allows (concurrent readers share it).
    const int helpers = AcquireHelpers(static_cast<int>(std::min<int64_t>(tasks - 1, 1 << 16)));
    std::vector<std::thread> pool;
    int started = 0;
    try {
      for (; started < helpers; ++started) pool.emplace_back(work);
    } catch (const std::system_error&) {
      // Fewer threads than hoped: the others do the work.
    }
    work();
    for (std::thread& t : pool) t.join();
    free_helpers_ += helpers;
    std::lock_guard lock(error_mutex);
    return first_error;
  }

 private:
  int AcquireHelpers(int want) {
    int free = free_helpers_.load();
    while (true) {
      const int take = std::clamp(want, 0, std::max(free, 0));
      if (free_helpers_.compare_exchange_weak(free, free - take)) return take;
    }
  }

  // Copies the part of chunk (zc, yc, xc) of `channel` that lies in the slab into `out`.
  Status CopyChunk(int channel, int64_t z0, int64_t nz, int64_t zc, int64_t yc, int64_t xc,
                   std::span<std::byte> out) {
    const int64_t ci = channel / cc_;
    const int64_t ti = info_.time / ct_;
    std::vector<int64_t> index(layout_.shape.size(), 0);
    index[layout_.x_dim] = xc;
    index[layout_.y_dim] = yc;
    if (layout_.z_dim >= 0) index[layout_.z_dim] = zc;
    if (layout_.channel_dim >= 0) index[layout_.channel_dim] = ci;
    if (layout_.time_dim >= 0) index[layout_.time_dim] = ti;

    // The chunk's part of the slab (image coordinates), and of the whole pass (read tracking:
    // one unit per channel-plane of the chunk inside the image).
    const int64_t zb = std::max(z0, zc * cz_),
                  ze = std::min({z0 + nz, (zc + 1) * cz_, info_.size[2]});
    const int64_t yb = yc * cy_, ye = std::min((yc + 1) * cy_, info_.size[1]);
    const int64_t xb = xc * cx_, xe = std::min((xc + 1) * cx_, info_.size[0]);
    const int64_t z_units = std::min(cz_, info_.size[2] - zc * cz_);
    const int64_t c_units = std::min<int64_t>(cc_, info_.channel_count() - ci * cc_);
    const uint64_t total_units = static_cast<uint64_t>(z_units * c_units);
    const uint64_t first_unit =
        static_cast<uint64_t>((channel - ci * cc_) * z_units + (zb - zc * cz_));
    const uint64_t units = static_cast<uint64_t>(ze - zb);
    const uint64_t key = ((static_cast<uint64_t>(ci) * grid_z_ + zc) * grid_y_ + yc) * grid_x_ + xc;

    if (whole_planes_ && units == total_units && c_units == 1 && z_units == cz_) {
      // The chunk is exactly planes zb..ze-1 of the slab, stored as the slab stores them: decode
      // it in place (no copy, no cache: nothing else in a pass needs it).
      const size_t at = static_cast<size_t>((zb - z0) * info_.PlaneVoxels() * bps_);
      std::span<std::byte> part = out.subspan(at, static_cast<size_t>(chunk_bytes_));
      OCTO_ASSIGN_OR_RETURN(bool present, reader_->ReadChunk(index, part));
      if (!present) FillSamples(part);
      return Status::Ok();
    }
    auto decode = [&]() -> Result<ChunkCache::Data> {
      std::shared_ptr<UninitializedBytes> buffer = buffers_->Take(chunk_bytes_);
      OCTO_ASSIGN_OR_RETURN(bool present, reader_->ReadChunk(index, *buffer));
      if (!present) return ChunkCache::Data();
      return ChunkCache::Data(std::move(buffer));
    };
    OCTO_ASSIGN_OR_RETURN(ChunkCache::Data data, cache_.Get(key, units < total_units, decode));

    const int64_t X = info_.size[0], Y = info_.size[1];
    const int64_t run = xe - xb;
    if (!data) {
      // Absent chunk: the fill value.
      for (int64_t z = zb; z < ze; ++z) {
        for (int64_t y = yb; y < ye; ++y) {
          std::byte* dst = out.data() + static_cast<size_t>((((z - z0) * Y + y) * X + xb) * bps_);
          FillSamples({dst, static_cast<size_t>(run) * bps_});
        }
      }
    } else {
      const std::vector<int64_t>& s = layout_.strides;
      int64_t base = 0;
      if (layout_.channel_dim >= 0) base += (channel - ci * cc_) * s[layout_.channel_dim];
      if (layout_.time_dim >= 0) base += (info_.time - ti * ct_) * s[layout_.time_dim];
      const int64_t sx = s[layout_.x_dim], sy = s[layout_.y_dim];
      const int64_t sz = layout_.z_dim >= 0 ? s[layout_.z_dim] : 0;
      const std::byte* src_chunk = data->data();
      for (int64_t z = zb; z < ze; ++z) {
        for (int64_t y = yb; y < ye; ++y) {
          const int64_t src = base + (z - zc * cz_) * sz + (y - yb) * sy;
          std::byte* dst = out.data() + static_cast<size_t>((((z - z0) * Y + y) * X + xb) * bps_);
          if (sx == 1) {
            std::memcpy(dst, src_chunk + src * bps_, static_cast<size_t>(run) * bps_);
          } else {
            for (int64_t i = 0; i < run; ++i) {
              std::memcpy(dst + i * bps_, src_chunk + (src + i * sx) * bps_, bps_);
            }
          }
        }
      }
    }
    cache_.MarkRead(key, first_unit, units, total_units);
    return Status::Ok();
  }

  // Writes the fill value into every sample of `part`.
  void FillSamples(std::span<std::byte> part) const {
    if (std::all_of(fill_.begin(), fill_.begin() + bps_,
                    [](std::byte b) { return b == std::byte{0}; })) {
      std::memset(part.data(), 0, part.size());
      return;
    }
    for (size_t i = 0; i + bps_ <= part.size(); i += bps_) {
      std::memcpy(part.data() + i, fill_.data(), bps_);
    }
  }

  // True when a decoded chunk is a run of whole planes laid out as a slab: x and y span the
  // image exactly, C order z, y, x, every other dim one element deep.
  bool WholePlanes() const {
    const std::vector<int64_t>& s = layout_.strides;
    if (cx_ != info_.size[0] || cy_ != info_.size[1] || s[layout_.x_dim] != 1 ||
        s[layout_.y_dim] != cx_ || (layout_.z_dim >= 0 && s[layout_.z_dim] != cx_ * cy_)) {
      return false;
    }
    for (size_t d = 0; d < layout_.chunk.size(); ++d) {
      const int dim = static_cast<int>(d);
      if (dim != layout_.x_dim && dim != layout_.y_dim && dim != layout_.z_dim &&
          layout_.chunk[d] != 1) {
        return false;
      }
    }
    return true;
  }

  const volume::VolumeInfo info_;
  const ChunkLayout layout_;
  const std::unique_ptr<ChunkReader> reader_;
  const std::string name_;
  const size_t bps_;
  const std::array<std::byte, 8> fill_;
  const uint64_t chunk_bytes_;
  int64_t cx_, cy_, cz_, cc_, ct_;
  int64_t grid_x_, grid_y_, grid_z_;
  bool whole_planes_ = false;  // Chunks are whole planes: decoded in place when read whole.
  ChunkCache cache_;
  const std::shared_ptr<BufferPool> buffers_;  // Decoded-chunk buffers, reused.
  std::atomic<int> free_helpers_;  // Decoding threads available beyond the readers' own.
};

}  // namespace

uint64_t ChunkLayout::ChunkElements() const {
  uint64_t n = 1;
  for (int64_t c : chunk) n = CheckedMul(n, static_cast<uint64_t>(c)).value_or(UINT64_MAX);
  return n;
}

std::vector<int64_t> ChunkLayout::StridesFor(const std::vector<int64_t>& chunk,
                                             const std::vector<int>& order) {
  const size_t n = chunk.size();
  std::vector<int64_t> strides(n, 1);
  int64_t s = 1;
  for (size_t k = n; k-- > 0;) {
    const size_t dim = order.empty() ? k : static_cast<size_t>(order[k]);
    strides[dim] = s;
    s *= chunk[dim];
  }
  return strides;
}

Result<std::unique_ptr<VolumeSource>> MakeChunkedVolume(volume::VolumeInfo info, ChunkLayout layout,
                                                        std::unique_ptr<ChunkReader> reader,
                                                        const ChunkedVolumeOptions& options) {
  const int dims = static_cast<int>(layout.shape.size());
  if (layout.chunk.size() != layout.shape.size() || layout.strides.size() != layout.shape.size()) {
    return InternalError(options.name + ": chunk layout dims disagree");
  }
  const int named[] = {layout.x_dim, layout.y_dim, layout.z_dim, layout.channel_dim,
                       layout.time_dim};
  for (int i = 0; i < 5; ++i) {
    if (named[i] < -1 || named[i] >= dims || (i < 2 && named[i] < 0)) {
      return InternalError(options.name + ": chunk layout axis out of range");
    }
    for (int j = 0; j < i; ++j) {
      if (named[i] >= 0 && named[i] == named[j]) {
        return InternalError(options.name + ": chunk layout names one dim twice");
      }
    }
  }
  const uint64_t elements = layout.ChunkElements();
  uint64_t last = 0;
  for (int d = 0; d < dims; ++d) {
    if (layout.chunk[d] < 1 || layout.strides[d] < 1) {
      return InternalError(options.name + ": chunk layout extent or stride < 1");
    }
    last += static_cast<uint64_t>(layout.chunk[d] - 1) * static_cast<uint64_t>(layout.strides[d]);
  }
  if (elements == UINT64_MAX || last >= elements) {
    return InternalError(options.name + ": chunk strides address outside the chunk");
  }
  int threads = options.threads;
  if (threads <= 0) {
    threads = static_cast<int>(std::clamp(std::thread::hardware_concurrency(), 1u, 16u));
  }
  return std::unique_ptr<VolumeSource>(
      new ChunkedVolume(std::move(info), std::move(layout), std::move(reader), options, threads));
}

}  // namespace octoscope::io
