// AccessControl without a server: tokens, expiry, share/view hooks and folder visibility.
#include "app/access_control.h"

#include <gtest/gtest.h>

#include <chrono>

#include "app/volume_options.h"
#include "dataset/dataset_registry.h"
#include "io/tiff_fixture.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;
using net::Principal;

User MakeUser(std::string name, std::string token, std::vector<fs::path> folders,
              bool admin = false) {
  return User{std::move(name), std::move(token), std::move(folders), admin, std::nullopt};
}

TEST(AccessControlTest, FoldersCompareComponentWise) {
  EXPECT_TRUE(IsUnderFolder("/srv/scans/alice/a.tif", "/srv/scans/alice"));
  EXPECT_TRUE(IsUnderFolder("/srv/scans/alice/a.tif", "/srv/scans/alice/"));
  EXPECT_TRUE(IsUnderFolder("/srv/scans/alice", "/srv/scans/alice"));
  EXPECT_TRUE(IsUnderFolder("/srv/scans/alice/x/y.tif", "/"));
  EXPECT_FALSE(IsUnderFolder("/srv/scans/alice2/a.tif", "/srv/scans/alice"));
  EXPECT_FALSE(IsUnderFolder("/srv/scans", "/srv/scans/alice"));
  EXPECT_FALSE(IsUnderFolder("", "/srv"));
  EXPECT_FALSE(IsUnderFolder("/srv/a", ""));
}

TEST(AccessControlTest, TokensUsersExpiryAndHooks) {
  std::vector<User> users = {MakeUser("alice", "alice-token-0123456789", {"/srv/a"}),
                             MakeUser("root", "root-token-0123456789", {}, true),
                             MakeUser("old", "old-token-0123456789", {"/srv"})};
  users[2].expires = std::chrono::system_clock::now() - std::chrono::hours(1);
  AccessControl access(users);
  auto alice = access.Authenticate("Bearer alice-token-0123456789", "");
  ASSERT_TRUE(alice.has_value());
  EXPECT_EQ(alice->kind, Principal::Kind::kUser);
  EXPECT_EQ(alice->user, "alice");
  EXPECT_FALSE(alice->admin);
  auto root = access.Authenticate("", "x=1&token=root-token-0123456789");
  ASSERT_TRUE(root.has_value());
  EXPECT_TRUE(root->admin);
  EXPECT_FALSE(access.Authenticate("", "token=alice-token-012345678").has_value());
  EXPECT_EQ(access.RefusalMessage("", "token=alice-token-012345678"), "missing or wrong token");
  EXPECT_FALSE(access.Authenticate("", "token=old-token-0123456789").has_value());
  EXPECT_EQ(access.RefusalMessage("", "token=old-token-0123456789"), "token expired");
  // No hooks: share and view links are refused.
  EXPECT_FALSE(access.Authenticate("", "share=s-123").has_value());
  access.SetShareLookup([](std::string_view t) -> std::optional<std::string> {
    if (t == "s-123") return "dataset00001";
    return std::nullopt;
  });
  access.SetViewLookup([](std::string_view t) -> std::optional<std::string> {
    if (t == "v-456") return "dataset00002";
    return std::nullopt;
  });
  auto share = access.Authenticate("", "share=s-123");
  ASSERT_TRUE(share.has_value());
  EXPECT_EQ(share->kind, Principal::Kind::kShare);
  EXPECT_EQ(share->credential, "s-123");
  EXPECT_FALSE(access.Authenticate("", "share=s-999").has_value());
  auto view = access.Authenticate("", "view=v-456");
  ASSERT_TRUE(view.has_value());
  EXPECT_EQ(view->kind, Principal::Kind::kView);
  EXPECT_FALSE(AccessControl::MayCreateStreams(*share));
  EXPECT_FALSE(AccessControl::MayReadMetrics(*view));
  EXPECT_TRUE(AccessControl::MayCreateStreams(*alice));
  EXPECT_FALSE(AccessControl::MayReadMetrics(*alice));
  EXPECT_TRUE(AccessControl::MayReadMetrics(*root));
  // A reload replaces the table: alice is gone.
  access.ReplaceUsers({MakeUser("bob", "bob-token-0123456789", {})});
  EXPECT_FALSE(access.Authenticate("", "token=alice-token-0123456789").has_value());
  EXPECT_TRUE(access.Authenticate("", "token=bob-token-0123456789").has_value());
}

