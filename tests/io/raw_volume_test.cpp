#include "io/raw_volume.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "io/confined_fixture.h"
#include "io/open_volume.h"
#include "io/tiff_fixture.h"
#include "protocol/raw_sidecar.h"
#include "volume/data_type.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

using volume::DataType;

constexpr DataType kAllTypes[] = {DataType::kUint8,   DataType::kInt8,   DataType::kUint16,
                                  DataType::kInt16,   DataType::kUint32, DataType::kInt32,
                                  DataType::kFloat32, DataType::kFloat64};

// The sample at (x, y, z, c), in the native byte order of `type`. Spreads values over every byte
// of the type (and both signs for signed types) so that a byte-order mistake shows.
struct Sample {
  std::array<std::byte, 8> bytes{};
  size_t size = 0;
  std::byte* begin() { return bytes.data(); }
  std::byte* end() { return bytes.data() + size; }
  const std::byte* data() const { return bytes.data(); }
};

Sample NativeSample(DataType type, int64_t x, int64_t y, int64_t z, int c) {
  const uint64_t base = static_cast<uint64_t>(x + 5 * y + 31 * z + 101 * c + 1);
  Sample out;
  out.size = volume::BytesPerSample(type);
  auto put = [&out](auto v) { std::memcpy(out.bytes.data(), &v, sizeof(v)); };
  switch (type) {
    case DataType::kUint8:
      put(static_cast<uint8_t>(base % 256));
      break;
    case DataType::kInt8:
      put(static_cast<int8_t>(static_cast<int>(base % 256) - 128));
      break;
    case DataType::kUint16:
      put(static_cast<uint16_t>(base * 257 % 65536));
      break;
    case DataType::kInt16:
      put(static_cast<int16_t>(static_cast<int32_t>(base * 257 % 65536) - 32768));
      break;
    case DataType::kUint32:
      put(static_cast<uint32_t>(base * 0x01030507u));
      break;
    case DataType::kInt32:
      put(static_cast<int32_t>(static_cast<int64_t>(base * 0x01030507u % 4294967296u) -
                               2147483648LL));
      break;
    case DataType::kFloat32:
      put(static_cast<float>(base) * 1.5f - 100.25f);
      break;
    case DataType::kFloat64:
      put(static_cast<double>(base) * 1e-3 - 1e5);
      break;
  }
  return out;
}

struct Case {
  DataType type;
  bool big_endian;
  bool interleaved;
  int channels;
  uint64_t header_bytes;
};

// Writes the raw file for `layout` sample by sample (independently of the reader).
void WriteRaw(const RawLayout& layout, std::byte header_fill = std::byte{0xAB}) {
  std::ofstream out(layout.data_file, std::ios::binary);
  std::vector<char> header(layout.header_bytes, static_cast<char>(header_fill));
  out.write(header.data(), static_cast<std::streamsize>(header.size()));
  const bool swap = layout.big_endian != (std::endian::native == std::endian::big);
  auto write_sample = [&](int64_t x, int64_t y, int64_t z, int c) {
    Sample s = NativeSample(layout.dtype, x, y, z, c);
    if (swap) std::reverse(s.begin(), s.end());
    out.write(reinterpret_cast<const char*>(s.data()), static_cast<std::streamsize>(s.size));
  };
  if (layout.interleaved) {
    for (int64_t z = 0; z < layout.size[2]; ++z)
      for (int64_t y = 0; y < layout.size[1]; ++y)
        for (int64_t x = 0; x < layout.size[0]; ++x)
          for (int c = 0; c < layout.channels; ++c) write_sample(x, y, z, c);
  } else {
    for (int c = 0; c < layout.channels; ++c)
      for (int64_t z = 0; z < layout.size[2]; ++z)
        for (int64_t y = 0; y < layout.size[1]; ++y)
          for (int64_t x = 0; x < layout.size[0]; ++x) write_sample(x, y, z, c);
  }
  ASSERT_TRUE(out.good());
}

// Reads planes z0..z0+nz-1 of `channel` and compares every voxel with NativeSample.
void ExpectSlab(VolumeSource& source, int channel, int64_t z0, int64_t nz) {
  const volume::VolumeInfo& info = source.info();
  const size_t bps = volume::BytesPerSample(info.dtype);
  std::vector<std::byte> slab(source.SlabBytes(nz));
  ASSERT_TRUE(source.ReadSlab(channel, z0, nz, slab).ok());
  size_t mismatches = 0;
  size_t i = 0;
  for (int64_t z = z0; z < z0 + nz; ++z) {
    for (int64_t y = 0; y < info.size[1]; ++y) {
      for (int64_t x = 0; x < info.size[0]; ++x, i += bps) {
        Sample want = NativeSample(info.dtype, x, y, z, channel);
        if (std::memcmp(slab.data() + i, want.data(), bps) != 0 && ++mismatches <= 3) {
          ADD_FAILURE() << "voxel (" << x << "," << y << "," << z << ") channel " << channel
                        << " differs";
        }
      }
    }
  }
  EXPECT_EQ(mismatches, 0u);
}

