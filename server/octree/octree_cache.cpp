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
constexpr char kShadowName[] = "octree.shadow";
constexpr char kDirtyName[] = "DIRTY";
constexpr char kCheckpointPrefix[] = "checkpoint-";
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

// checkpoint-G.NAME: a file of checkpoint generation G.
fs::path CheckpointFile(const fs::path& dir, uint64_t generation, std::string_view name) {
  return dir / (kCheckpointPrefix + std::to_string(generation) + "." + std::string(name));
}

// What DIRTY says once the build changed after checkpoint `generation`.
std::string DirtyText(uint64_t generation) {
  return "dirty after checkpoint " + std::to_string(generation) + "\n";
}

// Attachment names: [a-z]{1,32}, not "nodes" or "shadow" (the checkpoint's own files).
bool IsAttachmentName(std::string_view name) {
  return !name.empty() && name.size() <= 32 && name != "nodes" && name != "shadow" &&
         std::all_of(name.begin(), name.end(), [](char c) { return c >= 'a' && c <= 'z'; });
}

// A checkpoint file whose MANIFEST gives its checksum; kCorrupt naming it when it is missing or
// does not match.
Result<std::string> ReadCheckpointFile(const fs::path& path, uint64_t checksum,
                                       std::string_view what) {
  auto bytes = ReadSmallFile(path, kMaxNodesBytes);
  if (!bytes.ok() || Fnv1a64(*bytes) != checksum) {
    return CorruptError(path.string() + ": missing or damaged (the checkpoint's " +
                        std::string(what) + " does not match its MANIFEST)");
  }
  return bytes;
}

