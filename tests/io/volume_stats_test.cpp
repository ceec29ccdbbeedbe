#include "io/volume_stats.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <optional>
#include <random>
#include <stdexcept>
#include <thread>
#include <vector>

#include "io/memory_volume.h"
#include "io/ome_tiff_volume.h"
#include "io/ome_tiff_writer.h"
#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

using volume::DataType;

volume::VolumeInfo Info(DataType type, int64_t x, int64_t y, int64_t z, int channels) {
  volume::VolumeInfo info;
  info.format = "memory";
  info.size = {x, y, z};
  info.channels.resize(channels);
  info.dtype = type;
  return info;
}

TEST(VolumeStatsTest, Uint16ExactMinMaxMeanPerChannel) {
  auto vol = MemoryVolume::Create(Info(DataType::kUint16, 7, 5, 9, 2));
  ASSERT_TRUE(vol.ok());
  // Channel 0: x + 10*y + 100*z; channel 1: constant 65535 except one 3.
  double sum0 = 0;
  for (int z = 0; z < 9; ++z)
    for (int y = 0; y < 5; ++y)
      for (int x = 0; x < 7; ++x) {
        uint16_t v = static_cast<uint16_t>(x + 10 * y + 100 * z);
        (*vol)->Set<uint16_t>(0, x, y, z, v);
        (*vol)->Set<uint16_t>(1, x, y, z, 65535);
        sum0 += v;
      }
  (*vol)->Set<uint16_t>(1, 3, 2, 8, 3);
  StatsOptions options;
  options.slab_bytes = 7 * 5 * 2 * 2;  // Two planes per slab: exercises the last short slab.
  uint64_t last_done = 0, last_total = 0;
  options.progress = [&](uint64_t done, uint64_t total) {
    EXPECT_GT(done, last_done);
    last_done = done;
    last_total = total;
  };
  auto stats = ComputeVolumeStats(**vol, options);
  ASSERT_TRUE(stats.ok()) << stats.status().ToString();
  ASSERT_EQ(stats->channels.size(), 2u);
  EXPECT_EQ(stats->channels[0].min, 0);
  EXPECT_EQ(stats->channels[0].max, 6 + 40 + 800);
  EXPECT_DOUBLE_EQ(stats->channels[0].mean, sum0 / (7 * 5 * 9));
  EXPECT_EQ(stats->channels[1].min, 3);
  EXPECT_EQ(stats->channels[1].max, 65535);
  EXPECT_DOUBLE_EQ(stats->channels[1].mean, (65535.0 * 314 + 3) / 315);
  EXPECT_EQ(stats->channels[1].count, 315u);
  EXPECT_EQ(last_done, 18u);
  EXPECT_EQ(last_total, 18u);
}

TEST(VolumeStatsTest, SignedTypesReportFileUnits) {
  auto vol = MemoryVolume::Create(Info(DataType::kInt8, 4, 1, 1, 1));
  ASSERT_TRUE(vol.ok());
  int8_t values[] = {-128, -1, 0, 127};
  for (int x = 0; x < 4; ++x) (*vol)->Set<int8_t>(0, x, 0, 0, values[x]);
  auto stats = ComputeVolumeStats(**vol, {});
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->channels[0].min, -128);
  EXPECT_EQ(stats->channels[0].max, 127);
  EXPECT_DOUBLE_EQ(stats->channels[0].mean, -0.5);
}

TEST(VolumeStatsTest, FloatMeanIsCompensatedAndSkipsNaN) {
  // One huge value followed by many small ones: naive float accumulation loses them all.
  const int n = 1 << 16;
  auto vol = MemoryVolume::Create(Info(DataType::kFloat32, n, 1, 1, 1));
  ASSERT_TRUE(vol.ok());
  (*vol)->Set<float>(0, 0, 0, 0, 1e8f);
  for (int x = 1; x < n - 1; ++x) (*vol)->Set<float>(0, x, 0, 0, 0.1f);
  (*vol)->Set<float>(0, n - 1, 0, 0, std::numeric_limits<float>::quiet_NaN());
  auto stats = ComputeVolumeStats(**vol, {});
  ASSERT_TRUE(stats.ok());
  const ChannelStats& c = stats->channels[0];
  EXPECT_EQ(c.nan_count, 1u);
  EXPECT_EQ(c.count, static_cast<uint64_t>(n - 1));
  long double exact = 1e8L + static_cast<long double>(0.1f) * (n - 2);
  double expected = static_cast<double>(exact / (n - 1));
  EXPECT_NEAR(c.mean, expected, std::fabs(expected) * 1e-15);
  EXPECT_EQ(c.max, 1e8);
  EXPECT_FLOAT_EQ(static_cast<float>(c.min), 0.1f);
}

