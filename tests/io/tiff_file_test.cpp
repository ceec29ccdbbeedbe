// Tests for TiffFile: every layout libtiff writes (classic/BigTIFF, both byte orders, strips and
// tiles, compressions, predictors, sample types, chunky/planar) is decoded voxel by voxel against
// the values the fixture wrote, and every kind of broken file yields an error naming the file.
#include "io/tiff_file.h"

#include <gtest/gtest.h>
#include <sys/mman.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <vector>

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
using octoscope::testing::Regression;
using octoscope::testing::SampleBytes;
using octoscope::testing::TiffFixtureSpec;
using octoscope::testing::TiffFixtureTest;
using octoscope::testing::WriteAll;
using octoscope::testing::WriteTiffFixture;
using volume::DataType;

// ---------------------------------------------------------------------------------------------
// Byte-level helpers for patching classic TIFF files (either byte order).

bool BigEndian(const std::vector<uint8_t>& b) { return b[0] == 'M'; }

uint32_t Get(const std::vector<uint8_t>& b, size_t at, int n) {
  uint32_t v = 0;
  for (int i = 0; i < n; ++i) v = (v << 8) | b[at + (BigEndian(b) ? i : n - 1 - i)];
  return v;
}

void Put(std::vector<uint8_t>& b, size_t at, int n, uint32_t v) {
  for (int i = 0; i < n; ++i) {
    b[at + (BigEndian(b) ? n - 1 - i : i)] = static_cast<uint8_t>(v >> (8 * i));
  }
}

// Offset of IFD `k` in a classic TIFF.
size_t IfdOffset(const std::vector<uint8_t>& b, int k) {
  size_t at = Get(b, 4, 4);
  for (int i = 0; i < k; ++i) at = Get(b, at + 2 + Get(b, at, 2) * 12, 4);
  return at;
}

size_t NextPointerPos(const std::vector<uint8_t>& b, size_t ifd) {
  return ifd + 2 + Get(b, ifd, 2) * 12;
}

// Position of the entry for `tag` in the IFD at `ifd`; 0 when absent.
size_t EntryPos(const std::vector<uint8_t>& b, size_t ifd, uint16_t tag) {
  const uint32_t n = Get(b, ifd, 2);
  for (uint32_t i = 0; i < n; ++i) {
    size_t e = ifd + 2 + i * 12;
    if (Get(b, e, 2) == tag) return e;
  }
  return 0;
}

// Rewrites the entry for `tag` as one LONG holding `value`.
void PatchLong(std::vector<uint8_t>& b, size_t ifd, uint16_t tag, uint32_t value) {
  size_t e = EntryPos(b, ifd, tag);
  ASSERT_NE(e, 0u) << "tag " << tag << " not found";
  Put(b, e + 2, 2, TIFF_LONG);
  Put(b, e + 4, 4, 1);
  Put(b, e + 8, 4, value);
}

// The value of a one-valued SHORT or LONG entry.
uint32_t EntryValue(const std::vector<uint8_t>& b, size_t ifd, uint16_t tag) {
  size_t e = EntryPos(b, ifd, tag);
  if (e == 0) return 0;
  return Get(b, e + 2, 2) == TIFF_SHORT ? Get(b, e + 8, 2) : Get(b, e + 8, 4);
}

// ---------------------------------------------------------------------------------------------
// Round trips over every layout that matters.

constexpr FixtureCompression kCompressions[] = {
    {"none", COMPRESSION_NONE, false},
    {"lzw", COMPRESSION_LZW, false},
    {"lzwpred", COMPRESSION_LZW, true},
    {"deflate", COMPRESSION_ADOBE_DEFLATE, false},
    {"deflatepred", COMPRESSION_ADOBE_DEFLATE, true},
    {"olddeflate", COMPRESSION_DEFLATE, false},
    {"zstd", COMPRESSION_ZSTD, false},
    {"zstdpred", COMPRESSION_ZSTD, true},
    {"packbits", COMPRESSION_PACKBITS, false},
    {"lzma", COMPRESSION_LZMA, false},
};

constexpr FixtureSamples kSamples[] = {
    {"s1", 1, PLANARCONFIG_CONTIG},        {"chunky2", 2, PLANARCONFIG_CONTIG},
    {"planar3", 3, PLANARCONFIG_SEPARATE}, {"chunky4", 4, PLANARCONFIG_CONTIG},
    {"planar2", 2, PLANARCONFIG_SEPARATE}, {"planar4", 4, PLANARCONFIG_SEPARATE},
    {"chunky3", 3, PLANARCONFIG_CONTIG},
};

// Every type x compression x sample layout; container (classic/BigTIFF x byte order) and storage
// (strips of 3 rows, one strip, 16x16 tiles over a 37x21 image) rotate so each compression meets
// every container/storage pair several times.
std::vector<FixtureCase> AllCases() {
  return CrossCases(37, 21, 2, kCompressions, kSamples, [](int i, FixtureCase& fc) {
    TiffFixtureSpec& spec = fc.spec;
    const int container = i % 4;
    const int storage = (i / 4) % 3;
    spec.big_tiff = container >= 2;
    spec.big_endian = container % 2 == 1;
    if (storage == 0) spec.rows_per_strip = 3;
    if (storage == 1) spec.rows_per_strip = spec.height;
    if (storage == 2) spec.tile_width = spec.tile_height = 16;
    fc.name += ContainerName(spec) + "_" +
               (storage == 0   ? "strips"
                : storage == 1 ? "onestrip"
                               : "tiles");
  });
}

class TiffFileRoundTrip : public FixtureRoundTrip {};

