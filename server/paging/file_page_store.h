// FilePageStore: a PageStore backed by one regular file; page i lives at byte offset
// i * page_bytes. Uses pread/pwrite (no shared file offset, so any number of threads can read and
// write different pages at once), retries EINTR and continues short reads/writes. Reading past the
// end of the file yields zeros (never-written pages, and the missing tail of a torn last page after
// a crash). Write() extends the file as needed; gaps become holes that read as zeros.
//
// Every error message names the file, the operation, the page and the OS reason, e.g.
// "io error: /scratch/pages.bin: pwrite of page 12 (offset 25165824): No space left on device".
//
// Thread safety: as PageStore (fully thread-safe).
#ifndef OCTOSCOPE_PAGING_FILE_PAGE_STORE_H_
#define OCTOSCOPE_PAGING_FILE_PAGE_STORE_H_

#include <cstdint>
#include <filesystem>
#include <memory>

#include "paging/page_store.h"
#include "util/result.h"

namespace octoscope::paging {

enum class OpenMode {
  kCreateTruncate,  // Create the file, or truncate an existing one to empty.
  kOpenExisting,    // Open an existing file read-write; kNotFound when it does not exist.
};

// Largest page size a store accepts (1 GiB): larger pages are almost surely a bad argument.
inline constexpr uint64_t kMaxPageBytes = uint64_t{1} << 30;

// Opens (or creates) the page file at `path`.
// Errors: kInvalidArgument when page_bytes is 0 or > kMaxPageBytes or `path` is not a regular
// file; kNotFound for kOpenExisting on a missing file; kIoError when the OS refuses.
// A reopened file whose size is not a multiple of page_bytes is accepted (a torn last page from a
// crash): its last page counts and its missing tail reads as zeros.
Result<std::unique_ptr<PageStore>> OpenFilePageStore(const std::filesystem::path& path,
                                                     uint64_t page_bytes, OpenMode mode);

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_PAGING_FILE_PAGE_STORE_H_
