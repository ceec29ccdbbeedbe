#include "io/ome_tiff_volume.h"

#include <gtest/gtest.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "io/confined_fixture.h"
#include "io/open_volume.h"
#include "io/tiff_file.h"
#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;
using testing::MakeTempDir;
using testing::ReadStoredPlane;
using testing::TiffFixtureSpec;
using testing::WriteTiffFixture;
using volume::DataType;
using volume::Rgba;

const fs::path kData = OCTOSCOPE_TESTDATA;

// ---------------------------------------------------------------------------------------------
// Helpers, written independently of the reader under test.

// The plane index of (z, c, t) per the OME-TIFF spec, spelled out per order.
int64_t HandPlaneIndex(const std::string& order, int64_t size_z, int64_t size_c, int64_t size_t_,
                       int64_t z, int64_t c, int64_t t) {
  if (order == "XYZCT") return z + size_z * (c + size_c * t);
  if (order == "XYZTC") return z + size_z * (t + size_t_ * c);
  if (order == "XYCTZ") return c + size_c * (t + size_t_ * z);
  if (order == "XYCZT") return c + size_c * (z + size_z * t);
  if (order == "XYTCZ") return t + size_t_ * (c + size_c * z);
  if (order == "XYTZC") return t + size_t_ * (z + size_z * c);
  ADD_FAILURE() << "bad order " << order;
  return -1;
}

std::vector<std::byte> ReadSlab(VolumeSource& source, int channel, int64_t z0, int64_t nz) {
  std::vector<std::byte> out(source.SlabBytes(nz));
  Status status = source.ReadSlab(channel, z0, nz, out);
  EXPECT_TRUE(status.ok()) << status.ToString();
  return out;
}

// Decodes one page with TiffFile directly (the path the test computed by hand).
std::vector<std::byte> ReadIfd(const fs::path& path, int ifd, int sample = 0) {
  Result<std::unique_ptr<TiffFile>> file = TiffFile::Open(path);
  EXPECT_TRUE(file.ok()) << file.status().ToString();
  if (!file.ok()) return {};
  EXPECT_LT(ifd, (*file)->ifd_count()) << path;
  if (ifd >= (*file)->ifd_count()) return {};
  const TiffIfd& page = (*file)->ifd(ifd);
  std::vector<std::byte> out(static_cast<size_t>(page.width) * page.height *
                             volume::BytesPerSample(page.dtype.value_or(DataType::kUint8)));
  Status status = (*file)->ReadPlane(ifd, sample, out);
  EXPECT_TRUE(status.ok()) << status.ToString();
  return out;
}

// Sample i of a buffer in `type`, as int64 (all real test files are integer typed).
int64_t SampleAt(const std::vector<std::byte>& data, DataType type, size_t i) {
  switch (type) {
    case DataType::kInt8:
      return static_cast<int8_t>(data[i]);
    case DataType::kUint8:
      return static_cast<uint8_t>(data[i]);
    case DataType::kUint16: {
      uint16_t v;
      std::memcpy(&v, &data[2 * i], 2);
      return v;
    }
    case DataType::kInt16: {
      int16_t v;
      std::memcpy(&v, &data[2 * i], 2);
      return v;
    }
    default:
      ADD_FAILURE() << "unexpected type";
      return 0;
  }
}

int64_t Sum(const std::vector<std::byte>& data, DataType type) {
  int64_t sum = 0;
  const size_t n = data.size() / volume::BytesPerSample(type);
  for (size_t i = 0; i < n; ++i) sum += SampleAt(data, type, i);
  return sum;
}

Result<std::unique_ptr<VolumeSource>> Open(const fs::path& path, int series = 0, int time = 0) {
  OpenOptions options;
  options.series = series;
  options.time = time;
  return OpenOmeTiff(path, options);
}

// Asserts `status` failed with `code` and mentions each of `needles`.
void ExpectError(const Status& status, StatusCode code, const std::vector<std::string>& needles) {
  ASSERT_FALSE(status.ok());
  EXPECT_EQ(status.code(), code) << status.ToString();
  for (const std::string& needle : needles) {
    EXPECT_NE(status.message().find(needle), std::string::npos)
        << "'" << needle << "' not in: " << status.message();
  }
}

// ---------------------------------------------------------------------------------------------
// Real files.

// A plane checked against a sum (and voxels) computed by an independent decoder (a small Python
// TIFF reader, not libtiff) when the test data were added.
struct PlaneSum {
  int channel;
  int64_t z;
  int64_t sum;
  std::vector<std::array<int64_t, 3>> voxels;  // {x, y, value}
};

struct RealCase {
  std::string open_path;  // Relative to the test data.
  int series = 0;
  int time = 0;
  std::array<int64_t, 3> size;
  DataType dtype;
  std::vector<std::string> channel_names;
  std::array<std::optional<double>, 3> spacing;
  int series_count = 1;
  int time_points = 1;
  // The page holding (c, z) of the selected series/time, computed by hand from the OME-XML.
  std::function<std::pair<fs::path, int>(int c, int64_t z)> locate;
  std::vector<PlaneSum> sums;
};

void CheckRealCase(const RealCase& rc) {
  SCOPED_TRACE(rc.open_path + " series " + std::to_string(rc.series) + " time " +
               std::to_string(rc.time));
  Result<std::unique_ptr<VolumeSource>> opened = Open(kData / rc.open_path, rc.series, rc.time);
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  VolumeSource& source = **opened;
  const volume::VolumeInfo& info = source.info();
  EXPECT_EQ(info.format, "ome-tiff");
  EXPECT_EQ(info.size, rc.size);
  EXPECT_EQ(info.dtype, rc.dtype);
  ASSERT_EQ(info.channel_count(), static_cast<int>(rc.channel_names.size()));
  for (size_t c = 0; c < rc.channel_names.size(); ++c) {
    EXPECT_EQ(info.channels[c].name, rc.channel_names[c]) << "channel " << c;
  }
  for (int a = 0; a < 3; ++a) {
    ASSERT_EQ(info.spacing_um[a].has_value(), rc.spacing[a].has_value()) << "axis " << a;
    if (rc.spacing[a]) {
      EXPECT_DOUBLE_EQ(*info.spacing_um[a], *rc.spacing[a]) << "axis " << a;
    }
  }
  EXPECT_EQ(info.series_count, rc.series_count);
  EXPECT_EQ(info.series, rc.series);
  EXPECT_EQ(info.time_points, rc.time_points);
  EXPECT_EQ(info.time, rc.time);

  // Every plane of every channel, read as one slab per channel, equals the page located by hand.
  const size_t plane_bytes = source.SlabBytes(1);
  for (int c = 0; c < info.channel_count(); ++c) {
    std::vector<std::byte> slab = ReadSlab(source, c, 0, info.size[2]);
    for (int64_t z = 0; z < info.size[2]; ++z) {
      auto [file, ifd] = rc.locate(c, z);
      std::vector<std::byte> expected = ReadIfd(file, ifd);
      ASSERT_EQ(expected.size(), plane_bytes);
      EXPECT_TRUE(std::equal(expected.begin(), expected.end(), slab.begin() + z * plane_bytes))
          << "c " << c << " z " << z << " vs " << file << " IFD " << ifd;
    }
  }
  for (const PlaneSum& ps : rc.sums) {
    std::vector<std::byte> plane = ReadSlab(source, ps.channel, ps.z, 1);
    EXPECT_EQ(Sum(plane, info.dtype), ps.sum) << "c " << ps.channel << " z " << ps.z;
    for (const auto& [x, y, value] : ps.voxels) {
      EXPECT_EQ(SampleAt(plane, info.dtype, static_cast<size_t>(y * info.size[0] + x)), value)
          << "c " << ps.channel << " z " << ps.z << " x " << x << " y " << y;
    }
  }
}