TEST_P(TiffFileRoundTrip, DecodesEveryVoxel) {
  const FixtureCase& c = GetParam();
  const TiffFixtureSpec& spec = c.spec;
  const fs::path path = *dir_ / (c.name + ".tif");
  const DataType type = c.dtype;
  ASSERT_TRUE(WriteTiffFixture(path, spec, PatternOf(type)));

  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  TiffFile& f = **file;
  EXPECT_EQ(f.big_tiff(), spec.big_tiff);
  EXPECT_EQ(f.big_endian(), spec.big_endian);
  EXPECT_EQ(f.file_size(), fs::file_size(path));
  ASSERT_EQ(f.ifd_count(), spec.pages);
  for (int page = 0; page < spec.pages; ++page) {
    const TiffIfd& ifd = f.ifd(page);
    EXPECT_EQ(ifd.width, spec.width);
    EXPECT_EQ(ifd.height, spec.height);
    EXPECT_EQ(ifd.samples_per_pixel, spec.samples_per_pixel);
    EXPECT_EQ(ifd.bits_per_sample, spec.bits_per_sample);
    EXPECT_EQ(ifd.sample_format, spec.sample_format);
    EXPECT_EQ(ifd.planar_config,
              spec.samples_per_pixel > 1 ? spec.planar_config : ifd.planar_config);
    EXPECT_EQ(ifd.compression, spec.compression);
    EXPECT_EQ(ifd.tiled, spec.tile_width > 0);
    ASSERT_EQ(ifd.dtype, type);
  }
  EXPECT_GT(f.ifd(1).offset, 0u);
  EXPECT_NE(f.ifd(0).offset, f.ifd(1).offset);

  std::vector<std::byte> plane(uint64_t{spec.width} * spec.height * volume::BytesPerSample(type));
  // Read pages in reverse and samples interleaved, so IFD switching is exercised too.
  for (int page = spec.pages - 1; page >= 0; --page) {
    for (int sample = 0; sample < spec.samples_per_pixel; ++sample) {
      std::fill(plane.begin(), plane.end(), std::byte{0xA5});
      Status st = f.ReadPlane(page, sample, plane);
      ASSERT_TRUE(st.ok()) << st.ToString();
      EXPECT_EQ(CountMismatches(plane, type, spec.width, spec.height, page, sample), 0)
          << c.name << " page " << page << " sample " << sample;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(AllLayouts, TiffFileRoundTrip, ::testing::ValuesIn(AllCases()),
                         [](const ::testing::TestParamInfo<FixtureCase>& info) {
                           return info.param.name;
                         });

// ---------------------------------------------------------------------------------------------
// Metadata and odd layouts.

class TiffFileTest : public TiffFixtureTest {
 protected:
  TiffFileTest() : TiffFixtureTest("tiff-file") {}
};

TEST_F(TiffFileTest, ReadsDescriptionResolutionAndOffsets) {
  TiffFixtureSpec spec;
  spec.pages = 3;
  spec.descriptions = {"first page", "", "third"};
  spec.x_resolution = 2000;
  spec.y_resolution = 4000;
  spec.resolution_unit = RESUNIT_CENTIMETER;
  fs::path path = Fixture("meta.tif", spec);
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  ASSERT_EQ((*file)->ifd_count(), 3);
  EXPECT_EQ((*file)->path(), path);
  // The index keeps IFD 0's description; the others are read on demand.
  EXPECT_EQ((*file)->ifd(0).description, "first page");
  EXPECT_EQ((*file)->ifd(1).description, "");
  EXPECT_EQ((*file)->ifd(2).description, "");
  EXPECT_EQ(*(*file)->Description(0), "first page");
  EXPECT_EQ(*(*file)->Description(1), "");
  EXPECT_EQ(*(*file)->Description(2), "third");
  EXPECT_EQ((*file)->Description(2, 4).status().code(), StatusCode::kResourceExhausted);
  EXPECT_EQ((*file)->Description(0, 4).status().code(), StatusCode::kResourceExhausted);
  EXPECT_EQ((*file)->Description(3).status().code(), StatusCode::kOutOfRange);
  // Reading descriptions moves libtiff between IFDs; planes still decode correctly after it.
  std::vector<std::byte> plane(uint64_t{spec.width} * spec.height * 2);
  ASSERT_TRUE((*file)->ReadPlane(0, 0, plane).ok());
  EXPECT_EQ(*(*file)->Description(2), "third");
  ASSERT_TRUE((*file)->ReadPlane(0, 0, plane).ok());
  EXPECT_EQ((*file)->ifd(0).resolution_unit, RESUNIT_CENTIMETER);
  ASSERT_TRUE((*file)->ifd(0).x_resolution.has_value());
  EXPECT_DOUBLE_EQ(*(*file)->ifd(0).x_resolution, 2000.0);
  EXPECT_DOUBLE_EQ(*(*file)->ifd(0).y_resolution, 4000.0);
  EXPECT_EQ((*file)->ifd(0).photometric, PHOTOMETRIC_MINISBLACK);
  // Offsets match the chain as written in the bytes.
  std::vector<uint8_t> bytes = ReadAll(path);
  for (int k = 0; k < 3; ++k) EXPECT_EQ((*file)->ifd(k).offset, IfdOffset(bytes, k));
}

TEST_F(TiffFileTest, NoResolutionMeansNullopt) {
  auto file = TiffFile::Open(Fixture("nores.tif"));
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  EXPECT_FALSE((*file)->ifd(0).x_resolution.has_value());
  EXPECT_FALSE((*file)->ifd(0).y_resolution.has_value());
}

TEST_F(TiffFileTest, UnsupportedSampleLayoutsHaveNoDtype) {
  // 64-bit integers: no DataType.
  TiffFixtureSpec spec;
  spec.bits_per_sample = 64;
  spec.sample_format = SAMPLEFORMAT_INT;
  fs::path path = Fixture("int64.tif", spec);
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  EXPECT_FALSE((*file)->ifd(0).dtype.has_value());
  std::vector<std::byte> plane(16 * 8 * 8);
  Status st = (*file)->ReadPlane(0, 0, plane);
  EXPECT_EQ(st.code(), StatusCode::kUnsupported);
  ExpectErrorNaming(st, path);

  // 1-bit bilevel, written directly with libtiff.
  fs::path bilevel = dir_ / "bilevel.tif";
  TIFF* tif = TIFFOpen(bilevel.c_str(), "w");
  ASSERT_NE(tif, nullptr);
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 20);
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 4);
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 1);
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 4);
  uint8_t row[3] = {0xF0, 0x0F, 0xA0};
  for (uint32_t y = 0; y < 4; ++y) ASSERT_EQ(TIFFWriteScanline(tif, row, y, 0), 1);
  TIFFClose(tif);
  auto one_bit = TiffFile::Open(bilevel);
  ASSERT_TRUE(one_bit.ok()) << one_bit.status().ToString();
  EXPECT_EQ((*one_bit)->ifd(0).bits_per_sample, 1);
  EXPECT_FALSE((*one_bit)->ifd(0).dtype.has_value());
  std::vector<std::byte> small(20 * 4);
  st = (*one_bit)->ReadPlane(0, 0, small);
  EXPECT_EQ(st.code(), StatusCode::kUnsupported);
  ExpectErrorNaming(st, bilevel);
}

TEST_F(TiffFileTest, DecodesJpeg) {
  TiffFixtureSpec spec;
  spec.width = 40;
  spec.height = 24;
  spec.bits_per_sample = 8;
  spec.compression = COMPRESSION_JPEG;
  spec.rows_per_strip = 8;  // JPEG strips are multiples of 8 rows.
  auto smooth = [](uint32_t x, uint32_t y, int, int) { return 40.0 + 3.0 * x + 2.0 * y; };
  fs::path path = dir_ / "jpeg.tif";
  ASSERT_TRUE(WriteTiffFixture(path, spec, smooth));
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  EXPECT_EQ((*file)->ifd(0).compression, COMPRESSION_JPEG);
  std::vector<std::byte> plane(40 * 24);
  ASSERT_TRUE((*file)->ReadPlane(0, 0, plane).ok());
  // Lossy: a smooth ramp comes back within a few levels.
  int worst = 0;
  for (uint32_t y = 0; y < 24; ++y) {
    for (uint32_t x = 0; x < 40; ++x) {
      int got = static_cast<int>(plane[y * 40 + x]);
      worst = std::max(worst, std::abs(got - static_cast<int>(smooth(x, y, 0, 0))));
    }
  }
  EXPECT_LE(worst, 6);
}

TEST_F(TiffFileTest, ConcurrentReadsAreCorrect) {
  TiffFixtureSpec spec;
  spec.width = 64;
  spec.height = 48;
  spec.pages = 6;
  spec.samples_per_pixel = 2;
  spec.compression = COMPRESSION_ADOBE_DEFLATE;
  spec.rows_per_strip = 5;
  fs::path path = dir_ / "threads.tif";
  ASSERT_TRUE(WriteTiffFixture(path, spec, PatternOf(DataType::kUint16)));
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  TiffFile* f = file->get();
  std::vector<int> wrong(6, 0);
  std::vector<std::thread> threads;
  for (int t = 0; t < 6; ++t) {
    threads.emplace_back([f, t, &wrong] {
      std::mt19937 rng(t);
      std::vector<std::byte> plane(64 * 48 * 2);
      for (int i = 0; i < 40; ++i) {
        int page = static_cast<int>(rng() % 6), sample = static_cast<int>(rng() % 2);
        if (!f->ReadPlane(page, sample, plane).ok()) {
          ++wrong[t];
          continue;
        }
        for (uint32_t y = 0; y < 48; ++y) {
          for (uint32_t x = 0; x < 64; ++x) {
            auto want =
                SampleBytes(PatternFor(DataType::kUint16, x, y, page, sample), DataType::kUint16);
            if (std::memcmp(&plane[(y * 64 + x) * 2], want.data(), 2) != 0) ++wrong[t];
          }
        }
      }
    });
  }
  for (auto& th : threads) th.join();
  for (int t = 0; t < 6; ++t) EXPECT_EQ(wrong[t], 0) << "thread " << t;
}

