// PageStore: a linear array of fixed-size pages on some backing medium (a file, RAM in tests).
// It is the disk side of the out-of-core design: PageCache keeps a bounded working set of pages
// in RAM and reads/writes whole pages through this interface. A store knows nothing about what
// the pages hold (bricks, tables …).
//
// Semantics:
//  - Every page has exactly page_bytes() bytes; page indices are 0-based and unbounded except by
//    the medium (an index whose byte offset overflows 63 bits is kOutOfRange).
//  - A page that was never written reads as all zeros (so a fresh store is a zero-filled array).
//  - page_count() is one past the highest page ever written (0 for an empty store); for a store
//    reopened from a medium it is the number of (possibly partial) pages the medium holds. So a
//    page at or beyond page_count() reads as zeros: PageCache relies on this and zero-fills such
//    pages itself instead of reading them (a store must never under-report page_count()).
//  - Write() is not durable until Sync() returns OK (e.g. fsync for files).
//  - Read()/Write() take spans of exactly page_bytes(); any other size is kInvalidArgument.
//
// Thread safety: implementations are thread-safe: Read, Write and Sync may be called from several
// threads at once. Concurrent Read and Write of the SAME page give unspecified page contents in the
// reader (PageCache never does that); different pages never interfere.
#ifndef OCTOSCOPE_PAGING_PAGE_STORE_H_
#define OCTOSCOPE_PAGING_PAGE_STORE_H_

#include <cstddef>
#include <cstdint>
#include <span>

#include "util/status.h"

namespace octoscope::paging {

class PageStore {
 public:
  virtual ~PageStore() = default;

  // Bytes per page; > 0 and constant for the life of the store.
  virtual uint64_t page_bytes() const = 0;

  // One past the highest page index ever written (see the header comment).
  virtual uint64_t page_count() const = 0;

  // Reads page `page` into `out`. A never-written page (also one past page_count()) reads as zeros.
  // On error `out` holds unspecified data; errors name the medium (file path) and the page.
  // REQUIRES: out.size() == page_bytes() (else kInvalidArgument).
  virtual Status Read(uint64_t page, std::span<std::byte> out) = 0;

  // Writes `data` as page `page`, growing the store as needed. A failed write may have written a
  // prefix of the page (a torn page): callers keep their copy and retry.
  // REQUIRES: data.size() == page_bytes() (else kInvalidArgument).
  virtual Status Write(uint64_t page, std::span<const std::byte> data) = 0;

  // Makes every Write that returned OK before this call durable (fsync for files).
  virtual Status Sync() = 0;
};

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_PAGING_PAGE_STORE_H_
