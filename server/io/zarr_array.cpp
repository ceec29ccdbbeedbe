#include "io/zarr_array.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <deque>
#include <map>
#include <mutex>
#include <utility>

#include "io/buffer_pool.h"
#include "util/byte_swap.h"
#include "util/checked_math.h"
#include "util/file_reading.h"
#include "util/uninitialized_bytes.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

constexpr int kMaxDims = 32;
constexpr uint64_t kAbsent = UINT64_MAX;  // Shard index entry of an absent inner chunk.
constexpr size_t kShardIndexCacheEntries = 64;

std::string Num(uint64_t v) { return std::to_string(v); }

// An encoded chunk can only be this much larger than it decodes to (every supported compressor
// expands incompressible data by well under 1/16, plus headers and checksums).
uint64_t MaxEncodedBytes(uint64_t decoded) { return decoded + decoded / 16 + 4096; }

// Opens `path` through `gate` for reading; nullopt-like (no descriptor) when it does not exist.
Result<std::pair<std::unique_ptr<ScopedFd>, uint64_t>> OpenChunkFile(const FileGate& gate,
                                                                     const fs::path& path) {
  Result<int> fd = gate.OpenForReading(path);
  if (!fd.ok()) {
    switch (fd.status().code()) {
      case StatusCode::kNotFound:
        return std::pair(std::unique_ptr<ScopedFd>(), uint64_t{0});
      case StatusCode::kUnsupported:
        return CorruptError(path.string() + ": chunk is not a regular file");
      default:
        return fd.status();
    }
  }
  auto owned = std::make_unique<ScopedFd>(*fd);
  struct stat st;
  if (::fstat(*fd, &st) != 0) {
    return IoError(path.string() + ": cannot stat chunk: " + std::strerror(errno));
  }
  return std::pair(std::move(owned), static_cast<uint64_t>(st.st_size));
}

// Decodes `encoded` through `encoding` into `out` (the chunk's exact decoded size), then puts
// multi-byte samples into native byte order. Codec chains hold at most one compressor; crc32c
// stages around it are checked and stripped.
Status DecodeEncoded(const ZarrChunkEncoding& encoding, size_t bps,
                     std::span<const std::byte> encoded, std::span<std::byte> out) {
  const std::vector<ChunkCodec>& codecs = encoding.codecs;
  std::span<const std::byte> cur = encoded;
  int k = static_cast<int>(codecs.size()) - 1;
  // Checksums applied after the compressor: verify and strip, in place.
  for (; k >= 0 && codecs[k] == ChunkCodec::kCrc32c; --k) {
    OCTO_RETURN_IF_ERROR(CheckCrc32cTrailer(cur));
    cur = cur.first(cur.size() - 4);
  }
  if (k < 0) {
    if (cur.size() != out.size()) {
      return CorruptError("uncompressed chunk holds " + Num(cur.size()) + " bytes, expected " +
                          Num(out.size()));
    }
    std::memcpy(out.data(), cur.data(), out.size());
  } else if (k == 0) {
    OCTO_RETURN_IF_ERROR(DecodeChunk(codecs[0], cur, out));
  } else {
    // Checksums applied before the compressor: each added 4 bytes.
    UninitializedBytes inner(out.size() + 4 * static_cast<size_t>(k));
    OCTO_RETURN_IF_ERROR(DecodeChunk(codecs[k], cur, inner));
    std::span<const std::byte> rest = inner;
    for (int j = k - 1; j >= 0; --j) {
      OCTO_RETURN_IF_ERROR(CheckCrc32cTrailer(rest));
      rest = rest.first(rest.size() - 4);
    }
    std::memcpy(out.data(), rest.data(), out.size());
  }
  if (encoding.big_endian != (std::endian::native == std::endian::big)) {
    SwapBytesInPlace(out, bps);
  }
  return Status::Ok();
}

