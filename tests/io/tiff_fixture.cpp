#include "io/tiff_fixture.h"

#include <gtest/gtest.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>

namespace octoscope::testing {
namespace {

// Stores `v` as the sample type described by bits/format into `out`.
void StoreSample(double v, uint16_t bits, uint16_t format, uint8_t* out) {
  if (format == SAMPLEFORMAT_IEEEFP) {
    if (bits == 32) {
      float f = static_cast<float>(v);
      std::memcpy(out, &f, 4);
    } else {
      std::memcpy(out, &v, 8);
    }
    return;
  }
  if (format == SAMPLEFORMAT_INT) {
    int64_t i = static_cast<int64_t>(v);
    if (bits == 8) {
      int8_t x = static_cast<int8_t>(i);
      std::memcpy(out, &x, 1);
    }
    if (bits == 16) {
      int16_t x = static_cast<int16_t>(i);
      std::memcpy(out, &x, 2);
    }
    if (bits == 32) {
      int32_t x = static_cast<int32_t>(i);
      std::memcpy(out, &x, 4);
    }
    return;
  }
  uint64_t u = static_cast<uint64_t>(v);
  if (bits == 8) {
    uint8_t x = static_cast<uint8_t>(u);
    std::memcpy(out, &x, 1);
  }
  if (bits == 16) {
    uint16_t x = static_cast<uint16_t>(u);
    std::memcpy(out, &x, 2);
  }
  if (bits == 32) {
    uint32_t x = static_cast<uint32_t>(u);
    std::memcpy(out, &x, 4);
  }
}

// libtiff 4.5 byte-swaps the caller's samples to the file's byte order *before* applying the
// floating-point predictor, which expects native samples; such files decode (by libtiff, and by
// the Adobe Tech Note 3 definition) to byte-swapped values. Probes once whether this libtiff has
// that bug, so the fixture can hand it pre-swapped samples and the file holds the intended values.
bool LibtiffSwapsBeforeFloatPredictor() {
  static const bool swaps = [] {
    const bool host_big = std::endian::native == std::endian::big;
    std::filesystem::path path = std::filesystem::temp_directory_path() /
                                 ("octoscope-fp-probe-" + std::to_string(getpid()) + "-" +
                                  std::to_string(std::random_device{}()) + ".tif");
    TIFF* tif = TIFFOpen(path.c_str(), host_big ? "wl" : "wb");  // The non-native order.
    if (!tif) return false;
    float row[2] = {1.5f, -2.25f};
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 2);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 1);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 32);
    TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_IEEEFP);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ADOBE_DEFLATE);
    TIFFSetField(tif, TIFFTAG_PREDICTOR, PREDICTOR_FLOATINGPOINT);
    TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 1);
    TIFFWriteScanline(tif, row, 0, 0);
    TIFFClose(tif);
    bool result = false;
    tif = TIFFOpen(path.c_str(), "r");
    if (tif) {
      float back[2] = {0, 0};
      result = TIFFReadEncodedStrip(tif, 0, back, sizeof(back)) == sizeof(back) && back[0] != 1.5f;
      TIFFClose(tif);
    }
    std::filesystem::remove(path);
    return result;
  }();
  return swaps;
}

}  // namespace

double DefaultPattern(uint32_t x, uint32_t y, int page, int sample) {
  // Distinct per coordinate, wraps through the whole 8/16-bit range.
  return static_cast<double>((x * 7 + y * 131 + page * 1031 + sample * 15013) % 65536);
}

