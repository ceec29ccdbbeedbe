// A streamed dataset against its source voxels: every plane reads back exactly, the histogram
// equals a direct count, bad slabs get clear errors, and the finished cache opens with the real
// `octoscope render`-side loader (the binary's `info` on the cache).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "dataset/dataset.h"
#include "dataset/stream_test_volume.h"
#include "octree/voxel_reader.h"
#include "volume/value_map.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;
using testing::Bytes;
using testing::kChannels;
using testing::kX;
using testing::kY;
using testing::kZ;
using testing::Planes;
using testing::Spec;
using DatasetStreamTest = testing::StreamTestRoot;

TEST_F(DatasetStreamTest, StreamedPlanesReadBackExactlyAndHistogramIsExact) {
  auto created = Dataset::CreateStream(Spec(root_));
  ASSERT_TRUE(created.ok()) << created.status().ToString();
  std::shared_ptr<Dataset> ds = *created;
  EXPECT_EQ(ds->status().state, DatasetState::kStreaming);
  ASSERT_NE(ds->octree(), nullptr);

  // Slabs of uneven depths, channels interleaved, z out of order, one plane sent twice (first
  // with wrong values, then the right ones: the replacement must win, also in the histogram).
  std::mt19937 rng(5);
  std::vector<std::pair<int64_t, int64_t>> slabs;
  for (int64_t z = 0; z < kZ;) {
    const int64_t nz = std::min<int64_t>(kZ - z, 1 + rng() % 4);
    slabs.emplace_back(z, nz);
    z += nz;
  }
  std::shuffle(slabs.begin(), slabs.end(), rng);
  std::vector<uint16_t> wrong(kX * kY, 60000);
  ASSERT_TRUE(ds->AddSlab(1, 5, 1, Bytes(wrong), true).ok());
  for (auto [z0, nz] : slabs) {
    for (int c = 0; c < kChannels; ++c) {
      const Status s = ds->AddSlab(c, z0, nz, Bytes(Planes(c, z0, nz)), /*wait_visible=*/c == 0);
      ASSERT_TRUE(s.ok()) << s.ToString();
    }
  }
  // Visible within the latency even without wait_visible.
  EXPECT_TRUE(ds->WaitFor(
      [](const DatasetStatus& s) { return s.planes_inserted == uint64_t{kZ} * kChannels; },
      std::chrono::seconds(10)));
  ASSERT_TRUE(ds->Finish().ok());
  const DatasetStatus st = ds->status();
  EXPECT_EQ(st.state, DatasetState::kReady);
  EXPECT_EQ(st.planes_received, uint64_t{kZ} * kChannels);
  ASSERT_TRUE(st.missing_planes.has_value());
  EXPECT_EQ(*st.missing_planes, 0u);

  std::map<uint16_t, uint64_t> direct[kChannels];
  for (int c = 0; c < kChannels; ++c) {
    const std::vector<uint16_t> expected = Planes(c, 0, kZ);
    for (uint16_t v : expected) ++direct[c][v];
    ASSERT_NE(ds->octree(), nullptr);
    std::vector<uint16_t> got(expected.size());
    const Status s =
        octree::ReadVoxels(*ds->octree(), c, octree::Box{{0, 0, 0}, {kX, kY, kZ}}, got);
    ASSERT_TRUE(s.ok()) << s.ToString();
    EXPECT_EQ(got, expected) << "channel " << c;
  }
  const Histogram h = ds->histogram();
  ASSERT_EQ(h.channels(), kChannels);
  for (int c = 0; c < kChannels; ++c) {
    EXPECT_EQ(h.total(c), uint64_t{kX} * kY * kZ);
    for (uint32_t v = 0; v < 65536; ++v) {
      const auto it = direct[c].find(static_cast<uint16_t>(v));
      ASSERT_EQ(h.counts(c)[v], it == direct[c].end() ? 0u : it->second) << c << " " << v;
    }
  }
  EXPECT_TRUE(fs::exists(ds->cache_dir() / kHistogramFile));
  EXPECT_EQ(ds->AddSlab(0, 0, 1, Bytes(Planes(0, 0, 1)), true).code(),
            StatusCode::kFailedPrecondition);
  const fs::path cache = ds->cache_dir();
  ds->Close();
  ds.reset();

  // The committed cache opens with the real `octoscope render CACHE`.
  const std::string cmd = std::string(OCTOSCOPE_BINARY) + " render '" + cache.string() +
                          "' --out '" + (root_ / "view.png").string() +
                          "' --size 32x32 > /dev/null 2>&1";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
  EXPECT_TRUE(fs::exists(root_ / "view.png"));
}

TEST_F(DatasetStreamTest, BadSlabsGetClearErrors) {
  auto created = Dataset::CreateStream(Spec(root_));
  ASSERT_TRUE(created.ok()) << created.status().ToString();
  std::shared_ptr<Dataset> ds = *created;
  const std::vector<uint16_t> plane = Planes(0, 0, 1);
  EXPECT_EQ(ds->AddSlab(kChannels, 0, 1, Bytes(plane), true).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(ds->AddSlab(-1, 0, 1, Bytes(plane), true).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(ds->AddSlab(0, kZ, 1, Bytes(plane), true).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(ds->AddSlab(0, kZ - 1, 2, Bytes(Planes(0, 0, 2)), true).code(),
            StatusCode::kOutOfRange);
  EXPECT_EQ(ds->AddSlab(0, -1, 1, Bytes(plane), true).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(ds->AddSlab(0, 0, 2, Bytes(plane), true).code(), StatusCode::kInvalidArgument);
  std::vector<std::byte> odd(Bytes(plane).begin(), Bytes(plane).end() - 1);
  EXPECT_EQ(ds->AddSlab(0, 0, 1, odd, true).code(), StatusCode::kInvalidArgument);
  std::vector<std::byte> not_tiff(64, std::byte{7});
  EXPECT_FALSE(ds->AddTiffSlab(0, 0, 1, not_tiff, true).ok());
  EXPECT_EQ(ds->status().planes_received, 0u);
  EXPECT_TRUE(ds->AddSlab(0, 0, 1, Bytes(plane), true).ok());
  EXPECT_EQ(ds->status().planes_received, 1u);

  StreamSpec bad = Spec(root_);
  bad.id = "abcdef012346";
  bad.size = {0, 1, 1};
  EXPECT_EQ(Dataset::CreateStream(bad).status().code(), StatusCode::kInvalidArgument);
  bad.size = {1, 1, 1};
  bad.channels = 0;
  EXPECT_EQ(Dataset::CreateStream(bad).status().code(), StatusCode::kInvalidArgument);
  bad.channels = 1;
  bad.dtype = volume::DataType::kFloat32;
  EXPECT_EQ(Dataset::CreateStream(bad).status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace octoscope::dataset