TEST_F(TiffFileTest, HasTiffSignature) {
  auto write = [&](const std::string& name, const std::string& head) {
    fs::path p = dir_ / name;
    std::ofstream(p, std::ios::binary) << head;
    return p;
  };
  EXPECT_TRUE(HasTiffSignature(write("a", std::string("II*\0\x08\0\0\0", 8))));
  EXPECT_TRUE(HasTiffSignature(write("b", std::string("MM\0*\0\0\0\x08", 8))));
  EXPECT_TRUE(HasTiffSignature(write("c", std::string("II+\0\x08\0\0\0", 8))));
  EXPECT_TRUE(HasTiffSignature(write("d", std::string("MM\0+\0\x08\0\0", 8))));
  EXPECT_FALSE(HasTiffSignature(write("e", std::string("II*\x01", 4))));
  EXPECT_FALSE(HasTiffSignature(write("f", std::string("MM*\0", 4))));
  EXPECT_FALSE(HasTiffSignature(write("g", "")));
  EXPECT_FALSE(HasTiffSignature(write("h", "\x89PNG\r\n")));
  EXPECT_FALSE(HasTiffSignature(dir_ / "missing.tif"));
  EXPECT_TRUE(HasTiffSignature(Fixture("real.tif")));
}

// ---------------------------------------------------------------------------------------------
// Broken input: every case is an error naming the file, never a crash or a hang.

TEST_F(TiffFileTest, MissingFileAndDirectory) {
  Result<std::unique_ptr<TiffFile>> missing = TiffFile::Open(dir_ / "nope.tif");
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  ExpectErrorNaming(missing.status(), dir_ / "nope.tif");
  Status folder = TiffFile::Open(dir_).status();
  EXPECT_EQ(folder.code(), StatusCode::kUnsupported);
  ExpectErrorNaming(folder, dir_);
}

TEST_F(TiffFileTest, EmptyFile) {
  fs::path path = dir_ / "empty.tif";
  std::ofstream(path).close();
  ExpectErrorNaming(TiffFile::Open(path).status(), path);
}

TEST_F(TiffFileTest, NotATiff) {
  fs::path path = dir_ / "text.tif";
  std::ofstream(path) << "This is not a TIFF file at all, just some text.\n";
  ExpectErrorNaming(TiffFile::Open(path).status(), path);
  fs::path short_header = dir_ / "short.tif";
  std::ofstream(short_header, std::ios::binary) << std::string("II*\0\x08", 5);
  ExpectErrorNaming(TiffFile::Open(short_header).status(), short_header);
}

TEST_F(TiffFileTest, TruncatedInHalf) {
  for (bool big_tiff : {false, true}) {
    TiffFixtureSpec spec;
    spec.pages = 3;
    spec.big_tiff = big_tiff;
    fs::path path = Fixture(big_tiff ? "half_big.tif" : "half.tif", spec);
    std::vector<uint8_t> bytes = ReadAll(path);
    bytes.resize(bytes.size() / 2);
    WriteAll(path, bytes);
    auto file = TiffFile::Open(path);
    ExpectErrorNaming(file.status(), path);
  }
}

TEST_F(TiffFileTest, StripBeyondEndOfFileIsCorrupt) {
  for (bool big_endian : {false, true}) {
    TiffFixtureSpec spec;
    spec.rows_per_strip = spec.height;  // One strip: its offset sits in the entry.
    spec.big_endian = big_endian;
    fs::path path = Fixture(big_endian ? "strip_be.tif" : "strip_le.tif", spec);
    std::vector<uint8_t> bytes = ReadAll(path);
    const size_t ifd = IfdOffset(bytes, 0);
    PatchLong(bytes, ifd, TIFFTAG_STRIPOFFSETS, static_cast<uint32_t>(bytes.size() - 10));
    WriteAll(path, bytes);
    auto file = TiffFile::Open(path);
    ASSERT_TRUE(file.ok()) << file.status().ToString();
    std::vector<std::byte> plane(16 * 8 * 2);
    Status st = (*file)->ReadPlane(0, 0, plane);
    EXPECT_EQ(st.code(), StatusCode::kCorrupt);
    ExpectErrorNaming(st, path);
    EXPECT_NE(st.message().find("strip 0"), std::string::npos) << st.message();
  }
}

TEST_F(TiffFileTest, TruncatedTileIsCorrupt) {
  TiffFixtureSpec spec;
  spec.width = 40;
  spec.height = 40;
  spec.tile_width = spec.tile_height = 16;
  spec.compression = COMPRESSION_LZW;
  fs::path path = Fixture("tiles.tif", spec);
  std::vector<uint8_t> bytes = ReadAll(path);
  const size_t ifd = IfdOffset(bytes, 0);
  // Tile offsets are an array; point the array's last entry past the end of the file.
  const size_t e = EntryPos(bytes, ifd, TIFFTAG_TILEOFFSETS);
  ASSERT_NE(e, 0u);
  const uint32_t count = Get(bytes, e + 4, 4);
  ASSERT_EQ(count, 9u);
  const size_t array = Get(bytes, e + 8, 4);
  Put(bytes, array + (count - 1) * 4, 4, static_cast<uint32_t>(bytes.size() + 100));
  WriteAll(path, bytes);
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  std::vector<std::byte> plane(40 * 40 * 2);
  Status st = (*file)->ReadPlane(0, 0, plane);
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  ExpectErrorNaming(st, path);
  EXPECT_NE(st.message().find("tile 8"), std::string::npos) << st.message();
}

TEST_F(TiffFileTest, GarbledCompressedDataIsAnError) {
  TiffFixtureSpec spec;
  spec.width = 64;
  spec.height = 16;
  spec.rows_per_strip = 16;
  spec.compression = COMPRESSION_ADOBE_DEFLATE;
  fs::path path = Fixture("garbled.tif", spec);
  std::vector<uint8_t> bytes = ReadAll(path);
  const size_t ifd = IfdOffset(bytes, 0);
  const uint32_t offset = EntryValue(bytes, ifd, TIFFTAG_STRIPOFFSETS);
  const uint32_t count = EntryValue(bytes, ifd, TIFFTAG_STRIPBYTECOUNTS);
  ASSERT_GT(count, 4u);
  for (uint32_t i = 0; i < count; ++i) bytes[offset + i] = 0xFF;
  WriteAll(path, bytes);
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  std::vector<std::byte> plane(64 * 16 * 2);
  Status st = (*file)->ReadPlane(0, 0, plane);
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  ExpectErrorNaming(st, path);
  EXPECT_NE(st.message().find("libtiff"), std::string::npos) << st.message();
  // The handle stays usable for the next request (which fails the same way, not worse).
  EXPECT_FALSE((*file)->ReadPlane(0, 0, plane).ok());
}

