// The `serve --config` file and the users file: every key, and errors that name the key.
#include "protocol/serve_config.h"

#include <gtest/gtest.h>

#include <string>

namespace octoscope::protocol {
namespace {

std::string ErrorOf(std::string_view text) {
  auto parsed = ParseServeConfig(text, "cfg.json");
  return parsed.ok() ? std::string("OK") : parsed.status().message();
}

TEST(ServeConfigTest, EveryKeyIsRead) {
  auto c = ParseServeConfig(R"({
    "data": ["/srv/a", "/srv/b"], "watch": ["/srv/w"], "demo": true, "cache": "/var/cache/o",
    "bind": "0.0.0.0", "port": 8443, "token-file": "/etc/o/token", "ram-mb": 4096,
    "device-mb": 2048, "device": "gpu", "web": "/usr/share/o/web", "io-threads": 4,
    "max-upload-mb": 2048, "demo-size": [64, 64, 32], "demo-rate": 2.5,
    "public-url": "https://scope.lab.example/octoscope/", "trusted-proxy": ["127.0.0.1", "10.0.0.0/8"],
    "users": [{"name": "alice", "token": "alice-token-0123456789", "folders": ["/srv/a"],
               "expires": "2027-01-31T00:00:00Z"},
              {"name": "root", "token-file": "/etc/o/root", "admin": true}],
    "state-dir": "/var/lib/o", "max-sessions": 10, "max-participants": 4, "idle-timeout-s": 60
  })",
                            "cfg.json");
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->data, (std::vector<std::string>{"/srv/a", "/srv/b"}));
  EXPECT_EQ(c->watch, (std::vector<std::string>{"/srv/w"}));
  EXPECT_EQ(c->demo, true);
  EXPECT_EQ(c->cache, "/var/cache/o");
  EXPECT_EQ(c->bind, "0.0.0.0");
  EXPECT_EQ(c->port, 8443);
  EXPECT_EQ(c->token_file, "/etc/o/token");
  EXPECT_EQ(c->ram_mb, 4096);
  EXPECT_EQ(c->device_mb, 2048);
  EXPECT_EQ(c->device, "gpu");
  EXPECT_EQ(c->web, "/usr/share/o/web");
  EXPECT_EQ(c->io_threads, 4);
  EXPECT_EQ(c->max_upload_mb, 2048);
  EXPECT_EQ(c->demo_size, (std::vector<int64_t>{64, 64, 32}));
  EXPECT_EQ(c->demo_rate, 2.5);
  EXPECT_EQ(c->public_url, "https://scope.lab.example/octoscope/");
  EXPECT_EQ(c->trusted_proxy, (std::vector<std::string>{"127.0.0.1", "10.0.0.0/8"}));
  ASSERT_TRUE(c->users.has_value());
  ASSERT_EQ(c->users->size(), 2u);
  const UserConfig& alice = (*c->users)[0];
  EXPECT_EQ(alice.name, "alice");
  EXPECT_EQ(alice.token, "alice-token-0123456789");
  EXPECT_EQ(alice.folders, (std::vector<std::string>{"/srv/a"}));
  EXPECT_FALSE(alice.admin);
  EXPECT_EQ(alice.expires_unix_s, 1801353600);  // date -u -d 2027-01-31 +%s
  const UserConfig& root = (*c->users)[1];
  EXPECT_EQ(root.token_file, "/etc/o/root");
  EXPECT_TRUE(root.admin);
  EXPECT_FALSE(root.expires_unix_s.has_value());
  EXPECT_EQ(c->state_dir, "/var/lib/o");
  EXPECT_EQ(c->max_sessions, 10);
  EXPECT_EQ(c->max_participants, 4);
  EXPECT_EQ(c->idle_timeout_s, 60);
  // Nothing given: nothing set.
  auto empty = ParseServeConfig("{}", "cfg.json");
  ASSERT_TRUE(empty.ok());
  EXPECT_FALSE(empty->users.has_value());
  EXPECT_FALSE(empty->idle_timeout_s.has_value());
  EXPECT_TRUE(empty->trusted_proxy.empty());
}

