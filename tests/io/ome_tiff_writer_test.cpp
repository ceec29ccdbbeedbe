// Round trips through the OME-TIFF writer, decoded with libtiff directly (not our readers) and
// the OME-XML parsed with pugixml, so the test is independent of the code that reads OME-TIFF.
#include "io/ome_tiff_writer.h"

#include <gtest/gtest.h>
#include <tiffio.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <pugixml.hpp>
#include <string>
#include <vector>

#include "io/synthetic_embryo.h"
#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

// A tiny source whose voxel (x, y, z, c) is a formula, in any sample type.
class PatternSource : public VolumeSource {
 public:
  PatternSource(volume::DataType dtype, std::array<int64_t, 3> size, int channels) {
    info_.format = "pattern";
    info_.size = size;
    info_.dtype = dtype;
    for (int c = 0; c < channels; ++c) info_.channels.push_back({"ch" + std::to_string(c), {}});
  }
  const volume::VolumeInfo& info() const override { return info_; }
  volume::VolumeInfo& mutable_info() { return info_; }

  static double Value(volume::DataType dtype, int64_t x, int64_t y, int64_t z, int c) {
    const double v = static_cast<double>((x * 7 + y * 13 + z * 31 + c * 101) % 251);
    if (volume::IsFloat(dtype)) return (v - 125.5) * 0.37;
    if (volume::IsSigned(dtype)) return v - 125;
    return v * (volume::BytesPerSample(dtype) > 1 ? 211 : 1);
  }

  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    OCTO_RETURN_IF_ERROR(CheckSlabRequest(info_, channel, z0, nz, out.size()));
    if (channel == fail_channel_) return IoError("pattern: simulated read failure");
    std::byte* p = out.data();
    for (int64_t z = z0; z < z0 + nz; ++z) {
      for (int64_t y = 0; y < info_.size[1]; ++y) {
        for (int64_t x = 0; x < info_.size[0]; ++x) {
          p = Store(Value(info_.dtype, x, y, z, channel), p);
        }
      }
    }
    return Status::Ok();
  }

  void set_fail_channel(int c) { fail_channel_ = c; }

 private:
  std::byte* Store(double v, std::byte* p) const {
    auto put = [&](auto typed) {
      std::memcpy(p, &typed, sizeof(typed));
      return p + sizeof(typed);
    };
    switch (info_.dtype) {
      case volume::DataType::kUint8:
        return put(static_cast<uint8_t>(v));
      case volume::DataType::kInt8:
        return put(static_cast<int8_t>(v));
      case volume::DataType::kUint16:
        return put(static_cast<uint16_t>(v));
      case volume::DataType::kInt16:
        return put(static_cast<int16_t>(v));
      case volume::DataType::kUint32:
        return put(static_cast<uint32_t>(v) * 65537u);
      case volume::DataType::kInt32:
        return put(static_cast<int32_t>(v) * 65537);
      case volume::DataType::kFloat32:
        return put(static_cast<float>(v));
      case volume::DataType::kFloat64:
        return put(v / 3);
    }
    return p;
  }

  volume::VolumeInfo info_;
  int fail_channel_ = -1;
};

struct DecodedFile {
  bool big_tiff = false;
  int ifd_count = 0;
  std::string description;
  std::vector<std::vector<std::byte>> planes;  // Per IFD.
};

