// StreamTestVolume: the known voxels the dataset tests stream (a small 2-channel uint16 volume of
// uneven size, neither homogeneous nor trivially compressible), their StreamSpec, and a fixture
// owning a fresh temporary folder per test.
#ifndef OCTOSCOPE_TESTS_DATASET_STREAM_TEST_VOLUME_H_
#define OCTOSCOPE_TESTS_DATASET_STREAM_TEST_VOLUME_H_

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

#include "dataset/dataset.h"

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

}  // namespace octoscope::dataset::testing

#endif  // OCTOSCOPE_TESTS_DATASET_STREAM_TEST_VOLUME_H_
