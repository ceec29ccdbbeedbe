// Imaris (.ims) reading against an independent writer: files written by python3-h5py (every
// Imaris sample type, big-endian data, gzip with and without shuffle, uncompressed, contiguous,
// Fletcher32 and scale-offset pipelines (read through HDF5), the LZ4 filter 32004, never-written
// chunks, padded data arrays, attributes as character arrays and as strings, levels and time
// points) read back voxel for voxel; the real PtK2 demo file equal to h5py's decode; bad files
// refused with one clear error and nothing printed by HDF5; confined to its own folder (as the
// server opens a dataset), a file reading other files (external links, external storage, virtual
// datasets) refused alike whether or not those exist.
#include "io/ims_volume.h"

#include <gtest/gtest.h>
#include <hdf5.h>

#include <cstring>
#include <fstream>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "io/confined_fixture.h"
#include "io/open_volume.h"
#include "python_fixtures.h"
#include "tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;
using testing::PythonFixtureCase;

const fs::path kRealIms = fs::path(OCTOSCOPE_TESTDATA) / "zarrnii" / "PtK2Cell.ims";

struct ImarisFixturesScript {
  static constexpr const char* kScript = "write_ims_fixtures.py";
  static constexpr const char* kDirName = "ims-fixtures";
  static std::vector<std::string> Args() { return {kRealIms.string()}; }
};
class ImarisFixtures : public testing::PythonFixtureTest<ImarisFixturesScript> {};

TEST_F(ImarisFixtures, EverySampleTypeAndByteOrder) {
  for (const PythonFixtureCase& c : Cases("dtype-")) testing::ExpectVolumeMatchesCase(c, {});
}

TEST_F(ImarisFixtures, EveryFilterPipelineAndLayout) {
  for (const std::string prefix : {"gzip-noshuffle", "uncompressed-chunked", "contiguous",
                                   "fletcher32", "scaleoffset", "lz4-filter"}) {
    for (const PythonFixtureCase& c : Cases(prefix)) testing::ExpectVolumeMatchesCase(c, {});
  }
}

TEST_F(ImarisFixtures, MissingChunksReadAsTheFillValue) {
  for (const PythonFixtureCase& c : Cases("missing-chunks")) {
    testing::ExpectVolumeMatchesCase(c, {});
  }
}

TEST_F(ImarisFixtures, AttributeFormsUnitsAndSizesWithoutLevelAttributes) {
  for (const std::string prefix : {"string-attributes-nm", "no-level-sizes"}) {
    for (const PythonFixtureCase& c : Cases(prefix)) testing::ExpectVolumeMatchesCase(c, {});
  }
}

TEST_F(ImarisFixtures, EveryLevelAndTimePoint) {
  std::vector<PythonFixtureCase> cases = Cases("levels-times-level");
  ASSERT_EQ(cases.size(), 3u);
  for (const PythonFixtureCase& c : cases) testing::ExpectVolumeMatchesCase(c, {});
  OpenOptions options;
  options.level = 3;
  auto beyond = OpenVolume(cases[0].input, options);
  ASSERT_FALSE(beyond.ok());
  EXPECT_EQ(beyond.status().code(), StatusCode::kOutOfRange);
  options.level = 0;
  options.time = 2;
  EXPECT_EQ(OpenVolume(cases[0].input, options).status().code(), StatusCode::kOutOfRange);
}

TEST_F(ImarisFixtures, ChannelMetadataAndWindows) {
  auto source = OpenVolume(*dir_ / "levels-times.ims", {});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  const volume::VolumeInfo& info = (*source)->info();
  EXPECT_EQ(info.format, "imaris");
  ASSERT_EQ(info.channel_count(), 3);
  EXPECT_EQ(info.channels[2].name, "ch2");
  EXPECT_EQ(*info.channels[1].color, (volume::Rgba{255, 0, 128, 255}));
  EXPECT_EQ(*info.channels[1].window, (volume::DisplayWindow{10, 201, 0.0, 255.0}));
}

