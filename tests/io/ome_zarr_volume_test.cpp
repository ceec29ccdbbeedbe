// OME-Zarr reading against independent writers: stores written by python3-zarr/numcodecs (Zarr
// v2) and by the v3 specification with numcodecs compression (Zarr v3, NGFF 0.5), every dtype,
// byte order, compressor, shuffle, separator, axis order, missing chunks, partial edge chunks,
// levels and series, read back voxel for voxel; the real light-sheet store of the test data equal
// to python3-zarr's decode; and bad stores refused with one clear error.
#include "io/ome_zarr_volume.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "io/confined_fixture.h"
#include "io/open_volume.h"
#include "io/volume_stats.h"
#include "protocol/zarr_json.h"
#include "python_fixtures.h"
#include "tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;
using testing::PythonFixtureCase;

const fs::path kRealStore = fs::path(OCTOSCOPE_TESTDATA) / "zarrnii" /
                            "sub-AS36F2_sample-brain_acq-downsampled_SPIM.ome.zarr";

OpenOptions ZarrOptions() {
  OpenOptions options;
  options.zarr_json = protocol::MakeZarrJsonParsers();
  return options;
}

struct OmeZarrFixturesScript {
  static constexpr const char* kScript = "write_zarr_fixtures.py";
  static constexpr const char* kDirName = "zarr-fixtures";
  static std::vector<std::string> Args() { return {kRealStore.string()}; }
};
class OmeZarrFixtures : public testing::PythonFixtureTest<OmeZarrFixturesScript> {};

TEST_F(OmeZarrFixtures, EveryDtypeInEitherByteOrder) {
  for (const PythonFixtureCase& c : Cases("dtype-"))
    testing::ExpectVolumeMatchesCase(c, ZarrOptions());
}

TEST_F(OmeZarrFixtures, EveryCompressorAndShuffle) {
  for (const PythonFixtureCase& c : Cases("compressor-")) {
    testing::ExpectVolumeMatchesCase(c, ZarrOptions());
  }
}

TEST_F(OmeZarrFixtures, SeparatorsFortranOrderAndAxisOrders) {
  for (const std::string prefix : {"separator-", "order-", "axes-"}) {
    for (const PythonFixtureCase& c : Cases(prefix))
      testing::ExpectVolumeMatchesCase(c, ZarrOptions());
  }
}

TEST_F(OmeZarrFixtures, MissingChunksReadAsFillValue) {
  for (const PythonFixtureCase& c : Cases("missing-chunks")) {
    testing::ExpectVolumeMatchesCase(c, ZarrOptions());
  }
}

TEST_F(OmeZarrFixtures, LevelsSeriesAndBareArrays) {
  for (const std::string prefix : {"multiscale-", "bioformats2raw-", "bare-"}) {
    for (const PythonFixtureCase& c : Cases(prefix))
      testing::ExpectVolumeMatchesCase(c, ZarrOptions());
  }
}

TEST_F(OmeZarrFixtures, ZarrV3CodecsShardingAndNgff05) {
  for (const PythonFixtureCase& c : Cases("v3-"))
    testing::ExpectVolumeMatchesCase(c, ZarrOptions());
}

TEST_F(OmeZarrFixtures, MultiscaleMetadata) {
  OpenOptions options = ZarrOptions();
  options.level = 2;
  auto source = OpenVolume(*dir_ / "multiscale.ome.zarr", options);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  const volume::VolumeInfo& info = (*source)->info();
  EXPECT_EQ(info.format, "ome-zarr");
  EXPECT_EQ(info.level_count, 3);
  ASSERT_TRUE(info.channels[0].window.has_value());
  EXPECT_EQ(*info.channels[0].window, (volume::DisplayWindow{10, 1000, 0.0, 65535.0}));
  EXPECT_EQ(*info.channels[1].window, (volume::DisplayWindow{0, 2000, 0.0, 4095.0}));
  options.level = 3;
  auto beyond = OpenVolume(*dir_ / "multiscale.ome.zarr", options);
  ASSERT_FALSE(beyond.ok());
  EXPECT_EQ(beyond.status().code(), StatusCode::kOutOfRange);
  EXPECT_NE(beyond.status().message().find("level 3"), std::string::npos);

  options.level = 0;
  options.series = 2;
  auto series = OpenVolume(*dir_ / "bioformats2raw.zarr", options);
  ASSERT_FALSE(series.ok());
  EXPECT_EQ(series.status().code(), StatusCode::kOutOfRange);
  options.series = 1;
  auto second = OpenVolume(*dir_ / "bioformats2raw.zarr", options);
  ASSERT_TRUE(second.ok());
  EXPECT_EQ((*second)->info().series_count, 2);
}