TEST(ServeConfigTest, ErrorsNameTheKey) {
  EXPECT_NE(ErrorOf(R"({"idle-timeout":5})").find("unknown key \"idle-timeout\""),
            std::string::npos);
  EXPECT_NE(ErrorOf(R"({"max-sessions":0})").find("max-sessions"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"max-participants":"4"})").find("max-participants"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"idle-timeout-s":2592001})").find("idle-timeout-s"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"public-url":5})").find("public-url"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"trusted-proxy":"10.0.0.1"})").find("trusted-proxy"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"state-dir":[]})").find("state-dir"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users-file":1})").find("users-file"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":{}})").find("users"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":[{"name":"a","token":"t","tokn":"x"}]})").find("users[0]"),
            std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":[{"token":"t"}]})").find("users[0].name"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":[{"name":"a b","token":"t"}]})").find("users[0].name"),
            std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":[{"name":"a"}]})").find("token"), std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":[{"name":"a","token":"t","token-file":"f"}]})").find("users[0]"),
            std::string::npos);
  EXPECT_NE(
      ErrorOf(R"({"users":[{"name":"a","token":"t","folders":"/x"}]})").find("users[0].folders"),
      std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":[{"name":"a","token":"t","admin":1}]})").find("users[0].admin"),
            std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":[{"name":"a","token":"t","expires":"tomorrow"}]})")
                .find("users[0].expires"),
            std::string::npos);
  EXPECT_NE(
      ErrorOf(R"({"users":[{"name":"a","token":"t"},{"name":"a","token":"u"}]})").find("users[1]"),
      std::string::npos);
  EXPECT_NE(ErrorOf(R"({"users":[],"users-file":"u.json"})").find("not both"), std::string::npos);
}

TEST(ServeConfigTest, ConnectionCapsAndAllowedOrigins) {
  auto c = ParseServeConfig(R"({"max-connections": 2048, "max-connections-per-address": 16,
                                "allowed-origins": ["https://viewer.lab.example"]})",
                            "cfg.json");
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->max_connections, 2048);
  EXPECT_EQ(c->max_connections_per_address, 16);
  EXPECT_EQ(c->allowed_origins, (std::vector<std::string>{"https://viewer.lab.example"}));
  EXPECT_NE(ErrorOf(R"({"max-connections":0})").find("max-connections"), std::string::npos);
  EXPECT_NE(
      ErrorOf(R"({"max-connections-per-address":1000001})").find("max-connections-per-address"),
      std::string::npos);
  EXPECT_NE(ErrorOf(R"({"allowed-origins":"https://a.example"})").find("allowed-origins"),
            std::string::npos);
  EXPECT_NE(ErrorOf(R"({"allowed-origin":[]})").find("unknown key"), std::string::npos);
}

TEST(ServeConfigTest, Rfc3339UtcTimes) {
  EXPECT_EQ(*ParseRfc3339Utc("1970-01-01T00:00:00Z", "t"), 0);
  EXPECT_EQ(*ParseRfc3339Utc("2000-02-29T12:34:56Z", "t"), 951827696);  // date -u -d ... +%s
  EXPECT_EQ(*ParseRfc3339Utc("2026-11-25t10:00:00.25z", "t"), 1795600800);
  for (const char* bad : {"2027-01-31", "2027-01-31T00:00:00", "2027-01-31T00:00:00+01:00",
                          "2027-13-01T00:00:00Z", "2027-02-29T00:00:00Z", "2027-01-31T24:00:00Z",
                          "2027-01-31T00:00:00.Z", "2027-1-31T00:00:00Z", ""}) {
    auto r = ParseRfc3339Utc(bad, "users[0].expires");
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_NE(r.status().message().find("users[0].expires"), std::string::npos);
  }
}

TEST(ServeConfigTest, UsersFileIsAnArrayOfUsers) {
  auto users = ParseUsersFile(R"([{"name":"bob","token":"bob-token-0123456789","folders":["/x"]}])",
                              "users.json");
  ASSERT_TRUE(users.ok()) << users.status().ToString();
  ASSERT_EQ(users->size(), 1u);
  EXPECT_EQ((*users)[0].name, "bob");
  for (const char* bad : {"{}", "[", R"([{"name":"bob"}])", R"([1])", "null"}) {
    auto r = ParseUsersFile(bad, "users.json");
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_TRUE(r.status().message().starts_with("users.json: ")) << r.status().message();
  }
  EXPECT_FALSE(ParseUsersFile(std::string(kMaxServeConfigBytes + 1, ' '), "users.json").ok());
}

}  // namespace
}  // namespace octoscope::protocol
