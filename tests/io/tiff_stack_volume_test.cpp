// Tests for OpenTiffStack: plain multi-page TIFFs (pages = z, samples = channels), ImageJ
// hyperstacks (including the single-IFD > 4 GB layout, built by hand here), ScanImage, and the
// real NEUBIAS ImageJ files compared with an independent decode of their raw strips.
#include "io/tiff_stack_volume.h"

#include <gtest/gtest.h>
#include <tiffio.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <fstream>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "io/confined_fixture.h"
#include "io/open_volume.h"
#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;
using octoscope::testing::ContainerName;
using octoscope::testing::CountMismatches;
using octoscope::testing::CrossCases;
using octoscope::testing::ExpectErrorNaming;
using octoscope::testing::FixtureCase;
using octoscope::testing::FixtureCompression;
using octoscope::testing::FixtureRoundTrip;
using octoscope::testing::FixtureSamples;
using octoscope::testing::MakeTempDir;
using octoscope::testing::PatternFor;
using octoscope::testing::PatternOf;
using octoscope::testing::ReadAll;
using octoscope::testing::ReadStoredPlane;
using octoscope::testing::Regression;
using octoscope::testing::SampleBytes;
using octoscope::testing::TiffFixtureSpec;
using octoscope::testing::TiffFixtureTest;
using octoscope::testing::WriteAll;
using octoscope::testing::WriteTiffFixture;
using volume::DataType;

const fs::path kTestData = OCTOSCOPE_TESTDATA;

// ---------------------------------------------------------------------------------------------
// Plain stacks: every voxel of every (channel, z) through ReadSlab.

std::vector<FixtureCase> StackCases() {
  const FixtureSamples samples[] = {
      {"c1", 1, 1}, {"chunky3", 3, 1}, {"planar2", 2, 2}, {"chunky4", 4, 1}};
  const FixtureCompression compressions[] = {{"none", COMPRESSION_NONE, false},
                                             {"lzw", COMPRESSION_LZW, false},
                                             {"deflatepred", COMPRESSION_ADOBE_DEFLATE, true},
                                             {"zstd", COMPRESSION_ZSTD, false},
                                             {"packbits", COMPRESSION_PACKBITS, false},
                                             {"lzma", COMPRESSION_LZMA, false}};
  return CrossCases(23, 19, 5, compressions, samples, [](int i, FixtureCase& sc) {
    TiffFixtureSpec& spec = sc.spec;
    spec.big_tiff = (i % 4) >= 2;
    spec.big_endian = (i % 2) == 1;
    const bool tiles = (i / 4) % 2 == 1;
    if (tiles) spec.tile_width = spec.tile_height = 16;
    sc.name += ContainerName(spec) + (tiles ? "_tiles" : "_strips");
  });
}

class TiffStackRoundTrip : public FixtureRoundTrip {};