TEST_F(TiffFileTest, BitFlippedHeader) {
  TiffFixtureSpec spec;
  spec.pages = 2;
  const fs::path good = Fixture("good.tif", spec);
  const std::vector<uint8_t> original = ReadAll(good);
  for (int bit = 0; bit < 64; ++bit) {
    std::vector<uint8_t> bytes = original;
    bytes[bit / 8] ^= static_cast<uint8_t>(1u << (bit % 8));
    const fs::path path = dir_ / ("flip" + std::to_string(bit) + ".tif");
    WriteAll(path, bytes);
    auto file = TiffFile::Open(path);
    if (bit < 32) {
      // Signature or version damaged: never a TIFF.
      ExpectErrorNaming(file.status(), path);
      continue;
    }
    if (!file.ok()) {
      ExpectErrorNaming(file.status(), path);
      continue;
    }
    // A flipped low bit of the IFD offset may still land on something parseable: reading must
    // then fail cleanly or succeed, never crash.
    for (int i = 0; i < (*file)->ifd_count(); ++i) {
      const TiffIfd& ifd = (*file)->ifd(i);
      if (!ifd.dtype) continue;
      std::vector<std::byte> plane(uint64_t{ifd.width} * ifd.height *
                                   volume::BytesPerSample(*ifd.dtype));
      Status st = (*file)->ReadPlane(i, 0, plane);
      if (!st.ok()) ExpectErrorNaming(st, path);
    }
  }
}

TEST_F(TiffFileTest, IfdLoopIsAnError) {
  for (bool big_endian : {false, true}) {
    // A single IFD pointing at itself.
    TiffFixtureSpec one;
    one.big_endian = big_endian;
    fs::path self = Fixture(big_endian ? "self_be.tif" : "self_le.tif", one);
    std::vector<uint8_t> bytes = ReadAll(self);
    size_t ifd0 = IfdOffset(bytes, 0);
    Put(bytes, NextPointerPos(bytes, ifd0), 4, static_cast<uint32_t>(ifd0));
    WriteAll(self, bytes);
    auto file = TiffFile::Open(self);
    EXPECT_EQ(file.status().code(), StatusCode::kCorrupt);
    ExpectErrorNaming(file.status(), self);
    EXPECT_NE(file.status().message().find("loop"), std::string::npos) << file.status().message();

    // The third of three IFDs pointing back at the second.
    TiffFixtureSpec three;
    three.pages = 3;
    three.big_endian = big_endian;
    fs::path back = Fixture(big_endian ? "back_be.tif" : "back_le.tif", three);
    bytes = ReadAll(back);
    size_t ifd1 = IfdOffset(bytes, 1), ifd2 = IfdOffset(bytes, 2);
    Put(bytes, NextPointerPos(bytes, ifd2), 4, static_cast<uint32_t>(ifd1));
    WriteAll(back, bytes);
    file = TiffFile::Open(back);
    EXPECT_EQ(file.status().code(), StatusCode::kCorrupt);
    ExpectErrorNaming(file.status(), back);
  }
}

TEST_F(TiffFileTest, AbsurdDimensions) {
  TiffFixtureSpec spec;
  spec.rows_per_strip = spec.height;
  const fs::path good = Fixture("dims.tif", spec);
  const std::vector<uint8_t> original = ReadAll(good);
  const size_t ifd = IfdOffset(original, 0);

  std::vector<uint8_t> bytes = original;
  PatchLong(bytes, ifd, TIFFTAG_IMAGEWIDTH, 0x7fffffff);
  fs::path wide = dir_ / "wide.tif";
  WriteAll(wide, bytes);
  ExpectErrorNaming(TiffFile::Open(wide).status(), wide);

  bytes = original;
  PatchLong(bytes, ifd, TIFFTAG_IMAGEWIDTH, 70000);
  PatchLong(bytes, ifd, TIFFTAG_IMAGELENGTH, 70000);
  fs::path huge = dir_ / "huge.tif";
  WriteAll(huge, bytes);
  // Over the plane limit …
  ExpectErrorNaming(TiffFile::Open(huge).status(), huge);
  // … and, with the limit lifted, more than the file can hold.
  TiffFile::Limits lifted;
  lifted.max_plane_bytes = uint64_t{1} << 40;
  Status st = TiffFile::Open(huge, lifted).status();
  ExpectErrorNaming(st, huge);

  bytes = original;
  PatchLong(bytes, ifd, TIFFTAG_IMAGELENGTH, 0);
  fs::path zero = dir_ / "zero.tif";
  WriteAll(zero, bytes);
  ExpectErrorNaming(TiffFile::Open(zero).status(), zero);
}

TEST_F(TiffFileTest, LimitsAreEnforced) {
  TiffFixtureSpec spec;
  spec.pages = 3;
  fs::path path = Fixture("limits.tif", spec);
  TiffFile::Limits few_ifds;
  few_ifds.max_ifds = 2;
  Status st = TiffFile::Open(path, few_ifds).status();
  EXPECT_EQ(st.code(), StatusCode::kResourceExhausted);
  ExpectErrorNaming(st, path);
  TiffFile::Limits small_planes;
  small_planes.max_plane_bytes = 100;  // 16x8x2 = 256 bytes per plane.
  st = TiffFile::Open(path, small_planes).status();
  EXPECT_EQ(st.code(), StatusCode::kResourceExhausted);
  ExpectErrorNaming(st, path);
  TiffFile::Limits enough;
  enough.max_ifds = 3;
  enough.max_plane_bytes = 256;
  EXPECT_TRUE(TiffFile::Open(path, enough).ok());
}

TEST_F(TiffFileTest, OutOfRangeRequests) {
  TiffFixtureSpec spec;
  spec.pages = 2;
  spec.samples_per_pixel = 2;
  fs::path path = Fixture("range.tif", spec);
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  std::vector<std::byte> plane(16 * 8 * 2);
  for (auto [index, sample] : {std::pair{-1, 0}, {2, 0}, {0, -1}, {0, 2}, {1000000, 0}}) {
    Status st = (*file)->ReadPlane(index, sample, plane);
    EXPECT_EQ(st.code(), StatusCode::kOutOfRange) << index << "/" << sample;
    ExpectErrorNaming(st, path);
  }
  std::vector<std::byte> wrong_size(16 * 8);
  Status st = (*file)->ReadPlane(0, 0, wrong_size);
  EXPECT_EQ(st.code(), StatusCode::kInvalidArgument);
  ExpectErrorNaming(st, path);
  // Raw reads beyond the end are refused too.
  std::vector<std::byte> raw(64);
  ExpectErrorNaming((*file)->ReadBytes((*file)->file_size() - 10, raw), path);
  EXPECT_TRUE((*file)->ReadBytes(0, std::span<std::byte>(raw).first(8)).ok());
  EXPECT_EQ(raw[0], std::byte{'I'});
  // And a good read still works afterwards.
  EXPECT_TRUE((*file)->ReadPlane(1, 1, plane).ok());
}

// ---------------------------------------------------------------------------------------------
// Regressions for crafted files (each is also a fuzz regression input in fuzz/regressions/).

// A writable buffer of `bytes` (gigabytes) whose pages all alias one small memfd block: lets a
// test hand ReadPlane the plane of a 2^32-row image while touching only kBlock bytes of memory.
// Every alias shows the same bytes, so a fill of the block shows everywhere.
class AliasedBuffer {
 public:
  static constexpr uint64_t kBlock = uint64_t{8} << 20;

