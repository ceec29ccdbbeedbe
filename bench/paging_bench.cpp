// paging_bench: micro-benchmarks of the page cache (server/paging), each against the plainest code
// doing the same work, run by bench/paging.sh (one case per process, so every run starts with a
// fresh heap; the script alternates implementations and takes medians).
//
//   paging_bench fresh DIR PAGES PAGE_MIB cache|baseline
//     Pins PAGES never-written pages of PAGE_MIB MiB (budget = all of them, a fresh page file in
//     DIR), marks each dirty and fills it (memset). Baseline: malloc + the same memset per page.
//   paging_bench construct DIR PAGES BUDGET_PAGES PAGE_MIB PASSES WRITE_MBPS
//   cache|cache-wb|baseline
//     A construction-like loop over PAGES fresh pages with a budget of BUDGET_PAGES: pin, mark
//     dirty, fill, then PASSES read passes over the page (the "computation"), unpin; then Flush.
//     cache-wb enables write-behind (default marks). WRITE_MBPS > 0 throttles every store write to
//     that rate (an emulated slow disk); 0 writes to the file as fast as the OS takes it.
//     Baseline: one buffer, the same fill and passes, pwrite of each page (throttled alike), fsync.
// Prints one line of key=value pairs (seconds of the timed parts and the cache's counters).
//
// Thread safety: single-threaded driver (the cache may run its write-behind thread).
#include <sys/resource.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "paging/file_page_store.h"
#include "paging/page_cache.h"

namespace {

using octoscope::Status;
using octoscope::paging::PageCache;
using octoscope::paging::PageStore;
using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

// CPU time of the process so far (all threads), user and system, in seconds.
struct CpuTime {
  double user = 0, sys = 0;
};
CpuTime CpuNow() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  auto seconds = [](const timeval& tv) {
    return static_cast<double>(tv.tv_sec) + tv.tv_usec * 1e-6;
  };
  return {seconds(usage.ru_utime), seconds(usage.ru_stime)};
}
// " user_seconds=U sys_seconds=S" between two samples.
void PrintCpu(const CpuTime& a, const CpuTime& b) {
  std::printf(" user_seconds=%.6f sys_seconds=%.6f", b.user - a.user, b.sys - a.sys);
}

[[noreturn]] void Die(const std::string& message) {
  std::fprintf(stderr, "paging_bench: %s\n", message.c_str());
  std::exit(2);
}

// Sleeps so that writes proceed at most at `mbps` MB/s (an emulated disk), then forwards.
class ThrottledStore final : public PageStore {
 public:
  ThrottledStore(PageStore* inner, double mbps) : inner_(inner), mbps_(mbps) {}
  uint64_t page_bytes() const override { return inner_->page_bytes(); }
  uint64_t page_count() const override { return inner_->page_count(); }
  Status Read(uint64_t page, std::span<std::byte> out) override { return inner_->Read(page, out); }
  Status Write(uint64_t page, std::span<const std::byte> data) override {
    Throttle(data.size());
    return inner_->Write(page, data);
  }
  Status Sync() override { return inner_->Sync(); }

 private:
  void Throttle(size_t bytes) const {
    if (mbps_ > 0) {
      std::this_thread::sleep_for(
          std::chrono::duration<double>(static_cast<double>(bytes) / (mbps_ * 1e6)));
    }
  }
  PageStore* const inner_;
  const double mbps_;
};

// The "computation" on a page: PASSES read passes (a checksum the compiler cannot drop).
uint64_t Compute(const std::byte* data, size_t size, int passes) {
  uint64_t sum = 0;
  for (int p = 0; p < passes; ++p) {
    const auto* words = reinterpret_cast<const uint64_t*>(data);
    for (size_t i = 0; i < size / 8; ++i) sum += words[i] ^ (sum >> 7);
  }
  return sum;
}

// The cache side of both cases: pin each of `pages` pages, mark it dirty, fill it, run the
// "computation", unpin. Returns the checksum.
uint64_t DirtyPages(PageCache& cache, uint64_t pages, int passes) {
  const uint64_t page_bytes = cache.page_bytes();
  uint64_t checksum = 0;
  for (uint64_t p = 0; p < pages; ++p) {
    auto h = cache.Pin(p);
    if (!h.ok()) Die(h.status().ToString());
    h->MarkDirty();
    std::memset(h->data().data(), static_cast<int>(p & 0xFF) | 1, page_bytes);
    checksum += Compute(h->data().data(), page_bytes, passes);
  }
  return checksum;
}

void PrintStats(const PageCache& cache) {
  const auto s = cache.stats();
  std::printf(
      " misses=%llu evictions=%llu writebacks=%llu bytes_read=%llu peak_resident=%llu"
      " zero_pages=%llu buffer_allocations=%llu write_behind_writes=%llu",
      static_cast<unsigned long long>(s.misses), static_cast<unsigned long long>(s.evictions),
      static_cast<unsigned long long>(s.writebacks), static_cast<unsigned long long>(s.bytes_read),
      static_cast<unsigned long long>(s.peak_resident_bytes),
      static_cast<unsigned long long>(s.zero_pages),
      static_cast<unsigned long long>(s.buffer_allocations),
      static_cast<unsigned long long>(s.write_behind_writes));
}

std::unique_ptr<PageStore> OpenStore(const std::filesystem::path& path, uint64_t page_bytes) {
  auto store = octoscope::paging::OpenFilePageStore(path, page_bytes,
                                                    octoscope::paging::OpenMode::kCreateTruncate);
  if (!store.ok()) Die(store.status().ToString());
  return std::move(store).value();
}