// Checks that FindStoredPlane(channel, z) locates the plane exactly when `offered`, and that it
// then holds the plane's samples (compared with NativeSample, independently of ReadSlab).
void ExpectStoredPlane(VolumeSource& source, int channel, int64_t z, bool offered) {
  const volume::VolumeInfo& info = source.info();
  const size_t bps = volume::BytesPerSample(info.dtype);
  std::optional<std::vector<std::byte>> view = testing::ReadStoredPlane(source, channel, z);
  ASSERT_EQ(view.has_value(), offered) << "channel " << channel << " z " << z;
  if (!view) return;
  ASSERT_EQ(view->size(), source.SlabBytes(1));
  size_t mismatches = 0, i = 0;
  for (int64_t y = 0; y < info.size[1]; ++y) {
    for (int64_t x = 0; x < info.size[0]; ++x, i += bps) {
      Sample want = NativeSample(info.dtype, x, y, z, channel);
      if (std::memcmp(view->data() + i, want.data(), bps) != 0) ++mismatches;
    }
  }
  EXPECT_EQ(mismatches, 0u) << "channel " << channel << " z " << z;
}

class RawVolumeTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::MakeTempDir("raw"); }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::filesystem::path dir_;
};

TEST_F(RawVolumeTest, EveryTypeEndiannessLayoutAndHeader) {
  int file_index = 0;
  for (DataType type : kAllTypes) {
    for (bool big_endian : {false, true}) {
      for (bool interleaved : {false, true}) {
        for (int channels : {1, 3}) {
          for (uint64_t header : {uint64_t{0}, uint64_t{13}}) {
            RawLayout layout;
            std::string file_name = "v";
            file_name += std::to_string(file_index++);
            file_name += ".raw";
            layout.data_file = dir_ / file_name;
            layout.size = {5, 4, 3};
            layout.channels = channels;
            layout.dtype = type;
            layout.big_endian = big_endian;
            layout.interleaved = interleaved;
            layout.header_bytes = header;
            WriteRaw(layout);
            std::string trace(volume::NumpyName(type));
            trace += big_endian ? " big" : " little";
            trace += interleaved ? " interleaved" : " planar";
            trace += " channels " + std::to_string(channels) + " header " + std::to_string(header);
            SCOPED_TRACE(trace);
            Result<std::unique_ptr<VolumeSource>> source = OpenRawVolume(layout, OpenOptions{});
            ASSERT_TRUE(source.ok()) << source.status().ToString();
            const volume::VolumeInfo& info = (*source)->info();
            EXPECT_EQ(info.format, "raw");
            EXPECT_EQ(info.size, (std::array<int64_t, 3>{5, 4, 3}));
            EXPECT_EQ(info.channel_count(), channels);
            EXPECT_EQ(info.dtype, type);
            for (int c = 0; c < channels; ++c) {
              ExpectSlab(**source, c, 0, 3);  // Whole volume.
              ExpectSlab(**source, c, 1, 2);  // A slab that starts inside.
              ExpectSlab(**source, c, 2, 1);  // The last plane alone.
            }
            // Stored planes: planar (or one channel), native order, any header size.
            const size_t bps = volume::BytesPerSample(type);
            const bool offered =
                (!interleaved || channels == 1) &&
                (bps == 1 || big_endian == (std::endian::native == std::endian::big));
            for (int c = 0; c < channels; ++c) {
              ExpectStoredPlane(**source, c, 0, offered);
              ExpectStoredPlane(**source, c, 2, offered);
            }
            EXPECT_FALSE((*source)->FindStoredPlane(channels, 0).has_value());
            EXPECT_FALSE((*source)->FindStoredPlane(0, 3).has_value());
            EXPECT_FALSE((*source)->FindStoredPlane(0, -1).has_value());
          }
        }
      }
    }
  }
}

TEST_F(RawVolumeTest, InterleavedLargerThanOneChunk) {
  // 800x800x3 voxels x 3 channels of uint16 = 11.5 MB: three 4 MiB read chunks, the last one
  // partial, so the chunk loop's bookkeeping is exercised.
  RawLayout layout;
  layout.data_file = dir_ / "big.raw";
  layout.size = {800, 800, 3};
  layout.channels = 3;
  layout.dtype = DataType::kUint16;
  layout.interleaved = true;
  layout.big_endian = true;
  layout.header_bytes = 7;
  WriteRaw(layout);
  auto source = OpenRawVolume(layout, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  ExpectSlab(**source, 2, 0, 3);
  ExpectSlab(**source, 0, 1, 1);
}

TEST_F(RawVolumeTest, ConcurrentReadsAgree) {
  RawLayout layout;
  layout.data_file = dir_ / "mt.raw";
  layout.size = {64, 32, 8};
  layout.channels = 2;
  layout.dtype = DataType::kInt16;
  layout.interleaved = true;
  WriteRaw(layout);
  auto source = OpenRawVolume(layout, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&source, t] {
      for (int64_t z = 0; z < 8; ++z) ExpectSlab(**source, t % 2, z, 1);
    });
  }
  for (std::thread& t : threads) t.join();
}

