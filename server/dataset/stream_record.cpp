#include "dataset/stream_record.h"

#include <sys/stat.h>

#include <algorithm>
#include <system_error>

#include "dataset/dataset.h"
#include "util/durable_file.h"
#include "util/file_reading.h"

namespace octoscope::dataset {
namespace fs = std::filesystem;

fs::path StreamRecordDir(const fs::path& state_dir) { return state_dir / "streams"; }

Status EnsureStreamRecordDir(const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec)
    return IoError(dir.string() + ": cannot create the stream-record folder: " + ec.message());
  // Only the server's user may read them (they name users and folders).
  if (::chmod(dir.c_str(), 0700) != 0) {
    return IoError(dir.string() + ": cannot make the stream-record folder private");
  }
  return Status::Ok();
}

Status WriteStreamRecord(const fs::path& dir, const protocol::StreamRecord& record) {
  Status written = WriteFileDurably(dir / (record.id + ".json"), protocol::StreamRecordJson(record),
                                    ".tmp", 0600);
  return written.ok() ? written : written.WithContext("stream " + record.id + ": its record");
}

Result<std::vector<FoundStreamRecord>> ReadStreamRecords(const fs::path& dir) {
  std::vector<FoundStreamRecord> found;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const fs::path& path = it->path();
    const std::string id = path.stem().string();
    if (path.extension() != ".json" || !IsValidDatasetId(id)) continue;
    auto text = ReadSmallFile(path, protocol::kMaxStreamRecordBytes);
    Result<protocol::StreamRecord> record =
        text.ok() ? protocol::ParseStreamRecord(*text, path.string()) : text.status();
    if (record.ok() && record->id != id) {
      record = CorruptError(path.string() + ": records stream \"" + record->id + "\"");
    } else if (!record.ok() && record.status().code() != StatusCode::kCorrupt) {
      record = CorruptError(record.status().message());
    }
    found.push_back({path, std::move(record)});
  }
  if (ec) return IoError(dir.string() + ": cannot list the stream records: " + ec.message());
  std::sort(found.begin(), found.end(), [](const FoundStreamRecord& a, const FoundStreamRecord& b) {
    const int64_t ta = a.record.ok() ? a.record->created_unix_ms : 0;
    const int64_t tb = b.record.ok() ? b.record->created_unix_ms : 0;
    return ta != tb ? ta < tb : a.path < b.path;
  });
  return found;
}

}  // namespace octoscope::dataset