bool WriteTiffFixture(const std::filesystem::path& path, const TiffFixtureSpec& spec,
                      const VoxelValue& value) {
  std::string mode = "w";
  mode += spec.big_tiff ? "8" : "";
  mode += spec.big_endian ? "b" : "l";
  // libtiff's warnings (e.g. "legacy Deflate codec identifier", which the tests want) are noise
  // here; errors fail the test with libtiff's message.
  TIFFOpenOptions* options = TIFFOpenOptionsAlloc();
  TIFFOpenOptionsSetWarningHandlerExtR(
      options, [](TIFF*, void*, const char*, const char*, va_list) { return 1; }, nullptr);
  TIFFOpenOptionsSetErrorHandlerExtR(
      options,
      [](TIFF*, void*, const char* module, const char* fmt, va_list ap) {
        char text[512];
        std::vsnprintf(text, sizeof(text), fmt, ap);
        ADD_FAILURE() << "libtiff: " << (module ? module : "") << ": " << text;
        return 1;
      },
      nullptr);
  TIFF* tif = TIFFOpenExt(path.c_str(), mode.c_str(), options);
  TIFFOpenOptionsFree(options);
  if (!tif) {
    ADD_FAILURE() << "TIFFOpen(" << path << ") failed";
    return false;
  }
  const int bytes = spec.bits_per_sample / 8;
  const int spp = spec.samples_per_pixel;
  bool ok = true;
  for (int page = 0; page < spec.pages && ok; ++page) {
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, spec.width);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, spec.height);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, spp);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, spec.bits_per_sample);
    TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, spec.sample_format);
    TIFFSetField(tif, TIFFTAG_PLANARCONFIG, spec.planar_config);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, spp == 3 ? PHOTOMETRIC_RGB : PHOTOMETRIC_MINISBLACK);
    if (spp > 1 && spp != 3) {
      std::vector<uint16_t> extra(spp - 1, EXTRASAMPLE_UNSPECIFIED);
      TIFFSetField(tif, TIFFTAG_EXTRASAMPLES, spp - 1, extra.data());
    }
    TIFFSetField(tif, TIFFTAG_COMPRESSION, spec.compression);
    if (spec.predictor != 1) TIFFSetField(tif, TIFFTAG_PREDICTOR, spec.predictor);
    // Fast presets: the default LZMA preset alone costs ~100 ms and ~90 MB per file.
    if (spec.compression == COMPRESSION_LZMA) TIFFSetField(tif, TIFFTAG_LZMAPRESET, 1);
    if (spec.compression == COMPRESSION_ZSTD) TIFFSetField(tif, TIFFTAG_ZSTD_LEVEL, 1);
    if (spec.x_resolution > 0) {
      TIFFSetField(tif, TIFFTAG_XRESOLUTION, spec.x_resolution);
      TIFFSetField(tif, TIFFTAG_YRESOLUTION, spec.y_resolution);
      TIFFSetField(tif, TIFFTAG_RESOLUTIONUNIT, spec.resolution_unit);
    }
    if (page < static_cast<int>(spec.descriptions.size()) && !spec.descriptions[page].empty()) {
      TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, spec.descriptions[page].c_str());
    }
    if (spec.pages > 1) {
      TIFFSetField(tif, TIFFTAG_SUBFILETYPE, FILETYPE_PAGE);
      TIFFSetField(tif, TIFFTAG_PAGENUMBER, page, spec.pages);
    }
    // Fill one whole plane in memory in the file's sample layout, then write it in pieces.
    const int planes = spec.planar_config == PLANARCONFIG_SEPARATE ? spp : 1;
    const int per_pixel = spec.planar_config == PLANARCONFIG_SEPARATE ? 1 : spp;
    std::vector<std::vector<uint8_t>> plane(
        planes,
        std::vector<uint8_t>(static_cast<size_t>(spec.width) * spec.height * per_pixel * bytes));
    for (int p = 0; p < planes; ++p) {
      for (uint32_t y = 0; y < spec.height; ++y) {
        for (uint32_t x = 0; x < spec.width; ++x) {
          for (int s = 0; s < per_pixel; ++s) {
            int sample = planes > 1 ? p : s;
            size_t at = ((static_cast<size_t>(y) * spec.width + x) * per_pixel + s) * bytes;
            StoreSample(value(x, y, page, sample), spec.bits_per_sample, spec.sample_format,
                        &plane[p][at]);
          }
        }
      }
    }
    const bool swapped_file = spec.big_endian != (std::endian::native == std::endian::big);
    if (spec.predictor == PREDICTOR_FLOATINGPOINT && swapped_file &&
        LibtiffSwapsBeforeFloatPredictor()) {
      // Pre-swap so that libtiff's extra swap restores native samples (see above).
      for (auto& p : plane) {
        for (size_t at = 0; at + bytes <= p.size(); at += bytes) {
          std::reverse(p.begin() + at, p.begin() + at + bytes);
        }
      }
    }
    const size_t row_bytes = static_cast<size_t>(spec.width) * per_pixel * bytes;
    if (spec.tile_width > 0) {
      TIFFSetField(tif, TIFFTAG_TILEWIDTH, spec.tile_width);
      TIFFSetField(tif, TIFFTAG_TILELENGTH, spec.tile_height);
      std::vector<uint8_t> tile(static_cast<size_t>(spec.tile_width) * spec.tile_height *
                                per_pixel * bytes);
      for (int p = 0; p < planes && ok; ++p) {
        for (uint32_t ty = 0; ty < spec.height && ok; ty += spec.tile_height) {
          for (uint32_t tx = 0; tx < spec.width && ok; tx += spec.tile_width) {
            std::fill(tile.begin(), tile.end(), 0);
            for (uint32_t y = ty; y < std::min(spec.height, ty + spec.tile_height); ++y) {
              for (uint32_t x = tx; x < std::min(spec.width, tx + spec.tile_width); ++x) {
                std::memcpy(&tile[((y - ty) * spec.tile_width + (x - tx)) * per_pixel * bytes],
                            &plane[p][y * row_bytes + x * per_pixel * bytes], per_pixel * bytes);
              }
            }
            ok = TIFFWriteTile(tif, tile.data(), tx, ty, 0, static_cast<uint16_t>(p)) >= 0;
          }
        }
      }
    } else {
      TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, spec.rows_per_strip);
      for (int p = 0; p < planes && ok; ++p) {
        for (uint32_t y = 0; y < spec.height && ok; ++y) {
          ok = TIFFWriteScanline(tif, &plane[p][y * row_bytes], y, static_cast<uint16_t>(p)) >= 0;
        }
      }
    }
    ok = ok && TIFFWriteDirectory(tif);
  }
  TIFFClose(tif);
  if (!ok) ADD_FAILURE() << "writing " << path << " failed";
  return ok;
}

