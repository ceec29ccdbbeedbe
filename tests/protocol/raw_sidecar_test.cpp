#include "protocol/raw_sidecar.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

namespace octoscope::protocol {
namespace {

using volume::DataType;

const std::filesystem::path kBase = "/data/scans";

constexpr const char* kFull = R"({
  "file": "brain.raw",
  "size": [640, 480, 120],
  "channels": 2,
  "channel_names": ["dapi", "gfp"],
  "dtype": "int16",
  "endianness": "big",
  "layout": "interleaved",
  "header_bytes": 512,
  "spacing": [0.5, 0.5, null]
})";

TEST(RawSidecarTest, FullExample) {
  Result<io::RawLayout> layout = ParseRawSidecar(kFull, kBase);
  ASSERT_TRUE(layout.ok()) << layout.status().ToString();
  EXPECT_EQ(layout->data_file, kBase / "brain.raw");
  EXPECT_EQ(layout->size, (std::array<int64_t, 3>{640, 480, 120}));
  EXPECT_EQ(layout->channels, 2);
  EXPECT_EQ(layout->channel_names, (std::vector<std::string>{"dapi", "gfp"}));
  EXPECT_EQ(layout->dtype, DataType::kInt16);
  EXPECT_TRUE(layout->big_endian);
  EXPECT_TRUE(layout->interleaved);
  EXPECT_EQ(layout->header_bytes, 512u);
  EXPECT_EQ(layout->spacing_um[0], 0.5);
  EXPECT_EQ(layout->spacing_um[1], 0.5);
  EXPECT_FALSE(layout->spacing_um[2].has_value());
}

TEST(RawSidecarTest, MinimalExampleUsesDefaults) {
  Result<io::RawLayout> layout =
      ParseRawSidecar(R"({"file": "a.raw", "size": [3, 2, 1], "dtype": "float32"})", kBase);
  ASSERT_TRUE(layout.ok()) << layout.status().ToString();
  EXPECT_EQ(layout->data_file, kBase / "a.raw");
  EXPECT_EQ(layout->size, (std::array<int64_t, 3>{3, 2, 1}));
  EXPECT_EQ(layout->channels, 1);
  EXPECT_TRUE(layout->channel_names.empty());
  EXPECT_EQ(layout->dtype, DataType::kFloat32);
  EXPECT_FALSE(layout->big_endian);
  EXPECT_FALSE(layout->interleaved);
  EXPECT_EQ(layout->header_bytes, 0u);
  for (int axis = 0; axis < 3; ++axis) EXPECT_FALSE(layout->spacing_um[axis].has_value());
}

TEST(RawSidecarTest, EveryDtypeAndAbsoluteFile) {
  const std::pair<const char*, DataType> kTypes[] = {
      {"uint8", DataType::kUint8},     {"int8", DataType::kInt8},
      {"uint16", DataType::kUint16},   {"int16", DataType::kInt16},
      {"uint32", DataType::kUint32},   {"int32", DataType::kInt32},
      {"float32", DataType::kFloat32}, {"float64", DataType::kFloat64}};
  for (const auto& [name, type] : kTypes) {
    Result<io::RawLayout> layout = ParseRawSidecar(
        std::string(R"({"file": "/abs/x.bin", "size": [1, 1, 1], "dtype": ")") + name + "\"}",
        kBase);
    ASSERT_TRUE(layout.ok()) << name << ": " << layout.status().ToString();
    EXPECT_EQ(layout->dtype, type);
    EXPECT_EQ(layout->data_file, std::filesystem::path("/abs/x.bin"));
  }
}

// Each case must fail, with a message that contains `needle` (usually the offending key).
struct BadCase {
  const char* json;
  const char* needle;
};

TEST(RawSidecarTest, Errors) {
  const BadCase cases[] = {
      {R"({"file": "a.raw", "dtype": "uint8"})", "size"},                       // Missing size.
      {R"({"file": "a.raw", "size": [1, 1, 1]})", "dtype"},                     // Missing dtype.
      {R"({"size": [1, 1, 1], "dtype": "uint8"})", "file"},                     // No file.
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint12"})", "dtype"},  // Bad dtype.
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "float"})", "dtype"},   // Not numpy.
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": 16})", "dtype"},        // Wrong type.
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "chanels": 2})", "chanels"},
      {R"({"file": "a.raw", "size": [1, -5, 1], "dtype": "uint8"})", "size"},  // Negative.
      {R"({"file": "a.raw", "size": [1, 0, 1], "dtype": "uint8"})", "size"},   // Zero.
      {R"({"file": "a.raw", "size": [1, 1], "dtype": "uint8"})", "size"},      // Two axes.
      {R"({"file": "a.raw", "size": [1, 1, 1, 1], "dtype": "uint8"})", "size"},
      {R"({"file": "a.raw", "size": "1x1x1", "dtype": "uint8"})", "size"},
      {R"({"file": "a.raw", "size": [1, 1.5, 1], "dtype": "uint8"})", "size"},  // Fraction.
      {R"({"file": "a.raw", "size": [1, "2", 1], "dtype": "uint8"})", "size"},
      {R"({"file": "a.raw", "size": [1, 18446744073709551615, 1], "dtype": "uint8"})", "size"},
      {R"({"file": "a.raw", "size": [1, 1e300, 1], "dtype": "uint8"})", "size"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "channels": 0})", "channels"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "channels": 1e9})", "channels"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "channels": 99999999})",
       "channels"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "channels": true})", "channels"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "channels": 2,
           "channel_names": ["a"]})",
       "channel_names"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "channel_names": [7]})",
       "channel_names"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "endianness": "middle"})",
       "endianness"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "layout": "chunky"})", "layout"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "header_bytes": -1})",
       "header_bytes"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "header_bytes": "0"})",
       "header_bytes"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "spacing": [1, 1]})", "spacing"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "spacing": [1, 0, 1]})",
       "spacing"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "spacing": [1, "1", 1]})",
       "spacing"},
      {R"({"file": 3, "size": [1, 1, 1], "dtype": "uint8"})", "file"},
      {R"({"file": "", "size": [1, 1, 1], "dtype": "uint8"})", "file"},
      // The byte count overflows 64 bits.
      {R"({"file": "a.raw", "size": [4294967296, 4294967296, 2], "dtype": "uint8"})", "overflow"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "header_bytes":
           9223372036854775807})",
       "overflow"},
      {"not json at all", "JSON"},
      {"", "JSON"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8")", "JSON"},  // Unclosed.
      {R"([1, 2, 3])", "object"},
      {R"({"file": "a.raw", "size": [1, 1, 1], "dtype": "uint8", "spacing": [1, 1, 1e999]})",
       "JSON"},  // Out of double range: a parse error.
  };
  for (const BadCase& c : cases) {
    Result<io::RawLayout> layout = ParseRawSidecar(c.json, kBase);
    ASSERT_FALSE(layout.ok()) << c.json;
    EXPECT_NE(layout.status().message().find(c.needle), std::string::npos)
        << c.json << " -> " << layout.status().ToString();
  }
}

