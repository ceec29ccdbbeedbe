#include "io/slice_folder_volume.h"

#include <gtest/gtest.h>
#include <tiffio.h>

#include <array>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "io/confined_fixture.h"
#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

const std::filesystem::path kCellfinder =
    std::filesystem::path(OCTOSCOPE_TESTDATA) / "cellfinder_crop_planes";

// Independent decode of one cellfinder plane: uncompressed, one strip, big-endian uint16. libtiff
// only tells where the strip lies; the bytes are read and byte-swapped here.
std::vector<uint16_t> DecodeCellfinderPlane(const std::filesystem::path& path) {
  // "c": no strip chopping, so the file's single strip is reported as it is. Warnings about
  // ImageJ's private tags are silenced for this handle only.
  TIFFOpenOptions* options = TIFFOpenOptionsAlloc();
  TIFFOpenOptionsSetWarningHandlerExtR(
      options, [](TIFF*, void*, const char*, const char*, va_list) { return 1; }, nullptr);
  TIFF* tif = TIFFOpenExt(path.c_str(), "rc", options);
  TIFFOpenOptionsFree(options);
  if (tif == nullptr) {
    ADD_FAILURE() << "libtiff cannot open " << path;
    return {};
  }
  uint32_t width = 0, height = 0;
  uint16_t compression = 0, bits = 0;
  uint64_t* offsets = nullptr;
  uint64_t* counts = nullptr;
  TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &width);
  TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &height);
  TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &compression);
  TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetField(tif, TIFFTAG_STRIPOFFSETS, &offsets);
  TIFFGetField(tif, TIFFTAG_STRIPBYTECOUNTS, &counts);
  const bool big_endian = TIFFIsBigEndian(tif);
  const uint32_t strips = TIFFNumberOfStrips(tif);
  const uint64_t offset = offsets ? offsets[0] : 0;
  const uint64_t count = counts ? counts[0] : 0;
  TIFFClose(tif);
  EXPECT_EQ(width, 667u);
  EXPECT_EQ(height, 510u);
  EXPECT_EQ(compression, COMPRESSION_NONE);
  EXPECT_EQ(bits, 16);
  EXPECT_EQ(strips, 1u);
  EXPECT_TRUE(big_endian);
  EXPECT_EQ(count, 667u * 510u * 2u);

  std::ifstream in(path, std::ios::binary);
  in.seekg(static_cast<std::streamoff>(offset));
  std::vector<unsigned char> bytes(667 * 510 * 2);
  in.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  EXPECT_TRUE(in.good()) << path;
  std::vector<uint16_t> plane(667 * 510);
  for (size_t i = 0; i < plane.size(); ++i) {
    plane[i] = static_cast<uint16_t>((bytes[2 * i] << 8) | bytes[2 * i + 1]);
  }
  return plane;
}

std::filesystem::path CellfinderFile(int channel, int z) {
  char name[32];
  std::snprintf(name, sizeof(name), "ch%d/ch%d%04d.tif", channel, channel, z);
  return kCellfinder / name;
}

// printf-style file name (GCC 12 warns falsely on `"p" + std::to_string(z) + ".tif"`).
std::string Name(const char* pattern, int a, int b = 0, int c = 0) {
  char name[64];
  std::snprintf(name, sizeof(name), pattern, a, b, c);
  return name;
}

std::vector<uint16_t> ReadPlanes16(VolumeSource& source, int channel, int64_t z0, int64_t nz) {
  std::vector<uint16_t> out(static_cast<size_t>(source.SlabBytes(nz) / 2));
  Status s = source.ReadSlab(channel, z0, nz, std::as_writable_bytes(std::span<uint16_t>(out)));
  EXPECT_TRUE(s.ok()) << s.ToString();
  return out;
}