Status CheckEncoding(const ZarrChunkEncoding& e, size_t dims, const std::string& what) {
  int compressors = 0;
  for (ChunkCodec c : e.codecs) compressors += c != ChunkCodec::kCrc32c;
  if (compressors > 1) {
    return UnsupportedError(what + ": more than one compressor in a codec chain");
  }
  if (!e.order.empty()) {
    std::vector<int> sorted = e.order;
    std::sort(sorted.begin(), sorted.end());
    bool ok = sorted.size() == dims;
    for (size_t i = 0; ok && i < dims; ++i) ok = sorted[i] == static_cast<int>(i);
    if (!ok) return CorruptError(what + ": transpose order is not a permutation of the dims");
  }
  return Status::Ok();
}

class ZarrChunkReader final : public ChunkReader {
 public:
  ZarrChunkReader(fs::path dir, ZarrArrayMetadata meta, FileGate gate)
      : dir_(std::move(dir)),
        meta_(std::move(meta)),
        gate_(std::move(gate)),
        bps_(volume::BytesPerSample(meta_.dtype)) {
    if (meta_.sharding) {
      const ZarrSharding& s = *meta_.sharding;
      inner_per_shard_.resize(meta_.chunks.size());
      for (size_t d = 0; d < meta_.chunks.size(); ++d) {
        inner_per_shard_[d] = meta_.chunks[d] / s.inner_chunks[d];
        inner_count_ *= static_cast<uint64_t>(inner_per_shard_[d]);
      }
    }
  }

  Result<bool> ReadChunk(std::span<const int64_t> index, std::span<std::byte> out) override {
    if (!meta_.sharding) {
      const fs::path path = dir_ / Key(index);
      OCTO_ASSIGN_OR_RETURN(auto file, OpenChunkFile(gate_, path));
      if (!file.first) return false;
      if (file.second > MaxEncodedBytes(out.size())) {
        return CorruptError(path.string() + ": chunk file holds " + Num(file.second) +
                            " bytes, far more than its " + Num(out.size()) + " decoded bytes");
      }
      std::shared_ptr<UninitializedBytes> encoded =
          buffers_->Take(static_cast<size_t>(file.second));
      OCTO_RETURN_IF_ERROR(ReadFully(file.first->get(), 0, *encoded, path.string()));
      Status s = DecodeEncoded(meta_.encoding, bps_, *encoded, out);
      if (!s.ok()) return s.WithContext(path.string());
      return true;
    }
    return ReadInnerChunk(index, out);
  }

 private:
  // The chunk key of grid index `index` (shard index when sharded).
  std::string Key(std::span<const int64_t> index) const {
    std::string key = meta_.key_prefix;
    char digits[24];
    for (size_t d = 0; d < index.size(); ++d) {
      if (!key.empty()) key.push_back(meta_.separator);
      const int n = std::snprintf(digits, sizeof digits, "%lld", static_cast<long long>(index[d]));
      key.append(digits, static_cast<size_t>(n));
    }
    return key.empty() ? std::string(1, '0') : key;
  }

  Result<bool> ReadInnerChunk(std::span<const int64_t> index, std::span<std::byte> out) {
    const ZarrSharding& s = *meta_.sharding;
    std::vector<int64_t> shard(index.size());
    uint64_t inner = 0;  // Linear (C-order) index of the inner chunk within its shard.
    for (size_t d = 0; d < index.size(); ++d) {
      shard[d] = index[d] / inner_per_shard_[d];
      inner = inner * static_cast<uint64_t>(inner_per_shard_[d]) +
              static_cast<uint64_t>(index[d] % inner_per_shard_[d]);
    }
    const std::string key = Key(shard);
    const fs::path path = dir_ / key;
    OCTO_ASSIGN_OR_RETURN(auto file, OpenChunkFile(gate_, path));
    if (!file.first) return false;
    OCTO_ASSIGN_OR_RETURN(std::shared_ptr<const std::vector<uint64_t>> table,
                          ShardIndex(key, path, *file.first, file.second));
    const uint64_t offset = (*table)[2 * inner];
    const uint64_t nbytes = (*table)[2 * inner + 1];
    if (offset == kAbsent && nbytes == kAbsent) return false;
    const std::string where = path.string() + ": inner chunk " + Num(inner);
    if (nbytes > MaxEncodedBytes(out.size())) {
      return CorruptError(where + " holds " + Num(nbytes) + " bytes, far more than its " +
                          Num(out.size()) + " decoded bytes");
    }
    if (offset > file.second || nbytes > file.second - offset) {
      return CorruptError(where + " lies outside the shard (bytes " + Num(offset) + "+" +
                          Num(nbytes) + " of " + Num(file.second) + ")");
    }
    std::shared_ptr<UninitializedBytes> encoded = buffers_->Take(static_cast<size_t>(nbytes));
    OCTO_RETURN_IF_ERROR(ReadFully(file.first->get(), offset, *encoded, path.string()));
    Status st = DecodeEncoded(s.inner, bps_, *encoded, out);
    if (!st.ok()) return st.WithContext(where);
    return true;
  }

