// `octoscope serve` on a shared machine, end to end with the real binary on a loopback port: users
// from a users file see only the datasets under their folders (list, describe, histogram,
// WebSocket open), admins see all, an expired token is refused, SIGHUP re-reads the users, a
// dataset that refers to a file outside its own folder is refused with one message that tells
// nothing about that file, and a dataset nobody views is released after idle-timeout-s (RAM
// re-divided) and reopens from its cache.
#include <gtest/gtest.h>
#include <signal.h>

#include <ctime>
#include <filesystem>
#include <iterator>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "app/server_process.h"
#include "io/tiff_fixture.h"
#include "net/net_test_client.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
namespace http = boost::beast::http;
using net::testing::Fetch;
using net::testing::WsClient;
using std::chrono::seconds;
using testing::ServerProcess;

constexpr char kAdmin[] = "admin-token-0123456789abcdef";
constexpr char kAlice[] = "alice-token-0123456789abcdef";
constexpr char kBob[] = "bob-token-0123456789abcdef";
constexpr char kOld[] = "old-token-0123456789abcdef";

class AccessTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("octoscope-access-test-" + std::to_string(getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    // alice2 is not under alice: folders compare component by component.
    for (const char* name : {"alice", "alice2", "bob"}) {
      fs::create_directories(dir_ / "data" / name);
      testing::TiffFixtureSpec spec;
      spec.width = 24;
      spec.height = 16;
      spec.pages = 12;
      ASSERT_TRUE(
          testing::WriteTiffFixture(dir_ / "data" / name / (std::string(name) + ".tif"), spec));
    }
    WriteUsers(false);
  }
  void TearDown() override {
    if (server_.running()) {
      EXPECT_EQ(server_.Stop(), 0);
    }
    fs::remove_all(dir_);
  }

  // Replaces the users file atomically.
  void WriteUsersJson(const json& users) {
    std::ofstream(dir_ / "users.json.new") << users.dump(2);
    fs::rename(dir_ / "users.json.new", dir_ / "users.json");
  }
  json UserEntry(const std::string& name, const char* token, const std::string& folder) {
    return {{"name", name}, {"token", token}, {"folders", {(dir_ / "data" / folder).string()}}};
  }
  // Sends SIGHUP and waits until `token` gets `status` from GET /api/datasets.
  bool ReloadUntil(const char* token, int status) {
    if (kill(server_.pid(), SIGHUP) != 0) return false;
    for (int i = 0; i < 200; ++i) {
      if (Get("/api/datasets", token).status == status) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(25));
    }
    return false;
  }
  // Connects with `token`, opens `id`, saves the view; the view link's id ("" on failure).
  std::string SaveView(WsClient& ws, const char* token, const std::string& id) {
    auto opened = Open(ws, token, id);
    if (!opened || (*opened)["type"] != "opened") return "";
    ws.Send(json{{"type", "view_save"}}.dump());
    auto saved = ReadEvent(ws, "view_saved");
    return saved ? (*saved)["id"].get<std::string>() : "";
  }
  int ConnectStatus(const std::string& target) {
    WsClient ws;
    if (ws.Connect(server_.port(), target).empty()) return 101;
    return ws.handshake_status();
  }

  void WriteUsers(bool with_bob) {
    json users = json::array();
    users.push_back(
        {{"name", "alice"}, {"token", kAlice}, {"folders", {(dir_ / "data" / "alice").string()}}});
    users.push_back({{"name", "old"},
                     {"token", kOld},
                     {"folders", {(dir_ / "data").string()}},
                     {"expires", "2001-01-01T00:00:00Z"}});
    if (with_bob) {
      users.push_back(
          {{"name", "bob"}, {"token", kBob}, {"folders", {(dir_ / "data" / "bob" / "").string()}}});
    }
    std::ofstream(dir_ / "users.json.new") << users.dump(2);
    fs::rename(dir_ / "users.json.new", dir_ / "users.json");
  }

  void StartServer(std::vector<std::string> extra = {}) {
    std::vector<std::string> args = {"--port",       "0",
                                     "--cache",      (dir_ / "cache").string(),
                                     "--state-dir",  (dir_ / "state").string(),
                                     "--data",       (dir_ / "data").string(),
                                     "--token",      kAdmin,
                                     "--users-file", (dir_ / "users.json").string(),
                                     "--ram-mb",     "256",
                                     "--device",     "cpu"};
    args.insert(args.end(), extra.begin(), extra.end());
    ASSERT_TRUE(server_.Start(OCTOSCOPE_BINARY, args, (dir_ / "server.log").string()))
        << server_.error();
  }

  net::testing::HttpResult Get(const std::string& target, const char* token) {
    return Fetch(server_.port(), http::verb::get, target,
                 {{"Authorization", std::string("Bearer ") + token}});
  }

  // Dataset ids by file name ("alice.tif"), as `token` lists them.
  std::map<std::string, std::string> List(const char* token) {
    auto r = Get("/api/datasets", token);
    EXPECT_EQ(r.status, 200) << r.body;
    std::map<std::string, std::string> ids;
    if (r.status != 200) return ids;
    for (const json& d : json::parse(r.body)) {
      ids[fs::path(d["name"].get<std::string>()).filename().string()] = d["id"].get<std::string>();
    }
    return ids;
  }

  // The value of metric line `name` (with labels), or -1.
  double Metric(const std::string& name) {
    auto r = Get("/metrics", kAdmin);
    const size_t at = r.body.find("\n" + name + " ");
    if (at == std::string::npos) return -1;
    return std::stod(r.body.substr(at + name.size() + 2));
  }

  static std::optional<json> ReadEvent(WsClient& ws, const std::string& type,
                                       seconds timeout = seconds(30)) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      auto m = ws.Read(timeout);
      if (!m.ok) return std::nullopt;
      if (m.binary) continue;
      json event = json::parse(m.data);
      if (event.value("type", "") == type) return event;
    }
    return std::nullopt;
  }

  // Connects with `token`, says hello and asks to open `id`; the first "opened" or "error" event.
  std::optional<json> Open(WsClient& ws, const char* token, const std::string& id) {
    if (!ws.Connect(server_.port(), std::string("/ws?token=") + token).empty()) return std::nullopt;
    ws.Send(json{{"type", "hello"}, {"client", "access_test"}, {"protocol", 1}}.dump());
    if (!ReadEvent(ws, "welcome")) return std::nullopt;
    ws.Send(json{{"type", "open"}, {"dataset", id}}.dump());
    const auto deadline = std::chrono::steady_clock::now() + seconds(30);
    while (std::chrono::steady_clock::now() < deadline) {
      auto m = ws.Read(seconds(30));
      if (!m.ok) return std::nullopt;
      if (m.binary) continue;
      json event = json::parse(m.data);
      const std::string type = event.value("type", "");
      if (type == "opened" || type == "error") return event;
    }
    return std::nullopt;
  }

  fs::path dir_;
  ServerProcess server_;
};