  explicit AliasedBuffer(uint64_t bytes) : size_(bytes) {
    mapped_ = (bytes + kBlock - 1) / kBlock * kBlock;
    fd_ = ::memfd_create("aliased-buffer", MFD_CLOEXEC);
    if (fd_ < 0 || ::ftruncate(fd_, static_cast<off_t>(kBlock)) != 0) return;
    void* base =
        ::mmap(nullptr, mapped_, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (base == MAP_FAILED) return;
    base_ = static_cast<std::byte*>(base);
    for (uint64_t at = 0; at < mapped_; at += kBlock) {
      if (::mmap(base_ + at, kBlock, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_FIXED, fd_, 0) ==
          MAP_FAILED) {
        return;
      }
    }
    ok_ = true;
  }
  ~AliasedBuffer() {
    if (base_ != nullptr) ::munmap(base_, mapped_);
    if (fd_ >= 0) ::close(fd_);
  }
  AliasedBuffer(const AliasedBuffer&) = delete;
  AliasedBuffer& operator=(const AliasedBuffer&) = delete;

  bool ok() const { return ok_; }
  std::span<std::byte> span() { return {base_, size_}; }

 private:
  uint64_t size_ = 0;
  uint64_t mapped_ = 0;
  int fd_ = -1;
  std::byte* base_ = nullptr;
  bool ok_ = false;
};

// Bug: with RowsPerStrip 0xFFFFFFFF and a height > 2^31, strips per plane were computed in 32 bits
// and wrapped to 0, so ReadPlane returned OK without decoding anything. The file's one strip is a
// truncated deflate stream: decoding it must be attempted, and fail.
TEST_F(TiffFileTest, PlaneTallerThan2To31RowsInOneStripIsDecoded) {
  const fs::path path = Regression("strips-per-plane-wraps.tif");
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  ASSERT_EQ((*file)->ifd(0).height, 3000000000u);
  AliasedBuffer plane(3000000000u);
  ASSERT_TRUE(plane.ok());
  Status st = (*file)->ReadPlane(0, 0, plane.span());
  EXPECT_EQ(st.code(), StatusCode::kCorrupt) << st.ToString();
  ExpectErrorNaming(st, path);
  EXPECT_NE(st.message().find("strip 0"), std::string::npos) << st.ToString();
}

// The reviewer's 1 x 4e9 image of four 2^30-row tiles: with 32-bit loop counters `ty +=
// tile_height` would wrap past 2^32 and never end. This libtiff refuses tile grids whose count
// computation would wrap ("zero number of tiles"), so the file cannot be opened at all; ReadPlane
// loops in 64 bits anyway. The refusal must be a clear error, not a hang.
TEST_F(TiffFileTest, TileGridNearTwoToThe32IsRefusedNotLooped) {
  const fs::path path = Regression("tile-row-loop-wraps-hang.tif");
  Status st = TiffFile::Open(path).status();
  EXPECT_EQ(st.code(), StatusCode::kCorrupt) << st.ToString();
  ExpectErrorNaming(st, path);
}

// Issue 8: a 201-byte file declaring 4x4 pixels of 65,279 chunky samples (in a compression this
// libtiff cannot decode) took > 10 s to read channel by channel: each failed read re-selected the
// IFD. Now the first failure is remembered: every other sample fails at once with the same error,
// and the page is decoded once.
TEST_F(TiffFileTest, APageThatFailedToDecodeFailsAtOnceForItsOtherSamples) {
  const fs::path path = Regression("plain-tiff-65279-samples-per-pixel.tif");
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  ASSERT_EQ((*file)->ifd(0).samples_per_pixel, 65279);
  std::vector<std::byte> plane(4 * 4 * 2);
  const Status first = (*file)->ReadPlane(0, 0, plane);
  EXPECT_EQ(first.code(), StatusCode::kCorrupt) << first.ToString();
  ExpectErrorNaming(first, path);
  for (int sample = 1; sample < 65279; ++sample) {
    const Status again = (*file)->ReadPlane(0, sample, plane);
    ASSERT_EQ(again.code(), first.code());
    ASSERT_EQ(again.message(), first.message());
  }
  EXPECT_EQ((*file)->blocks_decoded(), 1u);
}

// Reading each sample of a chunky page in turn (one channel after another) decodes the page once,
// while it fits Limits::max_cached_bytes; least recently used pages are dropped first.
TEST_F(TiffFileTest, ChunkyPagesAreDecodedOnceForAllTheirSamples) {
  for (bool tiled : {false, true}) {
    SCOPED_TRACE(tiled ? "tiles" : "strips");
    TiffFixtureSpec spec;
    spec.width = 32;
    spec.height = 16;
    spec.pages = 3;
    spec.samples_per_pixel = 3;
    spec.planar_config = PLANARCONFIG_CONTIG;
    spec.compression = COMPRESSION_ADOBE_DEFLATE;
    spec.rows_per_strip = 5;                             // 4 strips per page.
    if (tiled) spec.tile_width = spec.tile_height = 16;  // 2 tiles per page.
    const uint64_t blocks = tiled ? 2 : 4;
    const fs::path path = dir_ / (tiled ? "chunky_tiles.tif" : "chunky_strips.tif");
    ASSERT_TRUE(WriteTiffFixture(path, spec, PatternOf(DataType::kUint16)));
    const uint64_t page_bytes = 32 * 16 * 3 * 2;
    std::vector<std::byte> plane(32 * 16 * 2);
    auto read = [&](TiffFile& file, int page, int sample) {
      ASSERT_TRUE(file.ReadPlane(page, sample, plane).ok());
      EXPECT_EQ(CountMismatches(plane, volume::DataType::kUint16, 32, 16, page, sample), 0)
          << "page " << page << " sample " << sample;
    };
    {
      auto file = TiffFile::Open(path);
      ASSERT_TRUE(file.ok()) << file.status().ToString();
      for (int page = 0; page < 3; ++page) {
        for (int sample = 0; sample < 3; ++sample) read(**file, page, sample);
      }
      EXPECT_EQ((*file)->blocks_decoded(), 3 * blocks);
      // All three pages are kept: reading them again decodes nothing.
      for (int page : {2, 0, 1}) read(**file, page, 1);
      EXPECT_EQ((*file)->blocks_decoded(), 3 * blocks);
    }
    {
      // Room for one page: page 0 is dropped when page 1 is read, and decoded again after.
      TiffFile::Limits limits;
      limits.max_cached_bytes = page_bytes;
      auto file = TiffFile::Open(path, limits);
      ASSERT_TRUE(file.ok());
      read(**file, 0, 0);
      read(**file, 0, 2);
      read(**file, 1, 0);
      read(**file, 0, 1);
      EXPECT_EQ((*file)->blocks_decoded(), 3 * blocks);
    }
    {
      // No room: every sample decodes its page again (the old behaviour, for huge pages).
      TiffFile::Limits limits;
      limits.max_cached_bytes = 0;
      auto file = TiffFile::Open(path, limits);
      ASSERT_TRUE(file.ok());
      for (int sample = 0; sample < 3; ++sample) read(**file, 1, sample);
      EXPECT_EQ((*file)->blocks_decoded(), 3 * blocks);
    }
  }
}

// Bug: Open left libtiff on the last IFD without the JPEG colour-mode set-up, and the first read
// of that IFD skipped the set-up, so single-page JPEG-YCbCr files could not be decoded.
TEST_F(TiffFileTest, SinglePageJpegYCbCrDecodesAsRgb) {
  const uint32_t width = 48, height = 32;
  auto value = [](uint32_t x, uint32_t y, int s) {
    return 30.0 + 2.0 * x + 1.5 * y + 40.0 * s;  // A smooth ramp per channel.
  };
  const fs::path path = dir_ / "ycbcr.tif";
  {
    TIFF* tif = TIFFOpen(path.c_str(), "w");
    ASSERT_NE(tif, nullptr);
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, width);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, height);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 3);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 8);
    TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
    TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_JPEG);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_YCBCR);
    TIFFSetField(tif, TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB);  // We hand libtiff RGB rows.
    TIFFSetField(tif, TIFFTAG_JPEGQUALITY, 95);
    TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 16);
    std::vector<uint8_t> row(width * 3);
    for (uint32_t y = 0; y < height; ++y) {
      for (uint32_t x = 0; x < width; ++x) {
        for (int s = 0; s < 3; ++s) row[x * 3 + s] = static_cast<uint8_t>(value(x, y, s));
      }
      ASSERT_EQ(TIFFWriteScanline(tif, row.data(), y, 0), 1);
    }
    TIFFClose(tif);
  }
  for (const fs::path& p : {path, Regression("jpeg-ycbcr-single-page.tif")}) {
    SCOPED_TRACE(p.string());
    auto file = TiffFile::Open(p);
    ASSERT_TRUE(file.ok()) << file.status().ToString();
    ASSERT_EQ((*file)->ifd_count(), 1);
    EXPECT_EQ((*file)->ifd(0).photometric, PHOTOMETRIC_YCBCR);
    const TiffIfd& ifd = (*file)->ifd(0);
    std::vector<std::byte> plane(uint64_t{ifd.width} * ifd.height);
    for (int s = 0; s < 3; ++s) {
      Status st = (*file)->ReadPlane(0, s, plane);
      ASSERT_TRUE(st.ok()) << st.ToString();
      if (p != path) continue;  // The crafted file's content is unknown; it must decode.
      int worst = 0;
      for (uint32_t y = 0; y < height; ++y) {
        for (uint32_t x = 0; x < width; ++x) {
          const int got = static_cast<int>(plane[y * width + x]);
          worst = std::max(worst, std::abs(got - static_cast<int>(value(x, y, s))));
        }
      }
      EXPECT_LE(worst, 8) << "sample " << s;  // JPEG (with chroma subsampling) is lossy.
    }
  }
}