TEST_F(OmeZarrFixtures, MetadataFilesOpenTheirStore) {
  for (const char* file : {".zattrs", ".zgroup"}) {
    auto source = OpenVolume(*dir_ / "multiscale.ome.zarr" / file, ZarrOptions());
    ASSERT_TRUE(source.ok()) << file << ": " << source.status().ToString();
    EXPECT_EQ((*source)->info().level_count, 3);
  }
  auto v3 = OpenVolume(*dir_ / "v3-multiscale.ome.zarr" / "zarr.json", ZarrOptions());
  ASSERT_TRUE(v3.ok()) << v3.status().ToString();
  EXPECT_EQ((*v3)->info().level_count, 2);
}

TEST_F(OmeZarrFixtures, RealLightSheetStoreEqualsPythonZarr) {
  // ../shared/testdata/zarrnii: 3 float64 channels (Abeta, CD31, YoPro), 4 levels; two chunks are
  // absent from our copy and read as fill value 0 (python3-zarr agrees).
  std::vector<PythonFixtureCase> cases = Cases("real-zarrnii-level");
  ASSERT_EQ(cases.size(), 4u);
  const std::array<std::array<int64_t, 3>, 4> sizes = {
      {{96, 158, 150}, {48, 79, 75}, {24, 39, 37}, {12, 19, 18}}};
  for (size_t level = 0; level < cases.size(); ++level) {
    EXPECT_EQ(cases[level].size, sizes[level]);
    EXPECT_EQ(cases[level].names, (std::vector<std::string>{"Abeta", "CD31", "YoPro"}));
    EXPECT_EQ(cases[level].colors, (std::vector<std::string>{"#00ff00", "#ffffff", "#ffffff"}));
    testing::ExpectVolumeMatchesCase(cases[level], ZarrOptions());
  }
  auto source = OpenVolume(kRealStore, ZarrOptions());
  ASSERT_TRUE(source.ok());
  const volume::VolumeInfo& info = (*source)->info();
  EXPECT_EQ(info.dtype, volume::DataType::kFloat64);
  EXPECT_EQ(info.level_count, 4);
  // Its axes carry no unit: the spacing is unknown, not guessed.
  for (int a = 0; a < 3; ++a) EXPECT_FALSE(info.spacing_um[a].has_value());
  EXPECT_EQ(*info.channels[2].window, (volume::DisplayWindow{0, 65535, 0.0, 65535.0}));
}

TEST_F(OmeZarrFixtures, ConcurrentReadersAgree) {
  // Builder-style: one thread per channel, thin slabs, channels sharing chunks (chunk c = 2).
  std::vector<PythonFixtureCase> cases = Cases("separator-slash");
  const PythonFixtureCase& c = cases[0];
  std::ifstream raw(c.raw, std::ios::binary);
  std::vector<char> expected((std::istreambuf_iterator<char>(raw)), {});
  OpenOptions options = ZarrOptions();
  options.decode_threads = 3;
  options.chunk_cache_bytes = 4096;  // Small: entries evicted while others are in use.
  auto source = OpenVolume(c.input, options);
  ASSERT_TRUE(source.ok());
  const uint64_t volume_bytes = (*source)->SlabBytes(c.size[2]);
  std::vector<std::thread> threads;
  std::vector<int> mismatches(static_cast<size_t>(c.channels) * 4, 0);
  for (int k = 0; k < c.channels * 4; ++k) {
    threads.emplace_back([&, k] {
      const int ch = k % c.channels;
      const uint64_t plane = (*source)->SlabBytes(1);
      std::vector<std::byte> one(plane * 2);
      for (int64_t z = k % 2; z + 2 <= c.size[2]; z += 2) {
        if (!(*source)->ReadSlab(ch, z, 2, one).ok() ||
            std::memcmp(one.data(), expected.data() + ch * volume_bytes + z * plane, 2 * plane)) {
          ++mismatches[k];
        }
      }
    });
  }
  for (std::thread& t : threads) t.join();
  for (int m : mismatches) EXPECT_EQ(m, 0);
}

// --- bad stores, written here byte by byte
// --------------------------------------------------------