// A locator for single files whose pages follow DimensionOrder from IFD 0.
std::function<std::pair<fs::path, int>(int, int64_t)> InOrder(const std::string& file,
                                                              const std::string& order, int64_t z,
                                                              int64_t c, int64_t t, int time) {
  return [=](int ch, int64_t zz) {
    return std::make_pair(kData / file,
                          static_cast<int>(HandPlaneIndex(order, z, c, t, zz, ch, time)));
  };
}

TEST(OmeTiffVolumeTest, OmeSamplesBigEndianInt8) {
  const std::array<std::optional<double>, 3> none;
  // 4D-series: XYZCT, Z 5, C 1, T 7. Sums from the independent decoder (IFDs 0, 17, 34).
  CheckRealCase({"ome_samples/4D-series.ome.tif",
                 0,
                 0,
                 {439, 167, 5},
                 DataType::kInt8,
                 {""},
                 none,
                 1,
                 7,
                 InOrder("ome_samples/4D-series.ome.tif", "XYZCT", 5, 1, 7, 0),
                 {{0, 0, 3470899, {{0, 0, 0}, {100, 50, 29}, {438, 166, 96}}}}});
  CheckRealCase({"ome_samples/4D-series.ome.tif",
                 0,
                 3,
                 {439, 167, 5},
                 DataType::kInt8,
                 {""},
                 none,
                 1,
                 7,
                 InOrder("ome_samples/4D-series.ome.tif", "XYZCT", 5, 1, 7, 3),
                 {{0, 2, 3470185, {{0, 0, 0}, {100, 50, 29}, {438, 166, 96}}}}});
  CheckRealCase({"ome_samples/4D-series.ome.tif",
                 0,
                 6,
                 {439, 167, 5},
                 DataType::kInt8,
                 {""},
                 none,
                 1,
                 7,
                 InOrder("ome_samples/4D-series.ome.tif", "XYZCT", 5, 1, 7, 6),
                 {{0, 4, 3470332, {}}}});
  // multi-channel-time-series: Z 1, C 3, T 7; time 4 channel 1 is IFD 13.
  CheckRealCase({"ome_samples/multi-channel-time-series.ome.tif",
                 0,
                 4,
                 {439, 167, 1},
                 DataType::kInt8,
                 {"", "", ""},
                 none,
                 1,
                 7,
                 InOrder("ome_samples/multi-channel-time-series.ome.tif", "XYZCT", 1, 3, 7, 4),
                 {{1, 0, 3461022, {{10, 20, -1}, {200, 100, 58}}}, {2, 0, 3460910, {}}}});
  // multi-channel-z-series: Z 5, C 3; channel 1 z 2 is IFD 7.
  CheckRealCase({"ome_samples/multi-channel-z-series.ome.tif",
                 0,
                 0,
                 {439, 167, 5},
                 DataType::kInt8,
                 {"", "", ""},
                 none,
                 1,
                 1,
                 InOrder("ome_samples/multi-channel-z-series.ome.tif", "XYZCT", 5, 3, 1, 0),
                 {{1, 2, 3459530, {{10, 20, -1}, {200, 100, 58}}}, {2, 4, 3459344, {}}}});
  CheckRealCase({"ome_samples/z-series.ome.tif",
                 0,
                 0,
                 {439, 167, 5},
                 DataType::kInt8,
                 {""},
                 none,
                 1,
                 1,
                 InOrder("ome_samples/z-series.ome.tif", "XYZCT", 5, 1, 1, 0),
                 {{0, 3, 3487048, {{10, 20, 12}, {200, 100, 58}}}, {0, 0, 3487378, {}}}});
}

TEST(OmeTiffVolumeTest, OmeSamplesChannelColor) {
  Result<std::unique_ptr<VolumeSource>> opened =
      Open(kData / "ome_samples/multifile_master/multifile-Z1.ome.tiff");
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  // Color="-2147483648" = 0x80000000.
  EXPECT_EQ((*opened)->info().channels[0].color, (Rgba{128, 0, 0, 0}));
  Result<std::unique_ptr<VolumeSource>> plain = Open(kData / "ome_samples/z-series.ome.tif");
  ASSERT_TRUE(plain.ok());
  EXPECT_FALSE((*plain)->info().channels[0].color.has_value());
}

const int64_t kMultifileSums[5] = {94605, 16575, 93330, 17136, 92820};

RealCase MultifileCase(const std::string& dir, const std::string& open_name) {
  RealCase rc;
  rc.open_path = "ome_samples/" + dir + "/" + open_name;
  rc.size = {18, 24, 5};
  rc.dtype = DataType::kUint8;
  rc.channel_names = {""};
  // XYCTZ with C = T = 1: one file per z, IFD 0 each.
  rc.locate = [dir](int, int64_t z) {
    return std::make_pair(
        kData / "ome_samples" / dir / ("multifile-Z" + std::to_string(z + 1) + ".ome.tiff"), 0);
  };
  for (int z = 0; z < 5; ++z) rc.sums.push_back({0, z, kMultifileSums[z], {}});
  rc.sums[2].voxels = {{0, 0, 255}, {5, 10, 255}, {17, 23, 255}};
  return rc;
}

TEST(OmeTiffVolumeTest, MultifileMasterOpensViaEveryMember) {
  for (int k = 1; k <= 5; ++k) {
    CheckRealCase(
        MultifileCase("multifile_master", "multifile-Z" + std::to_string(k) + ".ome.tiff"));
  }
}

TEST(OmeTiffVolumeTest, MultifileCompanionOpensViaCompanionAndMember) {
  CheckRealCase(MultifileCase("multifile_companion", "multifile.companion.ome"));
  CheckRealCase(MultifileCase("multifile_companion", "multifile-Z4.ome.tiff"));
}

TEST(OmeTiffVolumeTest, NdevBigTiffDeflate) {
  // neuron: XYZCT, C 4, sole TiffData IFD 0 PlaneCount 4.
  CheckRealCase(
      {"ndev_bigtiff_ome/neuron-4Ch.tiff",
       0,
       0,
       {502, 623, 1},
       DataType::kUint16,
       {"AF647", "AF568", "AF488", "DAPI"},
       {0.1241, 0.1241, 1.0},
       1,
       1,
       InOrder("ndev_bigtiff_ome/neuron-4Ch.tiff", "XYZCT", 1, 4, 1, 0),
       {{3, 0, 64260946, {{0, 0, 209}, {250, 300, 197}, {501, 622, 193}}}, {0, 0, 485772361, {}}}});
  // neocortex: XYCZT, C 3.
  CheckRealCase({"ndev_bigtiff_ome/neocortex-3Ch.tiff",
                 0,
                 0,
                 {402, 1112, 1},
                 DataType::kUint16,
                 {"CTIP2", "BRN2", "ROR"},
                 {1.0, 1.0, 1.0},
                 1,
                 1,
                 InOrder("ndev_bigtiff_ome/neocortex-3Ch.tiff", "XYCZT", 1, 3, 1, 0),
                 {{1, 0, 2606351808, {{0, 0, 1296}, {200, 500, 4240}, {401, 1111, 2608}}},
                  {2, 0, 3981102704, {}}}});
  // scratch assay: XYTCZ, C 4, T 10: (t, c) is IFD t + 10 c.
  for (int time : {0, 3, 9}) {
    RealCase rc{
        "ndev_bigtiff_ome/scratch-assay-labeled-10T-2Ch.tiff",
        0,
        time,
        {576, 210, 1},
        DataType::kUint16,
        {"H3342", "oblique", "nuclei", "cyto"},
        {0.619, 0.619, 1.0},
        1,
        10,
        InOrder("ndev_bigtiff_ome/scratch-assay-labeled-10T-2Ch.tiff", "XYTCZ", 1, 4, 10, time),
        {}};
    if (time == 3) {
      rc.sums = {{2, 0, 1621479, {{100, 100, 0}, {575, 209, 0}}},
                 {0, 0, 73850585, {}},
                 {1, 0, 991038051, {}},
                 {3, 0, 11232012, {}}};
    }
    if (time == 9) rc.sums = {{3, 0, 21873479, {}}, {0, 0, 72952483, {}}};
    CheckRealCase(rc);
  }
}

