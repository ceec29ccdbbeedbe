// The lossless default, end to end on real microscopy files: a refined orthographic MIP at the
// volume's size equals the column maximum of the file's voxels (decoded here independently with
// libtiff) at any window — dim structure included. A lossy build (--threshold) reports a per-
// channel error bound that the rendered pixels respect.
#include <gtest/gtest.h>
#include <tiffio.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "app/run_octoscope.h"
#include "encode/png_test_decoder.h"
#include "io/tiff_fixture.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;

// Channel c's voxels of a file as [z][y][x], read page by page with libtiff (pages in the order
// `page_of(z, c)`), 16-bit samples.
struct Volume {
  int64_t sx = 0, sy = 0, sz = 0;
  std::vector<std::vector<uint16_t>> data;  // [c][(z * sy + y) * sx + x]
  uint16_t ColumnMax(int c, int64_t x, int64_t y) const {
    uint16_t m = 0;
    for (int64_t z = 0; z < sz; ++z) m = std::max(m, data[c][(z * sy + y) * sx + x]);
    return m;
  }
};

bool ReadPage(TIFF* tif, std::vector<uint16_t>& out, int64_t& sx, int64_t& sy) {
  uint32_t w = 0, h = 0;
  TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &w);
  TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &h);
  sx = w;
  sy = h;
  const size_t base = out.size();
  out.resize(base + static_cast<size_t>(w) * h);
  std::vector<uint16_t> row(TIFFScanlineSize(tif) / 2 + 1);
  for (uint32_t y = 0; y < h; ++y) {
    if (TIFFReadScanline(tif, row.data(), y, 0) < 0) return false;
    std::copy(row.begin(), row.begin() + w, out.begin() + base + static_cast<size_t>(y) * w);
  }
  return true;
}

// An ImageJ hyperstack with pages in ZC order (c fastest).
Volume ReadHyperstack(const fs::path& path, int channels) {
  Volume v;
  v.data.resize(channels);
  TIFF* tif = TIFFOpen(path.c_str(), "r");
  EXPECT_NE(tif, nullptr);
  if (!tif) return v;
  int page = 0;
  do {
    EXPECT_TRUE(ReadPage(tif, v.data[page % channels], v.sx, v.sy));
    ++page;
  } while (TIFFReadDirectory(tif));
  TIFFClose(tif);
  v.sz = page / channels;
  return v;
}

// A folder of 2-D planes per channel (sub-folders ch0, ch1 …), planes in name order.
Volume ReadPlaneFolders(const fs::path& dir, int channels) {
  Volume v;
  v.data.resize(channels);
  for (int c = 0; c < channels; ++c) {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(dir / ("ch" + std::to_string(c)))) {
      files.push_back(e.path());
    }
    std::sort(files.begin(), files.end());
    for (const fs::path& f : files) {
      TIFF* tif = TIFFOpen(f.c_str(), "r");
      EXPECT_NE(tif, nullptr) << f;
      if (!tif) continue;
      EXPECT_TRUE(ReadPage(tif, v.data[c], v.sx, v.sy));
      TIFFClose(tif);
    }
    v.sz = static_cast<int64_t>(files.size());
  }
  return v;
}

struct Window {
  double lo, hi;
};

std::string ParamsJson(int channels, int shown, const Window& w) {
  std::string json = R"({"channels": [)";
  for (int c = 0; c < channels; ++c) {
    if (c) json += ", ";
    if (c != shown) {
      json += R"({"enabled": false})";
      continue;
    }
    json += R"({"color": [1, 1, 1], "window": )" + std::to_string(w.hi - w.lo) + R"(, "level": )" +
            std::to_string((w.hi + w.lo) / 2) + "}";
  }
  return json + "]}";
}

class LosslessRenderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("octoscope-lossless-" + std::to_string(getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Renders channel `shown` of INPUT (a scan or a cache) as an orthographic MIP along z at the
  // volume's size, refined to completion, and returns the largest |pixel - expected| over all
  // pixels, the expected value being the windowed column maximum of the source.
  double MaxMipError(const fs::path& input, const Volume& v, int channels, int shown,
                     const Window& w, int* bright_pixels = nullptr) {
    const fs::path params = dir_ / "params.json";
    std::ofstream(params) << ParamsJson(channels, shown, w);
    const fs::path out = dir_ / "mip.png";
    RunResult r = RunOctoscope("render " + Quote(input) + " --out " + Quote(out) +
                               " --projection ortho --view z --mode mip --refine --size " +
                               std::to_string(v.sx) + "x" + std::to_string(v.sy) + " --params " +
                               Quote(params));
    EXPECT_EQ(r.exit_code, 0) << r.err;
    const auto png = testing::DecodeTestPng(testing::ReadAll(out));
    EXPECT_TRUE(png.ok) << png.error;
    if (!png.ok) return 1e9;
    EXPECT_EQ(png.width, v.sx);
    EXPECT_EQ(png.height, v.sy);
    double worst = 0;
    int bright = 0;
    for (int y = 0; y < png.height; ++y) {
      for (int x = 0; x < png.width; ++x) {
        const double t =
            std::clamp((v.ColumnMax(shown, x, y) - w.lo) / (w.hi - w.lo), 0.0, 1.0) * 255;
        if (t > 64) ++bright;
        worst = std::max(worst, std::abs(png.At(x, y, 0) - t));
      }
    }
    if (bright_pixels) *bright_pixels = bright;
    return worst;
  }

  fs::path dir_;
};

TEST_F(LosslessRenderTest, ConfocalHyperstackAtAnyWindowEqualsTheColumnMaximum) {
  const fs::path file = fs::path(OCTOSCOPE_TESTDATA) / "neubias/xyzc_16bit__dna_conf_wf.tif";
  const Volume v = ReadHyperstack(file, 2);
  ASSERT_EQ(v.sx, 133);
  ASSERT_EQ(v.sy, 130);
  ASSERT_EQ(v.sz, 45);
  // The issue's example (channel 0, window 0-4096: dim structure at x >= 128 or y >= 128 used to
  // be flattened by the old 5 % default), a very narrow dim window and the full range.
  for (const Window& w : {Window{0, 4096}, Window{0, 300}, Window{0, 65535}}) {
    for (int c : {0, 1}) {
      int bright = 0;
      EXPECT_LE(MaxMipError(file, v, 2, c, w, &bright), 1.0)
          << "channel " << c << " window " << w.lo << "-" << w.hi;
      if (w.hi == 300) {
        EXPECT_GT(bright, 100) << "the dim window must show structure";
      }
    }
  }
}

TEST_F(LosslessRenderTest, SliceFolderScanEqualsTheColumnMaximum) {
  const fs::path folder = fs::path(OCTOSCOPE_TESTDATA) / "cellfinder_crop_planes";
  const Volume v = ReadPlaneFolders(folder, 2);
  ASSERT_EQ(v.sz, 30);
  for (int c : {0, 1}) {
    EXPECT_LE(MaxMipError(folder, v, 2, c, Window{0, 2000}), 1.0) << "channel " << c;
  }
}

TEST_F(LosslessRenderTest, LossyBuildReportsAnErrorBoundThePixelsRespect) {
  const fs::path file = fs::path(OCTOSCOPE_TESTDATA) / "neubias/xyzc_16bit__dna_conf_wf.tif";
  const Volume v = ReadHyperstack(file, 2);
  const fs::path cache = dir_ / "lossy";
  RunResult built =
      RunOctoscope("build " + Quote(file) + " --cache " + Quote(cache) + " --threshold 0.05");
  ASSERT_EQ(built.exit_code, 0) << built.err;
  const auto report = nlohmann::json::parse(built.out.substr(built.out.rfind('{')));
  EXPECT_EQ(report["lossless"], false);
  ASSERT_EQ(report["pruning_error"].size(), 2u);
  const Window w{0, 4096};
  for (int c : {0, 1}) {
    const double bound = report["pruning_error"][c].get<double>();
    EXPECT_GT(bound, 0) << "5 % of this channel's range prunes something";
    const double error = MaxMipError(cache, v, 2, c, w);
    // The MIP of values each within `bound` of the truth is within `bound` of the true MIP.
    EXPECT_LE(error, bound / (w.hi - w.lo) * 255 + 1.0) << "channel " << c;
    if (c == 0) {
      EXPECT_GT(error, 1.0) << "the lossy build is visibly lossy at this window";
    }
  }
  // The default build of the same file is lossless and says so.
  RunResult exact = RunOctoscope("build " + Quote(file) + " --cache " + Quote(dir_ / "exact"));
  ASSERT_EQ(exact.exit_code, 0) << exact.err;
  const auto exact_report = nlohmann::json::parse(exact.out.substr(exact.out.rfind('{')));
  EXPECT_EQ(exact_report["lossless"], true);
  EXPECT_EQ(exact_report["pruning_error"], nlohmann::json({0.0, 0.0}));
}

}  // namespace
}  // namespace octoscope::app