// Decodes every IFD with libtiff, checking the per-IFD tags against the expected layout.
DecodedFile DecodeWithLibtiff(const fs::path& path, const volume::VolumeInfo& info) {
  DecodedFile file;
  TIFF* tif = TIFFOpen(path.c_str(), "r");
  EXPECT_NE(tif, nullptr) << path;
  if (!tif) return file;
  file.big_tiff = TIFFIsBigTIFF(tif);
  const size_t bps = volume::BytesPerSample(info.dtype);
  const uint16_t format = volume::IsFloat(info.dtype)    ? SAMPLEFORMAT_IEEEFP
                          : volume::IsSigned(info.dtype) ? SAMPLEFORMAT_INT
                                                         : SAMPLEFORMAT_UINT;
  do {
    uint32_t width = 0, height = 0;
    uint16_t bits = 0, sample_format = SAMPLEFORMAT_UINT, samples = 0;
    TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &width);
    TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &height);
    TIFFGetField(tif, TIFFTAG_BITSPERSAMPLE, &bits);
    TIFFGetField(tif, TIFFTAG_SAMPLEFORMAT, &sample_format);
    TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &samples);
    EXPECT_EQ(width, info.size[0]);
    EXPECT_EQ(height, info.size[1]);
    EXPECT_EQ(bits, 8 * bps);
    EXPECT_EQ(sample_format, format);
    EXPECT_EQ(samples, 1);
    if (file.ifd_count == 0) {
      char* text = nullptr;
      if (TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &text) && text) file.description = text;
    }
    const size_t row_bytes = width * bps;
    std::vector<std::byte> plane(row_bytes * height);
    if (TIFFIsTiled(tif)) {
      uint32_t tw = 0, th = 0;
      TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tw);
      TIFFGetField(tif, TIFFTAG_TILELENGTH, &th);
      std::vector<std::byte> tile(TIFFTileSize(tif));
      for (uint32_t y0 = 0; y0 < height; y0 += th) {
        for (uint32_t x0 = 0; x0 < width; x0 += tw) {
          EXPECT_GE(TIFFReadEncodedTile(tif, TIFFComputeTile(tif, x0, y0, 0, 0), tile.data(),
                                        static_cast<tmsize_t>(tile.size())),
                    0);
          for (uint32_t y = y0; y < std::min(height, y0 + th); ++y) {
            std::memcpy(plane.data() + y * row_bytes + x0 * bps, tile.data() + (y - y0) * tw * bps,
                        (std::min(width, x0 + tw) - x0) * bps);
          }
        }
      }
    } else {
      uint32_t rows_per_strip = 0;
      TIFFGetFieldDefaulted(tif, TIFFTAG_ROWSPERSTRIP, &rows_per_strip);
      for (uint32_t strip = 0; strip < TIFFNumberOfStrips(tif); ++strip) {
        const uint32_t row = strip * rows_per_strip;
        const size_t bytes = std::min(rows_per_strip, height - row) * row_bytes;
        EXPECT_EQ(TIFFReadEncodedStrip(tif, strip, plane.data() + row * row_bytes,
                                       static_cast<tmsize_t>(bytes)),
                  static_cast<tmsize_t>(bytes));
      }
    }
    file.planes.push_back(std::move(plane));
    ++file.ifd_count;
  } while (TIFFReadDirectory(tif));
  TIFFClose(tif);
  return file;
}

// Asserts every IFD (z + SizeZ * c) equals the source's plane.
void ExpectPlanesMatchSource(const DecodedFile& file, VolumeSource& source) {
  const volume::VolumeInfo& info = source.info();
  ASSERT_EQ(file.ifd_count, info.size[2] * info.channel_count());
  std::vector<std::byte> expected(source.SlabBytes(1));
  for (int c = 0; c < info.channel_count(); ++c) {
    for (int64_t z = 0; z < info.size[2]; ++z) {
      ASSERT_TRUE(source.ReadSlab(c, z, 1, expected).ok());
      const auto& got = file.planes[z + info.size[2] * c];
      ASSERT_EQ(got.size(), expected.size());
      EXPECT_EQ(std::memcmp(got.data(), expected.data(), expected.size()), 0)
          << "plane z=" << z << " c=" << c;
    }
  }
}

std::vector<std::string> DirectoryNames(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(dir)) names.push_back(entry.path().filename());
  std::sort(names.begin(), names.end());
  return names;
}

class OmeTiffWriterTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = octoscope::testing::MakeTempDir("ome-writer"); }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(OmeTiffWriterTest, EmbryoRoundTripsWithCompleteOmeXml) {
  SyntheticEmbryoOptions embryo_options;
  embryo_options.size = {40, 30, 12};
  embryo_options.channels = 3;
  auto embryo = SyntheticEmbryo::Create(embryo_options);
  ASSERT_TRUE(embryo.ok());
  const fs::path path = dir_ / "embryo.ome.tif";
  OmeTiffWriteOptions options;
  options.slab_bytes = 40 * 30 * 2 * 5;  // Slabs of 5 planes: exercises partial last slabs.
  std::vector<std::pair<uint64_t, uint64_t>> progress;
  options.progress = [&](uint64_t done, uint64_t total) { progress.emplace_back(done, total); };
  Status s = WriteOmeTiff(**embryo, path, options);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(DirectoryNames(dir_), std::vector<std::string>{"embryo.ome.tif"});  // No .tmp left.

  ASSERT_EQ(progress.size(), 36u);
  for (size_t i = 0; i < progress.size(); ++i) {
    EXPECT_EQ(progress[i], std::make_pair(uint64_t{i + 1}, uint64_t{36}));
  }