TEST(OmeTiffVolumeTest, MicroManagerMultiPosition) {
  const std::string file = "real_ometiff_misc/181003_multi_pos_time_course_1_MMStack.ome.tif";
  // Two positions interleaved: (series s, time t) is IFD 2 t + s.
  const int64_t sums[20] = {582125680,  529121874,  621656151, 486246307, 624392177,
                            493615930,  890619278,  848331894, 940977093, 836304276,
                            1054538383, 1123256445, 605858032, 502874940, 566346603,
                            504299181,  566577596,  508616233, 528153036, 487611334};
  for (int series : {0, 1}) {
    for (int time : {0, 3, 9}) {
      RealCase rc{file,
                  series,
                  time,
                  {256, 256, 1},
                  DataType::kUint16,
                  {"Default"},
                  {5.2304, 5.2304, std::nullopt},
                  2,
                  10,
                  [=](int, int64_t) { return std::make_pair(kData / file, 2 * time + series); },
                  {{0, 0, sums[2 * time + series], {}}}};
      if (series == 1 && time == 3) {
        rc.sums[0].voxels = {{0, 0, 9734}, {128, 128, 12364}, {255, 255, 17622}};
      }
      CheckRealCase(rc);
    }
  }
}

TEST(OmeTiffVolumeTest, NeutrophilTirfFrame) {
  const std::string file = "real_ometiff_misc/170918_tn_neutrophil_migration_wave.ome.tif";
  CheckRealCase({file,
                 0,
                 0,
                 {1024, 1024, 1},
                 DataType::kUint16,
                 {"488 TIRF left"},
                 {1.0, 1.0, 1.0},
                 1,
                 1,
                 [=](int, int64_t) { return std::make_pair(kData / file, 0); },
                 {{0, 0, 706160670, {{0, 0, 552}, {512, 512, 641}, {1023, 1023, 615}}}}});
}

TEST(OmeTiffVolumeTest, PrairieMultiFileThreeSeries) {
  const fs::path dir = kData / "real_ometiff_misc/prairie_multifile";
  auto name = [](int series, int c, int t) {
    return "TSeries-camp-005_Cycle0000" + std::to_string(series + 1) + "_Ch" +
           std::to_string(c + 1) + "_00000" + std::to_string(t + 1) + ".ome.tif";
  };
  // Sums of (series, c, t) pages from the independent decoder.
  const int64_t sums[3][2][4] = {
      {{293685, 294135, 293695, 293770}, {203052, 202853, 202512, 202388}},
      {{292851, 292040, 291741, 293126}, {200043, 201704, 200972, 199130}},
      {{292189, 292230, 292339, 290080}, {199673, 202346, 201569, 199490}}};
  for (int series = 0; series < 3; ++series) {
    for (int time : {0, 2, 3}) {
      // Open through a member that is not the master, from another series.
      RealCase rc{"real_ometiff_misc/prairie_multifile/" + name((series + 1) % 3, 1, 3),
                  series,
                  time,
                  {128, 128, 1},
                  DataType::kUint16,
                  {"Ch1", "Ch2"},
                  {4.05296, 4.05296, 1.0},
                  3,
                  4,
                  [=](int c, int64_t) { return std::make_pair(dir / name(series, c, time), 0); },
                  {{0, 0, sums[series][0][time], {}}, {1, 0, sums[series][1][time], {}}}};
      if (series == 1 && time == 2) rc.sums[1].voxels = {{0, 0, 11}, {64, 64, 11}, {127, 127, 11}};
      CheckRealCase(rc);
    }
  }
}

TEST(OmeTiffVolumeTest, RealFileSeriesAndTimeOutOfRange) {
  const fs::path file = kData / "real_ometiff_misc/181003_multi_pos_time_course_1_MMStack.ome.tif";
  ExpectError(Open(file, 2, 0).status(), StatusCode::kOutOfRange, {file.string(), "series 2"});
  ExpectError(Open(file, -1, 0).status(), StatusCode::kOutOfRange, {file.string()});
  ExpectError(Open(file, 1, 10).status(), StatusCode::kOutOfRange,
              {file.string(), "time point 10"});
}

TEST(OmeTiffVolumeTest, NonOmeTiffIsUnsupported) {
  const fs::path file = kData / "real_ometiff_misc/ScanImageBigTIFFv57.tif";
  ExpectError(Open(file).status(), StatusCode::kUnsupported, {file.string()});
}

// ---------------------------------------------------------------------------------------------
// Synthetic files.

std::string OmeDoc(const std::string& pixels_attrs, const std::string& children,
                   const std::string& uuid = "urn:uuid:synthetic-0") {
  return "<?xml version=\"1.0\" encoding=\"UTF-8\"?>"
         "<OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/2016-06\" UUID=\"" +
         uuid + "\"><Image ID=\"Image:0\" Name=\"synthetic\"><Pixels ID=\"Pixels:0\" " +
         pixels_attrs + ">" + children + "</Pixels></Image></OME>";
}

std::string PixelsAttrs(const std::string& order, int x, int y, int z, int c, int t,
                        const std::string& type = "uint16") {
  return "DimensionOrder=\"" + order + "\" Type=\"" + type + "\" SizeX=\"" + std::to_string(x) +
         "\" SizeY=\"" + std::to_string(y) + "\" SizeZ=\"" + std::to_string(z) + "\" SizeC=\"" +
         std::to_string(c) + "\" SizeT=\"" + std::to_string(t) + "\"";
}

// The value stored at (x, y) of plane (z, c, t): every coordinate recoverable from the value.
uint16_t Pattern(int64_t z, int64_t c, int64_t t, uint32_t x, uint32_t y) {
  return static_cast<uint16_t>(((z * 8 + c) * 8 + t) * 256 + y * 16 + x);
}

constexpr int kW = 5, kH = 4, kZ = 3, kC = 2, kT = 4;

// Checks every voxel of every (c, t) of the source against Pattern.
void CheckPattern(const fs::path& path, int size_z, int size_c, int size_t_) {
  for (int t = 0; t < size_t_; ++t) {
    Result<std::unique_ptr<VolumeSource>> opened = Open(path, 0, t);
    ASSERT_TRUE(opened.ok()) << opened.status().ToString();
    VolumeSource& source = **opened;
    ASSERT_EQ(source.info().size, (std::array<int64_t, 3>{kW, kH, size_z}));
    ASSERT_EQ(source.info().channel_count(), size_c);
    ASSERT_EQ(source.info().time_points, size_t_);
    ASSERT_EQ(source.info().dtype, DataType::kUint16);
    for (int c = 0; c < size_c; ++c) {
      std::vector<std::byte> slab = ReadSlab(source, c, 0, size_z);
      for (int z = 0; z < size_z; ++z) {
        for (uint32_t y = 0; y < kH; ++y) {
          for (uint32_t x = 0; x < kW; ++x) {
            const size_t i = (static_cast<size_t>(z) * kH + y) * kW + x;
            ASSERT_EQ(SampleAt(slab, DataType::kUint16, i), Pattern(z, c, t, x, y))
                << path << " z " << z << " c " << c << " t " << t << " x " << x << " y " << y;
          }
        }
        // A stored plane, when located, holds the same plane.
        if (std::optional<std::vector<std::byte>> view = ReadStoredPlane(source, c, z)) {
          const size_t plane = static_cast<size_t>(kW) * kH * 2;
          EXPECT_EQ(*view, std::vector<std::byte>(slab.begin() + z * plane,
                                                  slab.begin() + (z + 1) * plane))
              << path << " z " << z << " c " << c << " t " << t;
        }
      }
    }
  }
}

