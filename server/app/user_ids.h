// UserIds: the stable id of each user name (docs/server.md, "Threat model"). Streams and view
// links record the id of the user they were made by, not the name: an id stays the same across
// token changes and restarts while the name stays in the users table, and a name that is removed
// (at start-up or by a SIGHUP reload) loses its id, so a new user who later gets that name
// inherits nothing. The table is kept in STATE_DIR/user_ids, one "NAME ID" per line (ID = "u" and
// 16 hex digits), written atomically with mode 0600 before a users table takes effect.
//
// Thread safety: not thread-safe; used by the main thread (start-up, SIGHUP).
#ifndef OCTOSCOPE_APP_USER_IDS_H_
#define OCTOSCOPE_APP_USER_IDS_H_

#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "app/access_control.h"
#include "util/result.h"

namespace octoscope::app {

class UserIds {
 public:
  // Reads STATE_DIR/user_ids (absent: empty). kCorrupt for a malformed file, naming the line.
  static Result<std::unique_ptr<UserIds>> Open(const std::filesystem::path& state_dir);

  // Gives every user of `users` its id (kept for names known before, new ones for new names),
  // forgets the names not in `users`, and makes the table durable. (The --token's user is not
  // in it: its id is always "admin".)
  Status Assign(std::vector<User>& users);

 private:
  explicit UserIds(std::filesystem::path file) : file_(std::move(file)) {}

  const std::filesystem::path file_;
  std::map<std::string, std::string> ids_;  // Name -> id.
};

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_USER_IDS_H_