TEST(SliceFolderCellfinderTest, OpensAsTwoChannelStack) {
  auto source = OpenSliceFolder(kCellfinder, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  const volume::VolumeInfo& info = (*source)->info();
  EXPECT_EQ(info.format, "slice-folder");
  EXPECT_EQ(info.size, (std::array<int64_t, 3>{667, 510, 30}));
  ASSERT_EQ(info.channel_count(), 2);
  EXPECT_EQ(info.channels[0].name, "ch0");
  EXPECT_EQ(info.channels[1].name, "ch1");
  EXPECT_EQ(info.dtype, volume::DataType::kUint16);
  // Every file says "Resolution: 1, 1 (unitless)" and ImageJ "unit=" (empty): no usable spacing.
  // (The 5x2x2 µm of SOURCES.md comes from cellfinder's test code, not from the files.)
  for (int axis = 0; axis < 3; ++axis) EXPECT_FALSE(info.spacing_um[axis].has_value()) << axis;
  EXPECT_EQ(info.series_count, 1);
  EXPECT_EQ(info.time_points, 1);
}

TEST(SliceFolderCellfinderTest, SpacingOverride) {
  OpenOptions options;
  options.spacing_um = {2.0, 2.0, 5.0};
  auto source = OpenSliceFolder(kCellfinder, options);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().spacing_um[0], 2.0);
  EXPECT_EQ((*source)->info().spacing_um[1], 2.0);
  EXPECT_EQ((*source)->info().spacing_um[2], 5.0);
}

TEST(SliceFolderCellfinderTest, VoxelsMatchIndependentDecode) {
  auto source = OpenSliceFolder(kCellfinder, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  for (int channel : {0, 1}) {
    for (int z : {0, 9, 10, 29}) {
      std::vector<uint16_t> want = DecodeCellfinderPlane(CellfinderFile(channel, z));
      std::vector<uint16_t> got = ReadPlanes16(**source, channel, z, 1);
      ASSERT_EQ(got.size(), want.size());
      EXPECT_TRUE(got == want) << "channel " << channel << " z " << z;
      uint16_t max_value = 0;
      for (uint16_t v : want) max_value = std::max(max_value, v);
      EXPECT_GT(max_value, 0) << "an all-zero plane would make the comparison meaningless";
    }
  }
  // A 3-plane slab is the three files in natural order.
  std::vector<uint16_t> slab = ReadPlanes16(**source, 1, 8, 3);
  const size_t plane = 667 * 510;
  for (int i = 0; i < 3; ++i) {
    std::vector<uint16_t> want = DecodeCellfinderPlane(CellfinderFile(1, 8 + i));
    EXPECT_TRUE(std::equal(want.begin(), want.end(), slab.begin() + i * plane)) << i;
  }
  // The channels differ (ch0 signal, ch1 autofluorescence): a channel mix-up would show.
  EXPECT_NE(ReadPlanes16(**source, 0, 5, 1), ReadPlanes16(**source, 1, 5, 1));
}

// Synthetic folders. Slice value: 1000 * channel + 100 * z + x + 10 * y (z = position in the
// stack, not the number in the file name).
class SliceFolderTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir("slices"); }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  void WriteSlice(const std::filesystem::path& path, int channel, int z,
                  testing::TiffFixtureSpec spec = SmallSpec()) {
    std::filesystem::create_directories(path.parent_path());
    ASSERT_TRUE(testing::WriteTiffFixture(
        path, spec, [channel, z](uint32_t x, uint32_t y, int, int sample) {
          return 1000.0 * channel + 100.0 * z + x + 10.0 * y + 5000.0 * sample;
        }));
  }

  static testing::TiffFixtureSpec SmallSpec() {
    testing::TiffFixtureSpec spec;
    spec.width = 6;
    spec.height = 4;
    return spec;
  }

  // Checks every voxel of the volume against the formula above.
  static void ExpectVoxels(VolumeSource& source, int folder_channels, int samples = 1) {
    const volume::VolumeInfo& info = source.info();
    ASSERT_EQ(info.channel_count(), folder_channels * samples);
    for (int c = 0; c < info.channel_count(); ++c) {
      std::vector<uint16_t> all = ReadPlanes16(source, c, 0, info.size[2]);
      size_t i = 0, bad = 0;
      for (int64_t z = 0; z < info.size[2]; ++z)
        for (int64_t y = 0; y < info.size[1]; ++y)
          for (int64_t x = 0; x < info.size[0]; ++x, ++i) {
            const double want =
                1000.0 * (c / samples) + 100.0 * z + x + 10.0 * y + 5000.0 * (c % samples);
            if (all[i] != want && ++bad <= 3) {
              ADD_FAILURE() << "channel " << c << " voxel (" << x << "," << y << "," << z << ") is "
                            << all[i] << ", want " << want;
            }
          }
      EXPECT_EQ(bad, 0u);
    }
  }

  std::filesystem::path dir_;
};