TEST_F(AccessTest, UsersSeeOnlyTheirFoldersAndAdminsSeeAll) {
  StartServer();
  const auto all = List(kAdmin);
  ASSERT_EQ(all.size(), 3u);
  const std::string a = all.at("alice.tif"), a2 = all.at("alice2.tif"), b = all.at("bob.tif");

  // Alice lists only her folder's dataset (not alice2, whose path only starts with hers).
  const auto mine = List(kAlice);
  ASSERT_EQ(mine.size(), 1u);
  EXPECT_EQ(mine.count("alice.tif"), 1u);
  EXPECT_EQ(Get("/api/datasets/" + a, kAlice).status, 200);
  EXPECT_EQ(Get("/api/datasets/" + a + "/histogram", kAlice).status, 200);
  // Others' datasets answer exactly like unknown ids.
  for (const std::string& id : {b, a2}) {
    auto r = Get("/api/datasets/" + id, kAlice);
    EXPECT_EQ(r.status, 404);
    EXPECT_EQ(json::parse(r.body), json({{"error", "no dataset '" + id + "'"}}));
    EXPECT_EQ(Get("/api/datasets/" + id + "/histogram", kAlice).status, 404);
    EXPECT_EQ(Fetch(server_.port(), http::verb::post,
                    "/api/datasets/" + id + "/finish?token=" + std::string(kAlice))
                  .status,
              404);
  }
  EXPECT_EQ(Get("/api/datasets/" + b, kAdmin).status, 200);
  // /metrics is for admins.
  EXPECT_EQ(Get("/metrics", kAlice).status, 403);
  EXPECT_EQ(Get("/metrics", kAdmin).status, 200);
  // An expired token: 401 saying so. A wrong one: the usual answer.
  auto expired = Get("/api/datasets", kOld);
  EXPECT_EQ(expired.status, 401);
  EXPECT_EQ(json::parse(expired.body), json({{"error", "token expired"}}));
  EXPECT_EQ(json::parse(Get("/api/datasets", "nobody-token-0123456789abc").body),
            json({{"error", "missing or wrong token"}}));
  WsClient refused;
  EXPECT_NE(refused.Connect(server_.port(), std::string("/ws?token=") + kOld), "");

  // WebSocket open: her dataset opens; bob's is "no dataset", like a made-up id.
  WsClient ws;
  auto opened = Open(ws, kAlice, a);
  ASSERT_TRUE(opened.has_value());
  EXPECT_EQ((*opened)["type"], "opened") << opened->dump();
  WsClient other;
  auto denied = Open(other, kAlice, b);
  ASSERT_TRUE(denied.has_value());
  EXPECT_EQ((*denied)["type"], "error");
  EXPECT_EQ((*denied)["message"], "no dataset '" + b + "'") << denied->dump();

  // A stream alice creates is hers: she and the admins see it.
  auto created =
      Fetch(server_.port(), http::verb::post, "/api/datasets?token=" + std::string(kAlice), {},
            R"({"size":[8,8,4],"channels":1,"dtype":"uint16"})");
  ASSERT_EQ(created.status, 201) << created.body;
  const std::string stream = json::parse(created.body)["id"];
  EXPECT_EQ(Get("/api/datasets/" + stream, kAlice).status, 200);
  EXPECT_EQ(Get("/api/datasets/" + stream, kAdmin).status, 200);

  // SIGHUP re-reads the users file: bob appears and sees his folder and not alice's stream.
  EXPECT_EQ(Get("/api/datasets", kBob).status, 401);
  WriteUsers(true);
  ASSERT_EQ(kill(server_.pid(), SIGHUP), 0);
  int status = 401;
  for (int i = 0; i < 100 && status == 401; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    status = Get("/api/datasets", kBob).status;
  }
  ASSERT_EQ(status, 200);
  const auto bobs = List(kBob);
  ASSERT_EQ(bobs.size(), 1u);
  EXPECT_EQ(bobs.count("bob.tif"), 1u);
  EXPECT_EQ(Get("/api/datasets/" + stream, kBob).status, 404);
  // A broken users file keeps the users in force.
  std::ofstream(dir_ / "users.json") << "[{\"name\": ";
  ASSERT_EQ(kill(server_.pid(), SIGHUP), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_EQ(Get("/api/datasets", kBob).status, 200);
  EXPECT_EQ(Get("/api/datasets", kAlice).status, 200);
}

// Issue 28: a folder grant admits a dataset by its own file; the files that file points to must
// lie in its own folder too. Alice (granted data/alice) must not read bob's file through a
// companion file naming ../bob/..., a reference by absolute path, or a slice symlinked into bob's
// folder; the refusal reads the same whether bob's file exists or not.
TEST_F(AccessTest, DatasetsReadNoFileOutsideTheirOwnFolder) {
  const fs::path alice = dir_ / "data" / "alice", bob = dir_ / "data" / "bob";
  auto ome = [](const std::string& uuid, const std::string& tiff_data) {
    return "<?xml version=\"1.0\"?><OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/"
           "2016-06\" UUID=\"" +
           uuid +
           "\"><Image ID=\"Image:0\"><Pixels ID=\"Pixels:0\" DimensionOrder=\"XYZCT\" "
           "Type=\"uint16\" SizeX=\"24\" SizeY=\"16\" SizeZ=\"3\" SizeC=\"1\" SizeT=\"1\">" +
           tiff_data + "</Pixels></Image></OME>";
  };
  auto names_file = [&](const std::string& file) {
    return ome("urn:uuid:peek",
               "<TiffData><UUID FileName=\"" + file + "\">urn:uuid:private</UUID></TiffData>");
  };
  testing::TiffFixtureSpec spec;
  spec.width = 24;
  spec.height = 16;
  spec.pages = 3;
  spec.descriptions = {ome("urn:uuid:private", "<TiffData/>")};
  ASSERT_TRUE(testing::WriteTiffFixture(bob / "private.ome.tif", spec));
  testing::TiffFixtureSpec plane = spec;
  plane.pages = 1;
  plane.descriptions.clear();
  ASSERT_TRUE(testing::WriteTiffFixture(bob / "plane.tif", plane));

  // Each refused dataset in two versions: bob's file exists, or it does not.
  std::ofstream(alice / "peek.companion.ome") << names_file("../bob/private.ome.tif");
  std::ofstream(alice / "ghost.companion.ome") << names_file("../bob/absent.ome.tif");
  std::ofstream(alice / "absolute.companion.ome") << names_file((bob / "private.ome.tif").string());
  std::ofstream(alice / "absghost.companion.ome") << names_file((bob / "absent.ome.tif").string());
  for (const char* folder : {"slices", "ghostslices"}) {
    fs::create_directories(alice / folder);
    ASSERT_TRUE(testing::WriteTiffFixture(alice / folder / "z0.tif", plane));
    ASSERT_TRUE(testing::WriteTiffFixture(alice / folder / "z1.tif", plane));
  }
  fs::create_symlink("../../bob/plane.tif", alice / "slices" / "z2.tif");
  fs::create_symlink("../../bob/noplane.tif", alice / "ghostslices" / "z2.tif");
  // A main file that is itself a link out: listed to alice alike, whether its target exists.
  fs::create_symlink("../bob/private.ome.tif", alice / "link.ome.tif");
  fs::create_symlink("../bob/absent.ome.tif", alice / "ghostlink.ome.tif");
  // A reference inside the own folder keeps working.
  std::ofstream(alice / "inside.companion.ome") << names_file("alice.tif");
  StartServer();

  auto r = Get("/api/datasets", kAlice);
  ASSERT_EQ(r.status, 200) << r.body;
  std::map<std::string, json> listed;
  for (const json& d : json::parse(r.body)) listed[d["name"].get<std::string>()] = d;
  const std::string refusal = ": it refers to a file outside its own folder";
  const std::vector<std::pair<std::string, std::string>> pairs = {
      {"peek.companion.ome", "ghost.companion.ome"},
      {"absolute.companion.ome", "absghost.companion.ome"},
      {"slices", "ghostslices"},
      {"link.ome.tif", "ghostlink.ome.tif"}};
  for (const auto& [exists, absent] : pairs) {
    for (const std::string& name : {exists, absent}) {
      ASSERT_EQ(listed.count(name), 1u) << name << " not listed: " << r.body;
      const json& d = listed.at(name);
      EXPECT_EQ(d["state"], "error") << d.dump();
      EXPECT_EQ(d["error"], "permission denied: " + (alice / name).string() + refusal) << d.dump();
      // Nothing of bob's file: no size, no channels.
      EXPECT_EQ(d["format"], "unknown") << d.dump();
      EXPECT_EQ(d["size"], json::array({1, 1, 1})) << d.dump();
    }
    // The WebSocket open: refused, and alike for both.
    std::map<std::string, std::string> messages;
    for (const std::string& name : {exists, absent}) {
      WsClient ws;
      const std::string id = listed.at(name)["id"];
      auto opened = Open(ws, kAlice, id);
      ASSERT_TRUE(opened.has_value()) << name;
      EXPECT_EQ((*opened)["type"], "error") << opened->dump();
      std::string message = (*opened).value("message", "");
      EXPECT_EQ(message.find("bob"), std::string::npos) << message;
      for (const std::string& own : {name, id}) {
        for (size_t at; (at = message.find(own)) != std::string::npos;) {
          message.replace(at, own.size(), "OWN");
        }
      }
      messages[name] = message;
    }
    EXPECT_EQ(messages[exists], messages[absent]);
  }

  // A refused folder is still searched: its own slices are listed. A folder that is no slice
  // folder (alice's own, with its link among other files) is not listed as a dataset.
  EXPECT_EQ(listed.count("z0.tif"), 1u) << r.body;
  EXPECT_EQ(listed.count("alice"), 0u) << r.body;

  // The reference inside her folder opens; bob's file itself is still his (and the admins').
  WsClient inside;
  auto opened = Open(inside, kAlice, listed.at("inside.companion.ome")["id"]);
  ASSERT_TRUE(opened.has_value());
  EXPECT_EQ((*opened)["type"], "opened") << opened->dump();
  const auto all = List(kAdmin);
  // Links to bob's file in alice's folder have ids of their own: his file stays listed.
  ASSERT_EQ(all.count("private.ome.tif"), 1u) << Get("/api/datasets", kAdmin).body;
  EXPECT_NE(all.at("private.ome.tif"), listed.at("link.ome.tif")["id"]);
  WsClient admin;
  auto bobs = Open(admin, kAdmin, all.at("private.ome.tif"));
  ASSERT_TRUE(bobs.has_value());
  EXPECT_EQ((*bobs)["type"], "opened") << bobs->dump();
}

TEST_F(AccessTest, IdleDatasetsAreReleasedRamIsRedividedAndTheyReopenFromTheirCache) {
  StartServer({"--idle-timeout-s", "1"});
  const auto all = List(kAdmin);
  const std::string a = all.at("alice.tif"), b = all.at("bob.tif");
  const std::string a_budget = "octoscope_dataset_ram_budget_bytes{dataset=\"" + a + "\"}";
  const std::string b_budget = "octoscope_dataset_ram_budget_bytes{dataset=\"" + b + "\"}";
  const std::string b_open = "octoscope_dataset_open{dataset=\"" + b + "\"}";
  auto ready = [&](const std::string& id) {
    for (int i = 0; i < 200; ++i) {
      auto d = json::parse(Get("/api/datasets/" + id, kAdmin).body);
      if (d["state"] == "ready") return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return false;
  };
  WsClient wa, wb;
  ASSERT_EQ((*Open(wa, kAdmin, a))["type"], "opened");
  ASSERT_EQ((*Open(wb, kAdmin, b))["type"], "opened");
  ASSERT_TRUE(ready(a));
  ASSERT_TRUE(ready(b));
  // Two datasets in use: half of the 256 MiB each.
  EXPECT_EQ(Metric(a_budget), 128.0 * (1 << 20));
  EXPECT_EQ(Metric(b_budget), 128.0 * (1 << 20));
  EXPECT_EQ(Metric(b_open), 1);
  std::map<std::string, fs::file_time_type> cache_files;
  for (const auto& e : fs::recursive_directory_iterator(dir_ / "cache" / b)) {
    if (e.is_regular_file()) cache_files[e.path().string()] = e.last_write_time();
  }
  ASSERT_FALSE(cache_files.empty());

  // Bob's viewer leaves: after the idle timeout his dataset is closed and alice's gets it all.
  wb.Close();
  double open = 1;
  for (int i = 0; i < 100 && open != 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    open = Metric(b_open);
  }
  EXPECT_EQ(open, 0);
  EXPECT_GE(Metric("octoscope_dataset_releases_total"), 1);
  EXPECT_EQ(Metric(a_budget), 256.0 * (1 << 20));
  EXPECT_EQ(Metric(b_budget), -1);  // Not listed while closed.
  // The dataset in use is never released.
  EXPECT_EQ(Metric("octoscope_dataset_open{dataset=\"" + a + "\"}"), 1);

  // Reopened: from the cache (no file of it rewritten), and the budget is divided again.
  WsClient again;
  ASSERT_EQ((*Open(again, kAdmin, b))["type"], "opened");
  ASSERT_TRUE(ready(b));
  EXPECT_EQ(Metric(b_open), 1);
  EXPECT_EQ(Metric(a_budget), 128.0 * (1 << 20));
  EXPECT_EQ(Metric(b_budget), 128.0 * (1 << 20));
  for (const auto& [path, time] : cache_files) {
    if (path.ends_with(".lock") || path.ends_with("lock")) continue;
    std::error_code ec;
    EXPECT_EQ(fs::last_write_time(path, ec), time) << path << " was rewritten";
  }
}

constexpr char kCarol[] = "carol-token-0123456789abcdef";
constexpr char kAlice2[] = "alice-again-token-0123456789";

TEST_F(AccessTest, ExpiryAndRemovalEndLiveConnectionsAndEveryLinkResting) {
  // carol's token expires a few seconds from now.
  const auto carol_expiry = std::chrono::system_clock::now() + seconds(4);
  const std::time_t t = std::chrono::system_clock::to_time_t(carol_expiry);
  char expires[32];
  std::strftime(expires, sizeof expires, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&t));
  json carol = UserEntry("carol", kCarol, "bob");
  carol["expires"] = expires;
  WriteUsersJson({UserEntry("alice", kAlice, "alice"), carol});
  StartServer();
  const auto all = List(kAdmin);
  const std::string a = all.at("alice.tif"), b = all.at("bob.tif");

  // alice: a session, a share link with a guest in it, a view link, a stream.
  WsClient alice;
  const std::string view = SaveView(alice, kAlice, a);
  ASSERT_FALSE(view.empty());
  alice.Send(json{{"type", "share_create"}, {"role", "viewer"}}.dump());
  auto link = ReadEvent(alice, "share_created");
  ASSERT_TRUE(link.has_value());
  const std::string share = (*link)["token"];
  WsClient guest;
  ASSERT_EQ(guest.Connect(server_.port(), "/ws?share=" + share), "");
  guest.Send(json{{"type", "hello"}, {"protocol", 1}}.dump());
  ASSERT_TRUE(ReadEvent(guest, "opened").has_value());
  auto created = Fetch(server_.port(), http::verb::post, "/api/datasets?token=" + std::string(kAlice),
                       {}, R"({"size":[8,8,4],"channels":1,"dtype":"uint16"})");
  ASSERT_EQ(created.status, 201);
  const std::string stream = json::parse(created.body)["id"];
  EXPECT_EQ(ConnectStatus("/ws?view=" + view), 101);

  // carol's token expires while she is connected: her connection ends (4005).
  WsClient carol_ws;
  auto opened = Open(carol_ws, kCarol, b);
  ASSERT_TRUE(opened.has_value());
  ASSERT_EQ((*opened)["type"], "opened");
  const auto closed = carol_ws.ReadUntilClose(nullptr, seconds(15));
  EXPECT_EQ(closed, 4005);
  EXPECT_GE(std::chrono::system_clock::now(), carol_expiry - seconds(1));

  // alice is removed by a reload: her connection, her guest, her links all end.
  WriteUsersJson(json::array({carol}));
  ASSERT_TRUE(ReloadUntil(kAlice, 401));
  EXPECT_EQ(alice.ReadUntilClose(nullptr, seconds(10)), 4005);
  EXPECT_EQ(guest.ReadUntilClose(nullptr, seconds(10)), 4005);
  EXPECT_EQ(ConnectStatus("/ws?share=" + share), 401);
  EXPECT_EQ(ConnectStatus("/ws?view=" + view), 401);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/datasets?share=" + share).status, 401);

  // A new user named alice inherits nothing: not the view link, not the stream.
  WriteUsersJson({UserEntry("alice", kAlice2, "alice"), carol});
  ASSERT_TRUE(ReloadUntil(kAlice2, 200));
  EXPECT_EQ(ConnectStatus("/ws?view=" + view), 401);
  auto mine = Get("/api/views", kAlice2);
  ASSERT_EQ(mine.status, 200);
  EXPECT_EQ(json::parse(mine.body), json::array());
  EXPECT_EQ(Get("/api/datasets/" + stream, kAlice2).status, 404);
  EXPECT_EQ(Get("/api/datasets/" + a, kAlice2).status, 200);  // Her folder is hers again.
  // The admin still sees the stream: nothing stored is lost.
  EXPECT_EQ(Get("/api/datasets/" + stream, kAdmin).status, 200);
}

TEST_F(AccessTest, AViewLinkOpensOnlyWhileItsMakerMaySeeTheDataset) {
  WriteUsersJson(json::array({UserEntry("alice", kAlice, "alice")}));
  StartServer();
  const auto all = List(kAdmin);
  const std::string a = all.at("alice.tif");
  WsClient alice;
  const std::string view = SaveView(alice, kAlice, a);
  ASSERT_FALSE(view.empty());
  alice.Close();
  EXPECT_EQ(ConnectStatus("/ws?view=" + view), 101);
  // Her folder changes: the link no longer opens (though the user still exists).
  WriteUsersJson(json::array({UserEntry("alice", kAlice, "alice2")}));
  ASSERT_TRUE(ReloadUntil(kAlice, 200));
  int status = 101;
  for (int i = 0; i < 100 && status == 101; ++i) {
    status = ConnectStatus("/ws?view=" + view);
    if (status == 101) std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  EXPECT_EQ(status, 401);
  // Granted again: it opens again (the link itself was never changed).
  WriteUsersJson(json::array({UserEntry("alice", kAlice, "alice")}));
  ASSERT_EQ(kill(server_.pid(), SIGHUP), 0);
  for (int i = 0; i < 100 && status != 101; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
    status = ConnectStatus("/ws?view=" + view);
  }
  EXPECT_EQ(status, 101);
}

TEST_F(AccessTest, ReloadsAreValidatedLikeStartUp) {
  WriteUsersJson(json::array({UserEntry("alice", kAlice, "alice")}));
  StartServer();
  // A user named like the admin token's user: refused at start-up, so refused on reload.
  WriteUsersJson({UserEntry("admin", kBob, "bob"), UserEntry("alice", kAlice, "alice")});
  ASSERT_EQ(kill(server_.pid(), SIGHUP), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  EXPECT_EQ(Get("/api/datasets", kBob).status, 401);
  EXPECT_EQ(Get("/api/datasets", kAlice).status, 200);
  // A user with the admin's token: refused too.
  WriteUsersJson(json::array({UserEntry("mallory", kAdmin, "bob")}));
  ASSERT_EQ(kill(server_.pid(), SIGHUP), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  EXPECT_EQ(Get("/api/datasets", kAlice).status, 200);
  std::ifstream log(dir_ / "server.log");
  const std::string text((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("keeping the users in force: a user is named \"admin\""), std::string::npos);
  EXPECT_NE(text.find("has the --token's token"), std::string::npos);
}

TEST_F(AccessTest, OnlyAdminsFeedOrFinishTheDemo) {
  StartServer({"--demo", "--demo-size", "32,32,16", "--demo-rate", "1"});
  const std::string demo = "demospecimen";
  EXPECT_EQ(Get("/api/datasets/" + demo, kAlice).status, 200);  // Everyone may look at it.
  const std::string plane(32 * 32 * 2, '\0');
  auto put = Fetch(server_.port(), http::verb::put,
                   "/api/datasets/" + demo + "/slabs?z=0&depth=1&channel=0&token=" + kAlice,
                   {{"Content-Type", "application/octet-stream"}}, plane);
  EXPECT_EQ(put.status, 403) << put.body;
  auto finish = Fetch(server_.port(), http::verb::post,
                      "/api/datasets/" + demo + "/finish?token=" + std::string(kAlice));
  EXPECT_EQ(finish.status, 403) << finish.body;
  EXPECT_EQ(json::parse(Get("/api/datasets/" + demo, kAdmin).body)["state"], "streaming");
  finish = Fetch(server_.port(), http::verb::post,
                 "/api/datasets/" + demo + "/finish?token=" + std::string(kAdmin));
  EXPECT_EQ(finish.status, 200) << finish.body;
}

}  // namespace
}  // namespace octoscope::app
