#include "octree/octree_cache.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <map>
#include <span>
#include <sstream>
#include <system_error>

#include "paging/file_page_store.h"
#include "util/durable_file.h"
#include "util/file_reading.h"
#include "util/strings.h"

namespace octoscope::octree {
namespace {

namespace fs = std::filesystem;

constexpr char kManifestName[] = "MANIFEST";
constexpr char kPoolName[] = "octree.pool";
constexpr char kNodesName[] = "octree.nodes";
constexpr char kBuildingName[] = "BUILDING";
constexpr char kLockName[] = "LOCK";
constexpr char kMagic[] = "octoscope-octree-cache";
constexpr uint64_t kMaxManifestBytes = 1 << 20;
constexpr uint64_t kMaxNodesBytes = uint64_t{16} << 30;
constexpr uint64_t kIdentityHeadBytes = 64 << 10;

std::string Hex(uint64_t v) {
  char buf[20];
  std::snprintf(buf, sizeof buf, "%016" PRIx64, v);
  return buf;
}

std::optional<uint64_t> ParseHex(std::string_view text) {
  if (text.empty() || text.size() > 16) return std::nullopt;
  uint64_t v = 0;
  for (char c : text) {
    int d = (c >= '0' && c <= '9') ? c - '0' : (c >= 'a' && c <= 'f') ? c - 'a' + 10 : -1;
    if (d < 0) return std::nullopt;
    v = v * 16 + static_cast<uint64_t>(d);
  }
  return v;
}

// Shortest text that parses back to exactly `v`.
std::string ExactDouble(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// Hashes one file's identity into `hash`: relative name, size, mtime (ns) and first 64 KiB.
Status HashFile(const fs::path& file, const std::string& relative, const io::FileGate& gate,
                uint64_t& hash, uint64_t& bytes) {
  Result<int> fd = gate.OpenForReading(file);
  if (!fd.ok() && io::IsOutsideFolderError(fd.status())) return fd.status();
  if (!fd.ok()) return IoError(file.string() + ": cannot stat");
  const ScopedFd owned(*fd);
  struct stat st;
  if (::fstat(*fd, &st) != 0) return IoError(file.string() + ": cannot stat");
  hash = Fnv1a64(relative, hash);
  std::string meta = std::to_string(st.st_size) + ":" + std::to_string(st.st_mtim.tv_sec) + "." +
                     std::to_string(st.st_mtim.tv_nsec);
  hash = Fnv1a64(meta, hash);
  std::string head(static_cast<size_t>(std::min<uint64_t>(st.st_size, kIdentityHeadBytes)), '\0');
  if (!ReadFully(*fd, 0, std::as_writable_bytes(std::span<char>(head.data(), head.size())),
                 file.string())
           .ok()) {
    return IoError(file.string() + ": cannot read its first bytes");
  }
  hash = Fnv1a64(head, hash);
  bytes += static_cast<uint64_t>(st.st_size);
  return Status::Ok();
}

// The pid an exclusive holder recorded in LOCK ("pid 1234\n"), for messages; "" when unknown.
std::string RecordedHolder(int fd) {
  char text[32] = {};
  const ssize_t n = ::pread(fd, text, sizeof text - 1, 0);
  if (n <= 0) return "";
  std::string_view line(text, static_cast<size_t>(n));
  line = line.substr(0, line.find('\n'));
  if (!line.starts_with("pid ") || !ParseInt64(line.substr(4))) return "";
  return std::string(line);
}

// flock(2), retried when a signal interrupts it; 0 or -1 with errno set.
int Flock(int fd, int operation) {
  int result;
  do {
    result = ::flock(fd, operation);
  } while (result != 0 && errno == EINTR);
  return result;
}

}  // namespace

Result<std::unique_ptr<CacheLock>> CacheLock::Acquire(const fs::path& dir, Mode mode) {
  const fs::path path = dir / kLockName;
  int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0 && (errno == EROFS || errno == EACCES)) {
    // A directory we cannot write: share it without a lock if nobody could write it either.
    fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0 && mode == Mode::kShared && (errno == ENOENT)) {
      return std::unique_ptr<CacheLock>(new CacheLock(dir, -1, mode));
    }
  }
  if (fd < 0) {
    return IoError(path.string() +
                   ": cannot open the cache directory's lock file: " + std::strerror(errno));
  }
  std::unique_ptr<CacheLock> lock(new CacheLock(dir, fd, mode));
  const int operation = (mode == Mode::kShared ? LOCK_SH : LOCK_EX) | LOCK_NB;
  if (Flock(fd, operation) != 0) {
    if (errno != EWOULDBLOCK) {
      return IoError(path.string() + ": cannot lock the cache directory: " + std::strerror(errno));
    }
    // A shared request fails only against an exclusive holder, which is building.
    if (mode == Mode::kShared) {
      const std::string holder = RecordedHolder(fd);
      return UnavailableError(dir.string() +
                              ": the cache directory is locked by another process that is "
                              "building into it" +
                              (holder.empty() ? "" : " (" + holder + ")") +
                              "; wait until it has finished, or use another cache directory");
    }
    return UnavailableError(dir.string() +
                            ": the cache directory is in use by another process; it cannot be "
                            "built into until that process has finished; use another cache "
                            "directory");
  }
  if (mode == Mode::kExclusive) lock->RecordHolder();
  return lock;
}

