#include "python_fixtures.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

#include "io/open_volume.h"
#include "util/strings.h"
#include "volume/data_type.h"

namespace octoscope::testing {
namespace {

namespace fs = std::filesystem;

std::string Quoted(const std::string& s) {
  std::string out(1, '\'');
  for (char c : s) {
    if (c == '\'') {
      out.append("'\\''");
    } else {
      out.push_back(c);
    }
  }
  out.push_back('\'');
  return out;
}

std::vector<std::string> SplitOn(const std::string& text, char sep) {
  std::vector<std::string> out;
  std::string cur;
  for (char c : text) {
    if (c == sep) {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  out.push_back(cur);
  return out;
}

std::string Hex(const volume::Rgba& c) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "#%02x%02x%02x", c.r, c.g, c.b);
  return buf;
}

}  // namespace

Status RunFixtureScript(const std::string& script, const fs::path& out_dir,
                        const std::vector<std::string>& args) {
  std::string command = Quoted(OCTOSCOPE_PYTHON3) + " " +
                        Quoted(std::string(OCTOSCOPE_SOURCE_DIR) + "/tests/io/fixtures/" + script) +
                        " " + Quoted(out_dir.string());
  for (const std::string& a : args) {
    command.push_back(' ');
    command.append(Quoted(a));
  }
  command.append(" 2>&1");
  FILE* pipe = popen(command.c_str(), "r");
  if (!pipe) return IoError("cannot run " + command);
  std::string output;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, pipe)) > 0) output.append(buf, n);
  const int status = pclose(pipe);
  if (status != 0) {
    return InternalError(command + " failed (" + std::to_string(status) +
                         "; the fixtures need python3-numpy, python3-zarr, python3-numcodecs and "
                         "python3-h5py from deploy/install_deps.sh):\n" +
                         output);
  }
  return Status::Ok();
}

std::vector<PythonFixtureCase> ReadFixtureManifest(const fs::path& out_dir) {
  std::ifstream in(out_dir / "manifest.tsv");
  std::vector<PythonFixtureCase> cases;
  if (!in) {
    ADD_FAILURE() << "no manifest in " << out_dir;
    return cases;
  }
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::vector<std::string> f = SplitOn(line, '\t');
    if (f.size() != 14) {
      ADD_FAILURE() << "bad manifest line: " << line;
      continue;
    }
    PythonFixtureCase c;
    c.name = f[0];
    c.input = fs::weakly_canonical(out_dir / f[1]);
    c.level = std::stoi(f[2]);
    c.series = std::stoi(f[3]);
    c.time_points = std::stoi(f[4]);
    c.channels = std::stoi(f[5]);
    c.size = {std::stoll(f[6]), std::stoll(f[7]), std::stoll(f[8])};
    c.dtype = f[9];
    std::vector<std::string> sp = SplitOn(f[10], ',');
    for (int a = 0; a < 3 && a < static_cast<int>(sp.size()); ++a) {
      if (sp[a] != "?") c.spacing[a] = std::stod(sp[a]);
    }
    if (!f[11].empty()) c.names = SplitOn(f[11], '|');
    if (!f[12].empty()) c.colors = SplitOn(f[12], '|');
    c.raw = out_dir / f[13];
    cases.push_back(std::move(c));
  }
  return cases;
}

void ExpectVolumeMatchesCase(const PythonFixtureCase& c, io::OpenOptions options) {
  SCOPED_TRACE(c.name + " (" + c.input.string() + ")");
  std::ifstream raw(c.raw, std::ios::binary);
  std::vector<char> expected((std::istreambuf_iterator<char>(raw)), {});
  options.level = c.level;
  options.series = c.series;
  for (int t = 0; t < c.time_points; ++t) {
    options.time = t;
    auto source = io::OpenVolume(c.input, options);
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    const volume::VolumeInfo& info = (*source)->info();
    EXPECT_EQ(info.size, c.size);
    ASSERT_EQ(info.channel_count(), c.channels);
    EXPECT_EQ(volume::NumpyName(info.dtype), c.dtype);
    EXPECT_EQ(info.time_points, c.time_points);
    EXPECT_EQ(info.level, c.level);
    EXPECT_EQ(info.series, c.series);
    for (int a = 0; a < 3; ++a) {
      ASSERT_EQ(info.spacing_um[a].has_value(), c.spacing[a].has_value()) << "axis " << a;
      if (c.spacing[a]) {
        EXPECT_NEAR(*info.spacing_um[a], *c.spacing[a], 1e-9 * *c.spacing[a]);
      }
    }
    for (int ch = 0; ch < c.channels; ++ch) {
      if (!c.names.empty()) {
        EXPECT_EQ(info.channels[ch].name, c.names[ch]);
      }
      if (!c.colors.empty()) {
        ASSERT_TRUE(info.channels[ch].color.has_value());
        EXPECT_EQ(Hex(*info.channels[ch].color), c.colors[ch]);
      }
    }
    const uint64_t volume_bytes = (*source)->SlabBytes(c.size[2]);
    ASSERT_EQ(expected.size(), volume_bytes * static_cast<uint64_t>(c.channels) * c.time_points);
    for (int ch = 0; ch < c.channels; ++ch) {
      const char* want =
          expected.data() + (static_cast<uint64_t>(t) * c.channels + ch) * volume_bytes;
      std::vector<std::byte> got(volume_bytes);
      ASSERT_TRUE((*source)->ReadSlab(ch, 0, c.size[2], got).ok());
      EXPECT_EQ(std::memcmp(got.data(), want, volume_bytes), 0) << "channel " << ch << " slab";
      // Plane by plane: slabs thinner than the chunks (served through the chunk cache).
      const uint64_t plane = (*source)->SlabBytes(1);
      std::vector<std::byte> one(plane);
      for (int64_t z = 0; z < c.size[2]; ++z) {
        ASSERT_TRUE((*source)->ReadSlab(ch, z, 1, one).ok());
        ASSERT_EQ(std::memcmp(one.data(), want + z * plane, plane), 0)
            << "channel " << ch << " plane " << z;
      }
    }
  }
}

}  // namespace octoscope::testing