TEST_F(SliceFolderTest, NaturalOrderOfNames) {
  // Byte order would give z1, z10, z2.
  WriteSlice(dir_ / "z1.tif", 0, 0);
  WriteSlice(dir_ / "z2.tif", 0, 1);
  WriteSlice(dir_ / "z10.tif", 0, 2);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().size, (std::array<int64_t, 3>{6, 4, 3}));
  ASSERT_EQ((*source)->info().channel_count(), 1);
  EXPECT_EQ((*source)->info().channels[0].name, "");
  ExpectVoxels(**source, 1);
}

TEST_F(SliceFolderTest, IgnoresHiddenAndNonTiffFiles) {
  WriteSlice(dir_ / "a_001.TIF", 0, 0);
  WriteSlice(dir_ / "a_002.tiff", 0, 1);
  WriteSlice(dir_ / ".a_000.tif", 7, 7);   // Hidden.
  WriteSlice(dir_ / "._a_001.TIF", 7, 7);  // macOS resource fork.
  std::ofstream(dir_ / "notes.txt") << "not a slice";
  std::ofstream(dir_ / "a_003.tif.bak") << "not a slice";
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().size[2], 2);
  ExpectVoxels(**source, 1);
}

TEST_F(SliceFolderTest, ChannelTokensInFlatNames) {
  struct Style {
    const char* pattern;  // printf pattern taking (channel token value, z number).
    int first_channel;
    std::vector<std::string> names;
  };
  const Style styles[] = {
      {"img_c%d_z%d.tif", 0, {"c0", "c1"}},
      {"img_z%2$d_c%1$d.tif", 0, {"c0", "c1"}},  // Channel token after the z number.
      {"stack_ch%d-%04d.tif", 1, {"ch1", "ch2"}},
      {"C%02dZ%03d.tif", 1, {"C01", "C02"}},
      {"scan_w%d_t%d.tiff", 1, {"w1", "w2"}},
      {"Channel%d_%d.tif", 0, {"Channel0", "Channel1"}},
  };
  for (const Style& style : styles) {
    SCOPED_TRACE(style.pattern);
    std::filesystem::path dir = dir_ / Name("style%d", static_cast<int>(&style - styles));
    const int z_numbers[] = {1, 2, 10};  // Also natural order within each channel.
    for (int c = 0; c < 2; ++c) {
      for (int z = 0; z < 3; ++z) {
        WriteSlice(dir / Name(style.pattern, style.first_channel + c, z_numbers[z]), c, z);
      }
    }
    auto source = OpenSliceFolder(dir, OpenOptions{});
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    EXPECT_EQ((*source)->info().size, (std::array<int64_t, 3>{6, 4, 3}));
    ASSERT_EQ((*source)->info().channel_count(), 2);
    EXPECT_EQ((*source)->info().channels[0].name, style.names[0]);
    EXPECT_EQ((*source)->info().channels[1].name, style.names[1]);
    ExpectVoxels(**source, 2);
  }
}

