#include "io/synthetic_embryo.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <thread>
#include <vector>

namespace octoscope::io {
namespace {

std::unique_ptr<SyntheticEmbryo> MakeEmbryo(std::array<int64_t, 3> size, int channels,
                                            uint64_t seed = 42) {
  SyntheticEmbryoOptions options;
  options.size = size;
  options.channels = channels;
  options.seed = seed;
  auto embryo = SyntheticEmbryo::Create(options);
  EXPECT_TRUE(embryo.ok()) << embryo.status().ToString();
  return embryo.ok() ? std::move(embryo).value() : nullptr;
}

// Planes z0 .. z0+nz-1 of one channel.
std::vector<uint16_t> Read(VolumeSource& source, int channel, int64_t z0, int64_t nz) {
  std::vector<uint16_t> out(source.info().PlaneVoxels() * nz);
  Status s = source.ReadSlab(channel, z0, nz, std::as_writable_bytes(std::span(out)));
  EXPECT_TRUE(s.ok()) << s.ToString();
  return out;
}

std::vector<uint16_t> ReadChannel(VolumeSource& source, int channel) {
  return Read(source, channel, 0, source.info().size[2]);
}

TEST(SyntheticEmbryoTest, CreateRejectsBadOptions) {
  auto create = [](auto mutate) {
    SyntheticEmbryoOptions options;
    options.size = {8, 8, 8};
    mutate(options);
    return SyntheticEmbryo::Create(options).status().code();
  };
  EXPECT_EQ(create([](auto& o) { o.size[0] = 0; }), StatusCode::kInvalidArgument);
  EXPECT_EQ(create([](auto& o) { o.size[2] = 65537; }), StatusCode::kInvalidArgument);
  EXPECT_EQ(create([](auto& o) { o.size[1] = -3; }), StatusCode::kInvalidArgument);
  EXPECT_EQ(create([](auto& o) { o.channels = 0; }), StatusCode::kInvalidArgument);
  EXPECT_EQ(create([](auto& o) { o.channels = 5; }), StatusCode::kInvalidArgument);
  EXPECT_EQ(create([](auto& o) { o.spacing_um[2] = 0; }), StatusCode::kInvalidArgument);
  EXPECT_EQ(create([](auto& o) { o.spacing_um[0] = std::nan(""); }), StatusCode::kInvalidArgument);
  EXPECT_EQ(create([](auto&) {}), StatusCode::kOk);
}

TEST(SyntheticEmbryoTest, InfoDescribesTheVolume) {
  SyntheticEmbryoOptions options;
  options.size = {40, 30, 20};
  options.channels = 4;
  options.spacing_um = {0.5, 0.25, 3.0};
  auto embryo = SyntheticEmbryo::Create(options);
  ASSERT_TRUE(embryo.ok());
  const volume::VolumeInfo& info = (*embryo)->info();
  EXPECT_TRUE(info.Validate().ok());
  EXPECT_EQ(info.size, (std::array<int64_t, 3>{40, 30, 20}));
  EXPECT_EQ(info.dtype, volume::DataType::kUint16);
  EXPECT_EQ(info.spacing_um[0], 0.5);
  EXPECT_EQ(info.spacing_um[1], 0.25);
  EXPECT_EQ(info.spacing_um[2], 3.0);
  ASSERT_EQ(info.channel_count(), 4);
  EXPECT_EQ(info.channels[0].name, "nuclei");
  EXPECT_EQ(info.channels[1].name, "membranes");
  EXPECT_EQ(info.channels[2].name, "spots");
  EXPECT_EQ(info.channels[3].name, "reporter");
  // Nuclei blue/cyan, membranes green, spots magenta.
  ASSERT_TRUE(info.channels[0].color && info.channels[1].color && info.channels[2].color);
  EXPECT_GT(info.channels[0].color->b, 200);
  EXPECT_EQ(info.channels[0].color->r, 0);
  EXPECT_EQ(*info.channels[1].color, (volume::Rgba{0, 255, 0, 255}));
  EXPECT_EQ(*info.channels[2].color, (volume::Rgba{255, 0, 255, 255}));
}

TEST(SyntheticEmbryoTest, SameSeedGivesIdenticalVoxelsAndOtherSeedsDiffer) {
  const std::array<int64_t, 3> size{48, 40, 24};
  auto a = MakeEmbryo(size, 4, 7);
  auto b = MakeEmbryo(size, 4, 7);
  auto c = MakeEmbryo(size, 4, 8);
  ASSERT_TRUE(a && b && c);
  EXPECT_EQ(a->nucleus_count(), b->nucleus_count());
  for (int ch = 0; ch < 4; ++ch) {
    std::vector<uint16_t> va = ReadChannel(*a, ch);
    EXPECT_EQ(va, ReadChannel(*b, ch)) << "channel " << ch;
    std::vector<uint16_t> vc = ReadChannel(*c, ch);
    size_t differing = 0;
    for (size_t i = 0; i < va.size(); ++i) differing += va[i] != vc[i];
    // The noise alone makes most voxels differ.
    EXPECT_GT(differing, va.size() / 2) << "channel " << ch;
  }
}

// FNV-1a over the bytes of every channel: pins the exact output so that a change of platform,
// compiler or library that altered a single voxel is caught. Changing the generator on purpose
// means updating this value.
TEST(SyntheticEmbryoTest, OutputIsPinnedBitForBit) {
  auto embryo = MakeEmbryo({32, 24, 16}, 4, 1234);
  ASSERT_TRUE(embryo);
  uint64_t hash = 1469598103934665603ull;
  for (int ch = 0; ch < 4; ++ch) {
    for (uint16_t v : ReadChannel(*embryo, ch)) {
      for (int byte = 0; byte < 2; ++byte) {
        hash ^= (v >> (8 * byte)) & 0xFF;
        hash *= 1099511628211ull;
      }
    }
  }
  EXPECT_EQ(hash, 16432616017856282610ull);
}

TEST(SyntheticEmbryoTest, SlabsAgreeWithPlanes) {
  auto embryo = MakeEmbryo({37, 29, 19}, 3);
  ASSERT_TRUE(embryo);
  const size_t plane = 37 * 29;
  for (int ch = 0; ch < 3; ++ch) {
    std::vector<uint16_t> whole = ReadChannel(*embryo, ch);
    for (int64_t z = 0; z < 19; ++z) {
      std::vector<uint16_t> one = Read(*embryo, ch, z, 1);
      ASSERT_TRUE(std::equal(one.begin(), one.end(), whole.begin() + z * plane))
          << "channel " << ch << " z " << z;
    }
    std::vector<uint16_t> middle = Read(*embryo, ch, 5, 7);
    EXPECT_TRUE(std::equal(middle.begin(), middle.end(), whole.begin() + 5 * plane));
  }
}

TEST(SyntheticEmbryoTest, ConcurrentReadsGiveTheSameBytes) {
  auto embryo = MakeEmbryo({64, 48, 24}, 3);
  ASSERT_TRUE(embryo);
  std::vector<std::vector<uint16_t>> expected;
  for (int ch = 0; ch < 3; ++ch) expected.push_back(ReadChannel(*embryo, ch));
  std::vector<std::vector<uint16_t>> got[2];
  auto worker = [&](int t) {
    for (int round = 0; round < 2; ++round) {
      for (int ch = 0; ch < 3; ++ch) {
        std::vector<uint16_t> out(expected[ch].size());
        if (embryo->ReadSlab(ch, 0, 24, std::as_writable_bytes(std::span(out))).ok()) {
          got[t].push_back(std::move(out));
        }
      }
    }
  };
  std::thread first(worker, 0), second(worker, 1);
  first.join();
  second.join();
  for (int t = 0; t < 2; ++t) {
    ASSERT_EQ(got[t].size(), 6u);
    for (int i = 0; i < 6; ++i) EXPECT_EQ(got[t][i], expected[i % 3]) << "thread " << t;
  }
}

TEST(SyntheticEmbryoTest, ReadSlabRejectsBadRequests) {
  auto embryo = MakeEmbryo({8, 8, 4}, 2);
  ASSERT_TRUE(embryo);
  std::vector<uint16_t> plane(64);
  auto bytes = std::as_writable_bytes(std::span(plane));
  EXPECT_EQ(embryo->ReadSlab(2, 0, 1, bytes).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(embryo->ReadSlab(-1, 0, 1, bytes).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(embryo->ReadSlab(0, 4, 1, bytes).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(embryo->ReadSlab(0, 0, 2, bytes).code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(embryo->ReadSlab(1, 3, 1, bytes).ok());
}

TEST(SyntheticEmbryoTest, DegenerateAndOddSizesWork) {
  for (std::array<int64_t, 3> size : std::vector<std::array<int64_t, 3>>{
           {1, 1, 1}, {1, 1, 23}, {1, 17, 1}, {31, 1, 1}, {7, 5, 3}, {3, 64, 2}, {65, 33, 9}}) {
    auto embryo = MakeEmbryo(size, 4);
    ASSERT_TRUE(embryo);
    for (int ch = 0; ch < 4; ++ch) {
      std::vector<uint16_t> v = ReadChannel(*embryo, ch);
      ASSERT_EQ(v.size(), static_cast<size_t>(size[0] * size[1] * size[2]));
      // Never below the camera offset minus a few noise sigmas.
      EXPECT_GT(*std::min_element(v.begin(), v.end()), 50)
          << size[0] << "x" << size[1] << "x" << size[2] << " channel " << ch;
      auto again = MakeEmbryo(size, 4);
      EXPECT_EQ(v, ReadChannel(*again, ch));
    }
  }
}

// Statistics of one channel of the 96x96x48 demo.
struct Region {
  double mean = 0;
  uint16_t max = 0;
  uint16_t min = std::numeric_limits<uint16_t>::max();
  size_t count = 0;
};

class SyntheticEmbryoLooksTest : public ::testing::Test {
 protected:
  static constexpr int64_t kX = 96, kY = 96, kZ = 48;
  void SetUp() override {
    embryo_ = MakeEmbryo({kX, kY, kZ}, 3);
    ASSERT_TRUE(embryo_);
    for (int ch = 0; ch < 3; ++ch) data_[ch] = ReadChannel(*embryo_, ch);
  }
  uint16_t At(int ch, int64_t x, int64_t y, int64_t z) const {
    return data_[ch][(z * kY + y) * kX + x];
  }
  Region Box(int ch, int64_t x0, int64_t x1, int64_t y0, int64_t y1, int64_t z0, int64_t z1) const {
    Region r;
    double sum = 0;
    for (int64_t z = z0; z < z1; ++z) {
      for (int64_t y = y0; y < y1; ++y) {
        for (int64_t x = x0; x < x1; ++x) {
          uint16_t v = At(ch, x, y, z);
          sum += v;
          r.max = std::max(r.max, v);
          r.min = std::min(r.min, v);
          ++r.count;
        }
      }
    }
    r.mean = sum / r.count;
    return r;
  }
  double FractionAbove(int ch, uint16_t threshold) const {
    size_t n = 0;
    for (uint16_t v : data_[ch]) n += v > threshold;
    return static_cast<double>(n) / data_[ch].size();
  }

  std::unique_ptr<SyntheticEmbryo> embryo_;
  std::vector<uint16_t> data_[3];
};

TEST_F(SyntheticEmbryoLooksTest, BackgroundIsDarkAndQuiet) {
  // The eight 6^3 corners lie outside the ellipsoid: camera offset plus low noise.
  for (int ch = 0; ch < 3; ++ch) {
    for (int corner = 0; corner < 8; ++corner) {
      const int64_t x0 = corner & 1 ? kX - 6 : 0, y0 = corner & 2 ? kY - 6 : 0,
                    z0 = corner & 4 ? kZ - 6 : 0;
      Region r = Box(ch, x0, x0 + 6, y0, y0 + 6, z0, z0 + 6);
      EXPECT_GE(r.min, 80) << "channel " << ch << " corner " << corner;
      EXPECT_LE(r.max, 200) << "channel " << ch << " corner " << corner;
      EXPECT_GE(r.mean, 100) << "channel " << ch;
      EXPECT_LE(r.mean, 130) << "channel " << ch;
    }
  }
}

TEST_F(SyntheticEmbryoLooksTest, NucleiMakeTheCentreBright) {
  Region background = Box(0, 0, 8, 0, 8, 0, kZ);
  Region centre = Box(0, kX / 4, 3 * kX / 4, kY / 4, 3 * kY / 4, kZ / 4, 3 * kZ / 4);
  EXPECT_GT(centre.mean, 2 * background.mean);
  EXPECT_GT(centre.mean, background.mean + 150);
  EXPECT_GT(centre.max, 1000);
  EXPECT_GT(embryo_->nucleus_count(), 100);
  EXPECT_LT(embryo_->nucleus_count(), 5000);
  // Nuclei are packed but separate: a good share, not all, of the centre is nuclear.
  size_t bright = 0;
  for (int64_t z = kZ / 4; z < 3 * kZ / 4; ++z) {
    for (int64_t y = kY / 4; y < 3 * kY / 4; ++y) {
      for (int64_t x = kX / 4; x < 3 * kX / 4; ++x) bright += At(0, x, y, z) > 600;
    }
  }
  EXPECT_GT(static_cast<double>(bright) / centre.count, 0.05);
  EXPECT_LT(static_cast<double>(bright) / centre.count, 0.6);
}

TEST_F(SyntheticEmbryoLooksTest, SpotsAreSparseAndVeryBright) {
  const double fraction = FractionAbove(2, 1500);
  EXPECT_GT(fraction, 0.0);
  EXPECT_LT(fraction, 0.01);
  EXPECT_GT(*std::max_element(data_[2].begin(), data_[2].end()), 3000);
  EXPECT_GT(embryo_->spot_count(), 10);
}

TEST_F(SyntheticEmbryoLooksTest, MembranesAreThin) {
  // Cell outlines cover a modest fraction of the volume: far more than spots, far less than
  // the embryo (which fills ~40% of the box).
  const double fraction = FractionAbove(1, 600);
  EXPECT_GT(fraction, 0.02);
  EXPECT_LT(fraction, 0.25);
  // And they are outlines, not blobs: along x, runs of bright voxels are short on average
  // (a membrane lying almost in the xz plane gives the odd long run).
  size_t runs = 0, run_voxels = 0;
  for (int64_t z = 0; z < kZ; ++z) {
    for (int64_t y = 0; y < kY; ++y) {
      bool in_run = false;
      for (int64_t x = 0; x < kX; ++x) {
        const bool bright = At(1, x, y, z) > 600;
        runs += bright && !in_run;
        run_voxels += bright;
        in_run = bright;
      }
    }
  }
  ASSERT_GT(runs, 100u);
  EXPECT_LT(static_cast<double>(run_voxels) / runs, 4.0);
}

TEST(SyntheticEmbryoTest, SmallEmbryoLeavesMostOfTheBoxBackground) {
  SyntheticEmbryoOptions options;
  options.size = {64, 64, 32};
  options.channels = 1;
  options.embryo_percent = 30;
  auto embryo = SyntheticEmbryo::Create(options);
  ASSERT_TRUE(embryo.ok());
  std::vector<uint16_t> slab(64 * 64 * 32);
  ASSERT_TRUE((*embryo)->ReadSlab(0, 0, 32, std::as_writable_bytes(std::span(slab))).ok());
  // Outside the central 30 % (plus the blur), everything is camera background.
  size_t bright_outside = 0, outside = 0;
  for (int z = 0; z < 32; ++z)
    for (int y = 0; y < 64; ++y)
      for (int x = 0; x < 64; ++x) {
        const double dx = (x + 0.5) / 64 - 0.5, dy = (y + 0.5) / 64 - 0.5,
                     dz = (z + 0.5) / 32 - 0.5;
        if (dx * dx + dy * dy + dz * dz < 0.25 * 0.25) continue;
        ++outside;
        if (slab[(static_cast<size_t>(z) * 64 + y) * 64 + x] > 250) ++bright_outside;
      }
  EXPECT_GT(outside, slab.size() / 2);
  EXPECT_EQ(bright_outside, 0u);
  options.embryo_percent = 0;
  EXPECT_FALSE(SyntheticEmbryo::Create(options).ok());
}

}  // namespace
}  // namespace octoscope::io
