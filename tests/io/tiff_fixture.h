// Test fixtures: writes TIFF files of any layout straight through libtiff (independent of the
// readers under test), so reader tests can compare decoded voxels with the values written.
#ifndef OCTOSCOPE_TESTS_IO_TIFF_FIXTURE_H_
#define OCTOSCOPE_TESTS_IO_TIFF_FIXTURE_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace octoscope::testing {

struct TiffFixtureSpec {
  uint32_t width = 16;
  uint32_t height = 8;
  int pages = 1;
  uint16_t samples_per_pixel = 1;
  uint16_t bits_per_sample = 16;
  uint16_t sample_format = 1;       // 1 uint, 2 int, 3 float.
  uint16_t planar_config = 1;       // 1 chunky, 2 planar.
  uint16_t compression = 1;         // COMPRESSION_* (1 none, 5 LZW, 8 Adobe deflate, 50000 zstd, 32773 PackBits ...).
  uint16_t predictor = 1;           // 1 none, 2 horizontal, 3 float.
  uint32_t tile_width = 0;          // 0: strips; else tiles of tile_width x tile_height.
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

}  // namespace octoscope::testing

#endif  // OCTOSCOPE_TESTS_IO_TIFF_FIXTURE_H_
