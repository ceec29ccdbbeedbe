// FolderWatcher against files written the way an acquisition writes them: the sidecar first,
// then plane files — one of them appearing truncated first (a writer still at work) and completed
// later. Every plane must arrive exactly (read back from the octree) and the dataset finish; after
// a restart the watcher goes on with the same stream.
#include "dataset/folder_watcher.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include "io/tiff_fixture.h"
#include "octree/voxel_reader.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;
using std::chrono::milliseconds;

constexpr uint32_t kW = 16, kH = 12;
constexpr int kZ = 4, kChannels = 2;

uint16_t Value(int c, uint32_t x, uint32_t y, int z) {
  return static_cast<uint16_t>(1000 * c + 100 * z + 7 * y + x);
}

bool WritePlane(const fs::path& path, int c, int z) {
  testing::TiffFixtureSpec spec;
  spec.width = kW;
  spec.height = kH;
  return testing::WriteTiffFixture(path, spec, [c, z](uint32_t x, uint32_t y, int, int) {
    return static_cast<double>(Value(c, x, y, z));
  });
}

bool WaitFor(const std::function<bool()>& done, milliseconds timeout = milliseconds(20000)) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    if (done()) return true;
    std::this_thread::sleep_for(milliseconds(20));
  }
  return done();
}

// Every voxel of the dataset as WritePlane wrote it.
void ExpectEveryVoxelAsWritten(const Dataset& dataset) {
  octree::Octree* tree = dataset.octree();
  ASSERT_NE(tree, nullptr);
  std::vector<uint16_t> voxels(kW * kH * kZ);
  for (int c = 0; c < kChannels; ++c) {
    octree::Box box;
    box.hi = {kW, kH, kZ};
    ASSERT_TRUE(octree::ReadVoxels(*tree, c, box, voxels).ok());
    int wrong = 0;
    for (int z = 0; z < kZ; ++z) {
      for (uint32_t y = 0; y < kH; ++y) {
        for (uint32_t x = 0; x < kW; ++x) {
          wrong += voxels[(z * kH + y) * kW + x] != Value(c, x, y, z);
        }
      }
    }
    EXPECT_EQ(wrong, 0) << "channel " << c;
  }
}

TEST(FolderWatcherTest, StreamsCompletePlanesOnlyAndFinishesTheAcquisition) {
  const fs::path dir = testing::MakeTempDir("folder-watcher");
  const fs::path watched = dir / "acquisition";
  fs::create_directories(watched / "ch2");
  RegistryOptions options;
  options.cache_root = dir / "cache";
  auto registry = DatasetRegistry::Create(options);
  ASSERT_TRUE(registry.ok()) << registry.status().ToString();
  NullLogger logger;
  WatchOptions watch;
  watch.poll_interval = milliseconds(20);
  watch.settle_time = milliseconds(100);
  watch.give_up_after = milliseconds(60000);
  auto watcher = FolderWatcher::Start(registry->get(), watched, &logger, watch);
  ASSERT_TRUE(watcher.ok());

  // The sidecar, then channel 0 as "img_c1_z####.tif" in the folder and channel 1 in ch2/
  // (numbered from 1, as index_base says).
  std::ofstream(watched / kWatchSidecarName)
      << R"({"name":"run 1","size":[16,12,4],"channels":2,"dtype":"uint16","index_base":1})";
  ASSERT_TRUE(WaitFor([&] { return !(*watcher)->stats().dataset_id.empty(); }));
  const std::string id = (*watcher)->stats().dataset_id;
  std::shared_ptr<Dataset> dataset = (*registry)->Find(id);
  ASSERT_NE(dataset, nullptr);

  // Plane z=2 of channel 0 appears truncated (half its bytes) and stays so for a while.
  const fs::path complete = dir / "complete.tif";
  ASSERT_TRUE(WritePlane(complete, 0, 1));
  std::ifstream in(complete, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), {});
  std::ofstream(watched / "img_c1_z0002.tif", std::ios::binary)
      << bytes.substr(0, bytes.size() / 2);
  for (int z = 0; z < kZ; ++z) {
    char name[40];
    std::snprintf(name, sizeof name, "img_c1_z%04d.tif", z + 1);
    if (z != 1) {
      ASSERT_TRUE(WritePlane(watched / name, 0, z));
    }
    ASSERT_TRUE(WritePlane(watched / "ch2" / (std::to_string(z + 1) + ".tif"), 1, z));
  }
  ASSERT_TRUE(WaitFor([&] { return (*watcher)->stats().planes_ingested == 7; }));
  std::this_thread::sleep_for(milliseconds(400));
  EXPECT_EQ((*watcher)->stats().planes_ingested, 7u);  // The truncated file was not read.
  EXPECT_EQ(dataset->status().state, DatasetState::kStreaming);
  // The writer finishes the file: it arrives, and the acquisition is complete.
  std::ofstream(watched / "img_c1_z0002.tif", std::ios::binary) << bytes;
  ASSERT_TRUE(WaitFor([&] { return dataset->status().state == DatasetState::kReady; }));
  EXPECT_EQ((*watcher)->stats().planes_ingested, 8u);
  EXPECT_EQ((*watcher)->stats().bad_files, 0u);

  ExpectEveryVoxelAsWritten(*dataset);
  watcher->reset();
  (*registry)->Close();
  fs::remove_all(dir);
}