  DecodedFile file = DecodeWithLibtiff(path, (*embryo)->info());
  EXPECT_FALSE(file.big_tiff);
  ExpectPlanesMatchSource(file, **embryo);

  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(file.description.c_str())) << file.description;
  pugi::xml_node ome = doc.child("OME");
  ASSERT_TRUE(ome);
  EXPECT_STREQ(ome.attribute("xmlns").value(), "http://www.openmicroscopy.org/Schemas/OME/2016-06");
  const std::string uuid = ome.attribute("UUID").value();
  EXPECT_EQ(uuid.rfind("urn:uuid:", 0), 0u);
  EXPECT_EQ(uuid.size(), 9u + 36u);
  pugi::xml_node image = ome.child("Image");
  EXPECT_STREQ(image.attribute("Name").value(), "embryo");
  pugi::xml_node pixels = image.child("Pixels");
  ASSERT_TRUE(pixels);
  EXPECT_STREQ(pixels.attribute("DimensionOrder").value(), "XYZCT");
  EXPECT_STREQ(pixels.attribute("Type").value(), "uint16");
  EXPECT_EQ(pixels.attribute("SizeX").as_int(), 40);
  EXPECT_EQ(pixels.attribute("SizeY").as_int(), 30);
  EXPECT_EQ(pixels.attribute("SizeZ").as_int(), 12);
  EXPECT_EQ(pixels.attribute("SizeC").as_int(), 3);
  EXPECT_EQ(pixels.attribute("SizeT").as_int(), 1);
  EXPECT_DOUBLE_EQ(pixels.attribute("PhysicalSizeX").as_double(), 0.4);
  EXPECT_DOUBLE_EQ(pixels.attribute("PhysicalSizeZ").as_double(), 2.0);
  EXPECT_STREQ(pixels.attribute("PhysicalSizeZUnit").value(), "\xC2\xB5m");
  std::vector<std::string> names;
  std::vector<int> colors;
  for (pugi::xml_node channel : pixels.children("Channel")) {
    names.push_back(channel.attribute("Name").value());
    colors.push_back(channel.attribute("Color").as_int());
  }
  EXPECT_EQ(names, (std::vector<std::string>{"nuclei", "membranes", "spots"}));
  // Signed RGBA: green 0x00FF00FF, magenta 0xFF00FFFF (negative as int32).
  ASSERT_EQ(colors.size(), 3u);
  EXPECT_EQ(colors[1], 0x00FF00FF);
  EXPECT_EQ(colors[2], static_cast<int32_t>(0xFF00FFFFu));
  pugi::xml_node tiff_data = pixels.child("TiffData");
  EXPECT_EQ(tiff_data.attribute("IFD").as_int(), 0);
  EXPECT_EQ(tiff_data.attribute("PlaneCount").as_int(), 36);
  EXPECT_STREQ(tiff_data.child("UUID").attribute("FileName").value(), "embryo.ome.tif");
  EXPECT_EQ(tiff_data.child("UUID").text().as_string(), uuid);
}

TEST_F(OmeTiffWriterTest, EveryDataTypeAndCompressionRoundTrips) {
  using volume::DataType;
  const std::vector<DataType> types = {DataType::kUint8,   DataType::kInt8,   DataType::kUint16,
                                       DataType::kInt16,   DataType::kUint32, DataType::kInt32,
                                       DataType::kFloat32, DataType::kFloat64};
  const std::vector<TiffCompression> compressions = {TiffCompression::kNone,
                                                     TiffCompression::kDeflate,
                                                     TiffCompression::kZstd, TiffCompression::kLzw};
  int case_index = 0;
  for (DataType type : types) {
    for (TiffCompression compression : compressions) {
      if (compression == TiffCompression::kZstd && !TIFFIsCODECConfigured(COMPRESSION_ZSTD))
        continue;
      SCOPED_TRACE(std::string(volume::NumpyName(type)) + " " +
                   std::string(TiffCompressionName(compression)));
      PatternSource source(type, {21, 13, 3}, 2);
      OmeTiffWriteOptions options;
      options.compression = compression;
      options.tile_size = case_index % 2 ? 16 : 0;  // Alternate strips and (padded) tiles.
      const fs::path path = dir_ / ("case" + std::to_string(case_index++) + ".ome.tif");
      Status s = WriteOmeTiff(source, path, options);
      ASSERT_TRUE(s.ok()) << s.ToString();
      DecodedFile file = DecodeWithLibtiff(path, source.info());
      ExpectPlanesMatchSource(file, source);
      pugi::xml_document doc;
      ASSERT_TRUE(doc.load_string(file.description.c_str()));
      pugi::xml_node pixels = doc.child("OME").child("Image").child("Pixels");
      EXPECT_EQ(volume::DataTypeFromOmeName(pixels.attribute("Type").value()), type);
      // No spacing known: no physical sizes claimed.
      EXPECT_FALSE(pixels.attribute("PhysicalSizeX"));
    }
  }
}

