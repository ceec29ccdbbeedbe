// Test fixtures written by independent encoders: runs the Python scripts of tests/io/fixtures
// (python3-zarr / python3-numcodecs / python3-h5py from Debian, installed by
// deploy/install_deps.sh) into a directory and reads back the manifest they write, then checks a
// VolumeSource against each case voxel for voxel. Test-only; not thread-safe (GoogleTest rules).
#ifndef OCTOSCOPE_TESTS_IO_PYTHON_FIXTURES_H_
#define OCTOSCOPE_TESTS_IO_PYTHON_FIXTURES_H_

#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "io/open_options.h"
#include "tiff_fixture.h"
#include "util/status.h"

namespace octoscope::testing {

// One line of manifest.tsv (column meanings in tests/io/fixtures/write_zarr_fixtures.py).
struct PythonFixtureCase {
  std::string name;
  std::filesystem::path input;  // Absolute.
  int level = 0, series = 0, time_points = 1, channels = 1;
  std::array<int64_t, 3> size{};
  std::string dtype;
  std::array<std::optional<double>, 3> spacing;
  std::vector<std::string> names, colors;  // Empty when the case names none.
  std::filesystem::path raw;               // (t, c, z, y, x) voxels, native byte order.
};

// Runs `script` (a file of tests/io/fixtures) with Debian's python3 as `script OUT_DIR ARGS...`;
// an error carries the script's output (e.g. a missing module: run deploy/install_deps.sh).
Status RunFixtureScript(const std::string& script, const std::filesystem::path& out_dir,
                        const std::vector<std::string>& args = {});

// The cases of out_dir/manifest.tsv (an empty list and a test failure when unreadable).
std::vector<PythonFixtureCase> ReadFixtureManifest(const std::filesystem::path& out_dir);

// Opens the case with `base` (plus its level, series and each time point) and expects its
// metadata and every voxel of every channel to equal the case, reading each channel both as one
// slab and plane by plane.
void ExpectVolumeMatchesCase(const PythonFixtureCase& c, io::OpenOptions base);

// A test suite whose fixtures `Script::kScript` writes once per test process (each test runs in
// its own process under ctest) into a temporary directory, passing `Script::Args()`.
template <typename Script>
class PythonFixtureTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new std::filesystem::path(MakeTempDir(Script::kDirName));
    status_ = new Status(RunFixtureScript(Script::kScript, *dir_, Script::Args()));
  }
  static void TearDownTestSuite() {
    std::filesystem::remove_all(*dir_);
    delete dir_;
    delete status_;
  }
  void SetUp() override { ASSERT_TRUE(status_->ok()) << status_->message(); }

  // The manifest's cases whose names start with `prefix` (a failure when there are none).
  std::vector<PythonFixtureCase> Cases(const std::string& prefix) {
    std::vector<PythonFixtureCase> out;
    for (PythonFixtureCase& c : ReadFixtureManifest(*dir_)) {
      if (c.name.rfind(prefix, 0) == 0) out.push_back(std::move(c));
    }
    EXPECT_FALSE(out.empty()) << "no fixture named " << prefix << "*";
    return out;
  }

  static inline std::filesystem::path* dir_ = nullptr;
  static inline Status* status_ = nullptr;
};

}  // namespace octoscope::testing

#endif  // OCTOSCOPE_TESTS_IO_PYTHON_FIXTURES_H_