TEST(FolderWatcherTest, BadFilesAreReportedAndSkipped) {
  const fs::path dir = testing::MakeTempDir("folder-watcher-bad");
  const fs::path watched = dir / "acquisition";
  fs::create_directories(watched);
  RegistryOptions options;
  options.cache_root = dir / "cache";
  auto registry = DatasetRegistry::Create(options);
  ASSERT_TRUE(registry.ok());
  NullLogger logger;
  WatchOptions watch;
  watch.poll_interval = milliseconds(20);
  watch.settle_time = milliseconds(50);
  watch.give_up_after = milliseconds(300);
  auto watcher = FolderWatcher::Start(registry->get(), watched, &logger, watch);
  ASSERT_TRUE(watcher.ok());
  std::ofstream(watched / kWatchSidecarName)
      << R"({"size":[16,12,2],"channels":1,"dtype":"uint16"})";
  std::ofstream(watched / "z0000.tif") << "not a tiff at all";
  testing::TiffFixtureSpec wrong_size;
  wrong_size.width = 8;
  ASSERT_TRUE(testing::WriteTiffFixture(watched / "z0001.tif", wrong_size));
  ASSERT_TRUE(WaitFor([&] { return (*watcher)->stats().bad_files == 2; }));
  EXPECT_EQ((*watcher)->stats().planes_ingested, 0u);
  // A good plane replacing a bad file is taken.
  ASSERT_TRUE(WritePlane(watched / "z0000.tif", 0, 0));
  ASSERT_TRUE(WaitFor([&] { return (*watcher)->stats().planes_ingested == 1; }));
  watcher->reset();
  (*registry)->Close();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace octoscope::dataset

namespace octoscope::dataset {
namespace {

// After a restart the watcher goes on with its folder's stream (found by the folder in the
// stream records): planes received before are not read again, the others arrive, and the
// acquisition finishes; an idle release of the stream meanwhile changes nothing.
TEST(FolderWatcherTest, ARestartResumesTheFolderStreamAndSkipsPlanesReceived) {
  const fs::path dir = testing::MakeTempDir("folder-watcher-restart");
  const fs::path watched = dir / "acquisition";
  fs::create_directories(watched);
  RegistryOptions options;
  options.cache_root = dir / "cache";
  options.state_dir = dir / "state";
  NullLogger logger;
  WatchOptions watch;
  watch.poll_interval = milliseconds(20);
  watch.settle_time = milliseconds(100);
  auto plane = [&](int c, int z) {
    char name[40];
    std::snprintf(name, sizeof name, "img_c%d_z%04d.tif", c + 1, z + 1);
    return watched / name;
  };
  std::ofstream(watched / kWatchSidecarName)
      << R"({"name":"run 2","size":[16,12,4],"channels":2,"dtype":"uint16","index_base":1})";
  for (int c = 0; c < kChannels; ++c) {
    for (int z = 0; z < 2; ++z) ASSERT_TRUE(WritePlane(plane(c, z), c, z));
  }
  std::string id;
  {
    auto registry = DatasetRegistry::Create(options);
    ASSERT_TRUE(registry.ok()) << registry.status().ToString();
    auto watcher = FolderWatcher::Start(registry->get(), watched, &logger, watch);
    ASSERT_TRUE(watcher.ok());
    ASSERT_TRUE(WaitFor([&] { return (*watcher)->stats().planes_ingested == 4; }));
    id = (*watcher)->stats().dataset_id;
    watcher->reset();
    (*registry)->Close();  // The server stops.
  }

  auto registry = DatasetRegistry::Create(options);
  ASSERT_TRUE(registry.ok()) << registry.status().ToString();
  std::shared_ptr<Dataset> dataset = (*registry)->Find(id);
  ASSERT_NE(dataset, nullptr);
  EXPECT_EQ(dataset->status().planes_received, 4u);
  EXPECT_EQ((*registry)->FindWatchedStream(watched), dataset);
  auto watcher = FolderWatcher::Start(registry->get(), watched, &logger, watch);
  ASSERT_TRUE(watcher.ok());
  ASSERT_TRUE(WaitFor([&] { return (*watcher)->stats().dataset_id == id; }));
  std::this_thread::sleep_for(milliseconds(300));
  EXPECT_EQ((*watcher)->stats().planes_ingested, 0u);  // Nothing read again.
  // Released as an idle dataset (suspended): the watcher goes on regardless.
  ASSERT_TRUE(dataset->Release(milliseconds(0)).ok());
  EXPECT_FALSE(dataset->status().open);
  for (int c = 0; c < kChannels; ++c) {
    for (int z = 2; z < kZ; ++z) ASSERT_TRUE(WritePlane(plane(c, z), c, z));
  }
  ASSERT_TRUE(WaitFor([&] { return dataset->status().state == DatasetState::kReady; }));
  EXPECT_EQ((*watcher)->stats().planes_ingested, 4u);
  EXPECT_EQ(dataset->status().missing_planes, uint64_t{0});
  ExpectEveryVoxelAsWritten(*dataset);
  watcher->reset();
  (*registry)->Close();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace octoscope::dataset
