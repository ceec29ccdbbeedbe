// End to end: `info`, `build` and `render` accept OME-Zarr and Imaris like an OME-TIFF
// (--level included), and bad stores and files give exit status 2 with one line naming the file
// and the problem.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "app/run_octoscope.h"
#include "encode/png_test_decoder.h"
#include "io/open_volume.h"
#include "io/tiff_fixture.h"
#include "render/device.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;

const fs::path kZarr = fs::path(OCTOSCOPE_TESTDATA) / "zarrnii" /
                       "sub-AS36F2_sample-brain_acq-downsampled_SPIM.ome.zarr";
const fs::path kIms = fs::path(OCTOSCOPE_TESTDATA) / "zarrnii" / "PtK2Cell.ims";

// Exactly one line on stderr naming `file`, status 2.
void ExpectBadInput(const RunResult& r, const std::string& file, const std::string& problem) {
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_NE(r.err.find(file), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(problem), std::string::npos) << r.err;
}

TEST(ChunkedFormatsCommand, InfoOmeZarrLevels) {
  RunResult r = RunOctoscope("info --json --level 2 " + Quote(kZarr));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["format"], "ome-zarr");
  EXPECT_EQ(j["size"], nlohmann::json({24, 39, 37}));
  EXPECT_EQ(j["level"], 2);
  EXPECT_EQ(j["level_count"], 4);
  EXPECT_EQ(j["channel_names"], nlohmann::json({"Abeta", "CD31", "YoPro"}));
  EXPECT_EQ(j["channel_colors"], nlohmann::json({"#00ff00ff", "#ffffffff", "#ffffffff"}));
  EXPECT_EQ(j["channel_windows"][0]["start"], 0.0);
  EXPECT_EQ(j["channel_windows"][0]["end"], 65535.0);
  EXPECT_EQ(j["dtype"], "float64");

  ExpectBadInput(RunOctoscope("info --level 4 " + Quote(kZarr)), kZarr.filename().string(),
                 "resolution level 4");
  // Single-resolution formats have level 0 only.
  const fs::path tiff = fs::path(OCTOSCOPE_TESTDATA) / "neubias/xyzc_16bit__dna_conf_wf.tif";
  ExpectBadInput(RunOctoscope("info --level 1 " + Quote(tiff)), tiff.filename().string(),
                 "resolution level 1 asked for, the file has 1");
}

TEST(ChunkedFormatsCommand, InfoImarisWithStats) {
  RunResult r = RunOctoscope("info --json --stats " + Quote(kIms));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["format"], "imaris");
  EXPECT_EQ(j["size"], nlohmann::json({256, 256, 32}));
  EXPECT_EQ(j["channel_names"],
            nlohmann::json({"Kinetochores", "Microtubules", "DNA", "Dynactin"}));
  EXPECT_EQ(j["max"], nlohmann::json({206.0, 200.0, 247.0, 209.0}));  // h5py's maxima.
  EXPECT_NEAR(j["spacing"][0].get<double>(), 0.066996, 1e-6);
  EXPECT_NEAR(j["spacing"][2].get<double>(), 0.2, 1e-9);
}

class ChunkedFormatsBadInput : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir("chunked-bad"); }
  void TearDown() override { fs::remove_all(dir_); }
  void Write(const fs::path& rel, const std::string& content) {
    fs::create_directories((dir_ / rel).parent_path());
    std::ofstream(dir_ / rel, std::ios::binary) << content;
  }
  fs::path dir_;
};

TEST_F(ChunkedFormatsBadInput, CorruptZarrChunkIsStatus2NamingTheChunk) {
  Write("s.zarr/.zarray", R"({"zarr_format": 2, "shape": [2, 4, 4], "chunks": [1, 4, 4],
      "dtype": "<u2", "compressor": {"id": "zstd"}, "fill_value": 0, "filters": null})");
  Write("s.zarr/0.0.0", "garbage that is not zstd");
  // Opening succeeds (metadata is fine); reading every voxel meets the bad chunk.
  ExpectBadInput(RunOctoscope("info --stats " + Quote(dir_ / "s.zarr")), "0.0.0", "zstd");
}