TEST(VolumeStatsTest, AllNaNChannelHasNoStatistics) {
  auto vol = MemoryVolume::Create(Info(DataType::kFloat64, 2, 2, 1, 1));
  ASSERT_TRUE(vol.ok());
  for (int i = 0; i < 4; ++i) (*vol)->Set<double>(0, i % 2, i / 2, 0, NAN);
  auto stats = ComputeVolumeStats(**vol, {});
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(stats->channels[0].count, 0u);
  EXPECT_TRUE(std::isnan(stats->channels[0].mean));
}

// A source that fails after a few reads: the error must surface, not hang or be dropped.
class FailingSource : public VolumeSource {
 public:
  explicit FailingSource(volume::VolumeInfo info) : info_(std::move(info)) {}
  const volume::VolumeInfo& info() const override { return info_; }
  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    OCTO_RETURN_IF_ERROR(CheckSlabRequest(info_, channel, z0, nz, out.size()));
    if (z0 >= 3) return IoError("disk.tif: read error at plane " + std::to_string(z0));
    return Status::Ok();
  }

 private:
  volume::VolumeInfo info_;
};

TEST(VolumeStatsTest, ReadErrorsPropagate) {
  FailingSource source(Info(DataType::kUint16, 4, 4, 10, 3));
  StatsOptions options;
  options.slab_bytes = 1;  // One plane per slab.
  auto stats = ComputeVolumeStats(source, options);
  ASSERT_FALSE(stats.ok());
  EXPECT_EQ(stats.status().code(), StatusCode::kIoError);
  EXPECT_NE(stats.status().message().find("disk.tif"), std::string::npos);
}

// A source whose reads throw (as std::vector does when a slab cannot be allocated).
class ThrowingSource : public FailingSource {
 public:
  using FailingSource::FailingSource;
  Status ReadSlab(int, int64_t, int64_t, std::span<std::byte>) override { throw std::bad_alloc(); }
};

TEST(VolumeStatsTest, ExceptionsInTheReaderThreadBecomeErrors) {
  ThrowingSource source(Info(DataType::kUint16, 4, 4, 10, 1));
  auto stats = ComputeVolumeStats(source, {});
  ASSERT_FALSE(stats.ok());
  EXPECT_EQ(stats.status().code(), StatusCode::kResourceExhausted);
}

TEST(VolumeStatsTest, AThrowingProgressCallbackStillJoinsTheReader) {
  auto vol = MemoryVolume::Create(Info(DataType::kUint8, 8, 8, 16, 2));
  ASSERT_TRUE(vol.ok());
  StatsOptions options;
  options.slab_bytes = 1;
  options.progress = [](uint64_t done, uint64_t) {
    if (done == 3) throw std::runtime_error("cancelled by the user");
  };
  EXPECT_THROW((void)ComputeVolumeStats(**vol, options), std::runtime_error);
}

// ---------------------------------------------------------------------------------------------
// The direct path (sources that locate stored planes, read piece by piece).

