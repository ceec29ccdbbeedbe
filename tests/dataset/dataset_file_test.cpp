// A file dataset built through Dataset (worker thread, cache) against the voxels written into the
// TIFF by an independent libtiff writer, and against the same scan streamed plane by plane: the
// two octrees read back identical voxels and identical histograms; a reopened cache reuses its
// histogram.bin.
#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "dataset/dataset.h"
#include "io/tiff_fixture.h"
#include "octree/voxel_reader.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;

constexpr uint32_t kX = 41, kY = 26;
constexpr int kZ = 19;

double Value(uint32_t x, uint32_t y, int z) {
  // A bright blob on a dim, noisy background: homogeneous and detailed bricks both occur.
  const double dx = x - 20.0, dy = y - 13.0, dz = z - 9.0;
  const uint32_t h = (x * 2654435761u) ^ (y * 40503u) ^ (static_cast<uint32_t>(z) * 977u);
  return (dx * dx + dy * dy + dz * dz < 60 ? 30000 : 100) + (x > 30 ? h % 9 : 0);
}

std::vector<uint16_t> Expected() {
  std::vector<uint16_t> out;
  for (int z = 0; z < kZ; ++z)
    for (uint32_t y = 0; y < kY; ++y)
      for (uint32_t x = 0; x < kX; ++x) out.push_back(static_cast<uint16_t>(Value(x, y, z)));
  return out;
}

std::vector<uint16_t> ReadAll(const Dataset& ds) {
  std::vector<uint16_t> got(size_t{kX} * kY * kZ);
  const octree::Octree* tree = ds.octree();
  EXPECT_NE(tree, nullptr);
  if (tree == nullptr) return {};
  const Status s = octree::ReadVoxels(*tree, 0, octree::Box{{0, 0, 0}, {kX, kY, kZ}}, got);
  EXPECT_TRUE(s.ok()) << s.ToString();
  return got;
}

bool Ready(const DatasetStatus& s) {
  return s.state == DatasetState::kReady || s.state == DatasetState::kError;
}

TEST(DatasetFileTest, BuiltFileEqualsSourceAndStreamedTwin) {
  const fs::path dir = testing::MakeTempDir("dataset_file");
  testing::TiffFixtureSpec tiff;
  tiff.width = kX;
  tiff.height = kY;
  tiff.pages = kZ;
  ASSERT_TRUE(testing::WriteTiffFixture(
      dir / "scan.tif", tiff,
      [](uint32_t x, uint32_t y, int page, int) { return Value(x, y, page); }));
  const std::vector<uint16_t> expected = Expected();
  std::map<uint16_t, uint64_t> direct;
  for (uint16_t v : expected) ++direct[v];

  SourceSpec spec;
  spec.id = "f00000000001";
  spec.path = dir / "scan.tif";
  spec.cache_root = dir / "caches";
  spec.ram_bytes = 32 << 20;
  std::shared_ptr<Dataset> file = Dataset::ForSource(spec);
  EXPECT_EQ(file->info().size[0], kX);
  ASSERT_TRUE(file->Open().ok());
  ASSERT_TRUE(file->WaitFor(Ready, std::chrono::seconds(60)));
  ASSERT_EQ(file->status().state, DatasetState::kReady) << file->status().error;
  ASSERT_TRUE(file->WaitFor([](const DatasetStatus& s) { return s.histogram_complete; },
                            std::chrono::seconds(60)));
  EXPECT_EQ(ReadAll(*file), expected);
  const Histogram fh = file->histogram();
  ASSERT_EQ(fh.channels(), 1);
  for (uint32_t v = 0; v < 65536; ++v) {
    const auto it = direct.find(static_cast<uint16_t>(v));
    ASSERT_EQ(fh.counts(0)[v], it == direct.end() ? 0u : it->second) << v;
  }
  EXPECT_TRUE(fs::exists(file->cache_dir() / kHistogramFile));

  // The same scan streamed one plane at a time, top plane first.
  StreamSpec stream;
  stream.id = "f00000000002";
  stream.size = {kX, kY, kZ};
  stream.cache_root = dir / "caches";
  auto created = Dataset::CreateStream(stream);
  ASSERT_TRUE(created.ok()) << created.status().ToString();
  std::shared_ptr<Dataset> streamed = *created;
  const size_t plane = size_t{kX} * kY;
  for (int z = kZ - 1; z >= 0; --z) {
    const std::span<const uint16_t> p(expected.data() + plane * z, plane);
    ASSERT_TRUE(streamed->AddSlab(0, z, 1, std::as_bytes(p), false).ok());
  }
  ASSERT_TRUE(streamed->Finish().ok());
  EXPECT_EQ(ReadAll(*streamed), expected);
  const Histogram sh = streamed->histogram();
  EXPECT_TRUE(std::equal(sh.counts(0).begin(), sh.counts(0).end(), fh.counts(0).begin(),
                         fh.counts(0).end()));
  EXPECT_EQ(sh.Percentile(0, 0.999), fh.Percentile(0, 0.999));

  // Close and reopen: the cache is reused with its histogram.
  file->Close();
  EXPECT_EQ(file->octree(), nullptr);
  ASSERT_TRUE(file->Open().ok());
  ASSERT_TRUE(file->WaitFor(
      [](const DatasetStatus& s) { return Ready(s) && s.open && s.histogram_complete; },
      std::chrono::seconds(60)));
  EXPECT_EQ(ReadAll(*file), expected);
  EXPECT_EQ(file->histogram().total(0), expected.size());
  file.reset();
  streamed.reset();
  fs::remove_all(dir);
}

TEST(DatasetFileTest, UnreadableFileIsAnErrorNotACrash) {
  const fs::path dir = testing::MakeTempDir("dataset_bad_file");
  {
    std::FILE* f = std::fopen((dir / "bad.tif").c_str(), "wb");
    ASSERT_NE(f, nullptr);
    std::fputs("II*\0garbage", f);
    std::fclose(f);
  }
  SourceSpec spec;
  spec.id = "f00000000003";
  spec.path = dir / "bad.tif";
  spec.cache_root = dir / "caches";
  std::shared_ptr<Dataset> ds = Dataset::ForSource(spec);
  EXPECT_EQ(ds->status().state, DatasetState::kError);
  EXPECT_FALSE(ds->status().error.empty());
  EXPECT_FALSE(ds->Open().ok());
  ds.reset();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace octoscope::dataset