TEST_F(SliceFolderTest, TokensWithoutMarkerOrNotVaryingAreNotChannels) {
  // "sec" ends in "c" after a letter: not a marker, so this is one channel of 4 slices.
  WriteSlice(dir_ / "a" / "sec1_1.tif", 0, 0);
  WriteSlice(dir_ / "a" / "sec1_2.tif", 0, 1);
  WriteSlice(dir_ / "a" / "sec2_1.tif", 0, 2);
  WriteSlice(dir_ / "a" / "sec2_2.tif", 0, 3);
  auto a = OpenSliceFolder(dir_ / "a", OpenOptions{});
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  EXPECT_EQ((*a)->info().channel_count(), 1);
  EXPECT_EQ((*a)->info().size[2], 4);
  ExpectVoxels(**a, 1);

  // A marker whose number is the only thing that varies numbers the slices, not channels.
  WriteSlice(dir_ / "b" / "slice_c1.tif", 0, 0);
  WriteSlice(dir_ / "b" / "slice_c2.tif", 0, 1);
  WriteSlice(dir_ / "b" / "slice_c3.tif", 0, 2);
  auto b = OpenSliceFolder(dir_ / "b", OpenOptions{});
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  EXPECT_EQ((*b)->info().channel_count(), 1);
  EXPECT_EQ((*b)->info().size[2], 3);
  ExpectVoxels(**b, 1);
}

TEST_F(SliceFolderTest, ChannelTokenWithMissingSliceIsAnError) {
  // c1 lacks z2: the error names the slice that has no counterpart and the channel.
  WriteSlice(dir_ / "img_c0_z1.tif", 0, 0);
  WriteSlice(dir_ / "img_c0_z2.tif", 0, 1);
  WriteSlice(dir_ / "img_c0_z3.tif", 0, 2);
  WriteSlice(dir_ / "img_c1_z1.tif", 1, 0);
  WriteSlice(dir_ / "img_c1_z3.tif", 1, 2);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_EQ(source.status().code(), StatusCode::kCorrupt);
  const std::string message = source.status().message();
  EXPECT_NE(message.find("img_c0_z2.tif"), std::string::npos) << message;
  EXPECT_NE(message.find("\"c1\""), std::string::npos) << message;
}

TEST_F(SliceFolderTest, ChannelTokenNamingOneSliceTwiceIsAnError) {
  WriteSlice(dir_ / "img_c0_z1.tif", 0, 0);
  WriteSlice(dir_ / "img_c0_z2.tif", 0, 1);
  WriteSlice(dir_ / "img_c1_z1.tif", 1, 0);
  WriteSlice(dir_ / "img_c1_z2.tif", 1, 1);
  WriteSlice(dir_ / "img_c01_z2.tif", 1, 1);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_NE(source.status().message().find("img_c01_z2.tif"), std::string::npos)
      << source.status().message();
}

TEST_F(SliceFolderTest, TwoVaryingChannelTokensAreAmbiguous) {
  for (int c = 0; c < 2; ++c) {
    for (int w = 0; w < 2; ++w) {
      for (int z = 0; z < 2; ++z) {
        WriteSlice(dir_ / Name("img_c%d_w%d_z%d.tif", c, w, z), c, z);
      }
    }
  }
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_NE(source.status().message().find("ambiguous"), std::string::npos)
      << source.status().message();
}

TEST_F(SliceFolderTest, SubFoldersAreChannelsInNaturalOrder) {
  for (const auto& [folder, channel] :
       std::vector<std::pair<std::string, int>>{{"ch2", 1}, {"ch10", 2}, {"ch1", 0}}) {
    for (int z = 0; z < 4; ++z) WriteSlice(dir_ / folder / Name("p%d.tif", z), channel, z);
  }
  std::filesystem::create_directories(dir_ / "empty");  // No TIFFs: not a channel.
  std::filesystem::create_directories(dir_ / ".hidden");
  WriteSlice(dir_ / ".hidden" / "p0.tif", 9, 0);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  const volume::VolumeInfo& info = (*source)->info();
  ASSERT_EQ(info.channel_count(), 3);
  EXPECT_EQ(info.channels[0].name, "ch1");
  EXPECT_EQ(info.channels[1].name, "ch2");
  EXPECT_EQ(info.channels[2].name, "ch10");
  EXPECT_EQ(info.size[2], 4);
  ExpectVoxels(**source, 3);
}

