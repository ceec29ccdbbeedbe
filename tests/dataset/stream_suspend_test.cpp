// An unfinished stream is never finished by anyone but its owner (issue 28): closing it (what a
// DatasetHub release and a shutdown do) checkpoints it and frees its octree; the next slab, open
// or finish resumes it with planes_received, the histogram and plane replacement exact.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <map>
#include <utility>
#include <vector>

#include "dataset/dataset.h"
#include "dataset/stream_test_volume.h"
#include "octree/voxel_reader.h"

namespace octoscope::dataset {
namespace {

using testing::Bytes;
using testing::kChannels;
using testing::kX;
using testing::kY;
using testing::kZ;
using testing::Planes;
using testing::Spec;
using StreamSuspendTest = testing::StreamTestRoot;

// Planes [z0, z0 + nz) of channel c.
struct PlaneRun {
  int c;
  int64_t z0, nz;
};

// The histogram and the stored voxels of `ds` are exactly those of the planes in `runs`.
void ExpectExactly(const Dataset& ds, const std::vector<PlaneRun>& runs) {
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

TEST_F(StreamSuspendTest, AClosedUnfinishedStreamResumesOnTheNextSlab) {
  auto created = Dataset::CreateStream(Spec(root_));
  ASSERT_TRUE(created.ok()) << created.status().ToString();
  std::shared_ptr<Dataset> ds = *created;
  for (int64_t z = 0; z < 10; ++z) {
    ASSERT_TRUE(ds->AddSlab(0, z, 1, Bytes(Planes(0, z, 1)), z % 2 == 0).ok());
  }
  ASSERT_TRUE(ds->AddSlab(1, 0, 5, Bytes(Planes(1, 0, 5)), false).ok());

  // Closed as an idle release closes it: nothing in RAM, still streaming, nothing lost.
  ds->Close();
  DatasetStatus st = ds->status();
  EXPECT_EQ(st.state, DatasetState::kStreaming);
  EXPECT_FALSE(st.open);
  EXPECT_EQ(ds->octree(), nullptr);
  EXPECT_EQ(st.planes_received, 15u);
  EXPECT_FALSE(st.missing_planes.has_value());
  EXPECT_EQ(ds->histogram().total(0), uint64_t{10} * kX * kY);

  // The next slab resumes it.
  const Status added = ds->AddSlab(0, 10, 1, Bytes(Planes(0, 10, 1)), true);
  ASSERT_TRUE(added.ok()) << added.ToString();
  st = ds->status();
  EXPECT_TRUE(st.open);
  EXPECT_EQ(st.state, DatasetState::kStreaming);
  EXPECT_EQ(st.planes_received, 16u);
  EXPECT_EQ(st.planes_inserted, 16u);
  // A plane received before the close is replaced (wrong values first, then the right ones).
  const std::vector<uint16_t> wrong(kX * kY, 65000);
  ASSERT_TRUE(ds->AddSlab(0, 3, 1, Bytes(wrong), true).ok());
  EXPECT_EQ(ds->histogram().counts(0)[65000], uint64_t{kX} * kY);
  ASSERT_TRUE(ds->AddSlab(0, 3, 1, Bytes(Planes(0, 3, 1)), true).ok());
  {
    SCOPED_TRACE("resumed by a slab");
    ExpectExactly(*ds, {{0, 0, 11}, {1, 0, 5}});
  }

  // Staged planes (wait_visible = false) survive a close too; Finish resumes and finishes.
  ASSERT_TRUE(ds->AddSlab(1, 5, 2, Bytes(Planes(1, 5, 2)), false).ok());
  ds->Close();
  EXPECT_EQ(ds->status().planes_received, 18u);
  ASSERT_TRUE(ds->Open().ok());  // Resumes on the worker.
  ASSERT_TRUE(ds->WaitFor([](const DatasetStatus& s) { return s.open; }, std::chrono::seconds(10)));
  EXPECT_EQ(ds->status().state, DatasetState::kStreaming);
  ds->Close();
  const Status finished = ds->Finish();
  ASSERT_TRUE(finished.ok()) << finished.ToString();
  st = ds->status();
  EXPECT_EQ(st.state, DatasetState::kReady);
  ASSERT_TRUE(st.missing_planes.has_value());
  EXPECT_EQ(*st.missing_planes, uint64_t{kZ} * kChannels - 18);
  {
    SCOPED_TRACE("resumed by Finish");
    ExpectExactly(*ds, {{0, 0, 11}, {1, 0, 7}});
  }
  EXPECT_EQ(ds->AddSlab(0, 12, 1, Bytes(Planes(0, 12, 1)), true).code(),
            StatusCode::kFailedPrecondition);
}

}  // namespace
}  // namespace octoscope::dataset