std::filesystem::path MakeTempDir(const std::string& name) {
  std::filesystem::path dir = std::filesystem::temp_directory_path() /
                              ("octoscope-test-" + name + "-" + std::to_string(getpid()) + "-" +
                               std::to_string(std::random_device{}()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

double PatternFor(volume::DataType type, uint32_t x, uint32_t y, int page, int sample) {
  const uint64_t base =
      uint64_t{x} * 7 + uint64_t{y} * 131 + uint64_t(page) * 1031 + uint64_t(sample) * 15013;
  if (volume::IsFloat(type)) return static_cast<double>(base % 65536) * 0.37 - 5000.5;
  return static_cast<double>((base * 65599u) % 4294967296u);
}

VoxelValue PatternOf(volume::DataType type) {
  return [type](uint32_t x, uint32_t y, int page, int sample) {
    return PatternFor(type, x, y, page, sample);
  };
}

std::array<std::byte, 8> SampleBytes(double v, volume::DataType type) {
  using volume::DataType;
  std::array<std::byte, 8> out{};
  auto put = [&](auto x) { std::memcpy(out.data(), &x, sizeof(x)); };
  switch (type) {
    case DataType::kUint8:
      put(static_cast<uint8_t>(static_cast<uint64_t>(v)));
      break;
    case DataType::kUint16:
      put(static_cast<uint16_t>(static_cast<uint64_t>(v)));
      break;
    case DataType::kUint32:
      put(static_cast<uint32_t>(static_cast<uint64_t>(v)));
      break;
    case DataType::kInt8:
      put(static_cast<int8_t>(static_cast<int64_t>(v)));
      break;
    case DataType::kInt16:
      put(static_cast<int16_t>(static_cast<int64_t>(v)));
      break;
    case DataType::kInt32:
      put(static_cast<int32_t>(static_cast<int64_t>(v)));
      break;
    case DataType::kFloat32:
      put(static_cast<float>(v));
      break;
    case DataType::kFloat64:
      put(v);
      break;
  }
  return out;
}

int CountMismatches(std::span<const std::byte> plane, volume::DataType type, uint32_t width,
                    uint32_t height, int page, int sample) {
  const size_t bytes = volume::BytesPerSample(type);
  int wrong = 0;
  for (uint32_t y = 0; y < height; ++y) {
    for (uint32_t x = 0; x < width; ++x) {
      const auto want = SampleBytes(PatternFor(type, x, y, page, sample), type);
      const std::byte* got = plane.data() + (uint64_t{y} * width + x) * bytes;
      if (std::memcmp(got, want.data(), bytes) != 0) {
        if (++wrong <= 3) {
          ADD_FAILURE() << "voxel x=" << x << " y=" << y << " page=" << page << " sample=" << sample
                        << " differs";
        }
      }
    }
  }
  return wrong;
}

std::vector<FixtureCase> CrossCases(uint32_t width, uint32_t height, int pages,
                                    std::span<const FixtureCompression> compressions,
                                    std::span<const FixtureSamples> samples,
                                    const std::function<void(int i, FixtureCase& c)>& finish) {
  std::vector<FixtureCase> cases;
  int i = 0;
  for (const FixtureCompression& c : compressions) {
    for (const FixtureType& t : kFixtureTypes) {
      for (const FixtureSamples& s : samples) {
        FixtureCase fc;
        TiffFixtureSpec& spec = fc.spec;
        spec.width = width;
        spec.height = height;
        spec.pages = pages;
        spec.samples_per_pixel = s.samples;
        spec.planar_config = s.planar;
        spec.bits_per_sample = t.bits;
        spec.sample_format = t.format;
        spec.compression = c.compression;
        spec.predictor = c.predictor ? (t.format == 3 ? 3 : 2) : 1;
        fc.dtype = t.dtype;
        fc.name = std::string(c.name) + "_" + t.name + "_" + s.name + "_";
        finish(i++, fc);
        cases.push_back(std::move(fc));
      }
    }
  }
  return cases;
}

std::string ContainerName(const TiffFixtureSpec& spec) {
  return std::string(spec.big_tiff ? "big" : "classic") + (spec.big_endian ? "BE" : "LE");
}

std::vector<uint8_t> ReadAll(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

void WriteAll(const std::filesystem::path& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
}

std::filesystem::path Regression(const std::string& name) {
  return std::filesystem::path(OCTOSCOPE_SOURCE_DIR) / "fuzz" / "regressions" / name;
}

std::optional<std::vector<std::byte>> ReadStoredPlane(const io::VolumeSource& source, int channel,
                                                      int64_t z) {
  std::optional<io::StoredPlane> stored = source.FindStoredPlane(channel, z);
  if (!stored) return std::nullopt;
  std::vector<std::byte> plane(source.SlabBytes(1));
  Status read = stored->file->ReadBytes(stored->offset, plane);
  if (!read.ok()) ADD_FAILURE() << "reading a stored plane: " << read.ToString();
  return plane;
}

void ExpectErrorNaming(const Status& status, const std::filesystem::path& path) {
  EXPECT_FALSE(status.ok());
  EXPECT_NE(status.message().find(path.string()), std::string::npos) << status.ToString();
}

std::filesystem::path* FixtureRoundTrip::dir_ = nullptr;

void FixtureRoundTrip::SetUpTestSuite() {
  dir_ = new std::filesystem::path(MakeTempDir("tiff-roundtrip"));
}

void FixtureRoundTrip::TearDownTestSuite() {
  std::filesystem::remove_all(*dir_);
  delete dir_;
  dir_ = nullptr;
}

}  // namespace octoscope::testing