Status CheckBudget(uint64_t ram_bytes, uint64_t page_bytes) {
  // Construction pins a few pages at once (a brick and its neighbours' aprons): a budget of fewer
  // pages could wait forever, so refuse it up front.
  if (ram_bytes >= OctreeCache::kMinPages * page_bytes) return Status::Ok();
  return ResourceExhaustedError("a RAM budget of " + std::to_string(ram_bytes >> 20) +
                                " MiB for brick pages holds fewer than " +
                                std::to_string(OctreeCache::kMinPages) + " pages of " +
                                std::to_string(page_bytes >> 10) +
                                " KiB; give more RAM (--ram-mb) or use smaller bricks (--brick)");
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
  out << "state " << (state == State::kComplete ? "complete" : "checkpoint") << "\n";
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
  if (state == State::kCheckpoint) {
    out << "generation " << generation << "\n";
    out << "shadow_map " << Hex(shadow_checksum) << "\n";
    for (const Attachment& a : attachments) {
      out << "attachment " << a.name << " " << Hex(a.checksum) << "\n";
    }
  }
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
    if (key != "value_map" && key != "attachment" && seen[key]++ > 0)
      return CorruptError("MANIFEST repeats '" + key + "'");
    if (key == "state") {
      if (f.size() != 2 || (f[1] != "complete" && f[1] != "checkpoint")) return bad(lines[i]);
      m.state = f[1] == "complete" ? State::kComplete : State::kCheckpoint;
    } else if (key == "generation") {
      auto v = f.size() == 2 ? integer(f[1], 1, INT64_MAX) : std::nullopt;
      if (!v) return bad(lines[i]);
      m.generation = static_cast<uint64_t>(*v);
    } else if (key == "attachment") {
      auto checksum = f.size() == 3 ? ParseHex(f[2]) : std::nullopt;
      if (!checksum || !IsAttachmentName(f[1])) return bad(lines[i]);
      for (const Attachment& a : m.attachments) {
        if (a.name == f[1]) return CorruptError("MANIFEST repeats attachment '" + a.name + "'");
      }
      m.attachments.push_back({std::string(f[1]), *checksum});
    } else if (key == "source_hash" || key == "nodes_checksum" || key == "shadow_map") {
      auto v = f.size() == 2 ? ParseHex(f[1]) : std::nullopt;
      if (!v) return bad(lines[i]);
      (key == "source_hash"      ? m.source.hash
       : key == "nodes_checksum" ? m.nodes_checksum
                                 : m.shadow_checksum) = *v;
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
  if (m.state == State::kCheckpoint && (seen["generation"] == 0 || seen["shadow_map"] == 0)) {
    return CorruptError("MANIFEST of a checkpoint lacks 'generation' or 'shadow_map'");
  }
  if (m.state == State::kComplete &&
      (seen["generation"] != 0 || seen["shadow_map"] != 0 || !m.attachments.empty())) {
    return CorruptError("MANIFEST of a complete cache has checkpoint keys");
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

struct OctreeCache::Layout {
  BrickGeometry geometry;
  OctreeOptions options;
  uint64_t page_bytes = 0;
};

Result<OctreeCache::Layout> OctreeCache::LayoutFor(const CacheParams& params) {
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
  return Layout{std::move(geometry), std::move(options), page_bytes};
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
  OCTO_ASSIGN_OR_RETURN(Layout layout, LayoutFor(params));
  OctreeOptions& options = layout.options;
  const uint64_t page_bytes = layout.page_bytes;
  OCTO_RETURN_IF_ERROR(CheckBudget(ram_bytes, page_bytes));

  // 1. A complete, matching cache is reused as it is.
  const fs::path manifest_path = dir / kManifestName;
  auto manifest_text = ReadSmallFile(manifest_path, kMaxManifestBytes);
  if (manifest_text.ok()) {
    auto manifest = CacheManifest::Parse(*manifest_text);
    if (manifest.ok() && manifest->state == CacheManifest::State::kCheckpoint) {
      // The only copy of an unfinished stream: neither served nor cleared.
      return FailedPreconditionError(
          dir.string() +
          ": the cache holds the checkpoint of a stream that has not finished (not a complete "
          "cache); it opens once the stream is finished");
    }
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
                        Octree::Create(layout.geometry, options, cache->page_cache_.get()));
  cache->manifest_.source = source;
  cache->manifest_.params = params;
  cache->manifest_.mapping = std::move(mapping);
  cache->manifest_.page_bytes = page_bytes;
  return cache;
}

Status OctreeCache::Commit() {
  // Bricks first: the node table refers to them, and the MANIFEST to both.
  OCTO_RETURN_IF_ERROR(octree_->Flush());
  if (shadow_ != nullptr && shadow_->shadowed_pages() != 0) {
    // Those pages are not in the pool yet; a Checkpoint puts them there safely.
    return FailedPreconditionError(dir_.string() +
                                   ": the build changed since its last checkpoint; checkpoint "
                                   "it before committing");
  }
  std::ostringstream nodes;
  OCTO_RETURN_IF_ERROR(octree_->Save(nodes));
  const std::string table = nodes.str();
  OCTO_RETURN_IF_ERROR(WriteFileDurably(dir_ / kNodesName, table));
  CacheManifest complete = manifest_;
  complete.state = CacheManifest::State::kComplete;
  complete.generation = 0;
  complete.attachments.clear();
  complete.nodes_checksum = Fnv1a64(table);
  OCTO_RETURN_IF_ERROR(WriteFileDurably(dir_ / kManifestName, complete.Serialize()));
  manifest_ = std::move(complete);
  std::error_code ec;
  fs::remove(dir_ / kBuildingName, ec);
  if (shadow_ != nullptr) {
    // A complete cache is never resumed: the checkpoint's files have no use any more.
    fs::remove(dir_ / kShadowName, ec);
    fs::remove(dir_ / kDirtyName, ec);
    RemoveCheckpointFiles(0);
  }
  OCTO_RETURN_IF_ERROR(SyncDirectory(dir_));
  return lock_ ? lock_->MakeShared() : Status::Ok();
}

void OctreeCache::RemoveCheckpointFiles(uint64_t keep) {
  std::error_code ec;
  std::vector<fs::path> stale;
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!name.starts_with(kCheckpointPrefix)) continue;
    const std::string_view rest = std::string_view(name).substr(sizeof kCheckpointPrefix - 1);
    const std::optional<int64_t> generation = ParseInt64(rest.substr(0, rest.find('.')));
    if (name.ends_with(".tmp") || !generation || static_cast<uint64_t>(*generation) != keep) {
      stale.push_back(it->path());
    }
  }
  for (const fs::path& path : stale) fs::remove(path, ec);
}

Result<std::unique_ptr<OctreeCache>> OctreeCache::CreateResumable(const fs::path& dir,
                                                                  const SourceIdentity& source,
                                                                  const CacheParams& params,
                                                                  uint64_t ram_bytes,
                                                                  ValueMapping mapping) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return IoError(dir.string() + ": cannot create the cache directory: " + ec.message());
  OCTO_ASSIGN_OR_RETURN(Layout layout, LayoutFor(params));
  OCTO_RETURN_IF_ERROR(CheckBudget(ram_bytes, layout.page_bytes));
  if (mapping.value_maps.size() != static_cast<size_t>(params.info.channel_count()) ||
      mapping.value_range.size() != static_cast<size_t>(params.info.channel_count())) {
    return InternalError("value mapping for the wrong number of channels");
  }
  std::unique_ptr<OctreeCache> cache(new OctreeCache());
  cache->dir_ = dir;
  OCTO_ASSIGN_OR_RETURN(cache->lock_, CacheLock::Acquire(dir, CacheLock::Mode::kExclusive));
  // From here on the directory is ours alone: no stale MANIFEST may describe the new files.
  for (const char* name : {kManifestName, kNodesName, kShadowName, kDirtyName}) {
    fs::remove(dir / name, ec);
  }
  cache->RemoveCheckpointFiles(0);
  OCTO_RETURN_IF_ERROR(SyncDirectory(dir));
  OCTO_RETURN_IF_ERROR(WriteFileDurably(dir / kBuildingName, "building\n"));
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<paging::PageStore> pool,
                        paging::OpenFilePageStore(dir / kPoolName, layout.page_bytes,
                                                  paging::OpenMode::kCreateTruncate));
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<paging::ShadowPageStore> shadow,
                        paging::ShadowPageStore::Create(std::move(pool), dir / kShadowName, 0));
  cache->shadow_ = shadow.get();
  cache->store_ = std::move(shadow);
  cache->page_cache_ = std::make_unique<paging::PageCache>(cache->store_.get(), ram_bytes);
  layout.options.value_range = mapping.value_range;
  OCTO_ASSIGN_OR_RETURN(cache->octree_,
                        Octree::Create(layout.geometry, layout.options, cache->page_cache_.get()));
  cache->manifest_.state = CacheManifest::State::kCheckpoint;
  cache->manifest_.source = source;
  cache->manifest_.params = params;
  cache->manifest_.mapping = std::move(mapping);
  cache->manifest_.page_bytes = layout.page_bytes;
  return cache;
}

