// Test fixtures: writes TIFF files of any layout straight through libtiff (independent of the
// readers under test), so reader tests can compare decoded voxels with the values written, plus
// the helpers the TIFF reader tests share (the value pattern and its expected bytes, round-trip
// case tables, file byte helpers). Test-only; the helpers hold no state and are thread-safe,
// except that those reporting through ADD_FAILURE follow GoogleTest's own rules.
#ifndef OCTOSCOPE_TESTS_IO_TIFF_FIXTURE_H_
#define OCTOSCOPE_TESTS_IO_TIFF_FIXTURE_H_

#include <gtest/gtest.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <ostream>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "io/volume_source.h"
#include "util/status.h"
#include "volume/data_type.h"

namespace octoscope::testing {

struct TiffFixtureSpec {
  uint32_t width = 16;
  uint32_t height = 8;
  int pages = 1;
  uint16_t samples_per_pixel = 1;
  uint16_t bits_per_sample = 16;
  uint16_t sample_format = 1;  // 1 uint, 2 int, 3 float.
  uint16_t planar_config = 1;  // 1 chunky, 2 planar.
  uint16_t compression =
      1;  // COMPRESSION_* (1 none, 5 LZW, 8 Adobe deflate, 50000 zstd, 32773 PackBits ...).
  uint16_t predictor = 1;   // 1 none, 2 horizontal, 3 float.
  uint32_t tile_width = 0;  // 0: strips; else tiles of tile_width x tile_height.
  uint32_t tile_height = 0;
  uint32_t rows_per_strip = 3;
  bool big_tiff = false;
  bool big_endian = false;
  // Per-page ImageDescription (index 0 used for page 0 only when size 1).
  std::vector<std::string> descriptions;
  // XResolution/YResolution in pixels per unit, ResolutionUnit (1 none, 2 inch, 3 cm); 0: absent.
  double x_resolution = 0, y_resolution = 0;
  uint16_t resolution_unit = 1;
};

// The value written at (x, y, page, sample), as a double; the writer casts it to the sample type.
using VoxelValue = std::function<double(uint32_t x, uint32_t y, int page, int sample)>;

// A default pattern that exercises every bit of 8/16-bit types and signs for signed types.
double DefaultPattern(uint32_t x, uint32_t y, int page, int sample);

// Writes the file; aborts the test (ADD_FAILURE + false) on libtiff errors.
bool WriteTiffFixture(const std::filesystem::path& path, const TiffFixtureSpec& spec,
                      const VoxelValue& value = DefaultPattern);

// A fresh, empty temporary directory for one test (removed by the caller or left in /tmp).
std::filesystem::path MakeTempDir(const std::string& name);

// ---------------------------------------------------------------------------------------------
// The typed value pattern: what reader tests write and expect back.

// The value written at (x, y, page, sample) for a file of `type`: integers exercise all 32 bits
// (and signs, once narrowed); floats get fractions and negatives.
double PatternFor(volume::DataType type, uint32_t x, uint32_t y, int page, int sample);

// PatternFor(type, ...) as a VoxelValue for WriteTiffFixture.
VoxelValue PatternOf(volume::DataType type);

// The bytes (native order, first BytesPerSample(type) used) the fixture stores for `v`, with the
// same casts it uses.
std::array<std::byte, 8> SampleBytes(double v, volume::DataType type);

// Compares a decoded plane (x fastest) with the pattern of (page, sample); returns the number of
// wrong voxels and reports the first few through ADD_FAILURE.
// REQUIRES: plane holds at least width * height samples of `type`.
int CountMismatches(std::span<const std::byte> plane, volume::DataType type, uint32_t width,
                    uint32_t height, int page, int sample);

// ---------------------------------------------------------------------------------------------
// Round-trip case tables: each test picks its own rows, so parameter names stay its own.

// A sample type as TIFF tags spell it, and the DataType a reader must report.
struct FixtureType {
  const char* name;
  uint16_t bits, format;
  volume::DataType dtype;
};
// All eight sample types the readers support.
inline constexpr FixtureType kFixtureTypes[] = {
    {"u8", 8, 1, volume::DataType::kUint8},     {"i8", 8, 2, volume::DataType::kInt8},
    {"u16", 16, 1, volume::DataType::kUint16},  {"i16", 16, 2, volume::DataType::kInt16},
    {"u32", 32, 1, volume::DataType::kUint32},  {"i32", 32, 2, volume::DataType::kInt32},
    {"f32", 32, 3, volume::DataType::kFloat32}, {"f64", 64, 3, volume::DataType::kFloat64},
};

// Samples per pixel and their planar configuration (1 chunky, 2 planar).
struct FixtureSamples {
  const char* name;
  uint16_t samples, planar;
};

// A compression; `predictor` means horizontal (2) for integers, floating point (3) for floats.
struct FixtureCompression {
  const char* name;
  uint16_t compression;
  bool predictor;
};

// One parameter of a round-trip test: the file to write and the type a reader must report.
struct FixtureCase {
  std::string name;
  TiffFixtureSpec spec;
  volume::DataType dtype;
};
inline void PrintTo(const FixtureCase& c, std::ostream* os) { *os << c.name; }

// Every compression x type (all of kFixtureTypes) x samples case of a width x height x pages file,
// in that nesting order, named "<compression>_<type>_<samples>_"; `finish(i, c)` then picks the
// container and storage of the i-th case and appends them to c.name.
std::vector<FixtureCase> CrossCases(uint32_t width, uint32_t height, int pages,
                                    std::span<const FixtureCompression> compressions,
                                    std::span<const FixtureSamples> samples,
                                    const std::function<void(int i, FixtureCase& c)>& finish);

// "classicLE", "classicBE", "bigLE" or "bigBE" after spec.big_tiff and spec.big_endian.
std::string ContainerName(const TiffFixtureSpec& spec);

// ---------------------------------------------------------------------------------------------
// Files as bytes, and expected errors.

std::vector<uint8_t> ReadAll(const std::filesystem::path& path);
void WriteAll(const std::filesystem::path& path, const std::vector<uint8_t>& bytes);

// The crafted input `name` under fuzz/regressions/ of the source tree.
std::filesystem::path Regression(const std::string& name);

// Expects `status` to be an error whose message names `path`.
void ExpectErrorNaming(const Status& status, const std::filesystem::path& path);

// The plane `source.FindStoredPlane(channel, z)` locates, read with its file's ReadBytes; nullopt
// when the source does not locate it (a failed read is recorded with ADD_FAILURE).
std::optional<std::vector<std::byte>> ReadStoredPlane(const io::VolumeSource& source, int channel,
                                                      int64_t z);

// ---------------------------------------------------------------------------------------------
// GoogleTest bases.

// A parameterized round-trip suite over FixtureCase; its tests share one temporary directory,
// dir_, made before the suite and removed after it (suites run one at a time).
class FixtureRoundTrip : public ::testing::TestWithParam<FixtureCase> {
 protected:
  static void SetUpTestSuite();
  static void TearDownTestSuite();
  static std::filesystem::path* dir_;
};

// A test with its own temporary directory dir_ (removed after the test) and a writer of small
// fixtures into it, filled with the suite's value pattern.
class TiffFixtureTest : public ::testing::Test {
 protected:
  explicit TiffFixtureTest(std::string dir_name, VoxelValue value = DefaultPattern)
      : dir_name_(std::move(dir_name)), value_(std::move(value)) {}
  void SetUp() override { dir_ = MakeTempDir(dir_name_); }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  // Writes the fixture `spec` (classic unless said otherwise) as dir_/name.
  std::filesystem::path Fixture(const std::string& name, const TiffFixtureSpec& spec = {}) {
    std::filesystem::path path = dir_ / name;
    EXPECT_TRUE(WriteTiffFixture(path, spec, value_));
    return path;
  }

  std::filesystem::path dir_;

 private:
  std::string dir_name_;
  VoxelValue value_;
};

}  // namespace octoscope::testing

#endif  // OCTOSCOPE_TESTS_IO_TIFF_FIXTURE_H_