class BadZarr : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir("bad-zarr"); }
  void TearDown() override { fs::remove_all(dir_); }

  void Write(const fs::path& rel, const std::string& content) {
    fs::create_directories((dir_ / rel).parent_path());
    std::ofstream(dir_ / rel, std::ios::binary) << content;
  }
  // An uncompressed 4x4x4 uint16 array (one chunk of 2x4x4 in z: two chunks).
  void GoodArray(const std::string& extra = "") {
    Write("a.zarr/.zarray",
          R"({"zarr_format": 2, "shape": [4, 4, 4], "chunks": [2, 4, 4], "dtype": "<u2",
              "compressor": null, "fill_value": 0, "order": "C", "filters": null)" +
              extra + "}");
    Write("a.zarr/0.0.0", std::string(64, '\1'));
    Write("a.zarr/1.0.0", std::string(64, '\2'));
  }
  Status Read(const fs::path& rel) {
    auto source = OpenVolume(dir_ / rel, ZarrOptions());
    if (!source.ok()) return source.status();
    std::vector<std::byte> all((*source)->SlabBytes((*source)->info().size[2]));
    for (int c = 0; c < (*source)->info().channel_count(); ++c) {
      OCTO_RETURN_IF_ERROR((*source)->ReadSlab(c, 0, (*source)->info().size[2], all));
    }
    return Status::Ok();
  }
  fs::path dir_;
};

TEST_F(BadZarr, GoodArrayReads) {
  GoodArray();
  EXPECT_TRUE(Read("a.zarr").ok()) << Read("a.zarr").ToString();
}

TEST_F(BadZarr, TruncatedChunkIsCorruptNamingTheChunk) {
  GoodArray();
  Write("a.zarr/1.0.0", std::string(63, '\2'));
  Status s = Read("a.zarr");
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  EXPECT_NE(s.message().find("1.0.0"), std::string::npos) << s.message();
}

TEST_F(BadZarr, CompressedChunksOfTheWrongSizeOrGarbageAreCorrupt) {
  for (const char* id : {"zstd", "blosc", "zlib", "gzip", "lz4"}) {
    SCOPED_TRACE(id);
    GoodArray();
    Write("a.zarr/.zarray",
          std::string(R"({"zarr_format": 2, "shape": [4, 4, 4], "chunks": [2, 4, 4], "dtype":
              "<u2", "compressor": {"id": ")") +
              id + R"("}, "fill_value": 0, "order": "C",
              "filters": null})");
    Write("a.zarr/0.0.0", "this is not a compressed chunk at all, just text of some length");
    fs::remove(dir_ / "a.zarr/1.0.0");  // Absent: only chunk 0.0.0 is bad.
    Status s = Read("a.zarr");
    EXPECT_EQ(s.code(), StatusCode::kCorrupt) << s.ToString();
    EXPECT_NE(s.message().find("0.0.0"), std::string::npos) << s.message();
  }
}

TEST_F(BadZarr, MalformedMetadataIsCorruptNamingTheFile) {
  GoodArray();
  Write("a.zarr/.zarray", R"({"zarr_format": 2, "shape": [4, 4, 4], "chunks": [2, 4)");
  Status s = Read("a.zarr");
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  EXPECT_NE(s.message().find(".zarray"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("not valid JSON"), std::string::npos) << s.message();
}

TEST_F(BadZarr, AbsurdDimensionsAreRefusedBeforeAllocating) {
  GoodArray();
  Write("a.zarr/.zarray",
        R"({"zarr_format": 2, "shape": [4000000000, 4000000000, 4000000000], "chunks": [1, 1,
            1], "dtype": "<u2", "compressor": null, "fill_value": 0, "filters": null})");
  Status s = Read("a.zarr");
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.code(), StatusCode::kInternal) << s.ToString();
  Write("a.zarr/.zarray",
        R"({"zarr_format": 2, "shape": [4, 4, 4], "chunks": [100000, 100000, 100000],
            "dtype": "<u2", "compressor": null, "fill_value": 0, "filters": null})");
  s = Read("a.zarr");
  EXPECT_EQ(s.code(), StatusCode::kResourceExhausted) << s.ToString();
}