// Bug: a compressed chunky page decoded whole strips of all its samples into scratch memory, so a
// 280-byte file (20000x20000, 64 uint16 samples per pixel, one deflate strip) asked for 51 GB.
TEST_F(TiffFileTest, ChunkyStripsLargerThanThePlaneLimitAreRefusedAtOpen) {
  const fs::path crafted = Regression("chunky-strip-51gb-scratch.tif");
  Status st = TiffFile::Open(crafted).status();
  EXPECT_EQ(st.code(), StatusCode::kResourceExhausted) << st.ToString();
  ExpectErrorNaming(st, crafted);

  // A 16x8 uint16 RGB page in one strip: a plane of one sample is 256 bytes, a strip 768.
  TiffFixtureSpec spec;
  spec.samples_per_pixel = 3;
  spec.rows_per_strip = 8;
  spec.compression = COMPRESSION_ADOBE_DEFLATE;
  const fs::path path = dir_ / "rgb.tif";
  ASSERT_TRUE(WriteTiffFixture(path, spec, PatternOf(DataType::kUint16)));
  TiffFile::Limits limits;
  limits.max_plane_bytes = 767;
  st = TiffFile::Open(path, limits).status();
  EXPECT_EQ(st.code(), StatusCode::kResourceExhausted) << st.ToString();
  ExpectErrorNaming(st, path);
  limits.max_plane_bytes = 768;
  auto file = TiffFile::Open(path, limits);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  std::vector<std::byte> plane(16 * 8 * 2);
  for (int s = 0; s < 3; ++s) {
    ASSERT_TRUE((*file)->ReadPlane(0, s, plane).ok());
    EXPECT_EQ(CountMismatches(plane, DataType::kUint16, 16, 8, 0, s), 0) << "sample " << s;
  }
}

// Bug: tiles were refused when larger than "4 planes + 1 MiB", which refuses legitimate images
// narrower than one tile. Now only the scratch limit bounds a tile.
TEST_F(TiffFileTest, ImageSmallerThanOneTileDecodes) {
  TiffFixtureSpec spec;
  spec.width = 1000;
  spec.height = 10;
  spec.tile_width = 1024;
  spec.tile_height = 1024;
  spec.compression = COMPRESSION_ADOBE_DEFLATE;
  const fs::path path = dir_ / "narrow.tif";
  ASSERT_TRUE(WriteTiffFixture(path, spec, PatternOf(DataType::kUint16)));
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  ASSERT_TRUE((*file)->ifd(0).tiled);
  std::vector<std::byte> plane(1000 * 10 * 2);
  Status st = (*file)->ReadPlane(0, 0, plane);
  ASSERT_TRUE(st.ok()) << st.ToString();
  EXPECT_EQ(CountMismatches(plane, DataType::kUint16, 1000, 10, 0, 0), 0);

  // A tile (2 MiB) above the limit is refused when the file is opened.
  TiffFile::Limits limits;
  limits.max_plane_bytes = 1 << 20;
  st = TiffFile::Open(path, limits).status();
  EXPECT_EQ(st.code(), StatusCode::kResourceExhausted) << st.ToString();
  ExpectErrorNaming(st, path);
}

// Bug: every IFD's ImageDescription was copied into the index (3000 IFDs sharing a 1 MB text took
// 3 GB). Only IFD 0's is kept; the others are read on demand.
TEST_F(TiffFileTest, LaterDescriptionsAreNotCopiedIntoTheIndex) {
  const fs::path path = Regression("description-per-ifd-amplification.tif");
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  ASSERT_EQ((*file)->ifd_count(), 350);
  const std::string& first = (*file)->ifd(0).description;
  EXPECT_GT(first.size(), 16000u);
  EXPECT_TRUE(first.starts_with("ImageJ="));
  for (int i = 1; i < (*file)->ifd_count(); ++i) {
    ASSERT_TRUE((*file)->ifd(i).description.empty()) << "IFD " << i;
  }
  Result<std::string> last = (*file)->Description(349);
  ASSERT_TRUE(last.ok()) << last.status().ToString();
  EXPECT_EQ(*last, first);
}