TEST_F(SliceFolderTest, SubFoldersWithDifferentSliceCountsAreAnError) {
  for (int z = 0; z < 3; ++z) WriteSlice(dir_ / "a" / Name("p%d.tif", z), 0, z);
  for (int z = 0; z < 2; ++z) WriteSlice(dir_ / "b" / Name("p%d.tif", z), 1, z);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_EQ(source.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(source.status().message().find("\"b\" has 2 slices"), std::string::npos)
      << source.status().message();
}

TEST_F(SliceFolderTest, MismatchedSliceSizeNamesTheOddFile) {
  WriteSlice(dir_ / "s1.tif", 0, 0);
  WriteSlice(dir_ / "s2.tif", 0, 1);
  testing::TiffFixtureSpec wide = SmallSpec();
  wide.width = 7;
  WriteSlice(dir_ / "s3.tif", 0, 2, wide);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_EQ(source.status().code(), StatusCode::kCorrupt);
  const std::string message = source.status().message();
  EXPECT_NE(message.find("s3.tif"), std::string::npos) << message;
  EXPECT_NE(message.find("7x4"), std::string::npos) << message;
  EXPECT_NE(message.find("6x4"), std::string::npos) << message;
}

TEST_F(SliceFolderTest, MismatchedSampleTypeNamesTheOddFile) {
  WriteSlice(dir_ / "s1.tif", 0, 0);
  testing::TiffFixtureSpec bytes = SmallSpec();
  bytes.bits_per_sample = 8;
  WriteSlice(dir_ / "s2.tif", 0, 0, bytes);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_NE(source.status().message().find("s2.tif"), std::string::npos)
      << source.status().message();
  EXPECT_NE(source.status().message().find("uint8"), std::string::npos)
      << source.status().message();
}

TEST_F(SliceFolderTest, EmptyOrMissingFolderIsAnError) {
  auto empty = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(empty.ok());
  EXPECT_EQ(empty.status().code(), StatusCode::kNotFound);
  EXPECT_NE(empty.status().message().find(dir_.string()), std::string::npos);

  std::ofstream(dir_ / "readme.txt") << "no slices here";
  std::filesystem::create_directories(dir_ / "sub");
  EXPECT_EQ(OpenSliceFolder(dir_, OpenOptions{}).status().code(), StatusCode::kNotFound);

  EXPECT_EQ(OpenSliceFolder(dir_ / "missing", OpenOptions{}).status().code(),
            StatusCode::kNotFound);
  EXPECT_EQ(OpenSliceFolder(dir_ / "readme.txt", OpenOptions{}).status().code(),
            StatusCode::kInvalidArgument);
}

TEST_F(SliceFolderTest, NotATiffInsideIsAnErrorNamingIt) {
  WriteSlice(dir_ / "s1.tif", 0, 0);
  std::ofstream(dir_ / "s2.tif") << "this is not a TIFF file at all";
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_NE(source.status().message().find("s2.tif"), std::string::npos)
      << source.status().message();
}

TEST_F(SliceFolderTest, MultiPageFileIsRefused) {
  WriteSlice(dir_ / "s1.tif", 0, 0);
  testing::TiffFixtureSpec pages = SmallSpec();
  pages.pages = 3;
  WriteSlice(dir_ / "s2.tif", 0, 1, pages);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_EQ(source.status().code(), StatusCode::kUnsupported);
  EXPECT_NE(source.status().message().find("s2.tif"), std::string::npos);
}

TEST_F(SliceFolderTest, SeriesOrTimeOtherThanZeroIsOutOfRange) {
  WriteSlice(dir_ / "s1.tif", 0, 0);
  OpenOptions options;
  options.time = 1;
  EXPECT_EQ(OpenSliceFolder(dir_, options).status().code(), StatusCode::kOutOfRange);
}

TEST_F(SliceFolderTest, SamplesPerPixelBecomeChannels) {
  testing::TiffFixtureSpec rgb = SmallSpec();
  rgb.samples_per_pixel = 3;
  rgb.bits_per_sample = 16;
  for (int z = 0; z < 2; ++z) WriteSlice(dir_ / Name("rgb%d.tif", z), 0, z, rgb);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  ASSERT_EQ((*source)->info().channel_count(), 3);
  EXPECT_EQ((*source)->info().channels[0].name, "s0");
  EXPECT_EQ((*source)->info().channels[2].name, "s2");
  ExpectVoxels(**source, 1, 3);
}

TEST_F(SliceFolderTest, SpacingFromImageJDescription) {
  testing::TiffFixtureSpec spec = SmallSpec();
  spec.descriptions = {"ImageJ=1.53t\nunit=micron\nspacing=3.5\nloop=false\n"};
  spec.x_resolution = 2.0;  // Pixels per micron.
  spec.y_resolution = 4.0;
  spec.resolution_unit = 1;
  WriteSlice(dir_ / "s1.tif", 0, 0, spec);
  WriteSlice(dir_ / "s2.tif", 0, 1, spec);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_DOUBLE_EQ((*source)->info().spacing_um[0].value_or(0), 0.5);
  EXPECT_DOUBLE_EQ((*source)->info().spacing_um[1].value_or(0), 0.25);
  EXPECT_DOUBLE_EQ((*source)->info().spacing_um[2].value_or(0), 3.5);

  OpenOptions options;
  options.spacing_um[2] = 7.0;
  auto overridden = OpenSliceFolder(dir_, options);
  ASSERT_TRUE(overridden.ok());
  EXPECT_DOUBLE_EQ((*overridden)->info().spacing_um[0].value_or(0), 0.5);
  EXPECT_DOUBLE_EQ((*overridden)->info().spacing_um[2].value_or(0), 7.0);
}

TEST_F(SliceFolderTest, SpacingFromResolutionUnits) {
  testing::TiffFixtureSpec cm = SmallSpec();
  cm.x_resolution = 10000.0;  // Pixels per cm: 1 µm pitch.
  cm.y_resolution = 5000.0;
  cm.resolution_unit = 3;
  WriteSlice(dir_ / "cm" / "s1.tif", 0, 0, cm);
  auto a = OpenSliceFolder(dir_ / "cm", OpenOptions{});
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  EXPECT_DOUBLE_EQ((*a)->info().spacing_um[0].value_or(0), 1.0);
  EXPECT_DOUBLE_EQ((*a)->info().spacing_um[1].value_or(0), 2.0);
  EXPECT_FALSE((*a)->info().spacing_um[2].has_value());

  testing::TiffFixtureSpec inch = SmallSpec();
  inch.x_resolution = 72.0;
  inch.y_resolution = 72.0;
  inch.resolution_unit = 2;
  WriteSlice(dir_ / "inch" / "s1.tif", 0, 0, inch);
  auto b = OpenSliceFolder(dir_ / "inch", OpenOptions{});
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  for (int axis = 0; axis < 3; ++axis) EXPECT_FALSE((*b)->info().spacing_um[axis].has_value());
}

// A slice whose image page follows a reduced-resolution thumbnail: its ImageJ description (not
// kept in the TiffFile index, which holds IFD 0's only) still gives the spacing.
TEST_F(SliceFolderTest, SpacingFromTheImagePageAfterAThumbnail) {
  for (int z = 0; z < 2; ++z) {
    const std::filesystem::path path = dir_ / Name("s%d.tif", z);
    TIFF* tif = TIFFOpen(path.c_str(), "w");
    ASSERT_NE(tif, nullptr);
    auto page = [&](uint32_t width, uint32_t height, bool thumbnail) {
      TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, width);
      TIFFSetField(tif, TIFFTAG_IMAGELENGTH, height);
      TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 16);
      TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
      TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
      TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
      TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, height);
      if (thumbnail) {
        TIFFSetField(tif, TIFFTAG_SUBFILETYPE, FILETYPE_REDUCEDIMAGE);
      } else {
        TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, "ImageJ=1.53t\nunit=micron\nspacing=3.5\n");
        TIFFSetField(tif, TIFFTAG_XRESOLUTION, 2.0);
        TIFFSetField(tif, TIFFTAG_YRESOLUTION, 4.0);
        TIFFSetField(tif, TIFFTAG_RESOLUTIONUNIT, RESUNIT_NONE);
      }
      std::vector<uint16_t> row(width);
      for (uint32_t y = 0; y < height; ++y) {
        for (uint32_t x = 0; x < width; ++x) row[x] = static_cast<uint16_t>(100 * z + x + 10 * y);
        ASSERT_EQ(TIFFWriteScanline(tif, row.data(), y, 0), 1);
      }
      ASSERT_TRUE(TIFFWriteDirectory(tif));
    };
    page(3, 2, true);
    page(6, 4, false);
    TIFFClose(tif);
  }
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().size, (std::array<int64_t, 3>{6, 4, 2}));
  EXPECT_DOUBLE_EQ((*source)->info().spacing_um[0].value_or(0), 0.5);
  EXPECT_DOUBLE_EQ((*source)->info().spacing_um[1].value_or(0), 0.25);
  EXPECT_DOUBLE_EQ((*source)->info().spacing_um[2].value_or(0), 3.5);
  ExpectVoxels(**source, 1);
}