TEST_F(BadZarr, MoreThan64ChannelsAreRefusedBeforeSizingAnything) {
  auto write = [&](int64_t channels) {
    Write("c.zarr/.zgroup", R"({"zarr_format": 2})");
    Write("c.zarr/.zattrs", R"({"multiscales": [{"version": "0.4", "axes": [
        {"name": "c", "type": "channel"}, {"name": "y", "type": "space"}, {"name": "x", "type":
        "space"}], "datasets": [{"path": "0"}]}]})");
    Write("c.zarr/0/.zarray", R"({"zarr_format": 2, "shape": [)" + std::to_string(channels) +
                                  R"(, 2, 2], "chunks": [1, 2, 2], "dtype": "<u2",
        "compressor": null, "fill_value": 0, "order": "C", "filters": null})");
  };
  write(64);
  auto source = OpenVolume(dir_ / "c.zarr", ZarrOptions());
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().channel_count(), 64);
  for (int64_t channels : {int64_t{65}, int64_t{1} << 40}) {
    write(channels);
    Status s = Read("c.zarr");
    EXPECT_EQ(s.code(), StatusCode::kResourceExhausted) << s.ToString();
    EXPECT_NE(s.message().find("more than the 64"), std::string::npos) << s.message();
    EXPECT_NE(s.message().find("c.zarr"), std::string::npos) << s.message();
  }
}

TEST_F(BadZarr, OmeroForAnotherChannelCountIsIgnoredWithAWarning) {
  Write("c.zarr/.zgroup", R"({"zarr_format": 2})");
  Write("c.zarr/0/.zarray", R"({"zarr_format": 2, "shape": [2, 2, 2], "chunks": [1, 2, 2],
      "dtype": "<u2", "compressor": null, "fill_value": 0, "order": "C", "filters": null})");
  const std::string multiscales = R"("multiscales": [{"version": "0.4", "axes": [
      {"name": "c", "type": "channel"}, {"name": "y", "type": "space"}, {"name": "x", "type":
      "space"}], "datasets": [{"path": "0"}]}])";
  Write("c.zarr/.zattrs",
        "{" + multiscales + R"(, "omero": {"channels": [{"label": "a"}, {"label": "b"}]}})");
  OpenOptions options = ZarrOptions();
  std::vector<std::string> reported;
  options.on_warning = [&](const std::string& w) { reported.push_back(w); };
  auto source = OpenVolume(dir_ / "c.zarr", options);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().channels[1].name, "b");
  EXPECT_TRUE((*source)->info().warnings.empty());
  EXPECT_TRUE(reported.empty());

  Write("c.zarr/.zattrs", "{" + multiscales + R"(, "omero": {"channels": [{"label": "a"}]}})");
  source = OpenVolume(dir_ / "c.zarr", options);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().channels[0].name, "");
  ASSERT_EQ((*source)->info().warnings.size(), 1u);
  const std::string& w = (*source)->info().warnings[0];
  EXPECT_NE(w.find("c.zarr"), std::string::npos) << w;
  EXPECT_NE(w.find("lists 1 channels, the image has 2"), std::string::npos) << w;
  EXPECT_EQ(reported, (*source)->info().warnings);
}

TEST_F(BadZarr, ShapeLargerThanTheChunksHoldReadsFillWhereChunksAreMissing) {
  // A shape that claims more than the chunk files hold is not an error in Zarr: missing chunks
  // are the fill value. A shape smaller than the chunks is cropped.
  GoodArray();
  Write("a.zarr/.zarray",
        R"({"zarr_format": 2, "shape": [6, 3, 4], "chunks": [2, 4, 4], "dtype": "<u2",
            "compressor": null, "fill_value": 9, "order": "C", "filters": null})");
  auto source = OpenVolume(dir_ / "a.zarr", ZarrOptions());
  ASSERT_TRUE(source.ok());
  std::vector<std::byte> all((*source)->SlabBytes(6));
  ASSERT_TRUE((*source)->ReadSlab(0, 0, 6, all).ok());
  const uint16_t* v = reinterpret_cast<const uint16_t*>(all.data());
  EXPECT_EQ(v[0], 0x0101);
  EXPECT_EQ(v[2 * 12], 0x0202);
  EXPECT_EQ(v[4 * 12], 9);
}