// Statistics computed here, independently: exact long double sums over every voxel.
std::vector<ChannelStats> HandStats(VolumeSource& source) {
  const volume::VolumeInfo& info = source.info();
  std::vector<ChannelStats> out;
  for (int c = 0; c < info.channel_count(); ++c) {
    std::vector<std::byte> all(source.SlabBytes(info.size[2]));
    EXPECT_TRUE(source.ReadSlab(c, 0, info.size[2], all).ok());
    const size_t n = all.size() / volume::BytesPerSample(info.dtype);
    long double sum = 0;
    ChannelStats s;
    s.min = std::numeric_limits<double>::infinity();
    s.max = -s.min;
    for (size_t i = 0; i < n; ++i) {
      double v;
      if (info.dtype == DataType::kUint16) {
        uint16_t x;
        std::memcpy(&x, all.data() + 2 * i, 2);
        v = x;
      } else {
        float x;
        std::memcpy(&x, all.data() + 4 * i, 4);
        v = x;
      }
      s.min = std::min(s.min, v);
      s.max = std::max(s.max, v);
      sum += v;
    }
    s.count = n;
    s.mean = static_cast<double>(sum / n);
    out.push_back(s);
  }
  return out;
}

// Compares two results: min, max and counts exactly; integer means exactly (exact sums), float
// means to a few units in the last place (the summation order differs).
void ExpectSameStats(const VolumeStats& a, const std::vector<ChannelStats>& b, DataType type) {
  ASSERT_EQ(a.channels.size(), b.size());
  for (size_t c = 0; c < b.size(); ++c) {
    SCOPED_TRACE("channel " + std::to_string(c));
    EXPECT_EQ(a.channels[c].min, b[c].min);
    EXPECT_EQ(a.channels[c].max, b[c].max);
    EXPECT_EQ(a.channels[c].count, b[c].count);
    EXPECT_EQ(a.channels[c].nan_count, b[c].nan_count);
    if (type == DataType::kUint16) {
      EXPECT_EQ(a.channels[c].mean, b[c].mean);
    } else {
      EXPECT_NEAR(a.channels[c].mean, b[c].mean, std::fabs(b[c].mean) * 1e-14);
    }
  }
}

class VolumeStatsFileTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir("volume-stats"); }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  // An uncompressed OME-TIFF of `z` planes x `channels` of pseudo-random values (one extreme
  // value per channel in the last plane), opened for reading.
  std::unique_ptr<VolumeSource> Write(DataType type, int channels, int64_t z,
                                      TiffCompression compression = TiffCompression::kNone) {
    auto vol = MemoryVolume::Create(Info(type, 67, 45, z, channels));
    EXPECT_TRUE(vol.ok());
    std::mt19937 rng(1234 + channels);
    std::uniform_int_distribution<int> ints(100, 60000);
    std::uniform_real_distribution<float> floats(-1000.f, 1000.f);
    for (int c = 0; c < channels; ++c)
      for (int64_t k = 0; k < z; ++k)
        for (int y = 0; y < 45; ++y)
          for (int x = 0; x < 67; ++x) {
            if (type == DataType::kUint16) {
              (*vol)->Set<uint16_t>(c, x, y, k, static_cast<uint16_t>(ints(rng)));
            } else {
              (*vol)->Set<float>(c, x, y, k, floats(rng) * static_cast<float>(c + 1));
            }
          }
    if (type == DataType::kUint16) {
      (*vol)->Set<uint16_t>(channels - 1, 66, 44, z - 1, 65535);
    } else {
      (*vol)->Set<float>(channels - 1, 66, 44, z - 1, 3e6f);
    }
    const std::filesystem::path path = dir_ / ("v" + std::to_string(files_++) + ".ome.tif");
    OmeTiffWriteOptions options;
    options.compression = compression;
    EXPECT_TRUE(WriteOmeTiff(**vol, path, options).ok());
    auto source = OpenOmeTiff(path, OpenOptions{});
    EXPECT_TRUE(source.ok()) << source.status().ToString();
    return source.ok() ? std::move(*source) : nullptr;
  }

  std::filesystem::path dir_;
  int files_ = 0;
};