TEST_F(TiffFileTest, ContiguousDataOffset) {
  TiffFixtureSpec spec;
  spec.rows_per_strip = 3;  // Several strips, written back to back by libtiff.
  fs::path path = Fixture("contig.tif", spec);
  auto file = TiffFile::Open(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  Result<uint64_t> offset = (*file)->ContiguousDataOffset(0);
  ASSERT_TRUE(offset.ok()) << offset.status().ToString();
  std::vector<uint8_t> bytes = ReadAll(path);
  const size_t ifd = IfdOffset(bytes, 0);
  const size_t e = EntryPos(bytes, ifd, TIFFTAG_STRIPOFFSETS);
  EXPECT_EQ(*offset, Get(bytes, Get(bytes, e + 8, 4), 4));  // First entry of the offsets array.
  // The raw bytes there are the plane (little-endian file on a little-endian host).
  std::vector<std::byte> raw(16 * 8 * 2), decoded(16 * 8 * 2);
  ASSERT_TRUE((*file)->ReadBytes(*offset, raw).ok());
  ASSERT_TRUE((*file)->ReadPlane(0, 0, decoded).ok());
  if (std::endian::native == std::endian::little) {
    EXPECT_EQ(raw, decoded);
  }

  TiffFixtureSpec lzw = spec;
  lzw.compression = COMPRESSION_LZW;
  auto compressed = TiffFile::Open(Fixture("contig_lzw.tif", lzw));
  ASSERT_TRUE(compressed.ok());
  EXPECT_EQ((*compressed)->ContiguousDataOffset(0).status().code(), StatusCode::kUnsupported);
}

// ---------------------------------------------------------------------------------------------
// StoredPlaneOffset: planes located exactly when the file holds the decoded samples as one run.

// The decoded plane of (page, sample), through ReadPlane.
std::vector<std::byte> Decoded(TiffFile& file, int page, int sample = 0) {
  const TiffIfd& ifd = file.ifd(page);
  std::vector<std::byte> out(size_t{ifd.width} * ifd.height * volume::BytesPerSample(*ifd.dtype));
  EXPECT_TRUE(file.ReadPlane(page, sample, out).ok());
  return out;
}

// The plane of (page, sample) read with ReadBytes where StoredPlaneOffset locates it; nullopt
// when it is not located.
std::optional<std::vector<std::byte>> Stored(TiffFile& file, int page, int sample = 0) {
  std::optional<uint64_t> offset = file.StoredPlaneOffset(page, sample);
  if (!offset) return std::nullopt;
  const TiffIfd& ifd = file.ifd(page);
  std::vector<std::byte> out(size_t{ifd.width} * ifd.height * volume::BytesPerSample(*ifd.dtype));
  EXPECT_TRUE(file.ReadBytes(*offset, out).ok());
  return out;
}

// The value array of the SHORT or LONG entry `tag` (strip offsets, byte counts): where it lies
// and the size of one value.
struct ValueArray {
  size_t at = 0;
  int size = 4;
  uint32_t Get(const std::vector<uint8_t>& b, int i) const {
    return ::octoscope::io::Get(b, at + i * size, size);
  }
  void Put(std::vector<uint8_t>& b, int i, uint32_t v) const {
    ::octoscope::io::Put(b, at + i * size, size, v);
  }
};

ValueArray ArrayOf(const std::vector<uint8_t>& b, size_t ifd, uint16_t tag) {
  const size_t e = EntryPos(b, ifd, tag);
  EXPECT_NE(e, 0u);
  ValueArray a;
  a.size = Get(b, e + 2, 2) == TIFF_SHORT ? 2 : 4;
  a.at = Get(b, e + 4, 4) * a.size > 4 ? Get(b, e + 8, 4) : e + 8;
  return a;
}

TEST_F(TiffFileTest, StoredPlaneEqualsReadPlaneForUncompressedLittleEndianStrips) {
  if (std::endian::native != std::endian::little) GTEST_SKIP() << "fixtures are little-endian";
  struct Case {
    const char* name;
    uint16_t bits, format;
    uint32_t rows_per_strip;
  };
  for (const Case& c :
       {Case{"u16_one_strip", 16, 1, 8}, Case{"u16_strips", 16, 1, 3}, Case{"u8_strips", 8, 1, 1},
        Case{"i16_strips", 16, 2, 5}, Case{"u32_strips", 32, 1, 3}, Case{"f32_one_strip", 32, 3, 8},
        Case{"f64_strips", 64, 3, 2}}) {
    SCOPED_TRACE(c.name);
    TiffFixtureSpec spec;
    spec.pages = 3;
    spec.bits_per_sample = c.bits;
    spec.sample_format = c.format;
    spec.rows_per_strip = c.rows_per_strip;
    const fs::path path = Fixture(std::string(c.name) + ".tif", spec);
    auto file = TiffFile::Open(path);
    ASSERT_TRUE(file.ok()) << file.status().ToString();
    const std::vector<uint8_t> bytes = ReadAll(path);
    for (int page : {2, 0, 1, 2}) {  // Out of order, and twice: the answer is cached.
      // Where the file says the page's first strip is, whatever its alignment (TIFF aligns to 2
      // bytes only; positioned reads need none).
      const uint32_t first_strip =
          ArrayOf(bytes, IfdOffset(bytes, page), TIFFTAG_STRIPOFFSETS).Get(bytes, 0);
      EXPECT_EQ((*file)->StoredPlaneOffset(page), std::optional<uint64_t>(first_strip));
      std::optional<std::vector<std::byte>> stored = Stored(**file, page);
      ASSERT_TRUE(stored.has_value()) << "page " << page;
      EXPECT_EQ(stored->size(), size_t{16} * 8 * c.bits / 8);
      EXPECT_EQ(*stored, Decoded(**file, page)) << "page " << page;
    }
    // Out-of-range requests are simply not located.
    EXPECT_FALSE((*file)->StoredPlaneOffset(3).has_value());
    EXPECT_FALSE((*file)->StoredPlaneOffset(-1).has_value());
    EXPECT_FALSE((*file)->StoredPlaneOffset(0, 1).has_value());
  }
}

TEST_F(TiffFileTest, StoredPlaneOfPlanarSamplesAndBigTiff) {
  if (std::endian::native != std::endian::little) GTEST_SKIP() << "fixtures are little-endian";
  TiffFixtureSpec spec;
  spec.pages = 2;
  spec.samples_per_pixel = 3;
  spec.planar_config = PLANARCONFIG_SEPARATE;
  spec.big_tiff = true;
  auto file = TiffFile::Open(Fixture("planar.tif", spec));
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  for (int page = 0; page < 2; ++page) {
    for (int sample = 0; sample < 3; ++sample) {
      std::optional<std::vector<std::byte>> stored = Stored(**file, page, sample);
      ASSERT_TRUE(stored.has_value()) << page << "/" << sample;
      EXPECT_EQ(*stored, Decoded(**file, page, sample)) << page << "/" << sample;
    }
  }
  EXPECT_FALSE((*file)->StoredPlaneOffset(0, 3).has_value());
}

TEST_F(TiffFileTest, StoredPlaneIsNotLocatedForOtherLayouts) {
  struct Case {
    const char* name;
    TiffFixtureSpec spec;
  };
  std::vector<Case> cases;
  TiffFixtureSpec deflate;
  deflate.compression = COMPRESSION_ADOBE_DEFLATE;
  cases.push_back({"deflate", deflate});
  TiffFixtureSpec packbits;
  packbits.compression = COMPRESSION_PACKBITS;
  cases.push_back({"packbits", packbits});
  TiffFixtureSpec big_endian;
  big_endian.big_endian = true;
  cases.push_back({"big_endian_u16", big_endian});
  TiffFixtureSpec tiled;
  tiled.width = 32;
  tiled.height = 32;
  tiled.tile_width = 16;
  tiled.tile_height = 16;
  cases.push_back({"tiled", tiled});
  TiffFixtureSpec chunky;
  chunky.samples_per_pixel = 3;
  chunky.planar_config = PLANARCONFIG_CONTIG;
  cases.push_back({"chunky_rgb", chunky});
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    auto file = TiffFile::Open(Fixture(std::string(c.name) + ".tif", c.spec));
    ASSERT_TRUE(file.ok()) << file.status().ToString();
    EXPECT_FALSE((*file)->StoredPlaneOffset(0).has_value());
    // ReadPlane still reads it.
    EXPECT_EQ(Decoded(**file, 0).size(), size_t{c.spec.width} * c.spec.height * 2);
  }
  // Bytes have no order: a big-endian 8-bit file's planes are stored as read.
  TiffFixtureSpec big_u8;
  big_u8.big_endian = true;
  big_u8.bits_per_sample = 8;
  auto file = TiffFile::Open(Fixture("big_endian_u8.tif", big_u8));
  ASSERT_TRUE(file.ok());
  std::optional<std::vector<std::byte>> stored = Stored(**file, 0);
  ASSERT_TRUE(stored.has_value());
  EXPECT_EQ(*stored, Decoded(**file, 0));
}