TEST_F(ImarisFixtures, RealPtK2CellEqualsH5py) {
  std::vector<PythonFixtureCase> cases = Cases("real-ptk2");
  ASSERT_EQ(cases.size(), 1u);
  // SOURCES.md: 4 channels (Kinetochores, Microtubules, DNA, Dynactin) x (32, 256, 256) ZYX uint8.
  EXPECT_EQ(cases[0].size, (std::array<int64_t, 3>{256, 256, 32}));
  EXPECT_EQ(cases[0].names,
            (std::vector<std::string>{"Kinetochores", "Microtubules", "DNA", "Dynactin"}));
  EXPECT_EQ(cases[0].colors,
            (std::vector<std::string>{"#ff0000", "#00ff00", "#0000ff", "#ffffff"}));
  testing::ExpectVolumeMatchesCase(cases[0], {});
  auto source = OpenVolume(kRealIms, {});
  ASSERT_TRUE(source.ok());
  EXPECT_EQ(*(*source)->info().channels[0].window, (volume::DisplayWindow{0, 247, 0.0, 255.0}));
}

TEST_F(ImarisFixtures, ConcurrentChannelReadersAgree) {
  std::vector<PythonFixtureCase> cases = Cases("levels-times-level0");
  const PythonFixtureCase& c = cases[0];
  std::ifstream raw(c.raw, std::ios::binary);
  std::vector<char> expected((std::istreambuf_iterator<char>(raw)), {});
  auto source = OpenVolume(c.input, {});
  ASSERT_TRUE(source.ok());
  const uint64_t volume_bytes = (*source)->SlabBytes(c.size[2]);
  std::vector<int> bad(static_cast<size_t>(c.channels), 0);
  std::vector<std::thread> threads;
  for (int ch = 0; ch < c.channels; ++ch) {
    threads.emplace_back([&, ch] {
      std::vector<std::byte> all(volume_bytes);
      for (int round = 0; round < 5; ++round) {
        if (!(*source)->ReadSlab(ch, 0, c.size[2], all).ok() ||
            std::memcmp(all.data(), expected.data() + ch * volume_bytes, volume_bytes) != 0) {
          ++bad[ch];
        }
      }
    });
  }
  for (std::thread& t : threads) t.join();
  for (int b : bad) EXPECT_EQ(b, 0);
}

// --- bad files, written with the HDF5 C API ------------------------------------------------------

class BadImaris : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir("bad-ims"); }
  void TearDown() override { fs::remove_all(dir_); }

  // A file with /DataSet/ResolutionLevel 0/TimePoint 0/Channel 0/Data of `dims` (z, y, x) u8,
  // optionally with ImageSize attributes.
  fs::path Write(const std::string& name, std::vector<hsize_t> dims, bool with_dataset = true,
                 const char* image_size_x = nullptr) {
    const fs::path path = dir_ / name;
    hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t lcpl = H5Pcreate(H5P_LINK_CREATE);
    H5Pset_create_intermediate_group(lcpl, 1);
    hid_t g = H5Gcreate2(f, "DataSet/ResolutionLevel 0/TimePoint 0/Channel 0", lcpl, H5P_DEFAULT,
                         H5P_DEFAULT);
    if (image_size_x) {
      hid_t type = H5Tcopy(H5T_C_S1);
      H5Tset_size(type, 1);
      const hsize_t n = strlen(image_size_x);
      hid_t space = H5Screate_simple(1, &n, nullptr);
      hid_t a = H5Acreate2(g, "ImageSizeX", type, space, H5P_DEFAULT, H5P_DEFAULT);
      H5Awrite(a, type, image_size_x);
      H5Aclose(a);
      H5Sclose(space);
      H5Tclose(type);
    }
    if (with_dataset) {
      hid_t space = H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr);
      hid_t d =
          H5Dcreate2(g, "Data", H5T_NATIVE_UINT8, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
      H5Dclose(d);
      H5Sclose(space);
    }
    H5Gclose(g);
    H5Pclose(lcpl);
    H5Fclose(f);
    return path;
  }

  // Opens `path` expecting `code` with `text` in the message and nothing on stderr.
  void ExpectRefused(const fs::path& path, StatusCode code, const std::string& text) {
    ::testing::internal::CaptureStderr();
    auto source = OpenVolume(path, {});
    const std::string printed = ::testing::internal::GetCapturedStderr();
    ASSERT_FALSE(source.ok()) << path;
    EXPECT_EQ(source.status().code(), code) << source.status().ToString();
    EXPECT_NE(source.status().message().find(text), std::string::npos) << source.status().message();
    EXPECT_NE(source.status().message().find(path.filename().string()), std::string::npos)
        << source.status().message();
    EXPECT_EQ(printed, "") << "HDF5 printed to stderr";
  }

  fs::path dir_;
};