  // The (offset, nbytes) table of a shard, from a small cache or read and checked.
  Result<std::shared_ptr<const std::vector<uint64_t>>> ShardIndex(const std::string& key,
                                                                  const fs::path& path,
                                                                  const ScopedFd& fd,
                                                                  uint64_t size) {
    {
      std::lock_guard lock(mutex_);
      auto it = indexes_.find(key);
      if (it != indexes_.end()) return it->second;
    }
    const ZarrSharding& s = *meta_.sharding;
    const uint64_t table_bytes = inner_count_ * 16;
    const uint64_t index_bytes = table_bytes + (s.index_crc32c ? 4 : 0);
    if (size < index_bytes) {
      return CorruptError(path.string() + ": shard of " + Num(size) +
                          " bytes is shorter than its index of " + Num(index_bytes));
    }
    UninitializedBytes raw(static_cast<size_t>(index_bytes));
    OCTO_RETURN_IF_ERROR(
        ReadFully(fd.get(), s.index_at_end ? size - index_bytes : 0, raw, path.string()));
    if (s.index_crc32c) {
      Status st = CheckCrc32cTrailer(raw);
      if (!st.ok()) return st.WithContext(path.string() + ": shard index");
    }
    auto table = std::make_shared<std::vector<uint64_t>>(static_cast<size_t>(inner_count_ * 2));
    for (size_t i = 0; i < table->size(); ++i) {
      uint64_t v = 0;
      for (int b = 7; b >= 0; --b) v = (v << 8) | static_cast<uint8_t>(raw[i * 8 + b]);
      (*table)[i] = v;
    }
    std::lock_guard lock(mutex_);
    if (order_.size() >= kShardIndexCacheEntries) {
      indexes_.erase(order_.front());
      order_.pop_front();
    }
    if (indexes_.emplace(key, table).second) order_.push_back(key);
    return std::shared_ptr<const std::vector<uint64_t>>(std::move(table));
  }

  const fs::path dir_;
  const ZarrArrayMetadata meta_;
  const FileGate gate_;
  const size_t bps_;
  // Encoded-chunk buffers, reused (a few per decoding thread at most).
  const std::shared_ptr<BufferPool> buffers_ = BufferPool::Create(16);
  std::vector<int64_t> inner_per_shard_;  // Inner chunks per shard along each dim.
  uint64_t inner_count_ = 1;              // Inner chunks per shard.
  std::mutex mutex_;
  std::map<std::string, std::shared_ptr<const std::vector<uint64_t>>> indexes_;  // GUARDED_BY
  std::deque<std::string> order_;  // GUARDED_BY(mutex_): insertion order, for eviction.
};

}  // namespace

const std::vector<int64_t>& ReadChunkShape(const ZarrArrayMetadata& meta) {
  return meta.sharding ? meta.sharding->inner_chunks : meta.chunks;
}

std::vector<int64_t> ReadChunkStrides(const ZarrArrayMetadata& meta) {
  return ChunkLayout::StridesFor(ReadChunkShape(meta),
                                 meta.sharding ? meta.sharding->inner.order : meta.encoding.order);
}