TEST_F(OmeTiffWriterTest, BigTiffCanBeForced) {
  PatternSource source(volume::DataType::kInt8, {17, 9, 4}, 2);
  OmeTiffWriteOptions options;
  options.big_tiff = BigTiffMode::kAlways;
  options.compression = TiffCompression::kLzw;
  const fs::path path = dir_ / "big.ome.tif";
  ASSERT_TRUE(WriteOmeTiff(source, path, options).ok());
  DecodedFile file = DecodeWithLibtiff(path, source.info());
  EXPECT_TRUE(file.big_tiff);
  ExpectPlanesMatchSource(file, source);
  EXPECT_EQ(DirectoryNames(dir_), std::vector<std::string>{"big.ome.tif"});
}

TEST_F(OmeTiffWriterTest, NamesAreEscapedInTheXml) {
  PatternSource source(volume::DataType::kUint16, {4, 4, 1}, 2);
  source.mutable_info().channels[0].name = "a<b & \"c\" > 'd'";
  source.mutable_info().channels[1].name =
      "tab\tand\x01"
      "control";
  source.mutable_info().channels[1].color = volume::Rgba{255, 255, 255, 255};
  OmeTiffWriteOptions options;
  options.image_name = "<img> & co";
  const fs::path path = dir_ / "names.ome.tif";
  ASSERT_TRUE(WriteOmeTiff(source, path, options).ok());
  DecodedFile file = DecodeWithLibtiff(path, source.info());
  EXPECT_EQ(file.description.find("a<b"), std::string::npos);
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(file.description.c_str()));
  pugi::xml_node image = doc.child("OME").child("Image");
  EXPECT_STREQ(image.attribute("Name").value(), "<img> & co");
  pugi::xml_node channel = image.child("Pixels").child("Channel");
  EXPECT_STREQ(channel.attribute("Name").value(), "a<b & \"c\" > 'd'");
  EXPECT_FALSE(channel.attribute("Color"));
  channel = channel.next_sibling("Channel");
  EXPECT_STREQ(channel.attribute("Name").value(), "tab\tand control");
  EXPECT_EQ(channel.attribute("Color").as_int(), -1);  // 0xFFFFFFFF.
}

TEST_F(OmeTiffWriterTest, FailuresLeaveNoFile) {
  PatternSource source(volume::DataType::kUint16, {8, 8, 3}, 3);
  // A missing directory.
  Status s = WriteOmeTiff(source, dir_ / "missing" / "a.ome.tif", {});
  EXPECT_EQ(s.code(), StatusCode::kIoError);
  EXPECT_NE(s.message().find("a.ome.tif"), std::string::npos) << s.message();
  // A bad tile size.
  OmeTiffWriteOptions tiles;
  tiles.tile_size = 24;
  EXPECT_EQ(WriteOmeTiff(source, dir_ / "b.ome.tif", tiles).code(), StatusCode::kInvalidArgument);
  // The source fails half way: its error comes back, and neither file nor .tmp remains.
  source.set_fail_channel(1);
  s = WriteOmeTiff(source, dir_ / "c.ome.tif", {});
  EXPECT_EQ(s.code(), StatusCode::kIoError);
  EXPECT_NE(s.message().find("simulated read failure"), std::string::npos) << s.message();
  EXPECT_TRUE(DirectoryNames(dir_).empty());
}

TEST_F(OmeTiffWriterTest, OverwritesAnExistingFile) {
  PatternSource small(volume::DataType::kUint8, {5, 5, 1}, 1);
  PatternSource larger(volume::DataType::kUint8, {9, 7, 2}, 1);
  const fs::path path = dir_ / "x.ome.tif";
  ASSERT_TRUE(WriteOmeTiff(small, path, {}).ok());
  ASSERT_TRUE(WriteOmeTiff(larger, path, {}).ok());
  ExpectPlanesMatchSource(DecodeWithLibtiff(path, larger.info()), larger);
}

TEST(TiffCompressionNameTest, ParsesNames) {
  EXPECT_EQ(TiffCompressionFromName("deflate"), TiffCompression::kDeflate);
  EXPECT_EQ(TiffCompressionFromName("ZSTD"), TiffCompression::kZstd);
  EXPECT_EQ(TiffCompressionFromName("lzw"), TiffCompression::kLzw);
  EXPECT_EQ(TiffCompressionFromName("none"), TiffCompression::kNone);
  EXPECT_EQ(TiffCompressionFromName("jpeg"), std::nullopt);
  EXPECT_EQ(TiffCompressionFromName(""), std::nullopt);
}

}  // namespace
}  // namespace octoscope::io