// Slab-request errors name the folder (CheckSlabRequest alone does not know it).
TEST_F(SliceFolderTest, SlabRequestErrorsNameTheFolder) {
  WriteSlice(dir_ / "s1.tif", 0, 0);
  WriteSlice(dir_ / "s2.tif", 0, 1);
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  std::vector<std::byte> plane((*source)->SlabBytes(1));
  std::vector<std::byte> small(5);
  for (Status st : {(*source)->ReadSlab(1, 0, 1, plane), (*source)->ReadSlab(0, 2, 1, plane),
                    (*source)->ReadSlab(0, 0, 1, small)}) {
    EXPECT_FALSE(st.ok());
    EXPECT_NE(st.message().find(dir_.string()), std::string::npos) << st.ToString();
  }
}

TEST_F(SliceFolderTest, ManySlicesThroughTheBoundedHandleCache) {
  // More slices than kMaxOpenSliceFiles, read forwards, backwards and from several threads.
  const int slices = kMaxOpenSliceFiles + 9;
  for (int z = 0; z < slices; ++z) {
    WriteSlice(dir_ / Name("plane_%d.tif", z), 0, z);
  }
  auto source = OpenSliceFolder(dir_, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  ASSERT_EQ((*source)->info().size[2], slices);
  ExpectVoxels(**source, 1);
  for (int z = slices - 1; z >= 0; --z) {
    std::vector<uint16_t> plane = ReadPlanes16(**source, 0, z, 1);
    EXPECT_EQ(plane[0], 100 * z) << z;
  }
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&source, t, slices] {
      for (int i = 0; i < slices; ++i) {
        const int z = (i * 7 + t * 11) % slices;
        std::vector<uint16_t> plane = ReadPlanes16(**source, 0, z, 1);
        EXPECT_EQ(plane[5 + 6 * 3], 100 * z + 5 + 30) << z;
      }
    });
  }
  for (std::thread& t : threads) t.join();
}