TEST_F(BadZarr, UnsupportedFeaturesAreNamed) {
  struct Case {
    const char* extra;
    const char* expect;
  } cases[] = {
      {R"(, "filters": [{"id": "delta", "dtype": "<u2"}])", "delta"},
  };
  for (const Case& c : cases) {
    Write("a.zarr/.zarray", std::string(R"({"zarr_format": 2, "shape": [4, 4, 4], "chunks": [2,
        4, 4], "dtype": "<u2", "compressor": null, "fill_value": 0)") +
                                c.extra + "}");
    Status s = Read("a.zarr");
    EXPECT_EQ(s.code(), StatusCode::kUnsupported) << s.ToString();
    EXPECT_NE(s.message().find(c.expect), std::string::npos) << s.message();
  }
  Write("b.zarr/.zarray", R"({"zarr_format": 2, "shape": [4, 4], "chunks": [2, 4], "dtype":
      "<i8", "compressor": null, "fill_value": 0, "filters": null})");
  Status s = Read("b.zarr");
  EXPECT_EQ(s.code(), StatusCode::kUnsupported);
  EXPECT_NE(s.message().find("<i8"), std::string::npos) << s.message();
}

TEST_F(BadZarr, DatasetPathsMayNotLeaveTheImage) {
  GoodArray();
  Write("img.zarr/.zgroup", R"({"zarr_format": 2})");
  Write("img.zarr/.zattrs", R"({"multiscales": [{"version": "0.4", "axes": [
      {"name": "z", "type": "space"}, {"name": "y", "type": "space"}, {"name": "x", "type":
      "space"}], "datasets": [{"path": "../a.zarr"}]}]})");
  Status s = Read("img.zarr");
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  EXPECT_NE(s.message().find("../a.zarr"), std::string::npos) << s.message();
}

TEST_F(BadZarr, GroupsThatAreNotImages) {
  Write("g.zarr/.zgroup", R"({"zarr_format": 2})");
  EXPECT_EQ(Read("g.zarr").code(), StatusCode::kUnsupported);
  Write("p.zarr/.zgroup", R"({"zarr_format": 2})");
  Write("p.zarr/.zattrs", R"({"plate": {"rows": [], "columns": []}})");
  Status s = Read("p.zarr");
  EXPECT_EQ(s.code(), StatusCode::kUnsupported);
  EXPECT_NE(s.message().find("plate"), std::string::npos);
  fs::create_directories(dir_ / "empty.zarr");
  EXPECT_EQ(Read("empty.zarr").code(), StatusCode::kNotFound);
}

TEST_F(BadZarr, WithoutTheParserZarrIsUnsupported) {
  GoodArray();
  auto source = OpenVolume(dir_ / "a.zarr", OpenOptions());
  ASSERT_FALSE(source.ok());
  EXPECT_EQ(source.status().code(), StatusCode::kUnsupported);
}

TEST(NgffUnits, LengthUnitsToMicrometres) {
  EXPECT_EQ(MicrometresPerNgffUnit("micrometer"), 1.0);
  EXPECT_EQ(MicrometresPerNgffUnit("nanometer"), 1e-3);
  EXPECT_EQ(MicrometresPerNgffUnit("millimeter"), 1e3);
  EXPECT_EQ(MicrometresPerNgffUnit("angstrom"), 1e-4);
  EXPECT_EQ(MicrometresPerNgffUnit("um"), 1.0);
  EXPECT_FALSE(MicrometresPerNgffUnit("second").has_value());
  EXPECT_FALSE(MicrometresPerNgffUnit("").has_value());
}

// Confined to the store, as the server opens a dataset (issue 28): metadata, level folders and
// chunks that are links out of the store are refused, whether or not their targets exist.
class ZarrConfinedTest : public testing::ConfinedTest {
 protected:
  // A bare Zarr v2 array of 2 planes of 4x4 little-endian uint16, one uncompressed chunk per
  // plane ("0.0.0", "1.0.0") whose samples are z * 100 + the sample's index.
  static void WriteArray(const fs::path& dir) {
    fs::create_directories(dir);
    std::ofstream(dir / ".zarray") << R"({"zarr_format": 2, "shape": [2, 4, 4],
        "chunks": [1, 4, 4], "dtype": "<u2", "compressor": null, "fill_value": 0,
        "order": "C", "filters": null})";
    for (int z = 0; z < 2; ++z) WriteChunk(dir / (std::to_string(z) + ".0.0"), z);
  }
  static void WriteChunk(const fs::path& path, int z) {
    std::string bytes;
    for (int i = 0; i < 16; ++i) {
      const int v = z * 100 + i;
      bytes.push_back(static_cast<char>(v & 0xff));
      bytes.push_back(static_cast<char>(v >> 8));
    }
    std::ofstream(path, std::ios::binary) << bytes;
  }
  // A fresh array own_/`name` whose `entry` is a link to `target`.
  fs::path ArrayWithLink(const std::string& name, const std::string& entry,
                         const fs::path& target) {
    const fs::path store = own_ / name;
    fs::remove_all(store);
    WriteArray(store);
    fs::remove(store / entry);
    fs::create_symlink(target, store / entry);
    return store;
  }
  static std::vector<uint16_t> Plane(VolumeSource& source, int64_t z) {
    std::vector<uint16_t> plane(16);
    const Status s = source.ReadSlab(0, z, 1, std::as_writable_bytes(std::span(plane)));
    EXPECT_TRUE(s.ok()) << s.ToString();
    return plane;
  }
};