// Writes `pages` pages where page p holds plane page_zct[p].
bool WritePages(const fs::path& path, const std::vector<std::array<int64_t, 3>>& page_zct,
                const std::string& description, uint16_t compression = 1) {
  TiffFixtureSpec spec;
  spec.width = kW;
  spec.height = kH;
  spec.pages = static_cast<int>(page_zct.size());
  spec.compression = compression;
  spec.descriptions = {description};
  return WriteTiffFixture(path, spec, [&](uint32_t x, uint32_t y, int page, int) {
    const auto& [z, c, t] = page_zct[page];
    return static_cast<double>(Pattern(z, c, t, x, y));
  });
}

// Pages in DimensionOrder order: page p = HandPlaneIndex(z, c, t).
std::vector<std::array<int64_t, 3>> PagesInOrder(const std::string& order) {
  std::vector<std::array<int64_t, 3>> pages(kZ * kC * kT);
  for (int64_t z = 0; z < kZ; ++z) {
    for (int64_t c = 0; c < kC; ++c) {
      for (int64_t t = 0; t < kT; ++t)
        pages[HandPlaneIndex(order, kZ, kC, kT, z, c, t)] = {z, c, t};
    }
  }
  return pages;
}

TEST(OmeTiffVolumeTest, EveryDimensionOrderSoleTiffData) {
  const fs::path dir = MakeTempDir("ome-orders");
  for (const std::string order : {"XYZCT", "XYZTC", "XYCTZ", "XYCZT", "XYTCZ", "XYTZC"}) {
    SCOPED_TRACE(order);
    const fs::path path = dir / (order + ".ome.tif");
    ASSERT_TRUE(WritePages(path, PagesInOrder(order),
                           OmeDoc(PixelsAttrs(order, kW, kH, kZ, kC, kT),
                                  "<Channel Name=\"a\"/><Channel Name=\"b\"/><TiffData/>"),
                           order == "XYTZC" ? 8 : 1));
    CheckPattern(path, kZ, kC, kT);
  }
  fs::remove_all(dir);
}

TEST(OmeTiffVolumeTest, EveryDimensionOrderExplicitTiffDataScrambledPages) {
  // Pages stored in reverse order; one TiffData per plane with an explicit IFD (no PlaneCount:
  // defaults to 1 because IFD is given), plus runs with PlaneCount for the first half.
  const fs::path dir = MakeTempDir("ome-explicit");
  const int n = kZ * kC * kT;
  for (const std::string order : {"XYZCT", "XYZTC", "XYCTZ", "XYCZT", "XYTCZ", "XYTZC"}) {
    SCOPED_TRACE(order);
    std::vector<std::array<int64_t, 3>> in_order = PagesInOrder(order);
    std::vector<std::array<int64_t, 3>> pages(in_order.rbegin(), in_order.rend());
    std::string children = "<Channel/><Channel/>";
    for (int64_t z = 0; z < kZ; ++z) {
      for (int64_t c = 0; c < kC; ++c) {
        for (int64_t t = 0; t < kT; ++t) {
          int64_t p = HandPlaneIndex(order, kZ, kC, kT, z, c, t);
          children += "<TiffData IFD=\"" + std::to_string(n - 1 - p) + "\" FirstZ=\"" +
                      std::to_string(z) + "\" FirstC=\"" + std::to_string(c) + "\" FirstT=\"" +
                      std::to_string(t) + "\"/>";
        }
      }
    }
    const fs::path path = dir / (order + ".ome.tif");
    ASSERT_TRUE(WritePages(path, pages, OmeDoc(PixelsAttrs(order, kW, kH, kZ, kC, kT), children)));
    CheckPattern(path, kZ, kC, kT);
  }
  fs::remove_all(dir);
}

TEST(OmeTiffVolumeTest, TiffDataRunsWithPlaneCount) {
  // XYZCT, pages: 2 junk pages, then planes 0..11 (t 0, 1), then planes 12..23 (t 2, 3) mapped by
  // two TiffData runs with explicit IFD and PlaneCount, the second starting at FirstT 2.
  const fs::path dir = MakeTempDir("ome-runs");
  std::vector<std::array<int64_t, 3>> pages = {{0, 0, 0}, {0, 0, 0}};
  std::vector<std::array<int64_t, 3>> in_order = PagesInOrder("XYZCT");
  pages.insert(pages.end(), in_order.begin(), in_order.end());
  const fs::path path = dir / "runs.ome.tif";
  ASSERT_TRUE(WritePages(path, pages,
                         OmeDoc(PixelsAttrs("XYZCT", kW, kH, kZ, kC, kT),
                                "<TiffData IFD=\"2\" PlaneCount=\"12\"/>"
                                "<TiffData IFD=\"14\" FirstT=\"2\" PlaneCount=\"12\"/>")));
  CheckPattern(path, kZ, kC, kT);
  fs::remove_all(dir);
}

// Multi-file: t0.ome.tif holds the master XML and planes of t 0..1; t1.ome.tif (BinaryOnly) t 2..3.
void WriteMultiFile(const fs::path& dir, bool with_companion) {
  const std::string u0 = "urn:uuid:file-0", u1 = "urn:uuid:file-1";
  std::vector<std::array<int64_t, 3>> all = PagesInOrder("XYZCT");
  std::vector<std::array<int64_t, 3>> first(all.begin(), all.begin() + 12);
  std::vector<std::array<int64_t, 3>> second(all.begin() + 12, all.end());
  // The master's own planes are referenced by UUID only (no FileName): they resolve to the file
  // whose OME@UUID matches.
  const std::string children =
      "<Channel Name=\"c0\" Color=\"-16776961\"/><Channel Name=\"c1\" Color=\"65535\"/>"
      "<TiffData IFD=\"0\" PlaneCount=\"12\"><UUID>" +
      u0 +
      "</UUID></TiffData>"
      "<TiffData IFD=\"0\" FirstT=\"2\" PlaneCount=\"12\"><UUID FileName=\"sub/t1.ome.tif\">" +
      u1 + "</UUID></TiffData>";
  const std::string pixels = PixelsAttrs("XYZCT", kW, kH, kZ, kC, kT) +
                             " PhysicalSizeX=\"0.25\" PhysicalSizeY=\"250\" "
                             "PhysicalSizeYUnit=\"nm\" PhysicalSizeZ=\"2\"";
  auto binary_only = [](const std::string& own, const std::string& metadata_file,
                        const std::string& master_uuid) {
    return "<?xml version=\"1.0\"?><OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/"
           "2016-06\" UUID=\"" +
           own + "\"><BinaryOnly MetadataFile=\"" + metadata_file + "\" UUID=\"" + master_uuid +
           "\"/></OME>";
  };
  fs::create_directories(dir / "sub");
  if (with_companion) {
    // The companion names both files explicitly.
    std::string companion_children =
        "<Channel Name=\"c0\" Color=\"-16776961\"/><Channel Name=\"c1\" Color=\"65535\"/>"
        "<TiffData IFD=\"0\" PlaneCount=\"12\"><UUID FileName=\"t0.ome.tif\">" +
        u0 +
        "</UUID></TiffData>"
        "<TiffData IFD=\"0\" FirstT=\"2\" PlaneCount=\"12\"><UUID FileName=\"sub/t1.ome.tif\">" +
        u1 + "</UUID></TiffData>";
    std::ofstream(dir / "set.companion.ome")
        << OmeDoc(pixels, companion_children, "urn:uuid:companion");
    ASSERT_TRUE(WritePages(dir / "t0.ome.tif", first,
                           binary_only(u0, "set.companion.ome", "urn:uuid:companion")));
    ASSERT_TRUE(WritePages(dir / "sub/t1.ome.tif", second,
                           binary_only(u1, "../set.companion.ome", "urn:uuid:companion")));
  } else {
    ASSERT_TRUE(WritePages(dir / "t0.ome.tif", first, OmeDoc(pixels, children, u0)));
    ASSERT_TRUE(WritePages(dir / "sub/t1.ome.tif", second, binary_only(u1, "../t0.ome.tif", u0)));
  }
}