// Confined to the folder, as the server opens a dataset (issue 28): a slice that is a link out of
// the folder refuses it, whether or not its target exists; links inside are followed.
class SliceFolderConfinedTest : public testing::ConfinedTest {
 protected:
  // A single-page 16x8 uint16 slice whose values are `z` * 1000 + the default pattern.
  static void WriteSlice(const std::filesystem::path& path, int z) {
    ASSERT_TRUE(testing::WriteTiffFixture(
        path, testing::TiffFixtureSpec{},
        [z](uint32_t x, uint32_t y, int, int) { return z * 1000.0 + y * 16 + x; }));
  }
  // `prefix` followed by `n` (appended: GCC 12 warns falsely about "literal" + std::string).
  static std::string Numbered(std::string prefix, size_t n, const char* suffix = "") {
    prefix += std::to_string(n);
    prefix += suffix;
    return prefix;
  }
  static std::vector<std::byte> Read(io::VolumeSource& source, int channel, int64_t z) {
    std::vector<std::byte> out(source.SlabBytes(1));
    const Status status = source.ReadSlab(channel, z, 1, out);
    EXPECT_TRUE(status.ok()) << status.ToString();
    return out;
  }
};

TEST_F(SliceFolderConfinedTest, ASliceLinkedOutRefusesTheFolderAlikeWhetherOrNotItExists) {
  WriteSlice(outside_ / "plane.tif", 7);
  const std::vector<std::filesystem::path> targets = {
      "../../outside/plane.tif", "../../outside/none.tif", outside_ / "plane.tif",
      outside_ / "none.tif"};
  for (size_t i = 0; i < targets.size(); ++i) {
    SCOPED_TRACE(targets[i]);
    const std::filesystem::path flat = own_ / Numbered("flat", i);
    std::filesystem::create_directories(flat);
    WriteSlice(flat / "z0.tif", 0);
    WriteSlice(flat / "z1.tif", 1);
    std::filesystem::create_symlink(targets[i], flat / "z2.tif");
    ExpectRefusal(OpenConfined(flat).status(), flat);
    // The same in a channel sub-folder.
    const std::filesystem::path channels = own_ / Numbered("channels", i);
    for (const char* ch : {"ch0", "ch1"}) {
      std::filesystem::create_directories(channels / ch);
      WriteSlice(channels / ch / "z0.tif", 0);
    }
    const std::filesystem::path deeper =
        targets[i].is_absolute() ? targets[i] : std::filesystem::path("..") / targets[i];
    std::filesystem::create_symlink(deeper, channels / "ch1" / "z1.tif");
    WriteSlice(channels / "ch0" / "z1.tif", 1);
    ExpectRefusal(OpenConfined(channels).status(), channels);
  }
}