TEST_F(VolumeStatsFileTest, DirectPathEqualsStreamingPathAndHandSums) {
  for (DataType type : {DataType::kUint16, DataType::kFloat32}) {
    for (int channels = 1; channels <= 3; ++channels) {
      SCOPED_TRACE(std::string(volume::NumpyName(type)) + " x" + std::to_string(channels));
      std::unique_ptr<VolumeSource> source = Write(type, channels, 7);  // Odd plane count.
      ASSERT_NE(source, nullptr);
      ASSERT_TRUE(source->FindStoredPlane(0, 0).has_value());
      const std::vector<ChannelStats> hand = HandStats(*source);

      StatsOptions copy;
      copy.direct = false;
      copy.slab_bytes = 1;  // One plane per slab.
      auto copied = ComputeVolumeStats(*source, copy);
      ASSERT_TRUE(copied.ok()) << copied.status().ToString();
      ExpectSameStats(*copied, hand, type);

      // 1, 2, 3 and more threads than planes: shares of different (and odd) sizes; pieces of
      // a few samples (7 bytes: 6 for uint16, 4 for float32), of an odd sample count, and whole
      // planes.
      for (auto [threads, piece] :
           {std::pair<int, uint64_t>{1, 7}, {2, 1000}, {3, 1 << 17}, {64, 1 << 20}}) {
        SCOPED_TRACE("threads " + std::to_string(threads) + " piece " + std::to_string(piece));
        StatsOptions zero;
        zero.threads = threads;
        zero.piece_bytes = piece;
        const std::thread::id caller = std::this_thread::get_id();
        uint64_t last = 0, calls = 0;
        zero.progress = [&](uint64_t done, uint64_t total) {
          EXPECT_EQ(std::this_thread::get_id(), caller);
          EXPECT_GT(done, last);
          EXPECT_EQ(total, static_cast<uint64_t>(7 * channels));
          last = done;
          ++calls;
        };
        auto mapped = ComputeVolumeStats(*source, zero);
        ASSERT_TRUE(mapped.ok()) << mapped.status().ToString();
        ExpectSameStats(*mapped, copied->channels, type);
        ExpectSameStats(*mapped, hand, type);
        EXPECT_EQ(last, static_cast<uint64_t>(7 * channels));
        EXPECT_GE(calls, 1u);
      }
    }
  }
}

TEST_F(VolumeStatsFileTest, CompressedFilesTakeTheCopyPath) {
  std::unique_ptr<VolumeSource> source = Write(DataType::kUint16, 2, 5, TiffCompression::kDeflate);
  ASSERT_NE(source, nullptr);
  EXPECT_FALSE(source->FindStoredPlane(0, 0).has_value());
  auto stats = ComputeVolumeStats(*source, {});
  ASSERT_TRUE(stats.ok()) << stats.status().ToString();
  ExpectSameStats(*stats, HandStats(*source), DataType::kUint16);
}

// Issue 8: an input may still be written (or rewritten) while it is read. A file that shrinks
// under a reader used to be memory-mapped, and touching a lost page killed the whole process with
// SIGBUS; now every read is a positioned read, and the loss is an error naming the file.
TEST_F(VolumeStatsFileTest, AFileTruncatedWhileBeingReadIsAnErrorNotACrash) {
  for (bool direct : {true, false}) {
    SCOPED_TRACE(direct ? "direct" : "streaming");
    std::unique_ptr<VolumeSource> source = Write(DataType::kUint16, 2, 9);
    ASSERT_NE(source, nullptr);
    ASSERT_TRUE(source->FindStoredPlane(0, 0).has_value());
    const std::filesystem::path path = dir_ / ("v" + std::to_string(files_ - 1) + ".ome.tif");
    const uint64_t size = std::filesystem::file_size(path);
    StatsOptions options;
    options.direct = direct;
    options.threads = 1;       // One thread: the truncation falls at a known point of the pass.
    options.slab_bytes = 1;    // Streaming: one plane per slab.
    options.piece_bytes = 64;  // Direct: many reads per plane.
    // After a few planes, the file loses its second half (as a writer that starts over would).
    options.progress = [&](uint64_t done, uint64_t) {
      if (done == 3) std::filesystem::resize_file(path, size / 2);
    };
    auto stats = ComputeVolumeStats(*source, options);
    ASSERT_FALSE(stats.ok());
    EXPECT_EQ(stats.status().code(), StatusCode::kCorrupt) << stats.status().ToString();
    EXPECT_NE(stats.status().message().find(path.filename().string()), std::string::npos)
        << stats.status().ToString();
    EXPECT_NE(stats.status().message().find("truncated"), std::string::npos)
        << stats.status().ToString();
    // Later reads fail the same way, and reads of what is left still work.
    std::vector<std::byte> plane(source->SlabBytes(1));
    EXPECT_EQ(source->ReadSlab(1, 8, 1, plane).code(), StatusCode::kCorrupt);
    EXPECT_TRUE(source->ReadSlab(0, 0, 1, plane).ok());
  }
}