void CheckMultiFileInfo(const fs::path& path) {
  Result<std::unique_ptr<VolumeSource>> opened = Open(path, 0, 3);
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  const volume::VolumeInfo& info = (*opened)->info();
  ASSERT_EQ(info.channel_count(), 2);
  EXPECT_EQ(info.channels[0].name, "c0");
  EXPECT_EQ(info.channels[0].color, (Rgba{255, 0, 0, 255}));
  EXPECT_EQ(info.channels[1].name, "c1");
  EXPECT_EQ(info.channels[1].color, (Rgba{0, 0, 255, 255}));
  EXPECT_DOUBLE_EQ(info.spacing_um[0].value_or(0), 0.25);
  EXPECT_DOUBLE_EQ(info.spacing_um[1].value_or(0), 0.25);
  EXPECT_DOUBLE_EQ(info.spacing_um[2].value_or(0), 2.0);
}

TEST(OmeTiffVolumeTest, MultiFileWithUuidAndFileName) {
  const fs::path dir = MakeTempDir("ome-multi");
  WriteMultiFile(dir, false);
  CheckPattern(dir / "t0.ome.tif", kZ, kC, kT);
  CheckPattern(dir / "sub/t1.ome.tif", kZ, kC, kT);
  CheckMultiFileInfo(dir / "sub/t1.ome.tif");
  fs::remove_all(dir);
}

TEST(OmeTiffVolumeTest, MultiFileWithCompanion) {
  const fs::path dir = MakeTempDir("ome-companion");
  WriteMultiFile(dir, true);
  CheckPattern(dir / "set.companion.ome", kZ, kC, kT);
  CheckPattern(dir / "sub/t1.ome.tif", kZ, kC, kT);
  CheckMultiFileInfo(dir / "t0.ome.tif");
  fs::remove_all(dir);
}

TEST(OmeTiffVolumeTest, StoredPlaneLocatedForUncompressedPagesOnly) {
  const fs::path dir = MakeTempDir("ome-mapped");
  for (uint16_t compression : {uint16_t{COMPRESSION_NONE}, uint16_t{COMPRESSION_ADOBE_DEFLATE}}) {
    const fs::path path = dir / ("c" + std::to_string(compression) + ".ome.tif");
    ASSERT_TRUE(WritePages(path, PagesInOrder("XYCZT"),
                           OmeDoc(PixelsAttrs("XYCZT", kW, kH, kZ, kC, kT), "<TiffData/>"),
                           compression));
    for (int t : {0, 3}) {
      auto source = Open(path, 0, t);
      ASSERT_TRUE(source.ok()) << source.status().ToString();
      for (int c = 0; c < kC; ++c) {
        for (int z = 0; z < kZ; ++z) {
          std::optional<std::vector<std::byte>> view = ReadStoredPlane(**source, c, z);
          ASSERT_EQ(view.has_value(),
                    compression == COMPRESSION_NONE && std::endian::native == std::endian::little);
          if (!view) continue;
          int wrong = 0;
          for (uint32_t y = 0; y < kH; ++y) {
            for (uint32_t x = 0; x < kW; ++x) {
              uint16_t got;
              std::memcpy(&got, view->data() + (y * kW + x) * 2, 2);
              if (got != Pattern(z, c, t, x, y)) ++wrong;
            }
          }
          EXPECT_EQ(wrong, 0) << "z " << z << " c " << c << " t " << t;
        }
      }
      EXPECT_FALSE((*source)->FindStoredPlane(kC, 0).has_value());
      EXPECT_FALSE((*source)->FindStoredPlane(0, kZ).has_value());
      EXPECT_FALSE((*source)->FindStoredPlane(-1, 0).has_value());
    }
  }
  fs::remove_all(dir);
}

TEST(OmeTiffVolumeTest, StoredPlanesOutliveCacheEvictionAcrossManyFiles) {
  if (std::endian::native != std::endian::little) GTEST_SKIP() << "fixtures are little-endian";
  // One plane per file, more files than the source keeps open in its cache: a StoredPlane handed
  // out keeps its file open while reads evict and reopen the cache's files.
  const fs::path dir = MakeTempDir("ome-many");
  constexpr int kFiles = 3 * static_cast<int>(kMaxOpenOmeTiffFiles);
  std::string children;
  for (int z = 0; z < kFiles; ++z) {
    children += "<TiffData FirstZ=\"" + std::to_string(z) +
                "\" PlaneCount=\"1\"><UUID FileName=\"f" + std::to_string(z) +
                ".ome.tif\">urn:uuid:f" + std::to_string(z) + "</UUID></TiffData>";
  }
  for (int z = 0; z < kFiles; ++z) {
    const std::string description =
        z == 0 ? OmeDoc(PixelsAttrs("XYZCT", kW, kH, kFiles, 1, 1), children, "urn:uuid:f0")
               : std::string("not the master");
    ASSERT_TRUE(WritePages(dir / ("f" + std::to_string(z) + ".ome.tif"), {{z, 0, 0}}, description));
  }
  auto source = Open(dir / "f0.ome.tif");
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  std::vector<std::optional<StoredPlane>> stored;
  for (int z = 0; z < kFiles; ++z) stored.push_back((*source)->FindStoredPlane(0, z));
  // Read every plane twice (evicting and reopening files), then read every stored plane.
  for (int round = 0; round < 2; ++round) {
    for (int z = 0; z < kFiles; ++z) {
      std::vector<std::byte> plane = ReadSlab(**source, 0, z, 1);
      ASSERT_EQ(SampleAt(plane, DataType::kUint16, 0), Pattern(z, 0, 0, 0, 0));
    }
  }
  int wrong = 0;
  std::vector<std::byte> plane((*source)->SlabBytes(1));
  for (int z = 0; z < kFiles; ++z) {
    ASSERT_TRUE(stored[z].has_value()) << "z " << z;
    ASSERT_TRUE(stored[z]->file->ReadBytes(stored[z]->offset, plane).ok());
    for (uint32_t y = 0; y < kH; ++y) {
      for (uint32_t x = 0; x < kW; ++x) {
        uint16_t got;
        std::memcpy(&got, plane.data() + (y * kW + x) * 2, 2);
        if (got != Pattern(z, 0, 0, x, y)) ++wrong;
      }
    }
  }
  EXPECT_EQ(wrong, 0);
  fs::remove_all(dir);
}

TEST(OmeTiffVolumeTest, RenamedSingleFileResolvesByOwnUuid) {
  const fs::path dir = MakeTempDir("ome-renamed");
  const fs::path path = dir / "renamed.ome.tif";
  ASSERT_TRUE(WritePages(path, PagesInOrder("XYCZT"),
                         OmeDoc(PixelsAttrs("XYCZT", kW, kH, kZ, kC, kT),
                                "<TiffData PlaneCount=\"24\"><UUID FileName=\"original.ome.tif\">"
                                "urn:uuid:synthetic-0</UUID></TiffData>")));
  CheckPattern(path, kZ, kC, kT);
  fs::remove_all(dir);
}

