// DecodeTiffPlanes: an in-memory TIFF decodes into exactly the planes written by an independent
// writer (libtiff through the fixture), in any container and compression; every mismatch with
// the expectation (size, type, samples, page count, byte limit) and every damaged or hostile
// input (fuzz seeds and regressions, truncations, garbage) is a clear error naming the input.
#include "io/tiff_planes.h"

#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <vector>

#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;
using testing::TiffFixtureSpec;

std::vector<std::byte> Bytes(const fs::path& path) {
  const std::vector<uint8_t> raw = testing::ReadAll(path);
  std::vector<std::byte> out(raw.size());
  std::memcpy(out.data(), raw.data(), raw.size());
  return out;
}

class TiffPlanesTest : public testing::TiffFixtureTest {
 protected:
  TiffPlanesTest() : TiffFixtureTest("tiff-planes") {}

  PlaneExpectation Expect(const TiffFixtureSpec& spec, volume::DataType dtype) {
    PlaneExpectation e;
    e.width = spec.width;
    e.height = spec.height;
    e.dtype = dtype;
    e.max_planes = 100;
    return e;
  }
};

TEST_F(TiffPlanesTest, DecodesEveryPageInAnyContainerAndCompression) {
  struct Row {
    uint16_t compression;
    bool big_tiff, big_endian;
    uint16_t bits, format;
    volume::DataType dtype;
  };
  const Row rows[] = {
      {1, false, false, 16, 1, volume::DataType::kUint16},
      {8, false, true, 16, 1, volume::DataType::kUint16},
      {5, true, false, 8, 1, volume::DataType::kUint8},
      {32773, true, true, 16, 2, volume::DataType::kInt16},
      {8, false, false, 8, 2, volume::DataType::kInt8},
  };
  int i = 0;
  for (const Row& r : rows) {
    TiffFixtureSpec spec;
    spec.width = 37;
    spec.height = 11;
    spec.pages = 3;
    spec.compression = r.compression;
    spec.big_tiff = r.big_tiff;
    spec.big_endian = r.big_endian;
    spec.bits_per_sample = r.bits;
    spec.sample_format = r.format;
    std::string name = "p";
    name.append(std::to_string(i++)).append(".tif");
    const fs::path path = dir_ / name;
    ASSERT_TRUE(testing::WriteTiffFixture(path, spec, testing::PatternOf(r.dtype)));
    SCOPED_TRACE(path.string());
    auto decoded = DecodeTiffPlanes(Bytes(path), "body", Expect(spec, r.dtype));
    ASSERT_TRUE(decoded.ok()) << decoded.status().ToString();
    ASSERT_EQ(decoded->count, 3);
    const size_t plane = 37 * 11 * volume::BytesPerSample(r.dtype);
    ASSERT_EQ(decoded->samples.size(), 3 * plane);
    for (int page = 0; page < 3; ++page) {
      EXPECT_EQ(testing::CountMismatches(std::span(decoded->samples).subspan(page * plane, plane),
                                         r.dtype, 37, 11, page, 0),
                0);
    }
  }
}

TEST_F(TiffPlanesTest, RefusesWhatTheExpectationDoesNotAllow) {
  TiffFixtureSpec spec;
  spec.width = 20;
  spec.height = 10;
  spec.pages = 4;
  const std::vector<std::byte> tiff = Bytes(Fixture("four.tif", spec));
  const PlaneExpectation ok = Expect(spec, volume::DataType::kUint16);
  ASSERT_TRUE(DecodeTiffPlanes(tiff, "body", ok).ok());

  auto expect_error = [&](PlaneExpectation e, StatusCode code, const char* what) {
    auto r = DecodeTiffPlanes(tiff, "slab.tif", e);
    ASSERT_FALSE(r.ok()) << what;
    EXPECT_EQ(r.status().code(), code) << what << ": " << r.status().ToString();
    EXPECT_EQ(r.status().message().rfind("slab.tif", 0), 0u) << r.status().ToString();
  };
  PlaneExpectation e = ok;
  e.width = 21;
  expect_error(e, StatusCode::kInvalidArgument, "width");
  e = ok;
  e.height = 9;
  expect_error(e, StatusCode::kInvalidArgument, "height");
  e = ok;
  e.dtype = volume::DataType::kInt16;
  expect_error(e, StatusCode::kInvalidArgument, "type");
  e = ok;
  e.planes = 3;
  expect_error(e, StatusCode::kInvalidArgument, "exact count");
  e = ok;
  e.max_planes = 3;
  expect_error(e, StatusCode::kInvalidArgument, "max planes");
  e = ok;
  e.max_bytes = 3 * 20 * 10 * 2;
  expect_error(e, StatusCode::kResourceExhausted, "max bytes");

  spec.samples_per_pixel = 3;
  spec.pages = 1;
  const std::vector<std::byte> rgb = Bytes(Fixture("rgb.tif", spec));
  auto r = DecodeTiffPlanes(rgb, "rgb", ok);
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument) << r.status().ToString();
}

TEST_F(TiffPlanesTest, DamagedAndHostileInputsAreErrors) {
  TiffFixtureSpec spec;
  spec.width = 64;
  spec.height = 64;
  spec.pages = 2;
  spec.compression = 8;
  const std::vector<std::byte> tiff = Bytes(Fixture("two.tif", spec));
  const PlaneExpectation e = Expect(spec, volume::DataType::kUint16);
  for (size_t cut : {size_t{0}, size_t{3}, size_t{8}, tiff.size() / 2, tiff.size() - 1}) {
    auto r = DecodeTiffPlanes(std::span(tiff).first(cut), "cut", e);
    EXPECT_FALSE(r.ok()) << cut;
    if (!r.ok()) {
      EXPECT_EQ(r.status().message().rfind("cut", 0), 0u) << r.status().ToString();
    }
  }
  std::vector<std::byte> garbage(1000, std::byte{0x41});
  EXPECT_FALSE(DecodeTiffPlanes(garbage, "garbage", e).ok());

  // Every fuzz input, decoded against its own first page's layout or a fixed one: never a crash.
  const fs::path fuzz = fs::path(OCTOSCOPE_SOURCE_DIR) / "fuzz";
  int files = 0;
  for (const char* folder : {"seeds", "regressions"}) {
    for (const auto& entry : fs::directory_iterator(fuzz / folder)) {
      if (!entry.is_regular_file()) continue;
      ++files;
      const std::vector<std::byte> bytes = Bytes(entry.path());
      PlaneExpectation any;
      any.width = 256;
      any.height = 256;
      any.max_planes = 512;
      any.max_bytes = 64 << 20;
      (void)DecodeTiffPlanes(bytes, entry.path().filename().string(), any);
    }
  }
  EXPECT_GT(files, 10);
}

}  // namespace
}  // namespace octoscope::io
