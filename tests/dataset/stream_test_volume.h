// StreamTestVolume: the known voxels the dataset tests stream (a small 2-channel uint16 volume of
// uneven size, neither homogeneous nor trivially compressible), their StreamSpec, a fixture
// owning a fresh temporary folder per test, and a check that a stream holds exactly some planes.
#ifndef OCTOSCOPE_TESTS_DATASET_STREAM_TEST_VOLUME_H_
#define OCTOSCOPE_TESTS_DATASET_STREAM_TEST_VOLUME_H_

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <span>
#include <string>
#include <vector>

#include "dataset/dataset.h"
#include "octree/voxel_reader.h"

namespace octoscope::dataset::testing {

class StreamTestRoot : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = std::filesystem::temp_directory_path() /
            ("octoscope_dataset_test_" + std::to_string(::getpid()) + "_" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(root_);
    std::filesystem::create_directories(root_);
  }
  void TearDown() override { std::filesystem::remove_all(root_); }
  std::filesystem::path root_;
};

inline constexpr int64_t kX = 37, kY = 29, kZ = 23;
inline constexpr int kChannels = 2;

inline uint16_t Voxel(int c, int64_t x, int64_t y, int64_t z) {
  // Smooth structure plus hash noise: neither homogeneous nor trivially compressible.
  const uint32_t h = static_cast<uint32_t>((x * 73856093) ^ (y * 19349663) ^ (z * 83492791) ^ c);
  return static_cast<uint16_t>(1000 * c + 20 * x + 7 * y + 3 * z + (h % 17));
}

inline std::vector<uint16_t> Planes(int c, int64_t z0, int64_t nz) {
  std::vector<uint16_t> out;
  for (int64_t z = z0; z < z0 + nz; ++z)
    for (int64_t y = 0; y < kY; ++y)
      for (int64_t x = 0; x < kX; ++x) out.push_back(Voxel(c, x, y, z));
  return out;
}

inline std::span<const std::byte> Bytes(const std::vector<uint16_t>& v) {
  return std::as_bytes(std::span<const uint16_t>(v));
}

inline StreamSpec Spec(const std::filesystem::path& root) {
  StreamSpec spec;
  spec.id = "abcdef012345";
  spec.name = "test stream";
  spec.size = {kX, kY, kZ};
  spec.channels = kChannels;
  spec.dtype = volume::DataType::kUint16;
  spec.cache_root = root;
  spec.ram_bytes = 64 << 20;
  return spec;
}

// Planes [z0, z0 + nz) of channel c.
struct PlaneRun {
  int c;
  int64_t z0, nz;
};

// The histogram and the stored voxels of `ds` are exactly those of the planes in `runs`.
inline void ExpectExactly(const Dataset& ds, const std::vector<PlaneRun>& runs) {
  std::map<uint16_t, uint64_t> direct[kChannels];
  uint64_t planes = 0;
  for (const PlaneRun& r : runs) {
    for (uint16_t v : Planes(r.c, r.z0, r.nz)) ++direct[r.c][v];
    planes += static_cast<uint64_t>(r.nz);
  }
  EXPECT_EQ(ds.status().planes_received, planes);
  const Histogram h = ds.histogram();
  ASSERT_EQ(h.channels(), kChannels);
  for (int c = 0; c < kChannels; ++c) {
    for (uint32_t v = 0; v < 65536; ++v) {
      const auto it = direct[c].find(static_cast<uint16_t>(v));
      ASSERT_EQ(h.counts(c)[v], it == direct[c].end() ? 0u : it->second) << c << " " << v;
    }
  }
  ASSERT_NE(ds.octree(), nullptr);
  for (const PlaneRun& r : runs) {
    std::vector<uint16_t> got(static_cast<size_t>(kX * kY * r.nz));
    const Status s = octree::ReadVoxels(*ds.octree(), r.c,
                                        octree::Box{{0, 0, r.z0}, {kX, kY, r.z0 + r.nz}}, got);
    ASSERT_TRUE(s.ok()) << s.ToString();
    const std::vector<uint16_t> want = Planes(r.c, r.z0, r.nz);
    const auto diff = std::mismatch(got.begin(), got.end(), want.begin());
    EXPECT_TRUE(diff.first == got.end())
        << "channel " << r.c << " planes from z " << r.z0 << ": voxel "
        << (diff.first - got.begin()) << " is " << *diff.first << ", not " << *diff.second;
  }
}

}  // namespace octoscope::dataset::testing

#endif  // OCTOSCOPE_TESTS_DATASET_STREAM_TEST_VOLUME_H_
