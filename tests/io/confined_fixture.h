// Test fixture for readers under a confined FileGate, as `octoscope serve` opens a dataset: a fresh
// temporary folder holding `own/` (the folders a dataset lives in) and `outside/` (another user's
// folder, with files the dataset's references may name). A reference out of the dataset's own
// folder must be refused with exactly the one refusal, whether what it names exists or not.
// Test-only; not thread-safe (GoogleTest rules).
#ifndef OCTOSCOPE_TESTS_IO_CONFINED_FIXTURE_H_
#define OCTOSCOPE_TESTS_IO_CONFINED_FIXTURE_H_

#include <gtest/gtest.h>

#include <filesystem>
#include <memory>
#include <string>

#include "io/file_gate.h"
#include "io/open_options.h"
#include "io/open_volume.h"
#include "io/tiff_fixture.h"
#include "io/volume_source.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::testing {

class ConfinedTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = MakeTempDir("confined");
    own_ = dir_ / "own";
    outside_ = dir_ / "outside";
    std::filesystem::create_directories(own_);
    std::filesystem::create_directories(outside_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  // OpenVolume(path, options) confined to the dataset's own folder, as the server opens it.
  static Result<std::unique_ptr<io::VolumeSource>> OpenConfined(const std::filesystem::path& path,
                                                                io::OpenOptions options = {}) {
    Result<io::FileGate> gate = io::FileGate::ForDataset(path);
    if (!gate.ok()) return gate.status();
    options.file_gate = *gate;
    return io::OpenVolume(path, options);
  }

  // `status` is exactly the refusal of the dataset at `dataset`: it names nothing else.
  static void ExpectRefusal(const Status& status, const std::filesystem::path& dataset) {
    EXPECT_EQ(status.ToString(), "permission denied: " + dataset.string() + ": " +
                                     std::string(io::kOutsideFolderMessage));
  }

  std::filesystem::path dir_, own_, outside_;
};

}  // namespace octoscope::testing

#endif  // OCTOSCOPE_TESTS_IO_CONFINED_FIXTURE_H_