TEST_F(ZarrConfinedTest, AChunkLinkedOutFailsItsReadAlikeWhetherOrNotItExists) {
  WriteChunk(outside_ / "chunk", 7);
  for (const fs::path& target : {outside_ / "chunk", outside_ / "none"}) {
    SCOPED_TRACE(target);
    const fs::path store = ArrayWithLink("a.zarr", "1.0.0", target);
    auto source = OpenConfined(store, ZarrOptions());
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    EXPECT_EQ(Plane(**source, 0)[5], 5);
    std::vector<std::byte> out((*source)->SlabBytes(1));
    ExpectRefusal((*source)->ReadSlab(0, 1, 1, out), store);
  }
  // Inside the store: a missing chunk is still the fill value, a linked one is read.
  const fs::path store = own_ / "b.zarr";
  WriteArray(store);
  fs::rename(store / "1.0.0", store / "plane1");
  auto source = OpenConfined(store, ZarrOptions());
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ(Plane(**source, 1)[5], 0);
  fs::create_symlink("plane1", store / "1.0.0");
  EXPECT_EQ(Plane(**source, 1)[5], 105);
}

TEST_F(ZarrConfinedTest, MetadataAndLevelsLinkedOutRefuseTheStoreAlikeWhetherOrNotTheyExist) {
  WriteArray(outside_ / "array");
  for (const fs::path& target : {outside_ / "array", outside_ / "none"}) {
    SCOPED_TRACE(target);
    // The array's own metadata.
    const fs::path bare = ArrayWithLink("bare.zarr", ".zarray", target / ".zarray");
    ExpectRefusal(OpenConfined(bare, ZarrOptions()).status(), bare);
    // An image whose level is a link.
    const fs::path image = own_ / "image.zarr";
    fs::remove_all(image);
    fs::create_directories(image);
    std::ofstream(image / ".zgroup") << R"({"zarr_format": 2})";
    std::ofstream(image / ".zattrs") << R"({"multiscales": [{"version": "0.4",
        "axes": [{"name": "z", "type": "space"}, {"name": "y", "type": "space"},
                 {"name": "x", "type": "space"}],
        "datasets": [{"path": "0", "coordinateTransformations":
                      [{"type": "scale", "scale": [1, 1, 1]}]}]}]})";
    fs::create_directory_symlink(target, image / "0");
    ExpectRefusal(OpenConfined(image, ZarrOptions()).status(), image);
    // A metadata file that may or may not be there decides nothing either.
    fs::remove(image / "0");
    WriteArray(image / "0");
    fs::create_symlink(target / "zarr.json", image / "zarr.json");
    ExpectRefusal(OpenConfined(image, ZarrOptions()).status(), image);
  }
}

TEST_F(ZarrConfinedTest, AnArrayOfAnImageDoesNotLookAboveItsOwnFolder) {
  const fs::path image = own_ / "image.zarr";
  fs::create_directories(image);
  std::ofstream(image / ".zgroup") << R"({"zarr_format": 2})";
  std::ofstream(image / ".zattrs") << R"({"multiscales": [{"version": "0.4",
      "axes": [{"name": "z", "type": "space"}, {"name": "y", "type": "space"},
               {"name": "x", "type": "space", "unit": "micrometer"}],
      "datasets": [{"path": "0", "coordinateTransformations":
                    [{"type": "scale", "scale": [1, 1, 2]}]}]}]})";
  WriteArray(image / "0");
  auto open = OpenVolume(image / "0", ZarrOptions());
  ASSERT_TRUE(open.ok()) << open.status().ToString();
  EXPECT_EQ((*open)->info().format, "ome-zarr");
  auto confined = OpenConfined(image / "0", ZarrOptions());
  ASSERT_TRUE(confined.ok()) << confined.status().ToString();
  EXPECT_EQ((*confined)->info().format, "zarr");
  EXPECT_EQ(Plane(**confined, 1), Plane(**open, 1));
}

}  // namespace
}  // namespace octoscope::io