TEST_F(BadImaris, MinimalFileReads) {
  auto source = OpenVolume(Write("ok.ims", {2, 3, 4}), {});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().size, (std::array<int64_t, 3>{4, 3, 2}));
  EXPECT_FALSE((*source)->info().spacing_um[0].has_value());
}

TEST_F(BadImaris, NotHdf5) {
  std::ofstream(dir_ / "text.ims") << "not an HDF5 file at all";
  ExpectRefused(dir_ / "text.ims", StatusCode::kCorrupt, "not an HDF5 file");
}

TEST_F(BadImaris, TruncatedHdf5) {
  const fs::path good = Write("whole.ims", {2, 3, 4});
  std::ifstream in(good, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), {});
  std::ofstream(dir_ / "cut.ims", std::ios::binary) << bytes.substr(0, bytes.size() / 3);
  ::testing::internal::CaptureStderr();
  auto source = OpenVolume(dir_ / "cut.ims", {});
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
  ASSERT_FALSE(source.ok());
  EXPECT_NE(source.status().message().find("cut.ims"), std::string::npos);
}

TEST_F(BadImaris, LacksDatasets) {
  ExpectRefused(Write("nodata.ims", {2, 3, 4}, false), StatusCode::kCorrupt, "dataset missing");
  const fs::path plain = dir_ / "plain.h5";
  H5Fclose(H5Fcreate(plain.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT));
  ExpectRefused(plain, StatusCode::kCorrupt, "/DataSet");
}

TEST_F(BadImaris, WrongRankAndLyingImageSize) {
  ExpectRefused(Write("rank2.ims", {3, 4}), StatusCode::kCorrupt, "2-D");
  ExpectRefused(Write("lying.ims", {2, 3, 4}, true, "5000000"), StatusCode::kCorrupt,
                "does not fit the data array");
}

TEST_F(BadImaris, MoreThan64ChannelsAreRefused) {
  // `channels` groups "Channel C", each with a 1x2x2 u8 Data array.
  auto write = [&](const std::string& name, int channels) {
    const fs::path path = dir_ / name;
    hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t lcpl = H5Pcreate(H5P_LINK_CREATE);
    H5Pset_create_intermediate_group(lcpl, 1);
    const hsize_t dims[3] = {1, 2, 2};
    hid_t space = H5Screate_simple(3, dims, nullptr);
    for (int c = 0; c < channels; ++c) {
      const std::string data =
          "DataSet/ResolutionLevel 0/TimePoint 0/Channel " + std::to_string(c) + "/Data";
      H5Dclose(
          H5Dcreate2(f, data.c_str(), H5T_NATIVE_UINT8, space, lcpl, H5P_DEFAULT, H5P_DEFAULT));
    }
    H5Sclose(space);
    H5Pclose(lcpl);
    H5Fclose(f);
    return path;
  };
  auto source = OpenVolume(write("64.ims", 64), {});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ((*source)->info().channel_count(), 64);
  ExpectRefused(write("65.ims", 65), StatusCode::kResourceExhausted, "more than 64 channels");
}