Status OctreeCache::Checkpoint(const CheckpointAttachments& attachments) {
  if (shadow_ == nullptr || manifest_.state != CacheManifest::State::kCheckpoint) {
    return FailedPreconditionError(dir_.string() + ": not a resumable build; no checkpoint");
  }
  const uint64_t generation = manifest_.generation + 1;
  CacheManifest next = manifest_;
  next.generation = generation;
  next.attachments.clear();
  // 1. The pool and its shadow as the node table will describe them, durable.
  OCTO_RETURN_IF_ERROR(octree_->Flush());
  // 2. The node table, the owner's files and the shadow's map, under this generation's names.
  std::ostringstream nodes;
  OCTO_RETURN_IF_ERROR(octree_->Save(nodes));
  const std::string table = nodes.str();
  OCTO_RETURN_IF_ERROR(WriteFileDurably(CheckpointFile(dir_, generation, "nodes"), table));
  next.nodes_checksum = Fnv1a64(table);
  for (const auto& [name, bytes] : attachments) {
    if (!IsAttachmentName(name)) {
      return InvalidArgumentError("checkpoint attachment name '" + Printable(name) + "'");
    }
    OCTO_RETURN_IF_ERROR(WriteFileDurably(CheckpointFile(dir_, generation, name), bytes));
    next.attachments.push_back({name, Fnv1a64(bytes)});
  }
  const std::string map = shadow_->Freeze().Serialize();
  OCTO_RETURN_IF_ERROR(WriteFileDurably(CheckpointFile(dir_, generation, "shadow"), map));
  next.shadow_checksum = Fnv1a64(map);
  // 3. The commit point: from now on Resume finds this generation.
  OCTO_RETURN_IF_ERROR(WriteFileDurably(dir_ / kManifestName, next.Serialize()));
  manifest_ = std::move(next);
  // 4. The shadowed pages into the pool; from now on every page written so far is protected.
  if (Status copied = shadow_->Apply(generation); !copied.ok()) {
    std::lock_guard<std::mutex> lock(dirty_mu_);
    copy_failed_ = true;
    return copied.WithContext(dir_.string() + ": after checkpoint " + std::to_string(generation));
  }
  {
    std::lock_guard<std::mutex> lock(dirty_mu_);
    dirty_ = false;
  }
  std::error_code ec;
  fs::remove(dir_ / kDirtyName, ec);  // Stale anyway: it names the previous generation.
  RemoveCheckpointFiles(generation);
  return SyncDirectory(dir_);
}

Status OctreeCache::MarkDirty() {
  std::lock_guard<std::mutex> lock(dirty_mu_);
  if (copy_failed_) {
    return FailedPreconditionError(dir_.string() +
                                   ": a checkpoint could not be completed; the cache takes no "
                                   "changes until it is reopened");
  }
  if (dirty_ || shadow_ == nullptr) return Status::Ok();
  OCTO_RETURN_IF_ERROR(WriteFileDurably(dir_ / kDirtyName, DirtyText(manifest_.generation)));
  dirty_ = true;
  return Status::Ok();
}