// A memory-backed source that locates some planes only (in an in-memory "file" holding every
// plane), and can fail or throw on reads of the others, or fail reading the file: exercises the
// per-plane fallback and error handling of the direct path.
class PartlyStoredSource : public VolumeSource {
 public:
  // The planes, (c, z) at (c * Z + z) * plane bytes; reads from byte `fail_from` on fail the way
  // a file truncated there does.
  class File : public PositionedFile {
   public:
    Status ReadBytes(uint64_t offset, std::span<std::byte> out) const override {
      if (offset + out.size() > fail_from) {
        return CorruptError("part.tif: the file ends at offset " + std::to_string(fail_from) +
                            ": the file is truncated");
      }
      std::memcpy(out.data(), bytes.data() + offset, out.size());
      return Status::Ok();
    }

    std::vector<std::byte> bytes;
    uint64_t fail_from = UINT64_MAX;
  };

  PartlyStoredSource(std::unique_ptr<MemoryVolume> vol, std::function<bool(int, int64_t)> stored)
      : vol_(std::move(vol)), stored_(std::move(stored)), file_(std::make_shared<File>()) {
    const volume::VolumeInfo& i = vol_->info();
    std::vector<std::byte> plane(vol_->SlabBytes(1));
    for (int c = 0; c < i.channel_count(); ++c) {
      for (int64_t z = 0; z < i.size[2]; ++z) {
        EXPECT_TRUE(vol_->ReadSlab(c, z, 1, plane).ok());
        file_->bytes.insert(file_->bytes.end(), plane.begin(), plane.end());
      }
    }
  }
  const volume::VolumeInfo& info() const override { return vol_->info(); }
  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    ++reads;
    if (fail_reads_from >= 0 && z0 >= fail_reads_from) {
      return IoError("part.tif: read error at plane " + std::to_string(z0));
    }
    if (throw_reads) throw std::bad_alloc();
    return vol_->ReadSlab(channel, z0, nz, out);
  }
  std::optional<StoredPlane> FindStoredPlane(int channel, int64_t z) const override {
    if (!stored_(channel, z)) return std::nullopt;
    return StoredPlane{file_, (channel * info().size[2] + z) * SlabBytes(1)};
  }
  File& file() { return *file_; }

  std::atomic<int> reads{0};
  int64_t fail_reads_from = -1;
  bool throw_reads = false;

 private:
  std::unique_ptr<MemoryVolume> vol_;
  std::function<bool(int, int64_t)> stored_;
  std::shared_ptr<File> file_;
};

std::unique_ptr<MemoryVolume> Ramp(int64_t z, int channels) {
  auto vol = MemoryVolume::Create(Info(DataType::kUint16, 9, 4, z, channels));
  EXPECT_TRUE(vol.ok());
  for (int c = 0; c < channels; ++c)
    for (int64_t k = 0; k < z; ++k)
      for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 9; ++x)
          (*vol)->Set<uint16_t>(c, x, y, k, static_cast<uint16_t>(x + 9 * y + 36 * k + 1000 * c));
  return std::move(*vol);
}

