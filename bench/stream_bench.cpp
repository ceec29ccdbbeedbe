// stream_bench: what a live stream's checkpoints cost (server/dataset, docs/benchmarks.md "Stream
// checkpoints"), run by bench/stream.sh (one case per process).
//
//   stream_bench DIR X Y Z plain|suspend
//     Streams a 2-channel uint16 X*Y*Z volume into a fresh stream under DIR, one plane per slab
//     (channels interleaved, not waiting for visibility), then finishes it. `plain` streams it in
//     one go; `suspend` suspends the stream halfway (Dataset::Release: checkpoint + close), sends
//     one plane of the first half again (the resume, and a replacement rewriting the
//     checkpoint's bricks), suspends again and streams the second half. No quiet or periodic
//     checkpoints run meanwhile.
// Prints one line of key=value pairs (milliseconds; MB/s of sample bytes).
//
// Thread safety: single-threaded driver (the dataset runs its own threads).
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "dataset/dataset.h"

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using octoscope::Status;

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

int Fail(const std::string& what, const Status& status) {
  std::fprintf(stderr, "stream_bench: %s: %s\n", what.c_str(), status.ToString().c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 6) {
    std::fprintf(stderr, "usage: stream_bench DIR X Y Z plain|suspend\n");
    return 64;
  }
  const fs::path dir = argv[1];
  const int64_t x = std::atoll(argv[2]), y = std::atoll(argv[3]), z = std::atoll(argv[4]);
  const bool suspend = std::string(argv[5]) == "suspend";
  octoscope::dataset::StreamSpec spec;
  spec.id = "streambench0";
  fs::remove_all(dir / spec.id);
  spec.size = {x, y, z};
  spec.channels = 2;
  spec.cache_root = dir;
  spec.ram_bytes = uint64_t{1} << 30;
  spec.checkpoint_quiet = std::chrono::hours(1);
  spec.checkpoint_interval = std::chrono::hours(1);

  Clock::time_point t = Clock::now();
  auto created = octoscope::dataset::Dataset::CreateStream(spec);
  if (!created.ok()) return Fail("create", created.status());
  std::shared_ptr<octoscope::dataset::Dataset> ds = *created;
  const double create_ms = MsSince(t);
  std::vector<uint16_t> plane(static_cast<size_t>(x * y));
  auto add = [&](int c, int64_t k, bool wait) {
    for (size_t i = 0; i < plane.size(); ++i) {
      plane[i] = static_cast<uint16_t>((i * 7 + k * 13 + c * 1000 + (i >> 10) * 3) % 4096);
    }
    return ds->AddSlab(c, k, 1, std::as_bytes(std::span<const uint16_t>(plane)), wait);
  };
  // Planes [z0, z1) of both channels, visible at the end; milliseconds.
  auto stream = [&](int64_t z0, int64_t z1, double* ms) {
    const Clock::time_point start = Clock::now();
    for (int64_t k = z0; k < z1; ++k) {
      for (int c = 0; c < 2; ++c) OCTO_RETURN_IF_ERROR(add(c, k, k + 1 == z1 && c == 1));
    }
    *ms = MsSince(start);
    return Status::Ok();
  };
  double first_ms = 0, second_ms = 0, suspend_ms = 0, resume_ms = 0, suspend_again_ms = 0;
  if (Status s = stream(0, z / 2, &first_ms); !s.ok()) return Fail("stream", s);
  if (suspend) {
    t = Clock::now();
    if (Status s = ds->Release(std::chrono::milliseconds(0)); !s.ok()) return Fail("suspend", s);
    suspend_ms = MsSince(t);
    t = Clock::now();
    if (Status s = add(0, z / 4, true); !s.ok()) return Fail("resume", s);
    resume_ms = MsSince(t);
    t = Clock::now();
    if (Status s = ds->Release(std::chrono::milliseconds(0)); !s.ok()) return Fail("suspend", s);
    suspend_again_ms = MsSince(t);
  }
  if (Status s = stream(z / 2, z, &second_ms); !s.ok()) return Fail("stream", s);
  t = Clock::now();
  if (Status s = ds->Finish(); !s.ok()) return Fail("finish", s);
  const double finish_ms = MsSince(t);
  ds.reset();
  fs::remove_all(dir / spec.id);
  const double half_mb = static_cast<double>(x * y) * (z / 2) * 2 * 2 / 1e6;
  std::printf(
      "case=%s create_ms=%.1f first_half_ms=%.1f first_half_mbps=%.1f suspend_ms=%.1f "
      "resume_replace_ms=%.1f suspend_again_ms=%.1f second_half_ms=%.1f second_half_mbps=%.1f "
      "finish_ms=%.1f\n",
      argv[5], create_ms, first_ms, half_mb / (first_ms / 1000), suspend_ms, resume_ms,
      suspend_again_ms, second_ms, half_mb / (second_ms / 1000), finish_ms);
  return 0;
}
