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
// The zero-copy path (sources that offer MappedPlane views).

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

TEST_F(VolumeStatsFileTest, ZeroCopyEqualsCopyPathAndHandSums) {
  for (DataType type : {DataType::kUint16, DataType::kFloat32}) {
    for (int channels = 1; channels <= 3; ++channels) {
      SCOPED_TRACE(std::string(volume::NumpyName(type)) + " x" + std::to_string(channels));
      std::unique_ptr<VolumeSource> source = Write(type, channels, 7);  // Odd plane count.
      ASSERT_NE(source, nullptr);
      ASSERT_TRUE(source->MappedPlane(0, 0).has_value());
      const std::vector<ChannelStats> hand = HandStats(*source);

      StatsOptions copy;
      copy.zero_copy = false;
      copy.slab_bytes = 1;  // One plane per slab.
      auto copied = ComputeVolumeStats(*source, copy);
      ASSERT_TRUE(copied.ok()) << copied.status().ToString();
      ExpectSameStats(*copied, hand, type);

      // 1, 2, 3 and more threads than planes: shares of different (and odd) sizes.
      for (int threads : {1, 2, 3, 64}) {
        SCOPED_TRACE("threads " + std::to_string(threads));
        StatsOptions zero;
        zero.threads = threads;
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
  EXPECT_FALSE(source->MappedPlane(0, 0).has_value());
  auto stats = ComputeVolumeStats(*source, {});
  ASSERT_TRUE(stats.ok()) << stats.status().ToString();
  ExpectSameStats(*stats, HandStats(*source), DataType::kUint16);
}

// A memory-backed source that offers views of some planes only, and can fail or throw on reads
// of the others: exercises the per-plane fallback and error handling of the zero-copy path.
class PartlyMappedSource : public VolumeSource {
 public:
  PartlyMappedSource(std::unique_ptr<MemoryVolume> vol, std::function<bool(int, int64_t)> mapped)
      : vol_(std::move(vol)), mapped_(std::move(mapped)) {
    const volume::VolumeInfo& i = vol_->info();
    for (int c = 0; c < i.channel_count(); ++c) {
      for (int64_t z = 0; z < i.size[2]; ++z) {
        planes_.emplace_back(vol_->SlabBytes(1));
        EXPECT_TRUE(vol_->ReadSlab(c, z, 1, planes_.back()).ok());
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
  std::optional<std::span<const std::byte>> MappedPlane(int channel, int64_t z) const override {
    if (!mapped_(channel, z)) return std::nullopt;
    return std::span<const std::byte>(planes_[channel * info().size[2] + z]);
  }

  std::atomic<int> reads{0};
  int64_t fail_reads_from = -1;
  bool throw_reads = false;

 private:
  std::unique_ptr<MemoryVolume> vol_;
  std::function<bool(int, int64_t)> mapped_;
  std::vector<std::vector<std::byte>> planes_;
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

TEST(VolumeStatsZeroCopyTest, PlanesWithoutViewsAreReadInstead) {
  // Odd z planes have views, even ones are read: both kinds in every thread's share.
  PartlyMappedSource source(Ramp(11, 2), [](int, int64_t z) { return z % 2 == 1 || z == 0; });
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

TEST(VolumeStatsZeroCopyTest, ReadErrorsInAnyThreadPropagate) {
  // Plane 0 has a view (so the zero-copy path is taken); the others fail from z 8 on, which lies
  // in the last thread's share.
  PartlyMappedSource source(Ramp(10, 3), [](int, int64_t z) { return z < 4; });
  source.fail_reads_from = 8;
  StatsOptions options;
  options.threads = 3;
  auto stats = ComputeVolumeStats(source, options);
  ASSERT_FALSE(stats.ok());
  EXPECT_EQ(stats.status().code(), StatusCode::kIoError);
  EXPECT_NE(stats.status().message().find("part.tif"), std::string::npos);
}

TEST(VolumeStatsZeroCopyTest, ExceptionsInHelperThreadsBecomeErrors) {
  PartlyMappedSource source(Ramp(10, 1), [](int, int64_t z) { return z == 0; });
  source.throw_reads = true;
  StatsOptions options;
  options.threads = 2;
  auto stats = ComputeVolumeStats(source, options);
  ASSERT_FALSE(stats.ok());
  EXPECT_EQ(stats.status().code(), StatusCode::kResourceExhausted);
}

TEST(VolumeStatsZeroCopyTest, AThrowingProgressCallbackStillJoinsTheHelpers) {
  PartlyMappedSource source(Ramp(40, 2), [](int, int64_t) { return true; });
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
