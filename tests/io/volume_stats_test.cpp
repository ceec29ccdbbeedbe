#include "io/volume_stats.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

#include "io/memory_volume.h"

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