TEST(VolumeStatsDirectTest, PlanesNotStoredAreReadInstead) {
  // Odd z planes are stored, even ones are read: both kinds in every thread's share.
  PartlyStoredSource source(Ramp(11, 2), [](int, int64_t z) { return z % 2 == 1 || z == 0; });
  StatsOptions options;
  options.threads = 2;
  auto stats = ComputeVolumeStats(source, options);
  ASSERT_TRUE(stats.ok()) << stats.status().ToString();
  EXPECT_EQ(source.reads.load(), 2 * 5);  // z = 2, 4, 6, 8, 10 of both channels.
  for (int c = 0; c < 2; ++c) {
    EXPECT_EQ(stats->channels[c].min, 1000 * c);
    EXPECT_EQ(stats->channels[c].max, 8 + 27 + 360 + 1000 * c);
    // Mean of x + 9y + 36z over the box: 4 + 13.5 + 180.
    EXPECT_DOUBLE_EQ(stats->channels[c].mean, 4 + 13.5 + 180 + 1000 * c);
    EXPECT_EQ(stats->channels[c].count, 9u * 4 * 11);
  }
}

TEST(VolumeStatsDirectTest, ReadErrorsInAnyThreadPropagate) {
  // Plane 0 is stored (so the direct path is taken); the others fail from z 8 on, which lies in
  // the last thread's share.
  PartlyStoredSource source(Ramp(10, 3), [](int, int64_t z) { return z < 4; });
  source.fail_reads_from = 8;
  StatsOptions options;
  options.threads = 3;
  auto stats = ComputeVolumeStats(source, options);
  ASSERT_FALSE(stats.ok());
  EXPECT_EQ(stats.status().code(), StatusCode::kIoError);
  EXPECT_NE(stats.status().message().find("part.tif"), std::string::npos);
}

TEST(VolumeStatsDirectTest, AFileTruncatedWhileReadIsAnErrorNamingIt) {
  // Every plane stored; the file "ends" in the middle of the last channel's plane 6.
  PartlyStoredSource source(Ramp(10, 2), [](int, int64_t) { return true; });
  source.file().fail_from = (10 + 6) * source.SlabBytes(1) + 10;
  StatsOptions options;
  options.threads = 2;
  options.piece_bytes = 16;
  auto stats = ComputeVolumeStats(source, options);
  ASSERT_FALSE(stats.ok());
  EXPECT_EQ(stats.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(stats.status().message().find("part.tif"), std::string::npos);
  EXPECT_NE(stats.status().message().find("truncated"), std::string::npos);
}

TEST(VolumeStatsDirectTest, ExceptionsInHelperThreadsBecomeErrors) {
  PartlyStoredSource source(Ramp(10, 1), [](int, int64_t z) { return z == 0; });
  source.throw_reads = true;
  StatsOptions options;
  options.threads = 2;
  auto stats = ComputeVolumeStats(source, options);
  ASSERT_FALSE(stats.ok());
  EXPECT_EQ(stats.status().code(), StatusCode::kResourceExhausted);
}

TEST(VolumeStatsDirectTest, AThrowingProgressCallbackStillJoinsTheHelpers) {
  PartlyStoredSource source(Ramp(40, 2), [](int, int64_t) { return true; });
  StatsOptions options;
  options.threads = 4;
  options.progress = [](uint64_t done, uint64_t) {
    if (done >= 3) throw std::runtime_error("cancelled by the user");
  };
  EXPECT_THROW((void)ComputeVolumeStats(source, options), std::runtime_error);
}

TEST(MemoryVolumeTest, RejectsBadRequestsAndHugeVolumes) {
  auto vol = MemoryVolume::Create(Info(DataType::kUint8, 2, 2, 2, 1));
  ASSERT_TRUE(vol.ok());
  std::vector<std::byte> buf(4);
  EXPECT_TRUE((*vol)->ReadSlab(0, 1, 1, buf).ok());
  EXPECT_EQ((*vol)->ReadSlab(1, 0, 1, buf).code(), StatusCode::kOutOfRange);
  EXPECT_EQ((*vol)->ReadSlab(0, 2, 1, buf).code(), StatusCode::kOutOfRange);
  EXPECT_EQ((*vol)->ReadSlab(0, 0, 2, buf).code(), StatusCode::kInvalidArgument);
  EXPECT_FALSE(MemoryVolume::Create(Info(DataType::kUint16, 1 << 20, 1 << 20, 1, 1)).ok());
}

}  // namespace
}  // namespace octoscope::io
