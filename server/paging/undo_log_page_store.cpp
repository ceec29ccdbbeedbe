#include "paging/undo_log_page_store.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>
#include <string_view>
#include <vector>

#include "util/durable_file.h"

namespace octoscope::paging {
namespace {

namespace fs = std::filesystem;

constexpr char kMagic[8] = {'O', 'C', 'T', 'O', 'U', 'N', 'D', 'O'};
constexpr uint32_t kVersion = 1;
constexpr uint64_t kHeaderBytes = 40;

void PutU64(std::byte* out, uint64_t v) {
  for (int i = 0; i < 8; ++i) out[i] = static_cast<std::byte>(v >> (8 * i));
}

uint64_t GetU64(const std::byte* in) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v |= static_cast<uint64_t>(in[i]) << (8 * i);
  return v;
}

std::string_view View(const std::byte* data, size_t bytes) {
  return {reinterpret_cast<const char*>(data), bytes};
}

std::vector<std::byte> Header(uint64_t generation, uint64_t page_bytes) {
  std::vector<std::byte> h(kHeaderBytes);
  std::memcpy(h.data(), kMagic, sizeof kMagic);
  for (int i = 0; i < 4; ++i) h[8 + i] = static_cast<std::byte>(kVersion >> (8 * i));
  PutU64(h.data() + 16, generation);
  PutU64(h.data() + 24, page_bytes);
  PutU64(h.data() + 32, Fnv1a64(View(h.data(), 32)));
  return h;
}

// The checksum of an entry: generation, page index (both little-endian) and the page's bytes.
uint64_t EntryChecksum(uint64_t generation, uint64_t page, std::span<const std::byte> bytes) {
  std::byte prefix[16];
  PutU64(prefix, generation);
  PutU64(prefix + 8, page);
  return Fnv1a64(View(bytes.data(), bytes.size()), Fnv1a64(View(prefix, sizeof prefix)));
}

Status OsError(const fs::path& path, const char* step) {
  return IoError(path.string() + ": " + step + ": " + std::strerror(errno));
}

Status PwriteAll(int fd, const fs::path& path, std::span<const std::byte> data, uint64_t offset) {
  size_t done = 0;
  while (done < data.size()) {
    const ssize_t n =
        ::pwrite(fd, data.data() + done, data.size() - done, static_cast<off_t>(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return OsError(path, "pwrite");
    if (n == 0) {
      errno = ENOSPC;
      return OsError(path, "pwrite");
    }
    done += static_cast<size_t>(n);
  }
  return Status::Ok();
}

// Reads up to out.size() bytes at `offset`; returns how many (fewer at the end of the file).
Result<size_t> PreadSome(int fd, const fs::path& path, std::span<std::byte> out, uint64_t offset) {
  size_t done = 0;
  while (done < out.size()) {
    const ssize_t n =
        ::pread(fd, out.data() + done, out.size() - done, static_cast<off_t>(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return OsError(path, "pread");
    if (n == 0) break;
    done += static_cast<size_t>(n);
  }
  return done;
}

}  // namespace

Result<std::unique_ptr<UndoLogPageStore>> UndoLogPageStore::Create(std::unique_ptr<PageStore> inner,
                                                                   const fs::path& log_path,
                                                                   uint64_t generation) {
  const int fd = ::open(log_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) return OsError(log_path, "open the undo log");
  std::unique_ptr<UndoLogPageStore> store(new UndoLogPageStore(std::move(inner), log_path, fd));
  std::lock_guard<std::mutex> lock(store->mu_);
  OCTO_RETURN_IF_ERROR(store->StartLogLocked(generation));
  OCTO_RETURN_IF_ERROR(
      SyncDirectory(log_path.parent_path().empty() ? "." : log_path.parent_path()));
  return store;
}

UndoLogPageStore::~UndoLogPageStore() { ::close(fd_); }

Status UndoLogPageStore::StartLogLocked(uint64_t generation) {
  const std::vector<std::byte> header = Header(generation, inner_->page_bytes());
  // The old entries go first; should the header reach the disk before the truncation does, their
  // checksums (of the old generation) still keep them from being applied.
  if (::ftruncate(fd_, 0) != 0) return OsError(log_path_, "ftruncate");
  OCTO_RETURN_IF_ERROR(PwriteAll(fd_, log_path_, header, 0));
  if (::fdatasync(fd_) != 0) return OsError(log_path_, "fdatasync");
  generation_ = generation;
  protected_ = inner_->page_count();
  log_bytes_ = kHeaderBytes;
  logged_.clear();
  return Status::Ok();
}

Status UndoLogPageStore::Restart(uint64_t generation) {
  std::lock_guard<std::mutex> lock(mu_);
  return StartLogLocked(generation);
}

uint64_t UndoLogPageStore::logged_pages() const {
  std::lock_guard<std::mutex> lock(mu_);
  return logged_.size();
}

Status UndoLogPageStore::SaveBeforeImage(uint64_t page) {
  std::lock_guard<std::mutex> lock(mu_);
  if (page >= protected_ || logged_.count(page) != 0) return Status::Ok();
  const uint64_t bytes = inner_->page_bytes();
  std::vector<std::byte> entry(bytes + 16);
  PutU64(entry.data(), page);
  const std::span<std::byte> image(entry.data() + 8, bytes);
  OCTO_RETURN_IF_ERROR(inner_->Read(page, image));
  PutU64(entry.data() + 8 + bytes, EntryChecksum(generation_, page, image));
  OCTO_RETURN_IF_ERROR(PwriteAll(fd_, log_path_, entry, log_bytes_));
  // Durable before the page is overwritten: a crash can tear only an entry whose page is intact.
  if (::fdatasync(fd_) != 0) return OsError(log_path_, "fdatasync");
  log_bytes_ += entry.size();
  logged_.insert(page);
  return Status::Ok();
}

Status UndoLogPageStore::Write(uint64_t page, std::span<const std::byte> data) {
  OCTO_RETURN_IF_ERROR(SaveBeforeImage(page));
  return inner_->Write(page, data);
}

Result<uint64_t> UndoLogPageStore::RollBack(PageStore& store, const fs::path& log_path,
                                            uint64_t generation) {
  const int fd = ::open(log_path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return uint64_t{0};
    return OsError(log_path, "open the undo log");
  }
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  const uint64_t bytes = store.page_bytes();
  std::vector<std::byte> header(kHeaderBytes);
  OCTO_ASSIGN_OR_RETURN(const size_t got, PreadSome(fd, log_path, header, 0));
  if (got != kHeaderBytes || header != Header(generation, bytes)) return uint64_t{0};
  std::vector<std::byte> entry(bytes + 16);
  std::set<uint64_t> restored;
  for (uint64_t offset = kHeaderBytes;; offset += entry.size()) {
    OCTO_ASSIGN_OR_RETURN(const size_t n, PreadSome(fd, log_path, entry, offset));
    if (n != entry.size()) break;  // The end, or a torn last entry.
    const uint64_t page = GetU64(entry.data());
    const std::span<const std::byte> image(entry.data() + 8, bytes);
    if (GetU64(entry.data() + 8 + bytes) != EntryChecksum(generation, page, image)) break;
    // The first image of a page is the checkpoint's; a later one (never written) is not.
    if (!restored.insert(page).second) continue;
    OCTO_RETURN_IF_ERROR(store.Write(page, image));
  }
  if (!restored.empty()) OCTO_RETURN_IF_ERROR(store.Sync());
  return static_cast<uint64_t>(restored.size());
}

}  // namespace octoscope::paging