TEST_P(TiffStackRoundTrip, ReadsEveryVoxel) {
  const FixtureCase& c = GetParam();
  const TiffFixtureSpec& spec = c.spec;
  const DataType type = c.dtype;
  const fs::path path = *dir_ / (c.name + ".tif");
  ASSERT_TRUE(WriteTiffFixture(path, spec, PatternOf(type)));
  auto source = OpenTiffStack(path, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  VolumeSource& v = **source;
  const volume::VolumeInfo& info = v.info();
  EXPECT_EQ(info.format, "tiff");
  EXPECT_EQ(info.size, (std::array<int64_t, 3>{spec.width, spec.height, spec.pages}));
  EXPECT_EQ(info.channel_count(), spec.samples_per_pixel);
  EXPECT_EQ(info.dtype, type);
  EXPECT_EQ(info.series_count, 1);
  EXPECT_EQ(info.time_points, 1);
  EXPECT_FALSE(info.spacing_um[0] || info.spacing_um[1] || info.spacing_um[2]);

  const uint64_t plane_bytes = info.PlaneVoxels() * volume::BytesPerSample(type);
  // Whole stack per channel, then a slab from the middle.
  for (int ch = 0; ch < info.channel_count(); ++ch) {
    std::vector<std::byte> all(v.SlabBytes(spec.pages));
    ASSERT_TRUE(v.ReadSlab(ch, 0, spec.pages, all).ok());
    for (int z = 0; z < spec.pages; ++z) {
      EXPECT_EQ(CountMismatches(std::span(all).subspan(z * plane_bytes, plane_bytes), type,
                                spec.width, spec.height, z, ch),
                0)
          << c.name << " channel " << ch << " z " << z;
    }
  }
  // Stored planes: located exactly for uncompressed strips of single samples (or planar samples)
  // in native byte order, and then equal to what ReadSlab decodes.
  const bool stored = std::endian::native == std::endian::little && spec.compression == 1 &&
                      spec.tile_width == 0 && (!spec.big_endian || spec.bits_per_sample == 8) &&
                      (spec.samples_per_pixel == 1 || spec.planar_config == 2);
  for (int ch = 0; ch < info.channel_count(); ++ch) {
    for (int z : {0, spec.pages - 1}) {
      std::optional<std::vector<std::byte>> plane = ReadStoredPlane(v, ch, z);
      ASSERT_EQ(plane.has_value(), stored) << c.name << " channel " << ch << " z " << z;
      if (!plane) continue;
      std::vector<std::byte> read(v.SlabBytes(1));
      ASSERT_TRUE(v.ReadSlab(ch, z, 1, read).ok());
      EXPECT_EQ(*plane, read) << c.name << " channel " << ch << " z " << z;
    }
  }
  EXPECT_FALSE(v.FindStoredPlane(info.channel_count(), 0).has_value());
  EXPECT_FALSE(v.FindStoredPlane(0, spec.pages).has_value());

  std::vector<std::byte> slab(v.SlabBytes(2));
  ASSERT_TRUE(v.ReadSlab(info.channel_count() - 1, 2, 2, slab).ok());
  EXPECT_EQ(CountMismatches(std::span(slab).first(plane_bytes), type, spec.width, spec.height, 2,
                            info.channel_count() - 1),
            0);
  EXPECT_EQ(CountMismatches(std::span(slab).subspan(plane_bytes), type, spec.width, spec.height, 3,
                            info.channel_count() - 1),
            0);
}

INSTANTIATE_TEST_SUITE_P(AllLayouts, TiffStackRoundTrip, ::testing::ValuesIn(StackCases()),
                         [](const ::testing::TestParamInfo<FixtureCase>& info) {
                           return info.param.name;
                         });

// ---------------------------------------------------------------------------------------------

// Fixtures hold the uint16 pattern (cast to each fixture's sample type).
class TiffStackTest : public TiffFixtureTest {
 protected:
  TiffStackTest() : TiffFixtureTest("tiff-stack", PatternOf(DataType::kUint16)) {}
};

TEST_F(TiffStackTest, PlainSpacingFromCentimetreResolutionOnly) {
  TiffFixtureSpec spec;
  spec.pages = 2;
  spec.x_resolution = 20000;  // Pixels per cm: 0.5 µm.
  spec.y_resolution = 4000;   // 2.5 µm.
  spec.resolution_unit = RESUNIT_CENTIMETER;
  auto cm = OpenTiffStack(Fixture("cm.tif", spec), OpenOptions{});
  ASSERT_TRUE(cm.ok()) << cm.status().ToString();
  ASSERT_TRUE((*cm)->info().spacing_um[0] && (*cm)->info().spacing_um[1]);
  EXPECT_DOUBLE_EQ(*(*cm)->info().spacing_um[0], 0.5);
  EXPECT_DOUBLE_EQ(*(*cm)->info().spacing_um[1], 2.5);
  EXPECT_FALSE((*cm)->info().spacing_um[2]);

  spec.x_resolution = spec.y_resolution = 72;
  spec.resolution_unit = RESUNIT_INCH;
  auto inch = OpenTiffStack(Fixture("inch.tif", spec), OpenOptions{});
  ASSERT_TRUE(inch.ok());
  EXPECT_FALSE((*inch)->info().spacing_um[0] || (*inch)->info().spacing_um[1]);

  spec.resolution_unit = RESUNIT_NONE;
  auto none = OpenTiffStack(Fixture("none.tif", spec), OpenOptions{});
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE((*none)->info().spacing_um[0] || (*none)->info().spacing_um[1]);
}

TEST_F(TiffStackTest, SpacingOverridesAndSeriesAndTime) {
  TiffFixtureSpec spec;
  spec.pages = 3;
  spec.x_resolution = spec.y_resolution = 10000;
  spec.resolution_unit = RESUNIT_CENTIMETER;
  fs::path path = Fixture("override.tif", spec);
  OpenOptions options;
  options.spacing_um = {std::nullopt, 3.0, 7.5};
  auto source = OpenTiffStack(path, options);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_DOUBLE_EQ(*(*source)->info().spacing_um[0], 1.0);  // From the file.
  EXPECT_DOUBLE_EQ(*(*source)->info().spacing_um[1], 3.0);
  EXPECT_DOUBLE_EQ(*(*source)->info().spacing_um[2], 7.5);

  OpenOptions series;
  series.series = 1;
  Status st = OpenTiffStack(path, series).status();
  EXPECT_EQ(st.code(), StatusCode::kOutOfRange);
  ExpectErrorNaming(st, path);
  OpenOptions time;
  time.time = 1;
  st = OpenTiffStack(path, time).status();
  EXPECT_EQ(st.code(), StatusCode::kOutOfRange);
  ExpectErrorNaming(st, path);
}

TEST_F(TiffStackTest, PagesThatDifferAreAnError) {
  TiffFixtureSpec spec;
  spec.pages = 2;
  spec.rows_per_strip = spec.height;
  fs::path path = Fixture("differ.tif", spec);
  // Shrink IFD 1's width in the bytes (little-endian classic; ImageWidth is a SHORT entry).
  std::vector<uint8_t> b = ReadAll(path);
  auto get32 = [&](size_t at) {
    return b[at] | b[at + 1] << 8 | b[at + 2] << 16 | b[at + 3] << 24;
  };
  size_t ifd0 = get32(4);
  size_t ifd1 = get32(ifd0 + 2 + (b[ifd0] | b[ifd0 + 1] << 8) * 12);
  size_t entry = ifd1 + 2;
  while ((b[entry] | b[entry + 1] << 8) != TIFFTAG_IMAGEWIDTH) entry += 12;
  ASSERT_EQ(b[entry + 2], TIFF_SHORT);
  b[entry + 8] = 8;
  b[entry + 9] = 0;
  WriteAll(path, b);
  Status st = OpenTiffStack(path, OpenOptions{}).status();
  ExpectErrorNaming(st, path);
  EXPECT_NE(st.message().find("IFD 1"), std::string::npos) << st.message();
}

TEST_F(TiffStackTest, BadRequestsAreErrors) {
  TiffFixtureSpec spec;
  spec.pages = 3;
  spec.samples_per_pixel = 2;
  fs::path path = Fixture("requests.tif", spec);
  auto source = OpenTiffStack(path, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  VolumeSource& v = **source;
  std::vector<std::byte> one(v.SlabBytes(1)), two(v.SlabBytes(2));
  EXPECT_EQ(v.ReadSlab(2, 0, 1, one).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(v.ReadSlab(-1, 0, 1, one).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(v.ReadSlab(0, 2, 2, two).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(v.ReadSlab(0, -1, 1, one).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(v.ReadSlab(0, 0, 0, one).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(v.ReadSlab(0, 0, 1, two).code(), StatusCode::kInvalidArgument);
  ExpectErrorNaming(v.ReadSlab(0, 3, 1, one), path);
  EXPECT_TRUE(v.ReadSlab(1, 1, 2, two).ok());
}

TEST_F(TiffStackTest, BrokenFilesAreErrors) {
  fs::path empty = dir_ / "empty.tif";
  std::ofstream(empty).close();
  ExpectErrorNaming(OpenTiffStack(empty, OpenOptions{}).status(), empty);

  fs::path text = dir_ / "text.tif";
  std::ofstream(text) << "hello, not a TIFF";
  ExpectErrorNaming(OpenTiffStack(text, OpenOptions{}).status(), text);

  TiffFixtureSpec spec;
  spec.pages = 4;
  fs::path half = Fixture("half.tif", spec);
  std::vector<uint8_t> bytes = ReadAll(half);
  bytes.resize(bytes.size() / 2);
  WriteAll(half, bytes);
  ExpectErrorNaming(OpenTiffStack(half, OpenOptions{}).status(), half);

  // Unsupported sample type (64-bit integers).
  TiffFixtureSpec int64 = spec;
  int64.bits_per_sample = 64;
  int64.sample_format = SAMPLEFORMAT_INT;
  fs::path wide = Fixture("int64.tif", int64);
  Status st = OpenTiffStack(wide, OpenOptions{}).status();
  EXPECT_EQ(st.code(), StatusCode::kUnsupported);
  ExpectErrorNaming(st, wide);
}

TEST_F(TiffStackTest, ConcurrentSlabsAreCorrect) {
  TiffFixtureSpec spec;
  spec.width = 40;
  spec.height = 30;
  spec.pages = 8;
  spec.samples_per_pixel = 3;
  spec.compression = COMPRESSION_LZW;
  fs::path path = Fixture("threads.tif", spec);
  auto source = OpenTiffStack(path, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  VolumeSource* v = source->get();
  std::vector<int> wrong(3, 0);
  std::vector<std::thread> threads;
  for (int ch = 0; ch < 3; ++ch) {
    threads.emplace_back([v, ch, &wrong] {
      const uint64_t plane_bytes = 40 * 30 * 2;
      std::vector<std::byte> slab(v->SlabBytes(2));
      for (int round = 0; round < 5; ++round) {
        for (int z = 0; z < 8; z += 2) {
          if (!v->ReadSlab(ch, z, 2, slab).ok()) {
            ++wrong[ch];
            continue;
          }
          for (int k = 0; k < 2; ++k) {
            for (uint32_t y = 0; y < 30; ++y) {
              for (uint32_t x = 0; x < 40; ++x) {
                auto want =
                    SampleBytes(PatternFor(DataType::kUint16, x, y, z + k, ch), DataType::kUint16);
                if (std::memcmp(&slab[k * plane_bytes + (y * 40 + x) * 2], want.data(), 2) != 0) {
                  ++wrong[ch];
                }
              }
            }
          }
        }
      }
    });
  }
  for (auto& t : threads) t.join();
  for (int ch = 0; ch < 3; ++ch) EXPECT_EQ(wrong[ch], 0) << "channel " << ch;
}

// ---------------------------------------------------------------------------------------------
// ImageJ.

// Opens time point t of the stack at `path`, with default options otherwise.
Result<std::unique_ptr<VolumeSource>> OpenAtTime(const fs::path& path, int t) {
  OpenOptions options;
  options.time = t;
  return OpenTiffStack(path, options);
}

TEST(ImageJDescriptionTest, Parses) {
  auto d = ParseImageJDescription(
      "ImageJ=1.54f\nimages=90\nchannels=2\nslices=45\nhyperstack=true\nmode=color\n"
      "unit=\\u00B5m\nspacing=0.4994126016284111\nfinterval=2.5\nloop=false\nmin=0.0\n");
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->images, 90);
  EXPECT_EQ(d->channels, 2);
  EXPECT_EQ(d->slices, 45);
  EXPECT_EQ(d->frames, 0);
  EXPECT_TRUE(d->hyperstack);
  EXPECT_EQ(d->unit, "\xC2\xB5m");
  ASSERT_TRUE(d->spacing.has_value());
  EXPECT_DOUBLE_EQ(*d->spacing, 0.4994126016284111);
  EXPECT_DOUBLE_EQ(d->finterval.value_or(0), 2.5);
  EXPECT_FALSE(ParseImageJDescription("<?xml version=\"1.0\"?><OME/>").has_value());
  EXPECT_FALSE(ParseImageJDescription("").has_value());
  // Garbage values are ignored, not trusted.
  auto g = ParseImageJDescription("ImageJ=\nimages=lots\nspacing=wide\n");
  ASSERT_TRUE(g.has_value());
  EXPECT_EQ(g->images, 0);
  EXPECT_FALSE(g->spacing.has_value());
}

TEST(ImageJDescriptionTest, Units) {
  EXPECT_EQ(MicrometresPerUnit("micron"), 1.0);
  EXPECT_EQ(MicrometresPerUnit("um"), 1.0);
  EXPECT_EQ(MicrometresPerUnit("\xC2\xB5m"), 1.0);
  EXPECT_EQ(MicrometresPerUnit("nm"), 1e-3);
  EXPECT_EQ(MicrometresPerUnit("mm"), 1e3);
  EXPECT_EQ(MicrometresPerUnit("cm"), 1e4);
  EXPECT_EQ(MicrometresPerUnit("pixel"), std::nullopt);
  EXPECT_EQ(MicrometresPerUnit(""), std::nullopt);
}

TEST_F(TiffStackTest, ImageJHyperstack) {
  // C=2, Z=3, T=4; pages ordered C fastest, then Z, then T.
  TiffFixtureSpec spec;
  spec.width = 21;
  spec.height = 13;
  spec.pages = 24;
  spec.big_endian = true;
  spec.descriptions = {
      "ImageJ=1.54f\nimages=24\nchannels=2\nslices=3\nframes=4\nhyperstack=true\n"
      "unit=nm\nspacing=750\nfinterval=2.5\nloop=false\n"};
  spec.x_resolution = 0.002;  // Pixels per nm: 500 nm = 0.5 µm.
  spec.y_resolution = 0.004;
  spec.resolution_unit = RESUNIT_NONE;
  fs::path path = Fixture("hyper.tif", spec);
  for (int t = 0; t < 4; ++t) {
    auto source = OpenAtTime(path, t);
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    const volume::VolumeInfo& info = (*source)->info();
    EXPECT_EQ(info.format, "imagej-tiff");
    EXPECT_EQ(info.size, (std::array<int64_t, 3>{21, 13, 3}));
    EXPECT_EQ(info.channel_count(), 2);
    EXPECT_EQ(info.time_points, 4);
    EXPECT_EQ(info.time, t);
    EXPECT_EQ(info.dtype, DataType::kUint16);
    EXPECT_NEAR(info.spacing_um[0].value_or(0), 0.5, 1e-6);
    EXPECT_NEAR(info.spacing_um[1].value_or(0), 0.25, 1e-6);
    EXPECT_NEAR(info.spacing_um[2].value_or(0), 0.75, 1e-12);
    const uint64_t plane_bytes = 21 * 13 * 2;
    for (int c = 0; c < 2; ++c) {
      std::vector<std::byte> slab((*source)->SlabBytes(3));
      ASSERT_TRUE((*source)->ReadSlab(c, 0, 3, slab).ok());
      for (int z = 0; z < 3; ++z) {
        const int page = c + 2 * (z + 3 * t);
        EXPECT_EQ(CountMismatches(std::span(slab).subspan(z * plane_bytes, plane_bytes),
                                  DataType::kUint16, 21, 13, page, 0),
                  0)
            << "c " << c << " z " << z << " t " << t;
      }
    }
  }
  OpenOptions late;
  late.time = 4;
  Status st = OpenTiffStack(path, late).status();
  EXPECT_EQ(st.code(), StatusCode::kOutOfRange);
  ExpectErrorNaming(st, path);
}

TEST_F(TiffStackTest, ImageJRgbAndPlainImageCount) {
  // images=N alone: a z stack; 3 samples per pixel become channels.
  TiffFixtureSpec spec;
  spec.pages = 4;
  spec.samples_per_pixel = 3;
  spec.bits_per_sample = 8;
  spec.descriptions = {"ImageJ=1.53t\nimages=4\nunit=micron\nspacing=2.0\n"};
  fs::path path = Fixture("rgb.tif", spec);
  auto source = OpenTiffStack(path, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().size[2], 4);
  EXPECT_EQ((*source)->info().channel_count(), 3);
  EXPECT_DOUBLE_EQ((*source)->info().spacing_um[2].value_or(0), 2.0);
  EXPECT_FALSE((*source)->info().spacing_um[0]);  // No resolution tags.
  std::vector<std::byte> slab((*source)->SlabBytes(4));
  ASSERT_TRUE((*source)->ReadSlab(2, 0, 4, slab).ok());
  for (int z = 0; z < 4; ++z) {
    EXPECT_EQ(
        CountMismatches(std::span(slab).subspan(z * 16 * 8, 16 * 8), DataType::kUint8, 16, 8, z, 2),
        0);
  }
}

TEST_F(TiffStackTest, ImageJInconsistentCountsAreErrors) {
  TiffFixtureSpec spec;
  spec.pages = 6;
  spec.descriptions = {"ImageJ=1.54f\nimages=5\nchannels=2\nslices=3\n"};
  fs::path mismatch = Fixture("mismatch.tif", spec);
  Status st = OpenTiffStack(mismatch, OpenOptions{}).status();
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  ExpectErrorNaming(st, mismatch);

  // More images declared than the file's IFDs hold (and more than one IFD).
  spec.descriptions = {"ImageJ=1.54f\nimages=12\nchannels=2\nslices=6\n"};
  fs::path missing = Fixture("missing.tif", spec);
  st = OpenTiffStack(missing, OpenOptions{}).status();
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  ExpectErrorNaming(st, missing);
}

// Bug: ImageJ counts sized allocations before the file was consulted: images=10^12 reserved a
// plane table of 8 TB (bad_alloc), channels=2*10^8 a channel list of 9 GB. Claims are now checked
// against what the file can hold, and channels capped, before anything is allocated.
TEST_F(TiffStackTest, ImageJCountsBeyondTheFileAreRefusedBeforeAllocating) {
  for (auto [name, code] : {std::pair{"imagej-images-bad-alloc.tif", StatusCode::kCorrupt},
                            {"imagej-channels-9gb-table.tif", StatusCode::kResourceExhausted}}) {
    const fs::path path = Regression(name);
    Status st = OpenTiffStack(path, OpenOptions{}).status();
    EXPECT_EQ(st.code(), code) << st.ToString();
    ExpectErrorNaming(st, path);
  }
  TiffFixtureSpec spec;
  spec.pages = 2;
  struct Case {
    const char* description;
    const char* needle;
    StatusCode code = StatusCode::kCorrupt;
  };
  const Case cases[] = {
      {"ImageJ=1.54f\nimages=1000000000000\n", "can hold at most"},
      {"ImageJ=1.54f\nimages=9223372036854775807\n", "can hold at most"},
      {"ImageJ=1.54f\nchannels=200000000\nimages=200000000\n",
       "channels=200000000: 200000000 channels, more than the 64", StatusCode::kResourceExhausted},
      {"ImageJ=1.54f\nchannels=65\n", "channels=65: 65 channels, more than the 64",
       StatusCode::kResourceExhausted},
      {"ImageJ=1.54f\nslices=4294967296\nframes=4294967296\n", "can hold at most"},
      {"ImageJ=1.54f\nchannels=2\nslices=2\n", "can hold at most 2 images"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.description);
    spec.descriptions = {c.description};
    const fs::path path = Fixture("counts.tif", spec);
    Status st = OpenTiffStack(path, OpenOptions{}).status();
    EXPECT_EQ(st.code(), c.code) << st.ToString();
    ExpectErrorNaming(st, path);
    EXPECT_NE(st.message().find(c.needle), std::string::npos) << st.ToString();
  }
  // Counts the file does hold still open.
  spec.descriptions = {"ImageJ=1.54f\nchannels=2\nimages=2\n"};
  auto ok = OpenTiffStack(Fixture("two.tif", spec), OpenOptions{});
  ASSERT_TRUE(ok.ok()) << ok.status().ToString();
  EXPECT_EQ((*ok)->info().channel_count(), 2);
}

// Bug: ScanImage products (channels x frames x slices, fly-back) overflowed to 0 and the page count
// was divided by it (SIGFPE). Metadata that overflows or needs more pages than the file has is
// ignored: the file opens as a plain stack.
TEST_F(TiffStackTest, ScanImageMetadataThatDoesNotFitOpensAsAPlainStack) {
  {
    const fs::path path = Regression("scanimage-div-by-zero.tif");
    auto source = OpenTiffStack(path, OpenOptions{});
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    EXPECT_EQ((*source)->info().size[2], 1);
    EXPECT_EQ((*source)->info().channel_count(), 1);
  }
  std::string channels64 = "[1";
  for (int c = 2; c <= 64; ++c) {
    channels64 += ';';  // Not `";" + to_string`: GCC 12 warns (-Wrestrict) on that falsely.
    channels64 += std::to_string(c);
  }
  channels64 += "]";
  TiffFixtureSpec spec;
  spec.pages = 4;
  struct Case {
    std::string metadata;
    int64_t z, channels, time_points;  // Expected: ScanImage's layout, or the plain 4 x 1 x 1.
  };
  const Case cases[] = {
      // Fits: 2 channels x 2 slices, one volume (shows metadata in the description is used).
      {"SI.hChannels.channelSave = [1;2]\nSI.hStackManager.enable = true\n"
       "SI.hStackManager.actualNumSlices = 2\n",
       2, 2, 1},
      // 64 x 2^29 x 2^29 wraps to 0 in 64 bits.
      {"SI.hChannels.channelSave = " + channels64 +
           "\nSI.hStackManager.enable = true\nSI.hStackManager.actualNumSlices = 536870912\n"
           "SI.hStackManager.framesPerSlice = 536870912\n",
       4, 1, 1},
      // More channels than pages.
      {"SI.hChannels.channelSave = [1;2;3;4;5]\n", 4, 1, 1},
      // Fly-back frames that make a volume longer than the file.
      {"SI.hChannels.channelSave = [1]\nSI.hFastZ.enable = true\n"
       "SI.hStackManager.actualNumSlices = 2\n"
       "SI.hStackManager.numFramesPerVolumeWithFlyback = 999999999\n",
       4, 1, 1},
      // Fly-back that fits: 2 slices + 1 fly-back frame per volume, one volume in 4 pages.
      {"SI.hChannels.channelSave = [1]\nSI.hFastZ.enable = true\n"
       "SI.hStackManager.actualNumSlices = 2\n"
       "SI.hStackManager.numFramesPerVolumeWithFlyback = 3\n",
       2, 1, 1},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.metadata);
    spec.descriptions = {c.metadata};
    const fs::path path = Fixture("si.tif", spec);
    auto source = OpenTiffStack(path, OpenOptions{});
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    EXPECT_EQ((*source)->info().size[2], c.z);
    EXPECT_EQ((*source)->info().channel_count(), c.channels);
    EXPECT_EQ((*source)->info().time_points, c.time_points);
    // Metadata that does not fit is ignored with a warning, never quietly.
    const bool plain = c.z == 4;
    ASSERT_EQ((*source)->info().warnings.size(), plain ? 1u : 0u);
    if (plain) {
      const std::string& warning = (*source)->info().warnings[0];
      EXPECT_NE(warning.find(path.string()), std::string::npos) << warning;
      EXPECT_NE(warning.find("ScanImage metadata does not fit"), std::string::npos) << warning;
    }
  }
}

// Builds an ImageJ file as ImageJ writes one > 4 GB: a single IFD right after the header, then
// the pixel data of all `images` uint16 images back to back (the IFD describes only the first).
struct ContiguousFile {
  uint32_t width = 11, height = 7;
  int images = 12;
  bool big_endian = true;
  std::string description;
  static uint16_t Value(int image, uint32_t x, uint32_t y) {
    return static_cast<uint16_t>(image * 4099 + y * 37 + x * 3 + 1);
  }

  std::vector<uint8_t> Build() const {
    std::vector<uint8_t> b;
    auto u16 = [&](uint32_t v) {
      if (big_endian) {
        b.push_back(static_cast<uint8_t>(v >> 8));
        b.push_back(static_cast<uint8_t>(v));
      } else {
        b.push_back(static_cast<uint8_t>(v));
        b.push_back(static_cast<uint8_t>(v >> 8));
      }
    };
    auto u32 = [&](uint32_t v) {
      if (big_endian) {
        u16(v >> 16);
        u16(v & 0xFFFF);
      } else {
        u16(v & 0xFFFF);
        u16(v >> 16);
      }
    };
    const uint32_t entries = 12;
    const uint32_t ifd = 8;
    const uint32_t text = ifd + 2 + entries * 12 + 4;
    const uint32_t text_size = static_cast<uint32_t>(description.size()) + 1;
    const uint32_t rational = (text + text_size + 1) & ~1u;
    const uint32_t data = rational + 16;
    const uint32_t plane = width * height * 2;
    b.push_back(big_endian ? 'M' : 'I');
    b.push_back(big_endian ? 'M' : 'I');
    u16(42);
    u32(ifd);
    u16(entries);
    auto entry = [&](uint16_t tag, uint16_t type, uint32_t count, uint32_t value) {
      u16(tag);
      u16(type);
      u32(count);
      if (type == TIFF_SHORT && count == 1) {
        u16(value);
        u16(0);
      } else {
        u32(value);
      }
    };
    entry(TIFFTAG_IMAGEWIDTH, TIFF_SHORT, 1, width);
    entry(TIFFTAG_IMAGELENGTH, TIFF_SHORT, 1, height);
    entry(TIFFTAG_BITSPERSAMPLE, TIFF_SHORT, 1, 16);
    entry(TIFFTAG_COMPRESSION, TIFF_SHORT, 1, COMPRESSION_NONE);
    entry(TIFFTAG_PHOTOMETRIC, TIFF_SHORT, 1, PHOTOMETRIC_MINISBLACK);
    entry(TIFFTAG_IMAGEDESCRIPTION, TIFF_ASCII, text_size, text);
    entry(TIFFTAG_STRIPOFFSETS, TIFF_LONG, 1, data);
    entry(TIFFTAG_SAMPLESPERPIXEL, TIFF_SHORT, 1, 1);
    entry(TIFFTAG_ROWSPERSTRIP, TIFF_SHORT, 1, height);
    entry(TIFFTAG_STRIPBYTECOUNTS, TIFF_LONG, 1, plane);
    entry(TIFFTAG_XRESOLUTION, TIFF_RATIONAL, 1, rational);
    entry(TIFFTAG_YRESOLUTION, TIFF_RATIONAL, 1, rational + 8);
    u32(0);  // No next IFD.
    for (char ch : description) b.push_back(static_cast<uint8_t>(ch));
    b.push_back(0);
    while (b.size() < rational) b.push_back(0);
    u32(5);  // 5 pixels per unit: 0.2 units.
    u32(1);
    u32(5);
    u32(2);  // 2.5 pixels per unit: 0.4 units.
    for (int i = 0; i < images; ++i) {
      for (uint32_t y = 0; y < height; ++y) {
        for (uint32_t x = 0; x < width; ++x) u16(Value(i, x, y));
      }
    }
    return b;
  }
};

TEST_F(TiffStackTest, ImageJSingleIfdContiguousImages) {
  for (bool big_endian : {true, false}) {
    ContiguousFile spec;
    spec.big_endian = big_endian;
    spec.description =
        "ImageJ=1.54f\nimages=12\nchannels=2\nslices=3\nframes=2\nhyperstack=true\n"
        "unit=micron\nspacing=1.5\nloop=false\n";
    fs::path path = dir_ / (big_endian ? "contig_be.tif" : "contig_le.tif");
    WriteAll(path, spec.Build());
    auto file = TiffFile::Open(path);
    ASSERT_TRUE(file.ok()) << file.status().ToString();
    ASSERT_EQ((*file)->ifd_count(), 1);
    for (int t = 0; t < 2; ++t) {
      auto source = OpenAtTime(path, t);
      ASSERT_TRUE(source.ok()) << source.status().ToString();
      const volume::VolumeInfo& info = (*source)->info();
      EXPECT_EQ(info.format, "imagej-tiff");
      EXPECT_EQ(info.size, (std::array<int64_t, 3>{11, 7, 3}));
      EXPECT_EQ(info.channel_count(), 2);
      EXPECT_EQ(info.time_points, 2);
      EXPECT_NEAR(info.spacing_um[0].value_or(0), 0.2, 1e-12);
      EXPECT_NEAR(info.spacing_um[1].value_or(0), 0.4, 1e-12);
      EXPECT_NEAR(info.spacing_um[2].value_or(0), 1.5, 1e-12);
      for (int c = 0; c < 2; ++c) {
        std::vector<std::byte> slab((*source)->SlabBytes(3));
        ASSERT_TRUE((*source)->ReadSlab(c, 0, 3, slab).ok());
        int wrong = 0;
        for (int z = 0; z < 3; ++z) {
          const int image = c + 2 * (z + 3 * t);
          for (uint32_t y = 0; y < 7; ++y) {
            for (uint32_t x = 0; x < 11; ++x) {
              uint16_t got;
              std::memcpy(&got, &slab[((z * 7 + y) * 11 + x) * 2], 2);
              if (got != ContiguousFile::Value(image, x, y)) ++wrong;
            }
          }
        }
        EXPECT_EQ(wrong, 0) << "c " << c << " t " << t;
        // The images are raw runs of the file: stored as read when in native byte order.
        for (int z = 0; z < 3; ++z) {
          std::optional<std::vector<std::byte>> plane = ReadStoredPlane(**source, c, z);
          ASSERT_EQ(plane.has_value(), big_endian == (std::endian::native == std::endian::big));
          if (plane) {
            EXPECT_EQ(*plane, std::vector<std::byte>(slab.begin() + z * 11 * 7 * 2,
                                                     slab.begin() + (z + 1) * 11 * 7 * 2));
          }
        }
        // A single-plane slab from the middle.
        std::vector<std::byte> one((*source)->SlabBytes(1));
        ASSERT_TRUE((*source)->ReadSlab(c, 2, 1, one).ok());
        uint16_t first;
        std::memcpy(&first, one.data(), 2);
        EXPECT_EQ(first, ContiguousFile::Value(c + 2 * (2 + 3 * t), 0, 0));
      }
    }

    // Cut off the last image: the declared images no longer fit.
    std::vector<uint8_t> bytes = spec.Build();
    bytes.resize(bytes.size() - 11 * 7 * 2 + 3);
    fs::path cut = dir_ / (big_endian ? "cut_be.tif" : "cut_le.tif");
    WriteAll(cut, bytes);
    Status st = OpenTiffStack(cut, OpenOptions{}).status();
    EXPECT_EQ(st.code(), StatusCode::kCorrupt);
    ExpectErrorNaming(st, cut);
    EXPECT_NE(st.message().find("truncated"), std::string::npos) << st.message();
  }
}

// ---------------------------------------------------------------------------------------------
// Real files.

// An independent reader for the classic, uncompressed, single-sample TIFFs ImageJ writes: walks
// the IFD chain and returns, per IFD, the raw strips of the plane in native byte order.
struct RawPlane {
  uint32_t width = 0, height = 0, bits = 0;
  std::vector<uint8_t> data;
};

std::vector<RawPlane> DecodeUncompressedTiff(const fs::path& path) {
  const std::vector<uint8_t> b = ReadAll(path);
  std::vector<RawPlane> planes;
  if (b.size() < 8) return planes;
  const bool be = b[0] == 'M';
  auto get = [&](size_t at, int n) {
    uint32_t v = 0;
    for (int i = 0; i < n; ++i) v = (v << 8) | b.at(at + (be ? i : n - 1 - i));
    return v;
  };
  // The values of an entry (SHORT or LONG), inline or at an offset.
  auto values = [&](size_t entry) {
    const uint32_t type = get(entry + 2, 2), count = get(entry + 4, 4);
    const int size = type == TIFF_SHORT ? 2 : 4;
    const size_t at = count * size <= 4 ? entry + 8 : get(entry + 8, 4);
    std::vector<uint32_t> out;
    for (uint32_t i = 0; i < count; ++i) out.push_back(get(at + i * size, size));
    return out;
  };
  size_t ifd = get(4, 4);
  while (ifd != 0 && planes.size() < 10000) {
    const uint32_t n = get(ifd, 2);
    RawPlane p;
    std::vector<uint32_t> offsets, counts;
    for (uint32_t i = 0; i < n; ++i) {
      const size_t e = ifd + 2 + i * 12;
      const uint32_t tag = get(e, 2);
      if (tag == TIFFTAG_IMAGEWIDTH) p.width = values(e)[0];
      if (tag == TIFFTAG_IMAGELENGTH) p.height = values(e)[0];
      if (tag == TIFFTAG_BITSPERSAMPLE) p.bits = values(e)[0];
      if (tag == TIFFTAG_STRIPOFFSETS) offsets = values(e);
      if (tag == TIFFTAG_STRIPBYTECOUNTS) counts = values(e);
    }
    for (size_t s = 0; s < offsets.size() && s < counts.size(); ++s) {
      p.data.insert(p.data.end(), b.begin() + offsets[s], b.begin() + offsets[s] + counts[s]);
    }
    const size_t bytes = p.bits / 8;
    if (be && bytes > 1) {
      for (size_t i = 0; i + bytes <= p.data.size(); i += bytes) {
        std::reverse(p.data.begin() + i, p.data.begin() + i + bytes);
      }
    }
    planes.push_back(std::move(p));
    ifd = get(ifd + 2 + n * 12, 4);
  }
  return planes;
}

struct NeubiasCase {
  const char* file;
  int64_t z, c, y, x;
  DataType dtype;
  double xy_um, z_um;
};

TEST(TiffStackRealTest, NeubiasImageJFiles) {
  const NeubiasCase cases[] = {
      {"xyzc_16bit__dna_conf_wf.tif", 45, 2, 130, 133, DataType::kUint16, 0.512, 0.499},
      {"xyzc_16bit__spots.tif", 17, 2, 88, 89, DataType::kUint16, 0.094, 0.4},
      // SOURCES.md gives no spacing for these two; the values are the files' own
      // (1/XResolution micron, spacing=).
      {"xyz_8bit__nuclei_autothresh.tif", 37, 1, 118, 132, DataType::kUint8, 1 / 1.20679, 4.0},
      {"xyz_calibrated_16bit__golgi_bfa.tif", 25, 1, 137, 147, DataType::kUint16, 1 / 2.84547,
       0.3876},
  };
  for (const NeubiasCase& nc : cases) {
    SCOPED_TRACE(nc.file);
    const fs::path path = kTestData / "neubias" / nc.file;
    auto source = OpenTiffStack(path, OpenOptions{});
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    const volume::VolumeInfo& info = (*source)->info();
    EXPECT_EQ(info.format, "imagej-tiff");
    EXPECT_EQ(info.size, (std::array<int64_t, 3>{nc.x, nc.y, nc.z}));
    EXPECT_EQ(info.channel_count(), nc.c);
    EXPECT_EQ(info.dtype, nc.dtype);
    EXPECT_EQ(info.time_points, 1);
    ASSERT_TRUE(info.spacing_um[0] && info.spacing_um[1] && info.spacing_um[2]);
    EXPECT_NEAR(*info.spacing_um[0], nc.xy_um, 1e-3);
    EXPECT_NEAR(*info.spacing_um[1], nc.xy_um, 1e-3);
    EXPECT_NEAR(*info.spacing_um[2], nc.z_um, 1e-3);

    const std::vector<RawPlane> raw = DecodeUncompressedTiff(path);
    ASSERT_EQ(static_cast<int64_t>(raw.size()), nc.z * nc.c);
    const uint64_t plane_bytes = info.PlaneVoxels() * volume::BytesPerSample(nc.dtype);
    for (int c = 0; c < nc.c; ++c) {
      for (int64_t z : {int64_t{0}, nc.z / 2, nc.z - 2}) {
        std::vector<std::byte> slab((*source)->SlabBytes(2));
        ASSERT_TRUE((*source)->ReadSlab(c, z, 2, slab).ok());
        for (int k = 0; k < 2; ++k) {
          const RawPlane& want = raw[(z + k) * nc.c + c];  // C fastest, then Z.
          ASSERT_EQ(want.data.size(), plane_bytes);
          EXPECT_EQ(std::memcmp(slab.data() + k * plane_bytes, want.data.data(), plane_bytes), 0)
              << "c " << c << " z " << z + k;
        }
      }
    }
  }
}

TEST(TiffStackRealTest, ScanImageBigTiffChannelsAndTime) {
  const fs::path path = kTestData / "real_ometiff_misc/ScanImageBigTIFFv57.tif";
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  for (int t = 0; t < 2; ++t) {
    auto source = OpenAtTime(path, t);
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    const volume::VolumeInfo& info = (*source)->info();
    EXPECT_EQ(info.size, (std::array<int64_t, 3>{64, 64, 1}));
    EXPECT_EQ(info.channel_count(), 2);
    EXPECT_EQ(info.time_points, 2);
    EXPECT_EQ(info.dtype, DataType::kInt16);
    // 2370.37 pixels per cm.
    EXPECT_NEAR(info.spacing_um[0].value_or(0), 1e4 / 2370.37, 1e-3);
    EXPECT_FALSE(info.spacing_um[2]);
    // TCYX: channel c of time t is page c + 2 t.
    for (int c = 0; c < 2; ++c) {
      std::vector<std::byte> slab((*source)->SlabBytes(1)), page(64 * 64 * 2);
      ASSERT_TRUE((*source)->ReadSlab(c, 0, 1, slab).ok());
      ASSERT_TRUE((*file)->ReadPlane(c + 2 * t, 0, page).ok());
      EXPECT_EQ(slab, page) << "c " << c << " t " << t;
    }
  }
  // The four pages are distinct images (so the mapping above is actually tested).
  std::vector<std::vector<std::byte>> pages(4, std::vector<std::byte>(64 * 64 * 2));
  for (int i = 0; i < 4; ++i) ASSERT_TRUE((*file)->ReadPlane(i, 0, pages[i]).ok());
  for (int i = 0; i < 4; ++i) {
    for (int j = i + 1; j < 4; ++j) EXPECT_NE(pages[i], pages[j]) << i << " vs " << j;
  }
  OpenOptions late;
  late.time = 2;
  ExpectErrorNaming(OpenTiffStack(path, late).status(), path);
}

// Issue 8: a 201-byte TIFF of 4x4 pixels claiming 65,279 samples per pixel opened as a
// 65,279-channel volume. A plain stack's samples are its channels, so the count is refused with
// the limit stated (volume::kMaxChannels), by every route that opens the file.
TEST(TiffStackVolumeTest, AbsurdSampleCountsAreRefusedWithTheChannelLimit) {
  const fs::path path = Regression("plain-tiff-65279-samples-per-pixel.tif");
  for (const Status& st :
       {OpenTiffStack(path, OpenOptions{}).status(), OpenVolume(path, OpenOptions{}).status()}) {
    EXPECT_EQ(st.code(), StatusCode::kResourceExhausted) << st.ToString();
    ExpectErrorNaming(st, path);
    EXPECT_NE(st.message().find("65279 samples per pixel"), std::string::npos) << st.ToString();
    EXPECT_NE(st.message().find("more than the 64 Octoscope supports"), std::string::npos)
        << st.ToString();
  }
  // 64 samples per pixel are 64 channels, each read right.
  const fs::path dir = MakeTempDir("many-samples");
  TiffFixtureSpec spec;
  spec.width = 5;
  spec.height = 3;
  spec.pages = 2;
  spec.samples_per_pixel = 64;
  spec.compression = COMPRESSION_LZW;
  ASSERT_TRUE(
      testing::WriteTiffFixture(dir / "s64.tif", spec, PatternOf(volume::DataType::kUint16)));
  auto source = OpenTiffStack(dir / "s64.tif", OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  ASSERT_EQ((*source)->info().channel_count(), 64);
  std::vector<std::byte> plane((*source)->SlabBytes(1));
  for (int c = 0; c < 64; ++c) {
    for (int z = 0; z < 2; ++z) {
      ASSERT_TRUE((*source)->ReadSlab(c, z, 1, plane).ok());
      EXPECT_EQ(CountMismatches(plane, volume::DataType::kUint16, 5, 3, z, c), 0);
    }
  }
  spec.samples_per_pixel = 65;
  ASSERT_TRUE(testing::WriteTiffFixture(dir / "s65.tif", spec));
  Status st = OpenTiffStack(dir / "s65.tif", OpenOptions{}).status();
  EXPECT_EQ(st.code(), StatusCode::kResourceExhausted) << st.ToString();
  fs::remove_all(dir);
}

// Confined to its own folder, as the server opens a dataset (issue 28): a stack that is a link
// into another folder is refused, whether or not its target exists; one within the folder opens.
class TiffStackConfinedTest : public testing::ConfinedTest {};

TEST_F(TiffStackConfinedTest, AStackLinkedOutIsRefusedAlikeWhetherOrNotItsTargetExists) {
  ASSERT_TRUE(testing::WriteTiffFixture(outside_ / "stack.tif", testing::TiffFixtureSpec{}));
  ASSERT_TRUE(testing::WriteTiffFixture(own_ / "mine.tif", testing::TiffFixtureSpec{}));
  fs::create_symlink("mine.tif", own_ / "same.tif");
  auto same = OpenConfined(own_ / "same.tif");
  ASSERT_TRUE(same.ok()) << same.status().ToString();
  for (const fs::path& target : {fs::path("../outside/stack.tif"), fs::path("../outside/none.tif"),
                                 outside_ / "stack.tif", outside_ / "none.tif"}) {
    const fs::path link = own_ / "link.tif";
    fs::remove(link);
    fs::create_symlink(target, link);
    ExpectRefusal(OpenConfined(link).status(), link);
  }
}

}  // namespace
}  // namespace octoscope::io
