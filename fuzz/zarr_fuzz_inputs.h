// What the OME-Zarr fuzz harnesses do with one input, shared by the libFuzzer entry points
// (zarr_*_fuzzer.cpp, chunk_codec_fuzzer.cpp) and the test that replays their seeds and
// regressions in every CI run (tests/io/zarr_fuzz_replay_test.cpp). Input formats:
//
// - Metadata: byte 0 picks the parser (even: array, `.zarray`/`zarr.json`; odd: attributes,
//   `.zattrs`/group `zarr.json`); the rest is the JSON text.
// - Chunk codec: byte 0 picks the codec (modulo 7, io::ChunkCodec order), bytes 1-3 the decoded
//   size (little-endian, modulo 1 MiB + 1 so runs stay fast), byte 4 an element size for
//   Unshuffle; the rest is the encoded chunk.
// - Store: segments separated by "@@@@": the image group's `.zattrs` (empty: none, the array is
//   opened by itself), the array's metadata (`0/zarr.json` when it says "zarr_format": 3, else
//   `0/.zarray`), then files of the array as "<relative name>\n<bytes>" (names of [0-9a-z./_]
//   only, never "..").
//
// Each returns the first error (or OK); a crash, hang, leak, sanitizer report or an error of
// kind kInternal is a finding.
//
// Thread safety: the functions are not meant to run concurrently on one scratch folder.
#ifndef OCTOSCOPE_FUZZ_ZARR_FUZZ_INPUTS_H_
#define OCTOSCOPE_FUZZ_ZARR_FUZZ_INPUTS_H_

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <span>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "io/chunk_codecs.h"
#include "io/open_volume.h"
#include "protocol/zarr_json.h"

namespace octoscope::fuzz {

inline Status ZarrMetadataInput(std::span<const uint8_t> data) {
  if (data.empty()) return Status::Ok();
  const std::string_view text(reinterpret_cast<const char*>(data.data()) + 1, data.size() - 1);
  if (data[0] % 2 == 0) return protocol::ParseZarrArrayJson(text).status();
  return protocol::ParseZarrAttributesJson(text).status();
}

inline Status ChunkCodecInput(std::span<const uint8_t> data) {
  if (data.size() < 5) return Status::Ok();
  const auto codec = static_cast<io::ChunkCodec>(data[0] % 7);
  const size_t out_size = (data[1] | data[2] << 8 | data[3] << 16) % ((1 << 20) + 1);
  const size_t element = data[4] % 9 + 1;
  const auto in = std::as_bytes(data.subspan(5));
  std::vector<std::byte> out(out_size);
  Status s = io::DecodeChunk(codec, in, out);
  if (in.size() == out.size()) io::Unshuffle(in, element, out);
  (void)io::Crc32c(in);
  return s;
}

inline Status ZarrStoreInput(std::span<const uint8_t> data, const std::filesystem::path& scratch) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::remove_all(scratch, ec);
  fs::create_directories(scratch / "0", ec);
  if (ec) return IoError("cannot make " + scratch.string());
  const std::string_view all(reinterpret_cast<const char*>(data.data()), data.size());
  std::vector<std::string_view> parts;
  for (size_t at = 0;;) {
    const size_t next = all.find("@@@@", at);
    parts.push_back(
        all.substr(at, next == std::string_view::npos ? std::string_view::npos : next - at));
    if (next == std::string_view::npos || parts.size() >= 256) break;
    at = next + 4;
  }
  auto write = [](const fs::path& path, std::string_view bytes) {
    std::ofstream(path, std::ios::binary)
        .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  };
  write(scratch / ".zgroup", R"({"zarr_format": 2})");
  if (!parts[0].empty()) write(scratch / ".zattrs", parts[0]);
  if (parts.size() > 1) {
    const bool v3 = parts[1].find("\"zarr_format\": 3") != std::string_view::npos ||
                    parts[1].find("\"zarr_format\":3") != std::string_view::npos;
    write(scratch / "0" / (v3 ? "zarr.json" : ".zarray"), parts[1]);
  }
  for (size_t i = 2; i < parts.size(); ++i) {
    const size_t newline = parts[i].find('\n');
    if (newline == std::string_view::npos || newline == 0 || newline > 64) continue;
    const std::string_view name = parts[i].substr(0, newline);
    if (name.find_first_not_of("0123456789abcdefghijklmnopqrstuvwxyz./_") !=
            std::string_view::npos ||
        name.find("..") != std::string_view::npos || name.front() == '/') {
      continue;
    }
    const fs::path file = scratch / "0" / std::string(name);
    fs::create_directories(file.parent_path(), ec);
    if (!ec) write(file, parts[i].substr(newline + 1));
  }

  io::OpenOptions options;
  options.zarr_json = protocol::MakeZarrJsonParsers();
  options.max_plane_bytes = 16 << 20;  // Keep each run small; real limits are far larger.
  options.max_chunk_bytes = 16 << 20;
  options.chunk_cache_bytes = 8 << 20;
  options.decode_threads = 2;
  auto source = io::OpenVolume(parts[0].empty() ? scratch / "0" : scratch, options);
  if (!source.ok()) return source.status();
  const volume::VolumeInfo& info = (*source)->info();
  if (info.VoxelBytes() > (64u << 20)) return Status::Ok();
  // Thin slabs (through the cache) and whole volumes (chunk-aligned).
  std::vector<std::byte> slab((*source)->SlabBytes(info.size[2]));
  for (int c = 0; c < info.channel_count(); ++c) {
    OCTO_RETURN_IF_ERROR((*source)->ReadSlab(c, 0, info.size[2], slab));
    for (int64_t z = 0; z < info.size[2]; ++z) {
      OCTO_RETURN_IF_ERROR(
          (*source)->ReadSlab(c, z, 1, std::span(slab).first((*source)->SlabBytes(1))));
    }
  }
  return Status::Ok();
}

}  // namespace octoscope::fuzz

#endif  // OCTOSCOPE_FUZZ_ZARR_FUZZ_INPUTS_H_
