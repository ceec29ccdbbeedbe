#include "paging/file_page_store.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <limits>
#include <mutex>
#include <string>

#include "util/checked_math.h"

namespace octoscope::paging {
namespace {

std::string Errno(int err) { return std::strerror(err); }

class FilePageStore final : public PageStore {
 public:
  FilePageStore(std::filesystem::path path, int fd, uint64_t page_bytes, uint64_t page_count,
                bool created)
      : path_(std::move(path)),
        fd_(fd),
        page_bytes_(page_bytes),
        page_count_(page_count),
        dir_needs_sync_(created) {}

  ~FilePageStore() override {
    // Errors of close() after a successful Sync() cannot lose synced data; nothing to report to.
    ::close(fd_);
  }

  uint64_t page_bytes() const override { return page_bytes_; }
  uint64_t page_count() const override { return page_count_.load(std::memory_order_acquire); }

  Status Read(uint64_t page, std::span<std::byte> out) override {
    if (out.size() != page_bytes_) return SizeError("read", page, out.size());
    OCTO_ASSIGN_OR_RETURN(const uint64_t offset, Offset("pread", page));
    size_t done = 0;
    while (done < out.size()) {
      ssize_t n =
          ::pread(fd_, out.data() + done, out.size() - done, static_cast<off_t>(offset + done));
      if (n < 0) {
        if (errno == EINTR) continue;
        return OsError("pread", page, offset, errno);
      }
      if (n == 0) {
        // End of file: never-written pages (or the lost tail of a torn last page) are zeros.
        std::fill(out.begin() + static_cast<ptrdiff_t>(done), out.end(), std::byte{0});
        break;
      }
      done += static_cast<size_t>(n);
    }
    return Status::Ok();
  }

  Status Write(uint64_t page, std::span<const std::byte> data) override {
    if (data.size() != page_bytes_) return SizeError("write", page, data.size());
    OCTO_ASSIGN_OR_RETURN(const uint64_t offset, Offset("pwrite", page));
    size_t done = 0;
    while (done < data.size()) {
      ssize_t n =
          ::pwrite(fd_, data.data() + done, data.size() - done, static_cast<off_t>(offset + done));
      if (n < 0) {
        if (errno == EINTR) continue;
        return OsError("pwrite", page, offset, errno);
      }
      if (n == 0) {
        // pwrite made no progress without an error: treat it as a full disk, never spin.
        return OsError("pwrite", page, offset, ENOSPC);
      }
      done += static_cast<size_t>(n);
    }
    // page_count_ = max(page_count_, page + 1), lock-free.
    uint64_t count = page_count_.load(std::memory_order_relaxed);
    while (count < page + 1 &&
           !page_count_.compare_exchange_weak(count, page + 1, std::memory_order_acq_rel)) {
    }
    return Status::Ok();
  }

  Status Sync() override {
    int rc;
    do {
      rc = ::fsync(fd_);
    } while (rc != 0 && errno == EINTR);
    if (rc != 0) return IoError(path_.string() + ": fsync: " + Errno(errno));
    // A newly created file is only durable once its directory entry is; sync the directory once.
    std::lock_guard lock(dir_mu_);
    if (dir_needs_sync_) {
      std::filesystem::path dir = path_.parent_path();
      if (dir.empty()) dir = ".";
      int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
      if (dfd < 0) return IoError(dir.string() + ": open directory for fsync: " + Errno(errno));
      do {
        rc = ::fsync(dfd);
      } while (rc != 0 && errno == EINTR);
      int err = errno;
      ::close(dfd);
      // Some file systems cannot fsync directories (EINVAL); that is not a data loss.
      if (rc != 0 && err != EINVAL) {
        return IoError(dir.string() + ": fsync of directory: " + Errno(err));
      }
      dir_needs_sync_ = false;
    }
    return Status::Ok();
  }

 private:
  Status SizeError(const char* op, uint64_t page, size_t size) const {
    return InvalidArgumentError(path_.string() + ": " + op + " of page " + std::to_string(page) +
                                " with a buffer of " + std::to_string(size) +
                                " bytes, page size is " + std::to_string(page_bytes_));
  }

  // Byte offset of `page`, checked so that the whole page fits in off_t.
  Result<uint64_t> Offset(const char* op, uint64_t page) const {
    auto offset = CheckedMul(page, page_bytes_);
    std::optional<uint64_t> end;
    if (offset) end = CheckedAdd(*offset, page_bytes_);
    if (!end || *end > static_cast<uint64_t>(std::numeric_limits<off_t>::max())) {
      return OutOfRangeError(path_.string() + ": " + op + " of page " + std::to_string(page) +
                             ": offset beyond the largest file size");
    }
    return *offset;
  }

  Status OsError(const char* op, uint64_t page, uint64_t offset, int err) const {
    return IoError(path_.string() + ": " + op + " of page " + std::to_string(page) + " (offset " +
                   std::to_string(offset) + "): " + Errno(err));
  }

  const std::filesystem::path path_;
  const int fd_;
  const uint64_t page_bytes_;
  std::atomic<uint64_t> page_count_;
  std::mutex dir_mu_;
  bool dir_needs_sync_;  // Guarded by dir_mu_.
};

}  // namespace

Result<std::unique_ptr<PageStore>> OpenFilePageStore(const std::filesystem::path& path,
                                                     uint64_t page_bytes, OpenMode mode) {
  if (page_bytes == 0 || page_bytes > kMaxPageBytes) {
    return InvalidArgumentError(path.string() + ": page size " + std::to_string(page_bytes) +
                                " is outside 1.." + std::to_string(kMaxPageBytes));
  }
  int flags = O_RDWR | O_CLOEXEC;
  if (mode == OpenMode::kCreateTruncate) flags |= O_CREAT | O_TRUNC;
  int fd;
  do {
    fd = ::open(path.c_str(), flags, 0644);
  } while (fd < 0 && errno == EINTR);
  if (fd < 0) {
    int err = errno;
    if (err == ENOENT && mode == OpenMode::kOpenExisting) {
      return NotFoundError(path.string() + ": page file does not exist");
    }
    if (err == EISDIR) return InvalidArgumentError(path.string() + ": is a directory");
    return IoError(path.string() + ": open: " + Errno(err));
  }
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    int err = errno;
    ::close(fd);
    return IoError(path.string() + ": fstat: " + Errno(err));
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    return InvalidArgumentError(path.string() + ": not a regular file");
  }
  const uint64_t size = static_cast<uint64_t>(st.st_size);
  // A partial last page (torn write at a crash) still counts as a page.
  const uint64_t page_count = size / page_bytes + (size % page_bytes != 0 ? 1 : 0);
  return std::unique_ptr<PageStore>(std::make_unique<FilePageStore>(
      path, fd, page_bytes, page_count, mode == OpenMode::kCreateTruncate));
}

}  // namespace octoscope::paging