Result<ZarrArrayMetadata> LoadZarrArray(const fs::path& dir, const ZarrJsonParsers& parsers,
                                        uint64_t max_chunk_bytes, const FileGate& gate) {
  fs::path file = dir / "zarr.json";
  OCTO_ASSIGN_OR_RETURN(const fs::file_type type, gate.Type(file));
  if (type != fs::file_type::regular) file = dir / ".zarray";
  const std::string name = file.string();
  if (!parsers.array) return UnsupportedError(name + ": Zarr metadata parsing is not enabled");
  Result<std::string> text = gate.ReadSmallFile(file, kMaxZarrJsonBytes);
  if (!text.ok()) {
    if (text.status().code() == StatusCode::kNotFound) {
      return NotFoundError(dir.string() + ": no Zarr array here (neither zarr.json nor .zarray)");
    }
    return text.status().WithContext(name);
  }
  Result<ZarrArrayMetadata> parsed = parsers.array(*text);
  if (!parsed.ok()) return parsed.status().WithContext(name);
  ZarrArrayMetadata meta = std::move(*parsed);

  const size_t dims = meta.shape.size();
  if (dims < 1 || dims > kMaxDims) {
    return UnsupportedError(name + ": arrays of " + Num(dims) + " dimensions are not supported");
  }
  if (meta.chunks.size() != dims) {
    return CorruptError(name + ": chunks has " + Num(meta.chunks.size()) + " entries, shape " +
                        Num(dims));
  }
  for (size_t d = 0; d < dims; ++d) {
    if (meta.shape[d] < 0) return CorruptError(name + ": negative shape");
    if (meta.chunks[d] < 1) return CorruptError(name + ": chunk extent below 1");
  }
  if (!meta.dimension_names.empty() && meta.dimension_names.size() != dims) {
    return CorruptError(name + ": dimension_names has " + Num(meta.dimension_names.size()) +
                        " entries for " + Num(dims) + " dimensions");
  }
  if (meta.separator != '.' && meta.separator != '/') {
    return CorruptError(name + ": chunk key separator must be \".\" or \"/\"");
  }
  OCTO_RETURN_IF_ERROR(CheckEncoding(meta.encoding, dims, name));
  if (meta.sharding) {
    const ZarrSharding& s = *meta.sharding;
    if (s.inner_chunks.size() != dims) {
      return CorruptError(name + ": sharding chunk_shape has " + Num(s.inner_chunks.size()) +
                          " entries for " + Num(dims) + " dimensions");
    }
    uint64_t inner = 1;
    for (size_t d = 0; d < dims; ++d) {
      if (s.inner_chunks[d] < 1 || meta.chunks[d] % s.inner_chunks[d] != 0) {
        return CorruptError(name + ": the inner chunk shape does not divide the shard shape");
      }
      inner = CheckedMul(inner, static_cast<uint64_t>(meta.chunks[d] / s.inner_chunks[d]))
                  .value_or(UINT64_MAX);
    }
    if (inner > kMaxShardIndexBytes / 16) {
      return ResourceExhaustedError(
          name + ": a shard holds " + (inner == UINT64_MAX ? std::string("too many") : Num(inner)) +
          " inner chunks, its index would exceed " + Num(kMaxShardIndexBytes) + " bytes");
    }
    OCTO_RETURN_IF_ERROR(CheckEncoding(s.inner, dims, name));
  }
  uint64_t elements = 1;
  for (int64_t c : ReadChunkShape(meta)) {
    elements = CheckedMul(elements, static_cast<uint64_t>(c)).value_or(UINT64_MAX);
  }
  const std::optional<uint64_t> bytes = CheckedMul(elements, volume::BytesPerSample(meta.dtype));
  if (!bytes || *bytes > max_chunk_bytes) {
    return ResourceExhaustedError(name + ": one chunk decodes to " +
                                  (bytes ? Num(*bytes) : std::string("over 2^64")) +
                                  " bytes, more than the limit of " + Num(max_chunk_bytes));
  }
  return meta;
}

std::unique_ptr<ChunkReader> MakeZarrChunkReader(const fs::path& dir, ZarrArrayMetadata meta,
                                                 FileGate gate) {
  return std::make_unique<ZarrChunkReader>(dir, std::move(meta), std::move(gate));
}

}  // namespace octoscope::io