CacheLock::~CacheLock() {
  if (fd_ >= 0) ::close(fd_);  // Releases the lock.
}

Status CacheLock::MakeExclusive() {
  if (mode_ == Mode::kExclusive) return Status::Ok();
  if (fd_ < 0) {
    return UnavailableError(dir_.string() +
                            ": the cache directory is read-only; it cannot be built into");
  }
  if (Flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    // flock(2) dropped the shared lock before failing: this object no longer holds anything.
    ::close(fd_);
    fd_ = -1;
    if (err != EWOULDBLOCK) {
      return IoError(dir_.string() + ": cannot lock the cache directory: " + std::strerror(err));
    }
    return UnavailableError(dir_.string() +
                            ": the cache directory is in use by another process (it reads the "
                            "octree stored there), so it cannot be rebuilt until that process "
                            "has finished; use another cache directory");
  }
  mode_ = Mode::kExclusive;
  RecordHolder();
  return Status::Ok();
}

Status CacheLock::MakeShared() {
  if (mode_ == Mode::kShared) return Status::Ok();
  if (Flock(fd_, LOCK_SH | LOCK_NB) != 0) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    return UnavailableError(dir_.string() + ": lost the cache directory's lock while sharing it: " +
                            std::strerror(err));
  }
  mode_ = Mode::kShared;
  // The pid recorded for exclusive holders no longer describes the directory (informational
  // only, as in RecordHolder).
  (void)!::ftruncate(fd_, 0);
  return Status::Ok();
}

void CacheLock::RecordHolder() {
  // Informational only (for the messages of processes that find the directory locked): a failed
  // write changes nothing about the lock.
  const std::string text = "pid " + std::to_string(::getpid()) + "\n";
  if (::ftruncate(fd_, 0) == 0) (void)!::pwrite(fd_, text.data(), text.size(), 0);
}

Result<SourceIdentity> ComputeSourceIdentity(const fs::path& input, const io::FileGate& gate) {
  SourceIdentity id;
  id.hash = kFnvOffsetBasis;
  OCTO_ASSIGN_OR_RETURN(const fs::file_type type, gate.Type(input));
  if (type == fs::file_type::directory) {
    OCTO_ASSIGN_OR_RETURN(const fs::path real, gate.Resolve(input));
    // Every regular file below the folder, in a fixed order (a link only as the gate lets it be
    // seen).
    std::error_code ec;
    std::vector<fs::path> files;
    for (fs::recursive_directory_iterator it(real, ec), end; !ec && it != end; it.increment(ec)) {
      const fs::path path = input / it->path().lexically_relative(real);
      std::error_code type_ec;
      if (gate.confined() && it->is_symlink(type_ec)) {
        OCTO_ASSIGN_OR_RETURN(const fs::file_type linked, gate.Type(path));
        if (linked == fs::file_type::regular) files.push_back(path);
      } else if (it->is_regular_file(type_ec)) {
        files.push_back(path);
      }
    }
    if (ec) return IoError(input.string() + ": cannot list: " + ec.message());
    std::sort(files.begin(), files.end());
    for (const fs::path& f : files) {
      OCTO_RETURN_IF_ERROR(
          HashFile(f, fs::relative(f, input, ec).string(), gate, id.hash, id.file_bytes));
    }
    return id;
  }
  OCTO_RETURN_IF_ERROR(HashFile(input, input.filename().string(), gate, id.hash, id.file_bytes));
  return id;
}

