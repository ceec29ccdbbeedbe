// StreamRecords: where the server keeps a record of each stream it was asked to create, so that
// the stream outlives the process (docs/server.md, "Stream records"): STATE_DIR/streams/ID.json,
// one protocol::StreamRecord each (what the stream is, who created it, its cache, whether it is
// finished). Written atomically (temporary file, fsync, rename, directory fsync) with mode 0600 in
// a folder of mode 0700; read back strictly. What the stream received lives in its cache.
//
// Thread safety: pure functions of the file system; writers of one record are serialised by its
// owner (the dataset), writers of different records never interfere.
#ifndef OCTOSCOPE_DATASET_STREAM_RECORD_H_
#define OCTOSCOPE_DATASET_STREAM_RECORD_H_

#include <filesystem>
#include <string>
#include <vector>

#include "protocol/dataset_json.h"
#include "util/result.h"

namespace octoscope::dataset {

// STATE_DIR/streams.
std::filesystem::path StreamRecordDir(const std::filesystem::path& state_dir);
// Creates `dir` (mode 0700) when missing.
Status EnsureStreamRecordDir(const std::filesystem::path& dir);
// Replaces `dir`/ID.json with `record`, durably.
Status WriteStreamRecord(const std::filesystem::path& dir, const protocol::StreamRecord& record);

// One file found in the record folder.
struct FoundStreamRecord {
  std::filesystem::path path;
  Result<protocol::StreamRecord> record;  // kCorrupt naming the file when it does not read back.
};
// Every ID.json of `dir` (ids [a-z0-9]{12}), oldest first (created_unix_ms, then id); a record
// whose "id" is not its file's name is kCorrupt. kIoError when `dir` cannot be listed.
Result<std::vector<FoundStreamRecord>> ReadStreamRecords(const std::filesystem::path& dir);

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_STREAM_RECORD_H_