TEST(Hdf5Signature, FoundAtZeroOrAfterAUserBlock) {
  const fs::path dir = testing::MakeTempDir("hdf5-signature");
  std::string sig = "\x89HDF\r\n\x1a\n";
  std::ofstream(dir / "a", std::ios::binary) << sig << std::string(100, 'x');
  std::ofstream(dir / "b", std::ios::binary) << std::string(512, ' ') << sig;
  std::ofstream(dir / "c", std::ios::binary) << std::string(300, ' ') << sig;
  EXPECT_TRUE(HasHdf5Signature(dir / "a"));
  EXPECT_TRUE(HasHdf5Signature(dir / "b"));
  EXPECT_FALSE(HasHdf5Signature(dir / "c"));
  EXPECT_FALSE(HasHdf5Signature(dir / "missing"));
  fs::remove_all(dir);
}

// --- confined to the file's own folder (issue 28), written with the HDF5 C API
// ----------------------

class ImarisConfinedTest : public testing::ConfinedTest {
 protected:
  static constexpr hsize_t kDims[3] = {2, 3, 4};  // z, y, x.

  // A plain HDF5 file with the uint8 dataset "/Data" of kDims holding 0, 1, 2, …
  static void WriteData(const fs::path& path) {
    hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    WriteValues(f, "Data", H5P_DEFAULT);
    H5Fclose(f);
  }
  // An Imaris file whose channel 0 is made by `data` (given the "Channel 0" group), or whose
  // /DataSet group is made by `dataset` (given the file).
  static void WriteIms(const fs::path& path, const std::function<void(hid_t)>& data,
                       const std::function<void(hid_t)>& dataset = nullptr) {
    hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    if (dataset) {
      dataset(f);
    } else {
      hid_t lcpl = H5Pcreate(H5P_LINK_CREATE);
      H5Pset_create_intermediate_group(lcpl, 1);
      hid_t g = H5Gcreate2(f, "DataSet/ResolutionLevel 0/TimePoint 0/Channel 0", lcpl, H5P_DEFAULT,
                           H5P_DEFAULT);
      data(g);
      H5Gclose(g);
      H5Pclose(lcpl);
    }
    H5Fclose(f);
  }
  static void WriteValues(hid_t loc, const char* name, hid_t dcpl) {
    hid_t space = H5Screate_simple(3, kDims, nullptr);
    hid_t d = H5Dcreate2(loc, name, H5T_NATIVE_UINT8, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
    std::vector<uint8_t> values(24);
    for (size_t i = 0; i < values.size(); ++i) values[i] = static_cast<uint8_t>(i);
    H5Dwrite(d, H5T_NATIVE_UINT8, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data());
    H5Dclose(d);
    H5Sclose(space);
  }
  // Plane `z` (4x3 uint8) of `source`.
  static std::vector<std::byte> Plane(VolumeSource& source, int64_t z) {
    std::vector<std::byte> out(source.SlabBytes(1));
    const Status s = source.ReadSlab(0, z, 1, out);
    EXPECT_TRUE(s.ok()) << s.ToString();
    return out;
  }
};

TEST_F(ImarisConfinedTest, AFileOfItsOwnReadsConfined) {
  WriteIms(own_ / "ok.ims", [](hid_t g) { WriteValues(g, "Data", H5P_DEFAULT); });
  auto source = OpenConfined(own_ / "ok.ims");
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  EXPECT_EQ(static_cast<int>(Plane(**source, 1)[5]), 17);
}

TEST_F(ImarisConfinedTest, ExternalLinksAreRefusedAlikeWhetherOrNotTheirFileExists) {
  WriteData(outside_ / "data.h5");
  WriteIms(outside_ / "whole.ims", [](hid_t g) { WriteValues(g, "Data", H5P_DEFAULT); });
  for (const char* name : {"data.h5", "none.h5"}) {
    SCOPED_TRACE(name);
    const std::string file = (outside_ / name).string();
    const fs::path channel = own_ / "channel.ims";
    WriteIms(channel, [&](hid_t g) {
      H5Lcreate_external(file.c_str(), "/Data", g, "Data", H5P_DEFAULT, H5P_DEFAULT);
    });
    ExpectRefusal(OpenConfined(channel).status(), channel);
    // The whole /DataSet group.
    const std::string whole =
        (outside_ / (std::string(name) == "data.h5" ? "whole.ims" : name)).string();
    const fs::path group = own_ / "group.ims";
    WriteIms(group, nullptr, [&](hid_t f) {
      H5Lcreate_external(whole.c_str(), "/DataSet", f, "DataSet", H5P_DEFAULT, H5P_DEFAULT);
    });
    ExpectRefusal(OpenConfined(group).status(), group);
  }
  // The command-line tools follow the link.
  auto open = OpenVolume(own_ / "channel.ims", {});
  EXPECT_FALSE(open.ok());  // The last one written names none.h5.
  WriteIms(own_ / "channel.ims", [&](hid_t g) {
    H5Lcreate_external((outside_ / "data.h5").c_str(), "/Data", g, "Data", H5P_DEFAULT,
                       H5P_DEFAULT);
  });
  open = OpenVolume(own_ / "channel.ims", {});
  ASSERT_TRUE(open.ok()) << open.status().ToString();
  EXPECT_EQ(static_cast<int>(Plane(**open, 1)[5]), 17);
}

TEST_F(ImarisConfinedTest, DataStoredInOtherFilesIsRefused) {
  std::string bytes(24, '\0');
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<char>(i);
  std::ofstream(outside_ / "raw.bin", std::ios::binary) << bytes;
  WriteData(outside_ / "source.h5");
  // External storage: the dataset's bytes in a raw file.
  const fs::path efl = own_ / "efl.ims";
  WriteIms(efl, [&](hid_t g) {
    hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
    H5Pset_external(dcpl, (outside_ / "raw.bin").c_str(), 0, 24);
    hid_t space = H5Screate_simple(3, kDims, nullptr);
    H5Dclose(H5Dcreate2(g, "Data", H5T_NATIVE_UINT8, space, H5P_DEFAULT, dcpl, H5P_DEFAULT));
    H5Sclose(space);
    H5Pclose(dcpl);
  });
  ExpectRefusal(OpenConfined(efl).status(), efl);
  auto open = OpenVolume(efl, {});
  ASSERT_TRUE(open.ok()) << open.status().ToString();
  EXPECT_EQ(static_cast<int>(Plane(**open, 1)[5]), 17);
  // A virtual dataset whose source is another file.
  const fs::path vds = own_ / "vds.ims";
  WriteIms(vds, [&](hid_t g) {
    hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
    hid_t space = H5Screate_simple(3, kDims, nullptr);
    hid_t source = H5Screate_simple(3, kDims, nullptr);
    H5Pset_virtual(dcpl, space, (outside_ / "source.h5").c_str(), "/Data", source);
    H5Dclose(H5Dcreate2(g, "Data", H5T_NATIVE_UINT8, space, H5P_DEFAULT, dcpl, H5P_DEFAULT));
    H5Sclose(source);
    H5Sclose(space);
    H5Pclose(dcpl);
  });
  ExpectRefusal(OpenConfined(vds).status(), vds);
}

TEST_F(ImarisConfinedTest, AFileLinkedOutIsRefusedAlikeWhetherOrNotItExists) {
  WriteIms(outside_ / "whole.ims", [](hid_t g) { WriteValues(g, "Data", H5P_DEFAULT); });
  for (const char* target : {"../outside/whole.ims", "../outside/none.ims"}) {
    const fs::path link = own_ / "link.ims";
    fs::remove(link);
    fs::create_symlink(target, link);
    ExpectRefusal(OpenConfined(link).status(), link);
  }
}

}  // namespace
}  // namespace octoscope::io