TEST(OmeTiffVolumeTest, RgbPagesHoldConsecutiveChannels) {
  // SizeC 3 stored as one 3-sample page per z (chunky and planar); one Channel, SamplesPerPixel 3.
  const fs::path dir = MakeTempDir("ome-rgb");
  for (uint16_t planar : {1, 2}) {
    SCOPED_TRACE(planar);
    const fs::path path = dir / ("rgb" + std::to_string(planar) + ".ome.tif");
    TiffFixtureSpec spec;
    spec.width = kW;
    spec.height = kH;
    spec.pages = 2;
    spec.samples_per_pixel = 3;
    spec.bits_per_sample = 8;
    spec.planar_config = planar;
    spec.descriptions = {OmeDoc(PixelsAttrs("XYCZT", kW, kH, 2, 3, 1, "uint8"),
                                "<Channel Name=\"rgb\" SamplesPerPixel=\"3\"/><TiffData/>")};
    auto value = [](uint32_t x, uint32_t y, int page, int sample) {
      return static_cast<double>(page * 100 + sample * 30 + y * 5 + x);
    };
    ASSERT_TRUE(WriteTiffFixture(path, spec, value));
    Result<std::unique_ptr<VolumeSource>> opened = Open(path);
    ASSERT_TRUE(opened.ok()) << opened.status().ToString();
    const volume::VolumeInfo& info = (*opened)->info();
    ASSERT_EQ(info.channel_count(), 3);
    EXPECT_EQ(info.channels[2].name, "rgb");
    EXPECT_EQ(info.channels[0].color, (Rgba{255, 0, 0, 255}));
    EXPECT_EQ(info.channels[2].color, (Rgba{0, 0, 255, 255}));
    for (int c = 0; c < 3; ++c) {
      std::vector<std::byte> slab = ReadSlab(**opened, c, 0, 2);
      for (int z = 0; z < 2; ++z) {
        for (uint32_t y = 0; y < kH; ++y) {
          for (uint32_t x = 0; x < kW; ++x) {
            ASSERT_EQ(SampleAt(slab, DataType::kUint8, (z * kH + y) * kW + x), value(x, y, z, c))
                << "c " << c << " z " << z;
          }
        }
      }
    }
  }
  fs::remove_all(dir);
}

TEST(OmeTiffVolumeTest, SpacingOverrideAndConcurrentReads) {
  const fs::path dir = MakeTempDir("ome-threads");
  const fs::path path = dir / "a.ome.tif";
  ASSERT_TRUE(WritePages(path, PagesInOrder("XYZCT"),
                         OmeDoc(PixelsAttrs("XYZCT", kW, kH, kZ, kC, kT) +
                                    " PhysicalSizeX=\"3\" PhysicalSizeXUnit=\"mm\"",
                                "<TiffData/>")));
  OpenOptions options;
  options.time = 1;
  options.spacing_um[2] = 7.5;
  Result<std::unique_ptr<VolumeSource>> opened = OpenOmeTiff(path, options);
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  VolumeSource& source = **opened;
  EXPECT_DOUBLE_EQ(source.info().spacing_um[0].value_or(0), 3000.0);
  EXPECT_FALSE(source.info().spacing_um[1].has_value());
  EXPECT_DOUBLE_EQ(source.info().spacing_um[2].value_or(0), 7.5);
  std::vector<std::thread> threads;
  std::vector<int> failures(4, 0);
  for (int k = 0; k < 4; ++k) {
    threads.emplace_back([&, k] {
      for (int round = 0; round < 50; ++round) {
        const int c = (k + round) % kC;
        const int z = round % kZ;
        std::vector<std::byte> plane(source.SlabBytes(1));
        if (!source.ReadSlab(c, z, 1, plane).ok()) {
          ++failures[k];
          continue;
        }
        uint16_t v;
        std::memcpy(&v, &plane[2 * (3 * kW + 4)], 2);
        if (v != Pattern(z, c, 1, 4, 3)) ++failures[k];
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(failures, std::vector<int>(4, 0));
  fs::remove_all(dir);
}

// Counts this process's open descriptors that point into `dir`.
int OpenFilesUnder(const fs::path& dir) {
  int count = 0;
  const std::string prefix = fs::canonical(dir).string();
  for (const fs::directory_entry& e : fs::directory_iterator("/proc/self/fd")) {
    std::error_code ec;
    fs::path target = fs::read_symlink(e.path(), ec);
    if (!ec && target.string().rfind(prefix, 0) == 0) ++count;
  }
  return count;
}

TEST(OmeTiffVolumeTest, ManyFilesKeepBoundedDescriptorsOpen) {
  // 48 z planes in 48 files; the master (z 0) holds the XML.
  const fs::path dir = MakeTempDir("ome-many");
  constexpr int kFiles = 48;
  std::string children;
  for (int z = 0; z < kFiles; ++z) {
    children += "<TiffData FirstZ=\"" + std::to_string(z) + "\" IFD=\"0\"><UUID FileName=\"z" +
                std::to_string(z) + ".ome.tif\">urn:uuid:z" + std::to_string(z) +
                "</UUID></TiffData>";
  }
  for (int z = 0; z < kFiles; ++z) {
    std::string description;
    if (z == 0) {
      description = OmeDoc(PixelsAttrs("XYZCT", kW, kH, kFiles, 1, 1), children, "urn:uuid:z0");
    } else {
      description = "<OME UUID=\"urn:uuid:z";
      description += std::to_string(z);
      description += "\"><BinaryOnly MetadataFile=\"z0.ome.tif\" UUID=\"urn:uuid:z0\"/></OME>";
    }
    ASSERT_TRUE(WritePages(dir / ("z" + std::to_string(z) + ".ome.tif"), {{z, 0, 0}}, description));
  }
  Result<std::unique_ptr<VolumeSource>> opened = Open(dir / "z7.ome.tif");
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  EXPECT_LE(OpenFilesUnder(dir), static_cast<int>(kMaxOpenOmeTiffFiles));
  std::vector<std::byte> slab = ReadSlab(**opened, 0, 0, kFiles);
  for (int z = 0; z < kFiles; ++z) {
    ASSERT_EQ(SampleAt(slab, DataType::kUint16, (z * kH + 2) * kW + 3), Pattern(z, 0, 0, 3, 2));
  }
  EXPECT_LE(OpenFilesUnder(dir), static_cast<int>(kMaxOpenOmeTiffFiles));
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// Errors.

class OmeTiffErrorTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = MakeTempDir("ome-errors"); }
  void TearDown() override { fs::remove_all(dir_); }

  // A 3-page uint16 XYZCT file (pages z 0..2) with `description`.
  fs::path Write(const std::string& name, const std::string& description) {
    fs::path path = dir_ / name;
    EXPECT_TRUE(WritePages(path, {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}}, description));
    return path;
  }

  fs::path dir_;
};

TEST_F(OmeTiffErrorTest, XmlClaimsMorePlanesThanIfds) {
  fs::path path =
      Write("short.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 5, 1, 1), "<TiffData/>"));
  ExpectError(Open(path).status(), StatusCode::kCorrupt, {path.string(), "3 IFDs"});
  path = Write("ifd.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 1),
                                     "<TiffData IFD=\"0\" PlaneCount=\"2\"/>"
                                     "<TiffData IFD=\"7\" FirstZ=\"2\"/>"));
  ExpectError(Open(path).status(), StatusCode::kCorrupt, {path.string(), "IFDs 7..7"});
  // Pages missing for a time point other than the one opened are still caught in this file.
  path = Write("later.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 2), "<TiffData/>"));
  ExpectError(Open(path, 0, 0).status(), StatusCode::kCorrupt, {path.string(), "3 IFDs"});
}

TEST_F(OmeTiffErrorTest, PlaneNotMapped) {
  fs::path path = Write("gap.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 1),
                                              "<TiffData IFD=\"0\" PlaneCount=\"2\"/>"));
  ExpectError(Open(path).status(), StatusCode::kCorrupt, {path.string(), "z 2, c 0, t 0"});
  path = Write("none.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 1), ""));
  ExpectError(Open(path).status(), StatusCode::kCorrupt, {path.string(), "no TiffData"});
  path = Write("over.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 1),
                                      "<TiffData FirstZ=\"1\" PlaneCount=\"3\"/>"));
  ExpectError(Open(path).status(), StatusCode::kCorrupt, {path.string(), "runs past"});
}

TEST_F(OmeTiffErrorTest, ReferencedFileMissing) {
  fs::path path = Write("master.ome.tif",
                        OmeDoc(PixelsAttrs("XYZCT", kW, kH, 4, 1, 1),
                               "<TiffData PlaneCount=\"3\"/>"
                               "<TiffData FirstZ=\"3\"><UUID FileName=\"gone.ome.tif\">urn:uuid:x"
                               "</UUID></TiffData>"));
  ExpectError(Open(path).status(), StatusCode::kNotFound,
              {path.string(), (dir_ / "gone.ome.tif").string()});
  fs::path member =
      Write("member.ome.tif", "<OME><BinaryOnly MetadataFile=\"lost.ome.tif\" UUID=\"u\"/></OME>");
  ExpectError(Open(member).status(), StatusCode::kNotFound,
              {member.string(), (dir_ / "lost.ome.tif").string()});
  ExpectError(Open(dir_ / "absent.ome.tif").status(), StatusCode::kNotFound,
              {(dir_ / "absent.ome.tif").string()});
}

// Issue 8: malformed OME-XML is never silently reinterpreted. A TIFF whose own OME-XML does not
// parse is read as the plain TIFF stack it also is (as tifffile does), with a warning naming the
// file and the XML's problem; a malformed document the opened file only refers to (a BinaryOnly
// master, a companion) is an error naming that document.
TEST_F(OmeTiffErrorTest, MalformedXmlOfTheFileItselfReadsAsPlainTiffWithAWarning) {
  struct Case {
    const char* name;
    std::string xml;
    const char* problem;  // What the warning must say about the XML.
  };
  const Case cases[] = {
      {"truncated.ome.tif", "<?xml version=\"1.0\"?><OME><Image ID=\"i\"><Pixels", "malformed"},
      {"sizex.ome.tif",
       OmeDoc("DimensionOrder=\"XYZCT\" Type=\"uint16\" SizeX=\"99999999999\" SizeY=\"4\" "
              "SizeZ=\"3\" SizeC=\"1\" SizeT=\"1\"",
              "<TiffData/>"),
       "SizeX"},
      {"prolog.ome.tif", "<?xml version=\"1.0\" <OME><Image/></OME>", "malformed"},
      // A member of a multi-file set whose own (BinaryOnly) XML is broken.
      {"member.ome.tif", "<OME><BinaryOnly MetadataFile=\"m.ome.tif\"></OME>", "malformed"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const fs::path path = Write(c.name, c.xml);
    for (bool through_open_volume : {false, true}) {
      auto source = through_open_volume ? OpenVolume(path, OpenOptions{}) : Open(path);
      ASSERT_TRUE(source.ok()) << source.status().ToString();
      const volume::VolumeInfo& info = (*source)->info();
      EXPECT_EQ(info.format, "tiff");
      EXPECT_EQ(info.size, (std::array<int64_t, 3>{kW, kH, 3}));
      EXPECT_EQ(info.channel_count(), 1);
      ASSERT_EQ(info.warnings.size(), 1u);
      const std::string& warning = info.warnings[0];
      for (const std::string& needle : {path.string(), std::string("OME-XML"),
                                        std::string(c.problem), std::string("plain TIFF")}) {
        EXPECT_NE(warning.find(needle), std::string::npos)
            << "'" << needle << "' not in: " << warning;
      }
      // The pages read as they are: page k is z plane k.
      for (int z = 0; z < 3; ++z) {
        std::vector<std::byte> plane = ReadSlab(**source, 0, z, 1);
        EXPECT_EQ(SampleAt(plane, DataType::kUint16, 5), Pattern(z, 0, 0, 5 % kW, 5 / kW));
      }
    }
  }
}

TEST_F(OmeTiffErrorTest, MalformedXmlThatCannotBeReadAsPlainTiffIsAnError) {
  // Pages of two sizes: no plain stack either. The error says both.
  const fs::path path = dir_ / "mixed.ome.tif";
  {
    TiffFixtureSpec spec;
    spec.width = kW;
    spec.height = kH;
    spec.descriptions = {"<OME><Image"};
    ASSERT_TRUE(WriteTiffFixture(path, spec));
    TIFF* tif = TIFFOpen(path.c_str(), "a");
    ASSERT_NE(tif, nullptr);
    const uint16_t pixels[4] = {1, 2, 3, 4};
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 2);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 2);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 16);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 2);
    ASSERT_EQ(TIFFWriteEncodedStrip(tif, 0, const_cast<uint16_t*>(pixels), sizeof pixels),
              static_cast<tmsize_t>(sizeof pixels));
    TIFFClose(tif);
  }
  ExpectError(Open(path).status(), StatusCode::kCorrupt,
              {path.string(), "malformed", "nor can the file be read as a plain TIFF stack",
               "pages differ"});
}

