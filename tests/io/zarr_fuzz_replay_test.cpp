// Replays the seeds and every regression of the OME-Zarr fuzz harnesses (fuzz/zarr/, input
// formats in fuzz/zarr_fuzz_inputs.h) through the harnesses' own code: no crash, no internal
// error, errors that name the file where there is one.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <vector>

#include "tiff_fixture.h"
#include "zarr_fuzz_inputs.h"

namespace octoscope::fuzz {
namespace {

namespace fs = std::filesystem;

std::vector<std::vector<uint8_t>> Inputs(const std::string& harness, size_t& files) {
  std::vector<std::vector<uint8_t>> out;
  const fs::path base = fs::path(OCTOSCOPE_SOURCE_DIR) / "fuzz" / "zarr";
  for (const char* kind : {"seeds", "regressions"}) {
    const fs::path dir = base / kind / harness;
    if (!fs::is_directory(dir)) continue;
    for (const auto& entry : fs::directory_iterator(dir)) {
      if (!entry.is_regular_file()) continue;
      std::ifstream in(entry.path(), std::ios::binary);
      out.emplace_back(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
      ++files;
    }
  }
  return out;
}

TEST(ZarrFuzzReplay, MetadataInputs) {
  size_t files = 0;
  for (const auto& input : Inputs("zarr_metadata", files)) {
    Status s = ZarrMetadataInput(input);
    EXPECT_NE(s.code(), StatusCode::kInternal) << s.ToString();
  }
  EXPECT_GT(files, 0u);
}

TEST(ZarrFuzzReplay, ChunkCodecInputs) {
  size_t files = 0;
  for (const auto& input : Inputs("chunk_codec", files)) {
    Status s = ChunkCodecInput(input);
    EXPECT_NE(s.code(), StatusCode::kInternal) << s.ToString();
  }
  EXPECT_GT(files, 0u);
}

TEST(ZarrFuzzReplay, StoreInputs) {
  const fs::path scratch = testing::MakeTempDir("zarr-fuzz-replay");
  size_t files = 0, ok = 0;
  for (const auto& input : Inputs("zarr_store", files)) {
    Status s = ZarrStoreInput(input, scratch / "store");
    EXPECT_NE(s.code(), StatusCode::kInternal) << s.ToString();
    if (s.ok()) {
      ++ok;
    } else {
      EXPECT_NE(s.message().find(scratch.string()), std::string::npos)
          << "error does not name the store: " << s.ToString();
    }
  }
  EXPECT_GT(files, 0u);
  EXPECT_GT(ok, 0u);  // The seeds made from valid stores read.
  fs::remove_all(scratch);
}

}  // namespace
}  // namespace octoscope::fuzz