TEST_F(TiffFileTest, StoredPlaneNeedsContiguousStrips) {
  if (std::endian::native != std::endian::little) GTEST_SKIP() << "fixtures are little-endian";
  TiffFixtureSpec spec;  // 16x8 uint16 in strips of 3 rows: 96 + 96 + 64 bytes.
  spec.rows_per_strip = 3;
  const fs::path good = Fixture("good.tif", spec);
  {
    auto file = TiffFile::Open(good);
    ASSERT_TRUE(file.ok());
    ASSERT_TRUE((*file)->StoredPlaneOffset(0).has_value());  // The unpatched control.
  }
  const std::vector<uint8_t> original = ReadAll(good);
  const size_t ifd = IfdOffset(original, 0);
  const ValueArray offsets = ArrayOf(original, ifd, TIFFTAG_STRIPOFFSETS);
  const ValueArray counts = ArrayOf(original, ifd, TIFFTAG_STRIPBYTECOUNTS);
  ASSERT_EQ(counts.Get(original, 0), 96u);
  ASSERT_EQ(counts.Get(original, 2), 64u);
  ASSERT_EQ(offsets.Get(original, 1), offsets.Get(original, 0) + 96);  // Contiguous, unpatched.

  // Each patch keeps every strip inside the file, so ReadPlane still reads the (moved) strips.
  auto expect_stored = [&](const std::string& name, bool stored,
                           const std::function<void(std::vector<uint8_t>&)>& patch) {
    SCOPED_TRACE(name);
    std::vector<uint8_t> bytes = original;
    patch(bytes);
    const fs::path path = dir_ / (name + ".tif");
    WriteAll(path, bytes);
    auto file = TiffFile::Open(path);
    ASSERT_TRUE(file.ok()) << file.status().ToString();
    std::optional<std::vector<std::byte>> plane = Stored(**file, 0);
    EXPECT_EQ(plane.has_value(), stored);
    if (plane) {
      EXPECT_EQ(*plane, Decoded(**file, 0));
    }
    std::vector<std::byte> decoded(16 * 8 * 2);
    EXPECT_TRUE((*file)->ReadPlane(0, 0, decoded).ok());
  };
  auto expect_not_mapped = [&](const std::string& name,
                               const std::function<void(std::vector<uint8_t>&)>& patch) {
    expect_stored(name, false, patch);
  };
  // A 2-byte gap before strip 1.
  expect_not_mapped("gap",
                    [&](std::vector<uint8_t>& b) { offsets.Put(b, 1, offsets.Get(b, 1) + 2); });
  // Strips 0 and 1 swapped in the file (equal sizes).
  expect_not_mapped("swapped", [&](std::vector<uint8_t>& b) {
    const uint32_t first = offsets.Get(b, 0), second = offsets.Get(b, 1);
    offsets.Put(b, 0, second);
    offsets.Put(b, 1, first);
  });
  // Strip 2 sparse (offset and byte count 0: read as zeros).
  expect_not_mapped("sparse", [&](std::vector<uint8_t>& b) {
    offsets.Put(b, 2, 0);
    counts.Put(b, 2, 0);
  });
  // Every strip one byte later: contiguous, 16-bit samples at odd offsets: located all the same
  // (positioned reads into an aligned buffer need no alignment in the file).
  expect_stored("misaligned", true, [&](std::vector<uint8_t>& b) {
    for (int s = 0; s < 3; ++s) offsets.Put(b, s, offsets.Get(b, s) + 1);
  });
}

TEST_F(TiffFileTest, StoredPlaneFromManyThreads) {
  if (std::endian::native != std::endian::little) GTEST_SKIP() << "fixtures are little-endian";
  TiffFixtureSpec spec;
  spec.pages = 8;
  spec.width = 64;
  spec.height = 32;
  auto file = TiffFile::Open(Fixture("threads.tif", spec));
  ASSERT_TRUE(file.ok());
  std::vector<std::vector<std::byte>> expected;
  for (int page = 0; page < 8; ++page) expected.push_back(Decoded(**file, page));
  // The first calls race to examine each page: every answer right, reads from every thread.
  std::vector<int> mismatches(4, 0);
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int round = 0; round < 20; ++round) {
        const int page = (t + round) % 8;
        std::optional<std::vector<std::byte>> stored = Stored(**file, page);
        if (!stored || *stored != expected[page]) ++mismatches[t];
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(mismatches, std::vector<int>(4, 0));
}

// ---------------------------------------------------------------------------------------------
// Real third-party files.

const fs::path kTestData = OCTOSCOPE_TESTDATA;

TEST(TiffFileRealTest, ScanImageBigTiff) {
  auto file = TiffFile::Open(kTestData / "real_ometiff_misc/ScanImageBigTIFFv57.tif");
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  EXPECT_TRUE((*file)->big_tiff());
  EXPECT_FALSE((*file)->big_endian());
  ASSERT_EQ((*file)->ifd_count(), 4);
  EXPECT_NE((*file)->ifd(0).software.find("SI.hChannels.channelSave = [1;2]"), std::string::npos);
  EXPECT_EQ((*file)->ifd(1).software, "");  // Kept for IFD 0 only.
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ((*file)->ifd(i).width, 64u);
    EXPECT_EQ((*file)->ifd(i).height, 64u);
    EXPECT_EQ((*file)->ifd(i).dtype, DataType::kInt16);
    std::vector<std::byte> plane(64 * 64 * 2);
    EXPECT_TRUE((*file)->ReadPlane(i, 0, plane).ok());
  }
}

TEST(TiffFileRealTest, MicroManagerIfdsBetweenImageData) {
  auto file = TiffFile::Open(kTestData /
                             "real_ometiff_misc/181003_multi_pos_time_course_1_MMStack.ome.tif");
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  ASSERT_EQ((*file)->ifd_count(), 20);  // 2 positions x 10 time points.
  EXPECT_GT((*file)->ifd(0).offset, 8u);
  std::vector<std::byte> plane(256 * 256 * 2);
  for (int i = (*file)->ifd_count() - 1; i >= 0; --i) {
    EXPECT_EQ((*file)->ifd(i).dtype, DataType::kUint16);
    Status st = (*file)->ReadPlane(i, 0, plane);
    EXPECT_TRUE(st.ok()) << st.ToString();
  }
}

TEST(TiffFileRealTest, BigTiffDeflateOme) {
  auto file = TiffFile::Open(kTestData / "ndev_bigtiff_ome/neuron-4Ch.tiff");
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  EXPECT_TRUE((*file)->big_tiff());
  ASSERT_GE((*file)->ifd_count(), 4);
  const TiffIfd& ifd = (*file)->ifd(0);
  EXPECT_EQ(ifd.compression, COMPRESSION_ADOBE_DEFLATE);
  EXPECT_EQ(ifd.width, 502u);
  EXPECT_EQ(ifd.height, 623u);
  EXPECT_NE(ifd.description.find("<OME"), std::string::npos);
  std::vector<std::byte> plane(502 * 623 * 2);
  for (int i = 0; i < 4; ++i) EXPECT_TRUE((*file)->ReadPlane(i, 0, plane).ok());
}

}  // namespace
}  // namespace octoscope::io