TEST(AccessControlTest, VisibilityOfDatasets) {
  const fs::path dir = testing::MakeTempDir("access-control");
  for (const char* name : {"a", "a2"}) {
    fs::create_directories(dir / "data" / name);
    testing::TiffFixtureSpec spec;
    spec.width = 24;
    spec.height = 16;
    spec.pages = 12;
    ASSERT_TRUE(testing::WriteTiffFixture(dir / "data" / name / "s.tif", spec));
  }
  dataset::RegistryOptions options;
  options.data_dirs = {dir / "data"};
  options.cache_root = dir / "cache";
  options.open = DefaultOpenOptions();
  auto registry = dataset::DatasetRegistry::Create(options);
  ASSERT_TRUE(registry.ok()) << registry.status().ToString();
  std::shared_ptr<dataset::Dataset> a, a2;
  for (const auto& d : (*registry)->List()) {
    (d->source_path().parent_path().filename() == "a" ? a : a2) = d;
  }
  ASSERT_TRUE(a && a2) << (*registry)->List().size() << " datasets";
  // A folder given through a symlink and with "..": canonicalised like the dataset's path.
  fs::create_directory_symlink(dir / "data", dir / "link");
  auto users = LoadUsers({protocol::UserConfig{"alice",
                                               "alice-token-0123456789",
                                               std::nullopt,
                                               {(dir / "link" / "x" / ".." / "a").string()},
                                               false,
                                               std::nullopt}},
                         "test");
  ASSERT_TRUE(users.ok()) << users.status().ToString();
  AccessControl access(*users);
  const Principal alice{Principal::Kind::kUser, "alice", false, ""};
  EXPECT_TRUE(access.MayView(alice, *a));
  EXPECT_FALSE(access.MayView(alice, *a2));
  EXPECT_TRUE(access.MayView(Principal{Principal::Kind::kUser, "root", true, ""}, *a2));
  EXPECT_FALSE(access.MayView(Principal{Principal::Kind::kUser, "carol", false, ""}, *a));
  EXPECT_FALSE(access.MayView(Principal{}, *a));  // No credentials.
  access.SetShareLookup([&](std::string_view) -> std::optional<std::string> { return a2->id(); });
  const Principal share{Principal::Kind::kShare, "", false, "s"};
  EXPECT_TRUE(access.MayView(share, *a2));
  EXPECT_FALSE(access.MayView(share, *a));
  const Principal view{Principal::Kind::kView, "", false, "v"};
  EXPECT_FALSE(access.MayView(view, *a2));  // No view hook.
  (*registry)->Close();
  fs::remove_all(dir);
}

TEST(AccessControlTest, LoadUsersChecksTokens) {
  EXPECT_EQ(
      LoadUsers({protocol::UserConfig{"a", "short", std::nullopt, {}, false, std::nullopt}}, "cfg")
          .status()
          .code(),
      StatusCode::kInvalidArgument);
  auto twice = LoadUsers(
      {protocol::UserConfig{"a", "same-token-0123456789", std::nullopt, {}, false, std::nullopt},
       protocol::UserConfig{"b", "same-token-0123456789", std::nullopt, {}, false, std::nullopt}},
      "cfg");
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.status().message().find("user \"b\""), std::string::npos);
  EXPECT_EQ(LoadUsers({protocol::UserConfig{
                          "a", std::nullopt, "/nonexistent/token", {}, false, std::nullopt}},
                      "cfg")
                .status()
                .code(),
            StatusCode::kNotFound);
}

}  // namespace
}  // namespace octoscope::app
