#include "io/voreen_vvd.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <span>
#include <string>
#include <vector>

#include "io/confined_fixture.h"
#include "io/raw_volume.h"
#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

const std::filesystem::path kWalnutDir =
    std::filesystem::path(OCTOSCOPE_TESTDATA) / "voreen_walnut";

void WriteText(const std::filesystem::path& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

std::string Vvd(const std::string& raw_attributes, const std::string& spacing) {
  return "<?xml version=\"1.0\" ?>\n<VoreenData version=\"1\"><Volumes><Volume>"
         "<RawData " +
         raw_attributes + " /><MetaData>" + spacing +
         "</MetaData></Volume></Volumes></VoreenData>\n";
}

TEST(VoreenVvdTest, WalnutHeader) {
  Result<RawLayout> layout = ReadVoreenVvd(kWalnutDir / "walnut.vvd");
  ASSERT_TRUE(layout.ok()) << layout.status().ToString();
  EXPECT_EQ(layout->data_file, kWalnutDir / "walnut.raw");
  EXPECT_EQ(layout->size, (std::array<int64_t, 3>{128, 96, 114}));
  EXPECT_EQ(layout->channels, 1);
  EXPECT_EQ(layout->dtype, volume::DataType::kUint16);
  EXPECT_FALSE(layout->big_endian);
  EXPECT_FALSE(layout->interleaved);
  EXPECT_EQ(layout->header_bytes, 0u);
  for (int axis = 0; axis < 3; ++axis) {
    ASSERT_TRUE(layout->spacing_um[axis].has_value());
    EXPECT_DOUBLE_EQ(*layout->spacing_um[axis], 15.625);  // 0.015625 mm.
  }
}

TEST(VoreenVvdTest, WalnutVoxelsMatchTheRawBytes) {
  Result<RawLayout> layout = ReadVoreenVvd(kWalnutDir / "walnut.vvd");
  ASSERT_TRUE(layout.ok()) << layout.status().ToString();
  auto source = OpenRawVolume(*layout, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  const volume::VolumeInfo& info = (*source)->info();
  EXPECT_EQ(info.format, "raw");
  EXPECT_EQ(info.size, (std::array<int64_t, 3>{128, 96, 114}));
  EXPECT_EQ(info.channel_count(), 1);
  EXPECT_EQ(info.dtype, volume::DataType::kUint16);
  EXPECT_DOUBLE_EQ(info.spacing_um[0].value_or(0), 15.625);
  EXPECT_DOUBLE_EQ(info.spacing_um[1].value_or(0), 15.625);
  EXPECT_DOUBLE_EQ(info.spacing_um[2].value_or(0), 15.625);

  // Independent decode: the file's bytes as little-endian uint16, x fastest, then y, then z.
  std::ifstream in(kWalnutDir / "walnut.raw", std::ios::binary);
  std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)),
                                   std::istreambuf_iterator<char>());
  ASSERT_EQ(bytes.size(), 128u * 96u * 114u * 2u);

  std::vector<uint16_t> volume(128 * 96 * 114);
  ASSERT_TRUE(
      (*source)->ReadSlab(0, 0, 114, std::as_writable_bytes(std::span<uint16_t>(volume))).ok());
  size_t mismatches = 0;
  uint16_t max_value = 0;
  for (size_t i = 0; i < volume.size(); ++i) {
    const uint16_t want = static_cast<uint16_t>(bytes[2 * i] | (bytes[2 * i + 1] << 8));
    if (volume[i] != want) ++mismatches;
    max_value = std::max(max_value, want);
  }
  EXPECT_EQ(mismatches, 0u);
  EXPECT_GT(max_value, 0);  // Not an all-zero file: the comparison means something.

  // A slab in the middle reads the same voxels.
  std::vector<uint16_t> slab(128 * 96 * 3);
  ASSERT_TRUE(
      (*source)->ReadSlab(0, 57, 3, std::as_writable_bytes(std::span<uint16_t>(slab))).ok());
  EXPECT_TRUE(std::equal(slab.begin(), slab.end(), volume.begin() + 57 * 128 * 96));
}

class VoreenVvdFileTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir("vvd"); }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::filesystem::path dir_;
};

TEST_F(VoreenVvdFileTest, Formats) {
  const std::pair<const char*, volume::DataType> kFormats[] = {
      {"uint8", volume::DataType::kUint8},   {"int8", volume::DataType::kInt8},
      {"uint16", volume::DataType::kUint16}, {"int16", volume::DataType::kInt16},
      {"uint32", volume::DataType::kUint32}, {"int32", volume::DataType::kInt32},
      {"float", volume::DataType::kFloat32}, {"double", volume::DataType::kFloat64}};
  for (const auto& [name, type] : kFormats) {
    WriteText(dir_ / "a.vvd", Vvd(std::string("filename=\"sub/a.raw\" format=\"") + name +
                                      "\" x=\"3\" y=\"4\" z=\"5\"",
                                  ""));
    Result<RawLayout> layout = ReadVoreenVvd(dir_ / "a.vvd");
    ASSERT_TRUE(layout.ok()) << name << ": " << layout.status().ToString();
    EXPECT_EQ(layout->dtype, type) << name;
    EXPECT_EQ(layout->size, (std::array<int64_t, 3>{3, 4, 5}));
    EXPECT_EQ(layout->data_file, dir_ / "sub" / "a.raw");
    for (int axis = 0; axis < 3; ++axis) EXPECT_FALSE(layout->spacing_um[axis].has_value());
  }
}