std::string CacheManifest::Serialize() const {
  const volume::VolumeInfo& info = params.info;
  std::ostringstream out;
  out << kMagic << " " << kVersion << "\n";
  out << "state complete\n";
  out << "source_hash " << Hex(source.hash) << "\n";
  out << "source_bytes " << source.file_bytes << "\n";
  out << "size " << info.size[0] << " " << info.size[1] << " " << info.size[2] << "\n";
  out << "channels " << info.channel_count() << "\n";
  out << "dtype " << volume::NumpyName(info.dtype) << "\n";
  out << "series " << info.series << "\n";
  out << "time " << info.time << "\n";
  out << "brick " << params.brick_size[0] << " " << params.brick_size[1] << " "
      << params.brick_size[2] << "\n";
  out << "threshold " << ExactDouble(params.threshold) << "\n";
  out << "value_range";
  for (uint32_t r : mapping.value_range) out << " " << r;
  out << "\n";
  for (size_t c = 0; c < mapping.value_maps.size(); ++c) {
    const volume::ValueMap& m = mapping.value_maps[c];
    out << "value_map " << c << " " << volume::NumpyName(m.stored_type) << " "
        << ExactDouble(m.offset) << " " << ExactDouble(m.scale) << "\n";
  }
  out << "page_bytes " << page_bytes << "\n";
  out << "nodes_checksum " << Hex(nodes_checksum) << "\n";
  return out.str();
}

Result<CacheManifest> CacheManifest::Parse(std::string_view text) {
  std::vector<std::string_view> lines = Split(text, '\n');
  if (!lines.empty() && lines.back().empty()) lines.pop_back();
  if (lines.empty()) return CorruptError("MANIFEST is empty");
  auto header = Split(lines[0], ' ');
  if (header.size() != 2 || header[0] != kMagic) return CorruptError("MANIFEST has no header line");
  if (ParseInt64(header[1]) != kVersion) {
    return UnsupportedError("MANIFEST version '" + Printable(header[1]) + "' (this build reads " +
                            std::to_string(kVersion) + ")");
  }
  CacheManifest m;
  volume::VolumeInfo& info = m.params.info;
  std::map<std::string, int> seen;
  int64_t channels = -1;
  auto bad = [](std::string_view line) {
    return CorruptError("MANIFEST line '" + Printable(line) + "' is malformed");
  };
  auto integer = [](std::string_view t, int64_t lo, int64_t hi) -> std::optional<int64_t> {
    auto v = ParseInt64(t);
    if (!v || *v < lo || *v > hi) return std::nullopt;
    return v;
  };
  for (size_t i = 1; i < lines.size(); ++i) {
    std::vector<std::string_view> f = Split(lines[i], ' ');
    const std::string key(f[0]);
    if (key != "value_map" && seen[key]++ > 0)
      return CorruptError("MANIFEST repeats '" + key + "'");
    if (key == "state") {
      if (f.size() != 2 || f[1] != "complete") return bad(lines[i]);
    } else if (key == "source_hash" || key == "nodes_checksum") {
      auto v = f.size() == 2 ? ParseHex(f[1]) : std::nullopt;
      if (!v) return bad(lines[i]);
      (key == "source_hash" ? m.source.hash : m.nodes_checksum) = *v;
    } else if (key == "source_bytes" || key == "page_bytes") {
      auto v = f.size() == 2 ? integer(f[1], 0, INT64_MAX) : std::nullopt;
      if (!v) return bad(lines[i]);
      (key == "source_bytes" ? m.source.file_bytes : m.page_bytes) = static_cast<uint64_t>(*v);
    } else if (key == "size" || key == "brick") {
      if (f.size() != 4) return bad(lines[i]);
      for (int a = 0; a < 3; ++a) {
        auto v = integer(f[a + 1], 1, kMaxVolumeAxis);
        if (!v) return bad(lines[i]);
        (key == "size" ? info.size[a] : m.params.brick_size[a]) = *v;
      }
    } else if (key == "channels") {
      auto v = f.size() == 2 ? integer(f[1], 1, kMaxChannels) : std::nullopt;
      if (!v) return bad(lines[i]);
      channels = *v;
      info.channels.resize(static_cast<size_t>(channels));
    } else if (key == "dtype") {
      auto t = f.size() == 2 ? volume::DataTypeFromNumpyName(f[1]) : std::nullopt;
      if (!t) return bad(lines[i]);
      info.dtype = *t;
    } else if (key == "series" || key == "time") {
      auto v = f.size() == 2 ? integer(f[1], 0, 1 << 30) : std::nullopt;
      if (!v) return bad(lines[i]);
      (key == "series" ? info.series : info.time) = static_cast<int>(*v);
    } else if (key == "threshold") {
      auto v = f.size() == 2 ? ParseDouble(f[1]) : std::nullopt;
      if (!v || !(*v >= 0 && *v <= 1)) return bad(lines[i]);
      m.params.threshold = *v;
    } else if (key == "value_range") {
      for (size_t k = 1; k < f.size(); ++k) {
        auto v = integer(f[k], 0, 65535);
        if (!v) return bad(lines[i]);
        m.mapping.value_range.push_back(static_cast<uint32_t>(*v));
      }
    } else if (key == "value_map") {
      if (f.size() != 5) return bad(lines[i]);
      auto c = integer(f[1], 0, kMaxChannels - 1);
      auto stored = volume::DataTypeFromNumpyName(f[2]);
      auto offset = ParseDouble(f[3]);
      auto scale = ParseDouble(f[4]);
      if (!c || !stored || !offset || !scale ||
          *c != static_cast<int64_t>(m.mapping.value_maps.size())) {
        return bad(lines[i]);
      }
      volume::ValueMap map;
      map.stored_type = *stored;
      map.offset = *offset;
      map.scale = *scale;
      m.mapping.value_maps.push_back(map);
    } else {
      return CorruptError("MANIFEST has an unknown key '" + Printable(key) + "'");
    }
  }
  for (const char* key :
       {"state", "source_hash", "source_bytes", "size", "channels", "dtype", "series", "time",
        "brick", "threshold", "value_range", "page_bytes", "nodes_checksum"}) {
    if (seen[key] == 0) return CorruptError(std::string("MANIFEST lacks '") + key + "'");
  }
  if (m.mapping.value_maps.size() != static_cast<size_t>(channels) ||
      m.mapping.value_range.size() != static_cast<size_t>(channels)) {
    return CorruptError("MANIFEST has value maps or ranges for another channel count");
  }
  for (volume::ValueMap& map : m.mapping.value_maps) map.file_type = info.dtype;
  return m;
}

