// Bad input never hurts: replays the fuzzer's seeds and every regression it found, and mutates
// real microscopy files (bit flips, truncation, byte stomps at the header and IFDs) through the
// whole open-and-read path. Each input must either open and read, or fail with a Status whose
// message names the file; never crash, hang or allocate by a corrupt header (ASan/UBSan builds
// catch the rest).
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "io/open_volume.h"
#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

std::vector<char> ReadAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<char>(std::istreambuf_iterator<char>(in), {});
}

void WriteAll(const fs::path& path, const std::vector<char>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Opens and reads everything; returns the first error (or OK).
Status OpenAndReadAll(const fs::path& path) {
  OpenOptions options;
  options.max_plane_bytes = 64 << 20;
  auto source = OpenVolume(path, options);
  if (!source.ok()) return source.status();
  const volume::VolumeInfo& info = (*source)->info();
  if (!info.Validate().ok()) return InternalError("source with invalid info: " + info.ToString());
  if (info.VoxelBytes() > (256u << 20)) return Status::Ok();
  std::vector<std::byte> slab((*source)->SlabBytes(1));
  for (int c = 0; c < info.channel_count(); ++c) {
    for (int64_t z = 0; z < info.size[2]; ++z)
      OCTO_RETURN_IF_ERROR((*source)->ReadSlab(c, z, 1, slab));
  }
  return Status::Ok();
}

void ExpectSafe(const fs::path& path) {
  Status s = OpenAndReadAll(path);
  if (!s.ok()) {
    EXPECT_NE(s.code(), StatusCode::kInternal) << s.ToString();
    EXPECT_NE(s.message().find(path.filename().string()), std::string::npos)
        << "error does not name the file: " << s.ToString();
  }
}

std::vector<fs::path> FilesIn(const fs::path& dir) {
  std::vector<fs::path> files;
  if (!fs::is_directory(dir)) return files;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (entry.is_regular_file() && entry.path().filename() != "README.md")
      files.push_back(entry.path());
  }
  return files;
}

TEST(BadInputTest, FuzzSeedsAndRegressionsAreSafe) {
  const fs::path fuzz = fs::path(OCTOSCOPE_SOURCE_DIR) / "fuzz";
  auto files = FilesIn(fuzz / "seeds");
  auto regressions = FilesIn(fuzz / "regressions");
  files.insert(files.end(), regressions.begin(), regressions.end());
  ASSERT_FALSE(files.empty()) << "no fuzz seeds found under " << fuzz;
  for (const fs::path& f : files) {
    SCOPED_TRACE(f.string());
    ExpectSafe(f);
  }
}

TEST(BadInputTest, EmptyAndNonTiffFilesGiveClearErrors) {
  fs::path dir = testing::MakeTempDir("bad-input");
  WriteAll(dir / "empty.tif", {});
  std::string text = "this is not an image\n";
  WriteAll(dir / "notes.tif", std::vector<char>(text.begin(), text.end()));
  WriteAll(dir / "magic-only.tif", {'I', 'I', '*', '\0'});
  for (const char* name : {"empty.tif", "notes.tif", "magic-only.tif"}) {
    Status s = OpenAndReadAll(dir / name);
    EXPECT_FALSE(s.ok()) << name;
    EXPECT_NE(s.message().find(name), std::string::npos) << s.ToString();
  }
  EXPECT_EQ(OpenAndReadAll(dir / "missing.tif").code(), StatusCode::kNotFound);
  fs::remove_all(dir);
}

// Deterministic mutations of small real files: the seeds of a fuzzer, run in every CI build.
TEST(BadInputTest, MutatedRealFilesAreSafe) {
  const fs::path testdata(OCTOSCOPE_TESTDATA);
  std::vector<fs::path> originals = {
      testdata / "neubias/xyzc_16bit__spots.tif",              // ImageJ, big-endian.
      testdata / "ome_samples/z-series.ome.tif",               // OME-TIFF, int8.
      testdata / "real_ometiff_misc/ScanImageBigTIFFv57.tif",  // BigTIFF.
      testdata / "ndev_bigtiff_ome/neuron-4Ch.tiff",           // BigTIFF + OME + deflate.
  };
  fs::path dir = testing::MakeTempDir("mutations");
  std::mt19937 rng(12345);
  int mutants = 0;
  for (const fs::path& original : originals) {
    if (!fs::exists(original)) {
      ADD_FAILURE() << "missing test file " << original;
      continue;
    }
    const std::vector<char> bytes = ReadAll(original);
    for (int round = 0; round < 60; ++round) {
      std::vector<char> m = bytes;
      switch (round % 4) {
        case 0:  // Flip bits near the start (header, first IFD of most files).
          for (int i = 0; i < 4; ++i) {
            size_t at = rng() % std::min<size_t>(m.size(), 4096);
            m[at] = static_cast<char>(m[at] ^ (1 << (rng() % 8)));
          }
          break;
        case 1:  // Truncate anywhere.
          m.resize(rng() % m.size());
          break;
        case 2:  // Stomp a 4-byte field anywhere with an extreme value.
        {
          size_t at = rng() % (m.size() - 4);
          uint32_t v = (rng() % 2) ? 0xffffffffu : 0x7fffffffu;
          std::memcpy(&m[at], &v, 4);
        } break;
        case 3:  // Flip bits anywhere (IFDs at the end, OME-XML, pixel data).
          for (int i = 0; i < 16; ++i) {
            size_t at = rng() % m.size();
            m[at] = static_cast<char>(m[at] ^ (1 << (rng() % 8)));
          }
          break;
      }
      fs::path mutant =
          dir / ("mutant-" + std::to_string(mutants++) + "-" + original.filename().string());
      WriteAll(mutant, m);
      SCOPED_TRACE(mutant.string());
      ExpectSafe(mutant);
      fs::remove(mutant);
    }
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace octoscope::io
