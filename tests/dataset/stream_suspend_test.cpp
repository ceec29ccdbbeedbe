// An unfinished stream is never finished by anyone but its owner (issue 28): closing it (what a
// DatasetHub release and a shutdown do) checkpoints it and frees its octree; the next slab, open
// or finish resumes it with planes_received, the histogram and plane replacement exact. A quiet
// stream is checkpointed by its timer, a busy one is not released, and a checkpoint is never
// served as a complete cache.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "dataset/cache_setup.h"
#include "dataset/dataset.h"
#include "dataset/stream_checkpoint.h"
#include "dataset/stream_test_volume.h"

namespace octoscope::dataset {
namespace {

using testing::Bytes;
using testing::ExpectExactly;
using testing::kChannels;
using testing::kX;
using testing::kY;
using testing::kZ;
using testing::Planes;
using testing::Spec;
using StreamSuspendTest = testing::StreamTestRoot;

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

namespace octoscope::dataset {
namespace {

using testing::Bytes;
using testing::Planes;
using testing::Spec;
using StreamCheckpointTest = testing::StreamTestRoot;
namespace fs = std::filesystem;

TEST_F(StreamCheckpointTest, ABusyStreamStaysOpenAndAQuietOneIsCheckpointed) {
  StreamSpec spec = Spec(root_);
  spec.checkpoint_quiet = std::chrono::milliseconds(50);
  auto created = Dataset::CreateStream(spec);
  ASSERT_TRUE(created.ok()) << created.status().ToString();
  std::shared_ptr<Dataset> ds = *created;
  auto generation = [&] {
    auto contents = octree::OctreeCache::Inspect(ds->cache_dir());
    return contents.ok() ? contents->manifest.generation : 0;
  };
  EXPECT_EQ(generation(), 1u);  // Checkpointed empty at creation.

  // Quiet for checkpoint_quiet after a slab: checkpointed by the stream's timer, with the plane.
  ASSERT_TRUE(ds->AddSlab(1, 4, 1, Bytes(Planes(1, 4, 1)), false).ok());
  for (int i = 0; i < 200 && generation() < 2; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  auto contents = octree::OctreeCache::Inspect(ds->cache_dir());
  ASSERT_TRUE(contents.ok()) << contents.status().ToString();
  EXPECT_EQ(contents->manifest.generation, 2u);
  EXPECT_FALSE(contents->unclean);
  auto progress = ParseStreamAttachments(contents->attachments, testing::kChannels, testing::kZ,
                                         contents->manifest.source, ds->value_maps());
  ASSERT_TRUE(progress.ok()) << progress.status().ToString();
  EXPECT_EQ(progress->received[testing::kZ + 4], 1);
  EXPECT_EQ(progress->histogram.total(1), uint64_t{testing::kX} * testing::kY);
  EXPECT_TRUE(ds->status().open);

  // A release leaves a stream that got a slab within `quiet` open; a quiet one is suspended.
  ASSERT_TRUE(ds->AddSlab(0, 0, 1, Bytes(Planes(0, 0, 1)), true).ok());
  EXPECT_EQ(ds->Release(std::chrono::hours(1)).code(), StatusCode::kFailedPrecondition);
  EXPECT_TRUE(ds->status().open);
  ASSERT_TRUE(ds->Release(std::chrono::milliseconds(0)).ok());
  EXPECT_FALSE(ds->status().open);
  EXPECT_EQ(ds->status().state, DatasetState::kStreaming);

  // A suspended stream's cache is a checkpoint: never served as a complete cache.
  const Status complete = OpenCompleteCache(ds->cache_dir(), 64 << 20).status();
  EXPECT_EQ(complete.code(), StatusCode::kFailedPrecondition) << complete.ToString();
  const std::string cmd = std::string(OCTOSCOPE_BINARY) + " render '" + ds->cache_dir().string() +
                          "' --out '" + (root_ / "x.png").string() +
                          "' --size 16x16 > /dev/null 2>&1";
  EXPECT_NE(std::system(cmd.c_str()), 0) << cmd;
  EXPECT_FALSE(fs::exists(root_ / "x.png"));
  EXPECT_EQ(ds->status().planes_received, 2u);
}

}  // namespace
}  // namespace octoscope::dataset