bool CacheManifest::Matches(const SourceIdentity& src, const CacheParams& p) const {
  const volume::VolumeInfo& a = params.info;
  const volume::VolumeInfo& b = p.info;
  if (!(source == src)) return false;
  if (a.size != b.size || a.channel_count() != b.channel_count() || a.dtype != b.dtype ||
      a.series != b.series || a.time != b.time) {
    return false;
  }
  return params.brick_size == p.brick_size && params.threshold == p.threshold;
}

uint64_t OctreeCache::PageBytesFor(uint64_t brick_bytes) {
  // Small pages (about 1 MiB: one to a few bricks) keep even modest RAM budgets many pages deep;
  // the page size is part of the pool's layout, so it must not depend on the budget.
  constexpr uint64_t kTargetPageBytes = 1 << 20;
  return brick_bytes * std::max<uint64_t>(1, kTargetPageBytes / brick_bytes);
}

OctreeCache::~OctreeCache() {
  // The octree and page cache are destroyed before the store (member order); an uncommitted
  // build's dirty pages are written back best-effort by the page cache, harmlessly.
  octree_.reset();
  page_cache_.reset();
  store_.reset();
}

Result<std::unique_ptr<OctreeCache>> OctreeCache::Open(
    const fs::path& dir, const SourceIdentity& source, const CacheParams& params,
    uint64_t ram_bytes, const std::function<Result<ValueMapping>()>& derive) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return IoError(dir.string() + ": cannot create the cache directory: " + ec.message());
  std::unique_ptr<OctreeCache> cache(new OctreeCache());
  cache->dir_ = dir;
  // Shared first: enough to reuse a complete cache alongside other readers; made exclusive below
  // only to rebuild.
  OCTO_ASSIGN_OR_RETURN(cache->lock_, CacheLock::Acquire(dir, CacheLock::Mode::kShared));

  OctreeOptions options;
  options.brick_size = params.brick_size;
  options.bytes_per_sample =
      static_cast<int>(volume::BytesPerSample(volume::StoredTypeFor(params.info.dtype)));
  options.homogeneity_threshold = params.threshold;
  OCTO_ASSIGN_OR_RETURN(
      BrickGeometry geometry,
      BrickGeometry::Create({Vec3{params.info.size[0], params.info.size[1], params.info.size[2]},
                             params.brick_size, params.info.channel_count(),
                             options.bytes_per_sample}));
  const uint64_t page_bytes = PageBytesFor(geometry.brick_bytes());
  // Construction pins a few pages at once (a brick and its neighbours' aprons): a budget of fewer
  // pages could wait forever, so refuse it up front.
  if (ram_bytes < kMinPages * page_bytes) {
    return ResourceExhaustedError("a RAM budget of " + std::to_string(ram_bytes >> 20) +
                                  " MiB for brick pages holds fewer than " +
                                  std::to_string(kMinPages) + " pages of " +
                                  std::to_string(page_bytes >> 10) +
                                  " KiB; give more RAM (--ram-mb) or use smaller bricks (--brick)");
  }

  // 1. A complete, matching cache is reused as it is.
  const fs::path manifest_path = dir / kManifestName;
  auto manifest_text = ReadSmallFile(manifest_path, kMaxManifestBytes);
  if (manifest_text.ok()) {
    auto manifest = CacheManifest::Parse(*manifest_text);
    if (!manifest.ok()) {
      cache->rebuild_reason_ = "unreadable manifest: " + manifest.status().message();
    } else if (!(manifest->source == source)) {
      cache->rebuild_reason_ = "source changed";
    } else if (!manifest->Matches(source, params) || manifest->page_bytes != page_bytes) {
      cache->rebuild_reason_ = "parameters changed";
    } else {
      auto nodes = ReadSmallFile(dir / kNodesName, kMaxNodesBytes);
      auto store =
          paging::OpenFilePageStore(dir / kPoolName, page_bytes, paging::OpenMode::kOpenExisting);
      if (!nodes.ok() || !store.ok() || Fnv1a64(*nodes) != manifest->nodes_checksum) {
        cache->rebuild_reason_ = "damaged (node table or pool missing or altered)";
      } else {
        cache->store_ = std::move(*store);
        cache->page_cache_ = std::make_unique<paging::PageCache>(cache->store_.get(), ram_bytes);
        std::istringstream in(*nodes);
        // (The node table carries the tolerances the mapping gave; nothing to re-derive.)
        auto octree = Octree::Load(in, cache->page_cache_.get());
        if (octree.ok()) {
          cache->octree_ = std::move(*octree);
          cache->manifest_ = std::move(*manifest);
          cache->reused_ = true;
          return cache;
        }
        cache->rebuild_reason_ = "damaged node table: " + octree.status().message();
        cache->page_cache_.reset();
        cache->store_.reset();
      }
    }
  } else if (fs::exists(dir / kPoolName, ec) || fs::exists(dir / kBuildingName, ec)) {
    cache->rebuild_reason_ = "incomplete (a build was interrupted)";
  } else {
    cache->rebuild_reason_ = "new";
  }

  // 2. Start over: first make sure no stale MANIFEST can ever describe the new files.
  OCTO_ASSIGN_OR_RETURN(ValueMapping mapping, derive());
  if (mapping.value_maps.size() != static_cast<size_t>(params.info.channel_count()) ||
      mapping.value_range.size() != static_cast<size_t>(params.info.channel_count())) {
    return InternalError("value mapping for the wrong number of channels");
  }
  options.value_range = mapping.value_range;
  // Nothing has been changed yet; from here on the directory is ours alone.
  OCTO_RETURN_IF_ERROR(cache->lock_->MakeExclusive());
  fs::remove(manifest_path, ec);
  fs::remove(dir / kNodesName, ec);
  OCTO_RETURN_IF_ERROR(SyncDirectory(dir));
  OCTO_RETURN_IF_ERROR(WriteFileDurably(dir / kBuildingName, "building\n"));
  OCTO_ASSIGN_OR_RETURN(
      cache->store_,
      paging::OpenFilePageStore(dir / kPoolName, page_bytes, paging::OpenMode::kCreateTruncate));
  cache->page_cache_ = std::make_unique<paging::PageCache>(cache->store_.get(), ram_bytes);
  OCTO_ASSIGN_OR_RETURN(cache->octree_,
                        Octree::Create(geometry, options, cache->page_cache_.get()));
  cache->manifest_.source = source;
  cache->manifest_.params = params;
  cache->manifest_.mapping = std::move(mapping);
  cache->manifest_.page_bytes = page_bytes;
  return cache;
}

Status OctreeCache::Commit() {
  // Bricks first: the node table refers to them, and the MANIFEST to both.
  OCTO_RETURN_IF_ERROR(octree_->Flush());
  std::ostringstream nodes;
  OCTO_RETURN_IF_ERROR(octree_->Save(nodes));
  const std::string table = nodes.str();
  OCTO_RETURN_IF_ERROR(WriteFileDurably(dir_ / kNodesName, table));
  manifest_.nodes_checksum = Fnv1a64(table);
  OCTO_RETURN_IF_ERROR(WriteFileDurably(dir_ / kManifestName, manifest_.Serialize()));
  std::error_code ec;
  fs::remove(dir_ / kBuildingName, ec);
  OCTO_RETURN_IF_ERROR(SyncDirectory(dir_));
  return lock_ ? lock_->MakeShared() : Status::Ok();
}

}  // namespace octoscope::octree