TEST_F(ChunkedFormatsBadInput, MalformedZarrMetadataAndAbsurdSizes) {
  Write("m.zarr/.zarray", R"({"zarr_format": 2, "shape": [)");
  ExpectBadInput(RunOctoscope("info " + Quote(dir_ / "m.zarr")), ".zarray", "not valid JSON");
  Write("a.zarr/.zarray", R"({"zarr_format": 2, "shape": [1, 3000000000, 3000000000],
      "chunks": [1, 64, 64], "dtype": "<u2", "compressor": null, "fill_value": 0})");
  ExpectBadInput(RunOctoscope("info " + Quote(dir_ / "a.zarr")), "a.zarr", "limit");
}

TEST_F(ChunkedFormatsBadInput, ImarisThatIsNotHdf5OrLacksDatasets) {
  Write("x.ims", "definitely not HDF5");
  ExpectBadInput(RunOctoscope("info " + Quote(dir_ / "x.ims")), "x.ims", "not an HDF5 file");
  // An HDF5 file without /DataSet: a real HDF5 header cut short.
  std::ifstream in(kIms, std::ios::binary);
  std::string bytes(4096, '\0');
  in.read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  Write("cut.ims", bytes);
  RunResult r = RunOctoscope("info " + Quote(dir_ / "cut.ims"));
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;  // No HDF5 stack.
  EXPECT_NE(r.err.find("cut.ims"), std::string::npos) << r.err;
}

TEST(ChunkedFormatsCommand, BuildFromImarisAndOmeZarrLevel) {
  const fs::path dir = testing::MakeTempDir("chunked-build");
  RunResult ims = RunOctoscope("build " + Quote(kIms) + " --cache " + Quote(dir / "ims"));
  ASSERT_EQ(ims.exit_code, 0) << ims.err;
  auto j = nlohmann::json::parse(ims.out.substr(ims.out.rfind('{')));
  EXPECT_EQ(j["input_bytes"], 256 * 256 * 32 * 4);
  RunResult zarr =
      RunOctoscope("build " + Quote(kZarr) + " --level 1 --cache " + Quote(dir / "zarr"));
  ASSERT_EQ(zarr.exit_code, 0) << zarr.err;
  auto z = nlohmann::json::parse(zarr.out.substr(zarr.out.rfind('{')));
  EXPECT_EQ(z["input_bytes"], 48 * 79 * 75 * 3 * 8);
  fs::remove_all(dir);
}

TEST(ChunkedFormatsCommand, RenderImarisMipContract) {
  auto device = render::ChooseDevice("");
  if (!device.ok()) GTEST_SKIP() << "no OpenCL device: " << device.status().ToString();
  const fs::path dir = testing::MakeTempDir("chunked-render");
  RunResult r = RunOctoscope("render " + Quote(kIms) + " --out " + Quote(dir / "mip.png") +
                             " --size 256x256 --view z --mode mip --refine --defaults raw");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::ifstream f(dir / "mip.png", std::ios::binary);
  std::vector<uint8_t> png((std::istreambuf_iterator<char>(f)), {});
  testing::DecodedPng image = testing::DecodeTestPng(png);
  ASSERT_TRUE(image.ok) << image.error;
  // Default parameters: every channel grey over 0..255, additive: pixel = clamp(sum of column
  // maxima / 255). Column maxima from the reader (checked against h5py in the io tests).
  auto source = io::OpenVolume(kIms, {});
  ASSERT_TRUE(source.ok());
  std::vector<int> sum(256 * 256, 0);
  std::vector<std::byte> vol((*source)->SlabBytes(32));
  for (int c = 0; c < 4; ++c) {
    ASSERT_TRUE((*source)->ReadSlab(c, 0, 32, vol).ok());
    for (int i = 0; i < 256 * 256; ++i) {
      int m = 0;
      for (int z = 0; z < 32; ++z) m = std::max(m, static_cast<int>(vol[z * 65536 + i]));
      sum[i] += m;
    }
  }
  int worst = 0;
  for (int y = 0; y < 256; ++y) {
    for (int x = 0; x < 256; ++x) {
      worst = std::max(worst, std::abs(image.At(x, y, 0) - std::min(255, sum[y * 256 + x])));
    }
  }
  EXPECT_LE(worst, 1);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace octoscope::app