TEST_F(RawVolumeTest, MetadataFromLayoutAndOverrides) {
  RawLayout layout;
  layout.data_file = dir_ / "m.raw";
  layout.size = {3, 2, 2};
  layout.channels = 2;
  layout.channel_names = {"dapi", "gfp"};
  layout.dtype = DataType::kUint8;
  layout.spacing_um = {0.5, 0.5, std::nullopt};
  WriteRaw(layout);
  auto source = OpenRawVolume(layout, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  const volume::VolumeInfo& info = (*source)->info();
  EXPECT_EQ(info.channels[0].name, "dapi");
  EXPECT_EQ(info.channels[1].name, "gfp");
  EXPECT_EQ(info.spacing_um[0], 0.5);
  EXPECT_EQ(info.spacing_um[1], 0.5);
  EXPECT_FALSE(info.spacing_um[2].has_value());
  EXPECT_EQ(info.series_count, 1);
  EXPECT_EQ(info.time_points, 1);

  OpenOptions options;
  options.spacing_um = {std::nullopt, 0.25, 2.0};
  auto overridden = OpenRawVolume(layout, options);
  ASSERT_TRUE(overridden.ok()) << overridden.status().ToString();
  EXPECT_EQ((*overridden)->info().spacing_um[0], 0.5);
  EXPECT_EQ((*overridden)->info().spacing_um[1], 0.25);
  EXPECT_EQ((*overridden)->info().spacing_um[2], 2.0);

  layout.channel_names.clear();
  auto unnamed = OpenRawVolume(layout, OpenOptions{});
  ASSERT_TRUE(unnamed.ok());
  EXPECT_EQ((*unnamed)->info().channels[0].name, "");
  EXPECT_EQ((*unnamed)->info().channels[1].name, "");
}

TEST_F(RawVolumeTest, ExtraTrailingBytesAreAllowed) {
  RawLayout layout;
  layout.data_file = dir_ / "t.raw";
  layout.size = {4, 4, 2};
  layout.dtype = DataType::kUint16;
  WriteRaw(layout);
  std::ofstream(layout.data_file, std::ios::binary | std::ios::app) << "trailer";
  auto source = OpenRawVolume(layout, OpenOptions{});
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  ExpectSlab(**source, 0, 0, 2);
}

TEST_F(RawVolumeTest, TruncatedFileIsCorruptAndNamesBothSizes) {
  RawLayout layout;
  layout.data_file = dir_ / "short.raw";
  layout.size = {10, 10, 10};
  layout.dtype = DataType::kUint16;
  layout.header_bytes = 100;
  {
    std::ofstream out(layout.data_file, std::ios::binary);
    std::vector<char> bytes(2099, 0);  // Needs 100 + 2000 = 2100.
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  }
  auto source = OpenRawVolume(layout, OpenOptions{});
  ASSERT_FALSE(source.ok());
  EXPECT_EQ(source.status().code(), StatusCode::kCorrupt);
  const std::string message = source.status().message();
  EXPECT_NE(message.find("short.raw"), std::string::npos) << message;
  EXPECT_NE(message.find("2099"), std::string::npos) << message;
  EXPECT_NE(message.find("2100"), std::string::npos) << message;
}

TEST_F(RawVolumeTest, BadLayoutsAreRefused) {
  RawLayout good;
  good.data_file = dir_ / "g.raw";
  good.size = {2, 2, 2};
  good.channels = 2;
  good.dtype = DataType::kUint8;
  WriteRaw(good);
  ASSERT_TRUE(OpenRawVolume(good, OpenOptions{}).ok());

  RawLayout zero_size = good;
  zero_size.size[1] = 0;
  // Layouts come from a sidecar file: impossible values are corruption of that file.
  EXPECT_EQ(OpenRawVolume(zero_size, OpenOptions{}).status().code(), StatusCode::kCorrupt);

  RawLayout negative = good;
  negative.size[2] = -4;
  EXPECT_EQ(OpenRawVolume(negative, OpenOptions{}).status().code(), StatusCode::kCorrupt);

  RawLayout no_channels = good;
  no_channels.channels = 0;
  EXPECT_EQ(OpenRawVolume(no_channels, OpenOptions{}).status().code(), StatusCode::kCorrupt);

  RawLayout overflow = good;
  overflow.size = {int64_t{1} << 40, int64_t{1} << 40, 2};
  Result<std::unique_ptr<VolumeSource>> r = OpenRawVolume(overflow, OpenOptions{});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(r.status().message().find("overflow"), std::string::npos) << r.status().message();

  RawLayout names = good;
  names.channel_names = {"only one"};
  EXPECT_EQ(OpenRawVolume(names, OpenOptions{}).status().code(), StatusCode::kCorrupt);

  RawLayout folder = good;
  folder.data_file = dir_;
  Status st = OpenRawVolume(folder, OpenOptions{}).status();
  EXPECT_EQ(st.code(), StatusCode::kUnsupported) << st.ToString();
  EXPECT_NE(st.message().find(dir_.string()), std::string::npos) << st.ToString();

  RawLayout missing = good;
  missing.data_file = dir_ / "nope.raw";
  EXPECT_EQ(OpenRawVolume(missing, OpenOptions{}).status().code(), StatusCode::kNotFound);

  OpenOptions series;
  series.series = 1;
  EXPECT_EQ(OpenRawVolume(good, series).status().code(), StatusCode::kOutOfRange);
  OpenOptions time;
  time.time = 1;
  EXPECT_EQ(OpenRawVolume(good, time).status().code(), StatusCode::kOutOfRange);

  OpenOptions small_planes;
  small_planes.max_plane_bytes = 3;  // A plane is 2x2 bytes.
  EXPECT_EQ(OpenRawVolume(good, small_planes).status().code(), StatusCode::kResourceExhausted);
}

TEST_F(RawVolumeTest, BadSlabRequestsAreRefused) {
  RawLayout layout;
  layout.data_file = dir_ / "s.raw";
  layout.size = {2, 2, 2};
  layout.dtype = DataType::kUint16;
  WriteRaw(layout);
  auto source = OpenRawVolume(layout, OpenOptions{});
  ASSERT_TRUE(source.ok());
  std::vector<std::byte> plane(8);
  std::vector<std::byte> wrong(7);
  // Each error names the file.
  for (Status st : {(*source)->ReadSlab(1, 0, 1, plane),     // No channel 1.
                    (*source)->ReadSlab(0, 2, 1, plane),     // No plane 2.
                    (*source)->ReadSlab(0, 0, 1, wrong)}) {  // Buffer size.
    EXPECT_FALSE(st.ok());
    EXPECT_NE(st.message().find(layout.data_file.string()), std::string::npos) << st.ToString();
  }
  EXPECT_TRUE((*source)->ReadSlab(0, 1, 1, plane).ok());
}

// Confined to its own folder, as the server opens a dataset (issue 28): a sidecar naming a raw
// file out of the folder, or that is itself a link out of it, is refused whether or not its
// target exists.
class RawConfinedTest : public testing::ConfinedTest {
 protected:
  static OpenOptions SidecarOptions() {
    OpenOptions options;
    options.parse_raw_sidecar = protocol::ParseRawSidecarFile;
    return options;
  }
  static std::string Sidecar(const std::string& file) {
    return R"({"file": ")" + file + R"(", "size": [4, 2, 1], "dtype": "uint8"})";
  }
};

TEST_F(RawConfinedTest, DataFilesAndSidecarsOutOfTheFolderAreRefusedAlike) {
  std::ofstream(outside_ / "x.raw") << "01234567";
  std::ofstream(outside_ / "x.raw.json") << Sidecar("x.raw");
  std::ofstream(own_ / "mine.raw") << "abcdefgh";
  std::ofstream(own_ / "mine.json") << Sidecar("mine.raw");
  auto mine = OpenConfined(own_ / "mine.json", SidecarOptions());
  ASSERT_TRUE(mine.ok()) << mine.status().ToString();
  for (const std::string& name : {std::string("x"), std::string("none")}) {
    SCOPED_TRACE(name);
    for (const std::string& file :
         {"../outside/" + name + ".raw", (outside_ / (name + ".raw")).string()}) {
      const fs::path sidecar = own_ / "a.json";
      std::ofstream(sidecar) << Sidecar(file);
      ExpectRefusal(OpenConfined(sidecar, SidecarOptions()).status(), sidecar);
    }
    // A raw file whose sidecar beside it is a link out.
    const fs::path raw = own_ / "b.raw";
    std::ofstream(raw) << "abcdefgh";
    fs::remove(own_ / "b.raw.json");
    fs::create_symlink("../outside/" + name + ".raw.json", own_ / "b.raw.json");
    ExpectRefusal(OpenConfined(raw, SidecarOptions()).status(), raw);
  }
}

}  // namespace
}  // namespace octoscope::io