TEST_F(OmeTiffErrorTest, MalformedXmlElsewhereIsAnErrorNamingIt) {
  // The master a member's BinaryOnly names.
  const fs::path master = Write("master.ome.tif", "<OME><Image ID=\"i\"><Pixels");
  const fs::path member = Write(
      "member.ome.tif", "<OME><BinaryOnly MetadataFile=\"master.ome.tif\" UUID=\"u\"/></OME>");
  ExpectError(Open(member).status(), StatusCode::kCorrupt,
              {member.string(), master.string(), "BinaryOnly", "malformed"});
  // The master itself reads as a plain TIFF, with the warning.
  auto opened = Open(master);
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  EXPECT_EQ((*opened)->info().warnings.size(), 1u);
  // A companion file: XML only, nothing else to read it as.
  fs::path companion = dir_ / "bad.companion.ome";
  std::ofstream(companion) << "<OME><Image></OME>";
  ExpectError(Open(companion).status(), StatusCode::kCorrupt, {companion.string(), "malformed"});
  ExpectError(OpenVolume(companion, OpenOptions{}).status(), StatusCode::kCorrupt,
              {companion.string(), "malformed"});
  // Well-formed OME-XML that contradicts the file stays an error (TiffData beyond the pages).
  const fs::path contradicts =
      Write("contradicts.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 5, 1, 1), "<TiffData/>"));
  ExpectError(Open(contradicts).status(), StatusCode::kCorrupt, {contradicts.string(), "3 IFDs"});
}

TEST_F(OmeTiffErrorTest, AbsurdSizes) {
  // (SizeX over 2^31 is invalid OME-XML: see MalformedXmlOfTheFileItselfReadsAsPlainTiff...)
  // Each size allowed, but one plane beyond the plane limit.
  fs::path path =
      Write("wide.ome.tif", OmeDoc("DimensionOrder=\"XYZCT\" Type=\"uint16\" "
                                   "SizeX=\"2147483648\" SizeY=\"2147483648\" SizeZ=\"1\" "
                                   "SizeC=\"1\" SizeT=\"1\"",
                                   "<TiffData/>"));
  ExpectError(Open(path).status(), StatusCode::kResourceExhausted, {path.string()});
  // Billions of planes of one voxel.
  path = Write("planes.ome.tif", OmeDoc("DimensionOrder=\"XYZCT\" Type=\"uint16\" SizeX=\"5\" "
                                        "SizeY=\"4\" SizeZ=\"2147483648\" SizeC=\"64\" "
                                        "SizeT=\"1000\"",
                                        "<TiffData/>"));
  ExpectError(Open(path).status(), StatusCode::kResourceExhausted,
              {path.string(), "planes per time point"});
  // More channels than a volume may have (volume::kMaxChannels), refused with the limit stated.
  path = Write("channels.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 1, 65, 1), "<TiffData/>"));
  ExpectError(Open(path).status(), StatusCode::kResourceExhausted,
              {path.string(), "SizeC=65", "65 channels, more than the 64 Octoscope supports"});
}

TEST_F(OmeTiffErrorTest, PixelsDisagreeWithPages) {
  fs::path path =
      Write("type.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 1, "uint8"), "<TiffData/>"));
  ExpectError(Open(path).status(), StatusCode::kCorrupt, {path.string(), "uint16", "uint8"});
  path = Write("width.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW + 1, kH, 3, 1, 1), "<TiffData/>"));
  ExpectError(Open(path).status(), StatusCode::kCorrupt, {path.string(), "5x4"});
  path = Write("rgb.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 1, 3, 1),
                                     "<Channel SamplesPerPixel=\"3\"/><TiffData/>"));
  ExpectError(Open(path).status(), StatusCode::kCorrupt, {path.string(), "samples per pixel"});
}

TEST_F(OmeTiffErrorTest, SeriesAndTimeOutOfRange) {
  fs::path path = Write("t.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 1), "<TiffData/>"));
  ExpectError(Open(path, 1, 0).status(), StatusCode::kOutOfRange, {path.string(), "series 1"});
  ExpectError(Open(path, 0, 1).status(), StatusCode::kOutOfRange, {path.string(), "time point 1"});
  ExpectError(Open(path, 0, -1).status(), StatusCode::kOutOfRange, {path.string()});
}

// Slab-request errors name the file (CheckSlabRequest alone does not know it).
TEST_F(OmeTiffErrorTest, SlabRequestErrorsNameTheFile) {
  fs::path path =
      Write("slab.ome.tif", OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 1), "<TiffData/>"));
  Result<std::unique_ptr<VolumeSource>> opened = Open(path);
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  std::vector<std::byte> plane((*opened)->SlabBytes(1));
  ExpectError((*opened)->ReadSlab(1, 0, 1, plane), StatusCode::kOutOfRange,
              {path.string(), "channel 1"});
  ExpectError((*opened)->ReadSlab(0, 3, 1, plane), StatusCode::kOutOfRange, {path.string()});
  std::vector<std::byte> small(3);
  ExpectError((*opened)->ReadSlab(0, 0, 1, small), StatusCode::kInvalidArgument, {path.string()});
}

// A decoding error names the file and IFD once (ReadPlane's message already starts with them),
// followed by the plane it belongs to.
TEST_F(OmeTiffErrorTest, DecodingErrorNamesFileOnceAndThePlane) {
  fs::path path = dir_ / "garbled.ome.tif";
  ASSERT_TRUE(WritePages(path, {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}},
                         OmeDoc(PixelsAttrs("XYZCT", kW, kH, 3, 1, 1), "<TiffData/>"),
                         8 /* COMPRESSION_ADOBE_DEFLATE */));
  {
    // Page 0's only strip starts right after the 8-byte header: garble its deflate stream.
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(8);
    f.write("\xff\xff\xff\xff\xff\xff", 6);
  }
  Result<std::unique_ptr<VolumeSource>> opened = Open(path);
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  std::vector<std::byte> plane((*opened)->SlabBytes(1));
  Status st = (*opened)->ReadSlab(0, 0, 1, plane);
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.code(), StatusCode::kCorrupt) << st.ToString();
  const std::string& m = st.message();
  const size_t first = m.find(path.string());
  ASSERT_EQ(first, 0u) << m;
  EXPECT_EQ(m.find(path.string(), first + 1), std::string::npos) << "file named twice: " << m;
  EXPECT_NE(m.find("IFD 0"), std::string::npos) << m;
  EXPECT_NE(m.find("(plane z 0, channel 0)"), std::string::npos) << m;
  // The other planes still read.
  EXPECT_TRUE((*opened)->ReadSlab(0, 1, 1, plane).ok());
}