Result<CacheContents> OctreeCache::Inspect(const fs::path& dir) {
  OCTO_ASSIGN_OR_RETURN(std::string text, ReadSmallFile(dir / kManifestName, kMaxManifestBytes));
  auto manifest = CacheManifest::Parse(text);
  if (!manifest.ok()) {
    return CorruptError((dir / kManifestName).string() + ": " + manifest.status().message());
  }
  CacheContents contents;
  if (manifest->state == CacheManifest::State::kCheckpoint) {
    for (const CacheManifest::Attachment& a : manifest->attachments) {
      OCTO_ASSIGN_OR_RETURN(std::string bytes,
                            ReadCheckpointFile(CheckpointFile(dir, manifest->generation, a.name),
                                               a.checksum, a.name));
      contents.attachments.emplace(a.name, std::move(bytes));
    }
    // The shadow map too: a checkpoint that cannot be resumed is reported now.
    OCTO_RETURN_IF_ERROR(ReadCheckpointFile(CheckpointFile(dir, manifest->generation, "shadow"),
                                            manifest->shadow_checksum, "shadow map")
                             .status());
    auto dirty = ReadSmallFile(dir / kDirtyName, 256);
    contents.unclean = dirty.ok() && *dirty == DirtyText(manifest->generation);
  }
  contents.manifest = std::move(*manifest);
  return contents;
}

Result<ResumedCache> OctreeCache::Resume(const fs::path& dir, uint64_t ram_bytes) {
  std::unique_ptr<OctreeCache> cache(new OctreeCache());
  cache->dir_ = dir;
  OCTO_ASSIGN_OR_RETURN(cache->lock_, CacheLock::Acquire(dir, CacheLock::Mode::kExclusive));
  auto inspected = Inspect(dir);
  if (!inspected.ok()) {
    if (inspected.status().code() != StatusCode::kNotFound) return inspected.status();
    return CorruptError(dir.string() + ": no checkpoint to resume (no MANIFEST)");
  }
  CacheContents& contents = *inspected;
  const CacheManifest& manifest = contents.manifest;
  if (manifest.state == CacheManifest::State::kComplete) {
    return FailedPreconditionError(dir.string() + ": the cache is complete; nothing to resume");
  }
  OCTO_ASSIGN_OR_RETURN(Layout layout, LayoutFor(manifest.params));
  if (layout.page_bytes != manifest.page_bytes) {
    return CorruptError(dir.string() + ": MANIFEST page_bytes " +
                        std::to_string(manifest.page_bytes) + " does not fit its brick size");
  }
  OCTO_RETURN_IF_ERROR(CheckBudget(ram_bytes, layout.page_bytes));
  const fs::path nodes_path = CheckpointFile(dir, manifest.generation, "nodes");
  OCTO_ASSIGN_OR_RETURN(std::string nodes,
                        ReadCheckpointFile(nodes_path, manifest.nodes_checksum, "node table"));
  const fs::path map_path = CheckpointFile(dir, manifest.generation, "shadow");
  OCTO_ASSIGN_OR_RETURN(std::string map_bytes,
                        ReadCheckpointFile(map_path, manifest.shadow_checksum, "shadow map"));
  auto map = paging::ShadowMap::Parse(map_bytes);
  if (!map.ok()) return map.status().WithContext(map_path.string());
  auto pool = paging::OpenFilePageStore(dir / kPoolName, layout.page_bytes,
                                        paging::OpenMode::kOpenExisting);
  if (!pool.ok()) {
    return CorruptError((dir / kPoolName).string() +
                        ": the checkpoint's pool cannot be opened: " + pool.status().message());
  }
  // The pool exactly as the checkpoint left it: its copy finished (should a crash have cut it
  // short), and what was written after it dropped.
  const fs::path shadow_path = dir / kShadowName;
  OCTO_RETURN_IF_ERROR(paging::ShadowPageStore::Recover(**pool, shadow_path, *map).status());
  const uint64_t dropped =
      paging::ShadowPageStore::PagesWrittenSince(shadow_path, manifest.generation);
  OCTO_ASSIGN_OR_RETURN(
      std::unique_ptr<paging::ShadowPageStore> shadow,
      paging::ShadowPageStore::Create(std::move(*pool), shadow_path, manifest.generation));
  cache->shadow_ = shadow.get();
  cache->store_ = std::move(shadow);
  cache->page_cache_ = std::make_unique<paging::PageCache>(cache->store_.get(), ram_bytes);
  std::istringstream in(nodes);
  auto octree = Octree::Load(in, cache->page_cache_.get());
  if (!octree.ok()) {
    return CorruptError(nodes_path.string() + ": " + octree.status().message());
  }
  cache->octree_ = std::move(*octree);
  cache->manifest_ = manifest;
  std::error_code ec;
  fs::remove(dir / kDirtyName, ec);  // Reported below; the pool is the checkpoint's again.
  cache->RemoveCheckpointFiles(manifest.generation);
  OCTO_RETURN_IF_ERROR(SyncDirectory(dir));
  ResumedCache resumed;
  resumed.cache = std::move(cache);
  resumed.attachments = std::move(contents.attachments);
  resumed.unclean = contents.unclean || dropped > 0;
  resumed.dropped_pages = dropped;
  return resumed;
}

}  // namespace octoscope::octree