int Fresh(const std::filesystem::path& dir, uint64_t pages, uint64_t page_bytes,
          const std::string& impl) {
  if (impl == "baseline") {
    std::vector<std::byte*> buffers;
    const CpuTime c0 = CpuNow();
    const auto t0 = Clock::now();
    for (uint64_t p = 0; p < pages; ++p) {
      auto* b = static_cast<std::byte*>(std::malloc(page_bytes));
      if (b == nullptr) Die("out of memory");
      std::memset(b, static_cast<int>(p & 0xFF) | 1, page_bytes);
      buffers.push_back(b);
    }
    const auto t1 = Clock::now();
    const CpuTime c1 = CpuNow();
    std::printf("case=fresh impl=baseline seconds=%.6f", Seconds(t0, t1));
    PrintCpu(c0, c1);
    std::printf("\n");
    for (auto* b : buffers) std::free(b);
    return 0;
  }
  if (impl != "cache") Die("unknown implementation " + impl);
  auto store = OpenStore(dir / "fresh.pages", page_bytes);
  PageCache cache(store.get(), pages * page_bytes);
  const CpuTime c0 = CpuNow();
  const auto t0 = Clock::now();
  DirtyPages(cache, pages, /*passes=*/0);
  const auto t1 = Clock::now();
  const CpuTime c1 = CpuNow();
  std::printf("case=fresh impl=cache seconds=%.6f", Seconds(t0, t1));
  PrintCpu(c0, c1);
  PrintStats(cache);
  std::printf("\n");
  // Not timed: the page file is not the point here.
  if (Status s = cache.SetBudget(0); !s.ok()) Die(s.ToString());
  std::filesystem::remove(dir / "fresh.pages");
  return 0;
}

int Construct(const std::filesystem::path& dir, uint64_t pages, uint64_t budget_pages,
              uint64_t page_bytes, int passes, double mbps, const std::string& impl) {
  const auto path = dir / "construct.pages";
  uint64_t checksum = 0;
  if (impl == "baseline") {
    auto file = OpenStore(path, page_bytes);
    ThrottledStore store(file.get(), mbps);
    std::unique_ptr<std::byte[]> buffer(new std::byte[page_bytes]);
    const CpuTime c0 = CpuNow();
    const auto t0 = Clock::now();
    for (uint64_t p = 0; p < pages; ++p) {
      std::memset(buffer.get(), static_cast<int>(p & 0xFF) | 1, page_bytes);
      checksum += Compute(buffer.get(), page_bytes, passes);
      if (Status s = store.Write(p, {buffer.get(), page_bytes}); !s.ok()) Die(s.ToString());
    }
    const auto t1 = Clock::now();
    if (Status s = store.Sync(); !s.ok()) Die(s.ToString());
    const auto t2 = Clock::now();
    const CpuTime c2 = CpuNow();
    std::printf(
        "case=construct impl=baseline seconds=%.6f loop_seconds=%.6f flush_seconds=%.6f"
        " checksum=%llu",
        Seconds(t0, t2), Seconds(t0, t1), Seconds(t1, t2),
        static_cast<unsigned long long>(checksum));
    PrintCpu(c0, c2);
    std::printf("\n");
    std::filesystem::remove(path);
    return 0;
  }
  if (impl != "cache" && impl != "cache-wb") Die("unknown implementation " + impl);
  auto file = OpenStore(path, page_bytes);
  ThrottledStore store(file.get(), mbps);
  octoscope::paging::PageCacheOptions options;
  options.write_behind = impl == "cache-wb";
  PageCache cache(&store, budget_pages * page_bytes, options);
  const CpuTime c0 = CpuNow();
  const auto t0 = Clock::now();
  checksum = DirtyPages(cache, pages, passes);
  const auto t1 = Clock::now();
  const uint64_t dirty_at_end = cache.stats().dirty_pages;
  if (Status s = cache.Flush(); !s.ok()) Die(s.ToString());
  const auto t2 = Clock::now();
  const CpuTime c2 = CpuNow();
  std::printf(
      "case=construct impl=%s seconds=%.6f loop_seconds=%.6f flush_seconds=%.6f"
      " dirty_at_flush=%llu checksum=%llu",
      impl.c_str(), Seconds(t0, t2), Seconds(t0, t1), Seconds(t1, t2),
      static_cast<unsigned long long>(dirty_at_end), static_cast<unsigned long long>(checksum));
  PrintCpu(c0, c2);
  PrintStats(cache);
  std::printf("\n");
  std::filesystem::remove(path);
  return 0;
}

uint64_t Number(const char* text) {
  char* end = nullptr;
  const unsigned long long v = std::strtoull(text, &end, 10);
  if (end == text || *end != '\0') Die(std::string("not a number: ") + text);
  return v;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string usage =
      "usage: paging_bench fresh DIR PAGES PAGE_MIB cache|baseline\n"
      "       paging_bench construct DIR PAGES BUDGET_PAGES PAGE_MIB PASSES WRITE_MBPS "
      "cache|cache-wb|baseline";
  if (argc < 2) Die(usage);
  const std::string mode = argv[1];
  if (mode == "fresh" && argc == 6) {
    return Fresh(argv[2], Number(argv[3]), Number(argv[4]) << 20, argv[5]);
  }
  if (mode == "construct" && argc == 9) {
    return Construct(argv[2], Number(argv[3]), Number(argv[4]), Number(argv[5]) << 20,
                     static_cast<int>(Number(argv[6])), static_cast<double>(Number(argv[7])),
                     argv[8]);
  }
  Die(usage);
}