// fs::absolute throws when the working directory is gone; opening a relative path must then
// return an error instead.
TEST_F(OmeTiffErrorTest, RelativePathWithoutWorkingDirectoryIsAnError) {
  const fs::path previous = fs::current_path();
  const fs::path gone = dir_ / "gone";
  fs::create_directories(gone);
  ASSERT_EQ(::chdir(gone.c_str()), 0);
  fs::remove(gone);
  Result<std::unique_ptr<VolumeSource>> opened(InternalError("not run"));
  try {
    opened = Open("relative.ome.tif");
  } catch (const std::exception& e) {
    ADD_FAILURE() << "threw: " << e.what();
  }
  ASSERT_EQ(::chdir(previous.c_str()), 0);
  ASSERT_FALSE(opened.ok());
  EXPECT_NE(opened.status().code(), StatusCode::kInternal) << opened.status().ToString();
  EXPECT_NE(opened.status().message().find("relative.ome.tif"), std::string::npos)
      << opened.status().ToString();
}

TEST_F(OmeTiffErrorTest, NotOme) {
  fs::path path = Write("plain.tif", "just a description");
  ExpectError(Open(path).status(), StatusCode::kUnsupported, {path.string()});
  fs::path text = dir_ / "notes.companion.ome";
  std::ofstream(text) << "hello";
  ExpectError(Open(text).status(), StatusCode::kUnsupported, {text.string()});
}

// ---------------------------------------------------------------------------------------------
// Confined to the dataset's own folder, as the server opens a dataset (issue 28): the files an
// OME-XML document names must lie in the folder holding the file that was opened.

class OmeTiffConfinedTest : public testing::ConfinedTest {
 protected:
  // Three uint16 pages, planes z 0..2, holding `description`.
  static void WriteThree(const fs::path& path, const std::string& description) {
    ASSERT_TRUE(WritePages(path, {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}}, description));
  }
  static std::string Pixels() { return PixelsAttrs("XYZCT", kW, kH, 3, 1, 1); }
};

TEST_F(OmeTiffConfinedTest, ReferencesOutOfTheFolderAreRefusedAlikeWhetherOrNotTheyExist) {
  WriteThree(outside_ / "private.ome.tif", OmeDoc(Pixels(), "<TiffData/>", "urn:uuid:private"));
  const std::vector<std::string> targets = {"../outside/private.ome.tif", "../outside/none.ome.tif",
                                            (outside_ / "private.ome.tif").string(),
                                            (outside_ / "none.ome.tif").string(),
                                            "sub/../../outside/private.ome.tif"};
  for (size_t i = 0; i < targets.size(); ++i) {
    SCOPED_TRACE(targets[i]);
    // A companion file whose TiffData names the file.
    const fs::path companion = own_ / ("c" + std::to_string(i) + ".companion.ome");
    std::ofstream(companion) << OmeDoc(
        Pixels(),
        "<TiffData><UUID FileName=\"" + targets[i] + "\">urn:uuid:private</UUID></TiffData>",
        "urn:uuid:companion");
    ExpectRefusal(OpenConfined(companion).status(), companion);
    // A member whose BinaryOnly names it as the master.
    const fs::path member = own_ / ("m" + std::to_string(i) + ".ome.tif");
    WriteThree(member,
               "<OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/2016-06\" "
               "UUID=\"urn:uuid:m\"><BinaryOnly MetadataFile=\"" +
                   targets[i] + "\" UUID=\"urn:uuid:private\"/></OME>");
    ExpectRefusal(OpenConfined(member).status(), member);
  }
  // The command-line tools keep reading what the user named.
  Result<std::unique_ptr<VolumeSource>> unconfined = OpenVolume(own_ / "c0.companion.ome", {});
  ASSERT_TRUE(unconfined.ok()) << unconfined.status().ToString();
  EXPECT_EQ((*unconfined)->info().size[2], 3);
}

TEST_F(OmeTiffConfinedTest, ReferencesInsideTheFolderStillWork) {
  WriteMultiFile(own_, true);
  for (const fs::path& path : {own_ / "set.companion.ome", own_ / "t0.ome.tif"}) {
    for (int t = 0; t < kT; ++t) {
      OpenOptions options;
      options.time = t;
      Result<std::unique_ptr<VolumeSource>> confined = OpenConfined(path, options);
      ASSERT_TRUE(confined.ok()) << confined.status().ToString();
      Result<std::unique_ptr<VolumeSource>> open = OpenVolume(path, options);
      ASSERT_TRUE(open.ok()) << open.status().ToString();
      for (int c = 0; c < kC; ++c) {
        EXPECT_EQ(ReadSlab(**confined, c, 0, kZ), ReadSlab(**open, c, 0, kZ)) << path;
      }
    }
  }
  // A member in a sub-folder: its master is outside the folder holding it (open the master).
  ExpectRefusal(OpenConfined(own_ / "sub" / "t1.ome.tif").status(), own_ / "sub" / "t1.ome.tif");
}

}  // namespace
}  // namespace octoscope::io