TEST(RawSidecarTest, RandomMutationsNeverCrash) {
  // Byte flips, insertions and deletions of a valid sidecar: every result must be a value or an
  // error, never an exception or a crash. Also counts both outcomes so the loop is not vacuous.
  std::mt19937 rng(12345);
  const std::string valid = kFull;
  int ok = 0, failed = 0;
  for (int iteration = 0; iteration < 3000; ++iteration) {
    std::string text = valid;
    const int edits = 1 + static_cast<int>(rng() % 4);
    for (int e = 0; e < edits; ++e) {
      const size_t pos = rng() % (text.size() + 1);
      switch (rng() % 3) {
        case 0:
          if (pos < text.size()) text[pos] = static_cast<char>(rng() % 256);
          break;
        case 1:
          text.insert(pos, 1, "{}[]\",:0123456789-e.nultrfa \\\xff"[rng() % 31]);
          break;
        case 2:
          if (pos < text.size()) text.erase(pos, 1 + rng() % 8);
          break;
      }
    }
    Result<io::RawLayout> layout = ParseRawSidecar(text, kBase);
    if (layout.ok()) {
      ++ok;
      EXPECT_GE(layout->size[0], 1);
      EXPECT_GE(layout->channels, 1);
    } else {
      ++failed;
      EXPECT_NE(layout.status().code(), StatusCode::kInternal) << layout.status().ToString();
    }
  }
  EXPECT_GT(ok, 0);
  EXPECT_GT(failed, 0);
}

class RawSidecarFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("octoscope-test-sidecar-" + std::to_string(getpid()) + "-" +
            std::to_string(std::random_device{}()));
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  void Write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name, std::ios::binary) << text;
  }
  std::filesystem::path dir_;
};

TEST_F(RawSidecarFileTest, DefaultFileIsSidecarNameMinusJson) {
  Write("scan.raw.json", R"({"size": [4, 4, 4], "dtype": "uint16"})");
  Result<io::RawLayout> layout = LoadRawSidecar(dir_ / "scan.raw.json");
  ASSERT_TRUE(layout.ok()) << layout.status().ToString();
  EXPECT_EQ(layout->data_file, dir_ / "scan.raw");
}

TEST_F(RawSidecarFileTest, FileIsRelativeToTheSidecar) {
  Write("meta.json", R"({"file": "data/v.bin", "size": [4, 4, 4], "dtype": "uint8"})");
  Result<io::RawLayout> layout = LoadRawSidecar(dir_ / "meta.json");
  ASSERT_TRUE(layout.ok()) << layout.status().ToString();
  EXPECT_EQ(layout->data_file, dir_ / "data" / "v.bin");
}

TEST_F(RawSidecarFileTest, ErrorsNameTheSidecar) {
  Write("bad.json", R"({"size": [4, 4, 4], "dtype": "uint8", "spacnig": [1, 1, 1]})");
  Result<io::RawLayout> layout = LoadRawSidecar(dir_ / "bad.json");
  ASSERT_FALSE(layout.ok());
  EXPECT_NE(layout.status().message().find("bad.json"), std::string::npos)
      << layout.status().message();
  EXPECT_NE(layout.status().message().find("spacnig"), std::string::npos)
      << layout.status().message();

  EXPECT_EQ(LoadRawSidecar(dir_ / "missing.json").status().code(), StatusCode::kNotFound);

  // Larger than the 1 MiB cap: refused before parsing (it would be valid JSON otherwise).
  std::string huge = R"({"size": [4, 4, 4], "dtype": "uint8", "file": ")" +
                     std::string(kMaxRawSidecarBytes, 'a') + "\"}";
  Write("huge.json", huge);
  EXPECT_EQ(LoadRawSidecar(dir_ / "huge.json").status().code(), StatusCode::kResourceExhausted);
}

}  // namespace
}  // namespace octoscope::protocol