TEST_F(SliceFolderConfinedTest, LinksInsideTheFolderAreFollowed) {
  const std::filesystem::path folder = own_ / "planes";
  std::filesystem::create_directories(folder / "store");
  WriteSlice(folder / "store" / "a.tif", 0);
  std::filesystem::create_symlink("store/a.tif", folder / "z0.tif");
  WriteSlice(folder / "z1.tif", 1);
  auto source = OpenConfined(folder);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  ASSERT_EQ((*source)->info().size[2], 2);
  auto open = OpenSliceFolder(folder, OpenOptions{});
  ASSERT_TRUE(open.ok());
  for (int64_t z = 0; z < 2; ++z) EXPECT_EQ(Read(**source, 0, z), Read(**open, 0, z));
}

TEST_F(SliceFolderConfinedTest, AChannelFolderLinkedOutIsNotReadAndSaysSo) {
  std::filesystem::create_directories(outside_ / "ch");
  WriteSlice(outside_ / "ch" / "z0.tif", 5);
  for (const char* target : {"../../outside/ch", "../../outside/none"}) {
    SCOPED_TRACE(target);
    const std::filesystem::path folder = own_ / "channels";
    std::filesystem::remove_all(folder);
    std::filesystem::create_directories(folder / "ch0");
    WriteSlice(folder / "ch0" / "z0.tif", 0);
    std::filesystem::create_directory_symlink(target, folder / "ch1");
    auto source = OpenConfined(folder);
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    ASSERT_EQ((*source)->info().channel_count(), 1);
    EXPECT_EQ((*source)->info().channels[0].name, "ch0");
    EXPECT_EQ((*source)->info().warnings,
              std::vector<std::string>{folder.string() +
                                       ": ch1 is not read as a channel: it leads outside the "
                                       "folder"});
  }
}

TEST_F(SliceFolderConfinedTest, ASliceReplacedByALinkOutAfterOpeningFailsItsRead) {
  const std::filesystem::path folder = own_ / "many";
  std::filesystem::create_directories(folder);
  // More slices than are kept open: the last ones are reopened (through the gate) when read.
  const int slices = kMaxOpenSliceFiles + 8;
  for (int z = 0; z < slices; ++z) WriteSlice(folder / Numbered("z", z, ".tif"), z);
  WriteSlice(outside_ / "plane.tif", 7);
  auto source = OpenConfined(folder);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  const std::filesystem::path last = folder / Numbered("z", slices - 1, ".tif");
  std::filesystem::remove(last);
  std::filesystem::create_symlink("../../outside/plane.tif", last);
  std::vector<std::byte> out((*source)->SlabBytes(1));
  ExpectRefusal((*source)->ReadSlab(0, slices - 1, 1, out), folder);
  EXPECT_TRUE((*source)->ReadSlab(0, 0, 1, out).ok());
}

}  // namespace
}  // namespace octoscope::io