TEST_F(VoreenVvdFileTest, SpacingIsMillimetres) {
  WriteText(dir_ / "s.vvd",
            Vvd("filename=\"s.raw\" format=\"uint8\" x=\"1\" y=\"1\" z=\"1\"",
                "<MetaItem name=\"Offset\" type=\"Vec3MetaData\"><value x=\"-1\" y=\"-1\" z=\"-1\" "
                "/></MetaItem><MetaItem name=\"Spacing\" type=\"Vec3MetaData\"><value x=\"0.5\" "
                "y=\"0.25\" z=\"2\" /></MetaItem>"));
  Result<RawLayout> layout = ReadVoreenVvd(dir_ / "s.vvd");
  ASSERT_TRUE(layout.ok()) << layout.status().ToString();
  EXPECT_DOUBLE_EQ(*layout->spacing_um[0], 500);
  EXPECT_DOUBLE_EQ(*layout->spacing_um[1], 250);
  EXPECT_DOUBLE_EQ(*layout->spacing_um[2], 2000);
}

TEST_F(VoreenVvdFileTest, Errors) {
  struct BadCase {
    const char* what;
    std::string text;
    StatusCode code;
  };
  const std::string ok_raw = "filename=\"a.raw\" format=\"uint8\" x=\"2\" y=\"2\" z=\"2\"";
  const BadCase cases[] = {
      {"not xml", "this is not <xml", StatusCode::kCorrupt},
      {"no volume", "<VoreenData><Volumes/></VoreenData>", StatusCode::kCorrupt},
      {"no rawdata", "<VoreenData><Volumes><Volume/></Volumes></VoreenData>", StatusCode::kCorrupt},
      {"vector format",
       Vvd("filename=\"a.raw\" format=\"Vector3(uint8)\" x=\"2\" y=\"2\" z=\"2\"", ""),
       StatusCode::kUnsupported},
      {"missing x", Vvd("filename=\"a.raw\" format=\"uint8\" y=\"2\" z=\"2\"", ""),
       StatusCode::kCorrupt},
      {"zero z", Vvd("filename=\"a.raw\" format=\"uint8\" x=\"2\" y=\"2\" z=\"0\"", ""),
       StatusCode::kCorrupt},
      {"text size", Vvd("filename=\"a.raw\" format=\"uint8\" x=\"two\" y=\"2\" z=\"2\"", ""),
       StatusCode::kCorrupt},
      {"no filename", Vvd("format=\"uint8\" x=\"2\" y=\"2\" z=\"2\"", ""), StatusCode::kCorrupt},
      {"negative spacing",
       Vvd(ok_raw, "<MetaItem name=\"Spacing\"><value x=\"-1\" y=\"1\" z=\"1\" /></MetaItem>"),
       StatusCode::kCorrupt},
      {"spacing without value", Vvd(ok_raw, "<MetaItem name=\"Spacing\" />"), StatusCode::kCorrupt},
  };
  for (const BadCase& c : cases) {
    WriteText(dir_ / "bad.vvd", c.text);
    Result<RawLayout> layout = ReadVoreenVvd(dir_ / "bad.vvd");
    ASSERT_FALSE(layout.ok()) << c.what;
    EXPECT_EQ(layout.status().code(), c.code) << c.what << ": " << layout.status().ToString();
    EXPECT_NE(layout.status().message().find("bad.vvd"), std::string::npos)
        << c.what << ": " << layout.status().message();
  }
  EXPECT_EQ(ReadVoreenVvd(dir_ / "missing.vvd").status().code(), StatusCode::kNotFound);
}

// Confined to its own folder, as the server opens a dataset (issue 28): RawData naming a file out
// of the folder is refused, whether or not it exists.
class VoreenConfinedTest : public testing::ConfinedTest {};

TEST_F(VoreenConfinedTest, RawDataOutOfTheFolderIsRefusedAlikeWhetherOrNotItExists) {
  std::ofstream(outside_ / "x.raw") << "0123456789abcdef";
  auto vvd = [&](const std::string& file) {
    const fs::path path = own_ / "v.vvd";
    std::ofstream(path) << "<VoreenData version=\"1\"><Volumes><Volume><RawData filename=\"" +
                               file +
                               "\" format=\"uint8\" x=\"4\" y=\"2\" z=\"2\" />"
                               "</Volume></Volumes></VoreenData>";
    return path;
  };
  std::ofstream(own_ / "mine.raw") << "0123456789abcdef";
  auto mine = OpenConfined(vvd("mine.raw"));
  ASSERT_TRUE(mine.ok()) << mine.status().ToString();
  for (const std::string& file :
       {std::string("../outside/x.raw"), std::string("../outside/none.raw"),
        (outside_ / "x.raw").string(), (outside_ / "none.raw").string()}) {
    SCOPED_TRACE(file);
    ExpectRefusal(OpenConfined(vvd(file)).status(), own_ / "v.vvd");
  }
}

}  // namespace
}  // namespace octoscope::io
