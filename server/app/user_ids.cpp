#include "app/user_ids.h"

#include <sstream>

#include "util/durable_file.h"
#include "util/file_reading.h"
#include "util/random_token.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;

constexpr char kFileName[] = "user_ids";
constexpr uint64_t kMaxFileBytes = 16 << 20;

bool IsIdChar(char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'); }

bool IsUserId(const std::string& id) {
  if (id.size() != 17 || id[0] != 'u') return false;
  for (size_t i = 1; i < id.size(); ++i) {
    if (!IsIdChar(id[i])) return false;
  }
  return true;
}

}  // namespace

Result<std::unique_ptr<UserIds>> UserIds::Open(const fs::path& state_dir) {
  std::unique_ptr<UserIds> table(new UserIds(state_dir / kFileName));
  std::error_code ec;
  if (!fs::exists(table->file_, ec)) return table;
  OCTO_ASSIGN_OR_RETURN(std::string text, ReadSmallFile(table->file_, kMaxFileBytes));
  std::istringstream in(text);
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    std::istringstream fields(line);
    std::string name, id, extra;
    if (!(fields >> name >> id) || (fields >> extra) || !IsUserId(id)) {
      return CorruptError(table->file_.string() + ":" + std::to_string(number) +
                          ": expected \"NAME ID\"");
    }
    table->ids_[name] = id;
  }
  return table;
}

Status UserIds::Assign(std::vector<User>& users) {
  std::map<std::string, std::string> next;
  for (User& user : users) {
    auto known = ids_.find(user.name);
    if (known != ids_.end()) {
      user.id = known->second;
    } else {
      OCTO_ASSIGN_OR_RETURN(std::string hex, RandomHex(8));
      user.id = "u" + hex;
    }
    next[user.name] = user.id;
  }
  if (next != ids_) {
    std::string text;
    for (const auto& [name, id] : next) text += name + " " + id + "\n";
    std::error_code ec;
    fs::create_directories(file_.parent_path(), ec);
    Status written = WriteFileDurably(file_, text, ".tmp", 0600);
    if (!written.ok()) return written.WithContext("saving the user ids");
  }
  ids_ = std::move(next);
  return Status::Ok();
}

}  // namespace octoscope::app
