// AccessControl without a server: tokens, expiry, share/view hooks and folder visibility.
#include "app/access_control.h"

#include <gtest/gtest.h>

#include <chrono>
#include <map>

#include "app/volume_options.h"
#include "dataset/dataset_registry.h"
#include "io/tiff_fixture.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;
using net::Principal;

using protocol::GrantRef;

User MakeUser(std::string name, std::string token, std::vector<fs::path> folders,
              bool admin = false, std::string id = "") {
  return User{std::move(name), std::move(token), std::move(folders),
              admin,           std::nullopt,     std::move(id)};
}

Principal UserPrincipal(std::string name, bool admin = false) {
  return Principal{Principal::Kind::kUser, std::move(name), admin, "", ""};
}

// A stream dataset of id `id` in `dir` created under `creator`, and the access control's finder
// knowing it alone.
std::shared_ptr<dataset::Dataset> StreamKnownTo(AccessControl& access, const fs::path& dir,
                                                const std::string& id, const GrantRef& creator) {
  dataset::StreamSpec spec;
  spec.id = id;
  spec.creator = protocol::GrantRefText(creator);  // What the stream keeps (and its record).
  spec.size = {8, 8, 4};
  spec.cache_root = dir;
  auto stream = dataset::Dataset::CreateStream(spec);
  EXPECT_TRUE(stream.ok()) << stream.status().ToString();
  if (!stream.ok()) return nullptr;
  std::shared_ptr<dataset::Dataset> dataset = *stream;
  access.SetDatasetFinder([dataset, id](std::string_view wanted) {
    return wanted == id ? dataset : std::shared_ptr<dataset::Dataset>();
  });
  return dataset;
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
  const GrantRef by_alice{GrantRef::Kind::kUser, "alice"};
  auto share_of = [by_alice](std::string_view key) -> std::optional<ShareGrantInfo> {
    if (key == "s-123" || key == "id-123") return ShareGrantInfo{"id-123", by_alice, ""};
    return std::nullopt;
  };
  access.SetShareLookups(share_of, share_of);
  // A view link of a stream alice created (its maker's grant must cover its dataset).
  const fs::path dir = testing::MakeTempDir("access-hooks");
  const std::string stream_id = "dataset00002";
  std::shared_ptr<dataset::Dataset> stream = StreamKnownTo(access, dir, stream_id, by_alice);
  ASSERT_NE(stream, nullptr);
  const std::string view_id(22, 'v');
  access.SetViewLookup([&](std::string_view id) -> std::optional<ViewGrantInfo> {
    if (id != view_id) return std::nullopt;
    ViewGrantInfo info;
    info.dataset = stream_id;
    info.grant.emplace();
    info.grant->creator = by_alice;
    info.grant->owner = by_alice;
    return info;
  });
  auto share = access.Authenticate("", "share=s-123");
  ASSERT_TRUE(share.has_value());
  EXPECT_EQ(share->kind, Principal::Kind::kShare);
  EXPECT_EQ(share->credential, "s-123");
  EXPECT_EQ(access.GrantOf(*share), (GrantRef{GrantRef::Kind::kShare, "id-123"}));
  EXPECT_FALSE(access.Authenticate("", "share=s-999").has_value());
  auto view = access.Authenticate("", "view=" + view_id);
  ASSERT_TRUE(view.has_value());
  EXPECT_EQ(view->kind, Principal::Kind::kView);
  EXPECT_FALSE(access.Authenticate("", "view=v-456").has_value());
  EXPECT_FALSE(AccessControl::MayCreateStreams(*share));
  EXPECT_FALSE(AccessControl::MayReadMetrics(*view));
  EXPECT_TRUE(AccessControl::MayCreateStreams(*alice));
  EXPECT_FALSE(AccessControl::MayReadMetrics(*alice));
  EXPECT_TRUE(AccessControl::MayReadMetrics(*root));
  // A reload replaces the table: alice is gone, and so is every link resting on her grant.
  access.ReplaceUsers({MakeUser("bob", "bob-token-0123456789", {})});
  EXPECT_FALSE(access.Authenticate("", "token=alice-token-0123456789").has_value());
  EXPECT_TRUE(access.Authenticate("", "token=bob-token-0123456789").has_value());
  EXPECT_FALSE(access.Authenticate("", "share=s-123").has_value());
  EXPECT_FALSE(access.Authenticate("", "view=" + view_id).has_value());
  EXPECT_EQ(access.RefusalMessage("", "share=s-123"),
            "this share link is not valid (revoked or expired)");
  EXPECT_EQ(access.RefusalMessage("", "view=" + view_id),
            "this view link does not open: the access of the view link's maker ended (user "
            "removed)");
  stream->Close();
  fs::remove_all(dir);
}

TEST(AccessControlTest, GrantsHoldWhileTheirWholeChainHolds) {
  // alice (id ua) may see "dsa"; a share link of her session for "dsa"; a view link made through
  // it; a view link made by her; a view link made in a session opened through that one.
  const fs::path dir = testing::MakeTempDir("grant-chains");
  AccessControl access({MakeUser("alice", "alice-token-0123456789", {"/srv/a"}, false, "ua")});
  const std::string stream_id = "dsa000000001";
  // alice created the stream: her grant covers it.
  std::shared_ptr<dataset::Dataset> stream =
      StreamKnownTo(access, dir, stream_id, GrantRef{GrantRef::Kind::kUser, "ua"});
  ASSERT_NE(stream, nullptr);
  std::map<std::string, ShareGrantInfo> shares = {
      {"sh1", ShareGrantInfo{"sh1", GrantRef{GrantRef::Kind::kUser, "ua"}, stream_id}}};
  const GrantRef ua{GrantRef::Kind::kUser, "ua"};
  std::map<std::string, ViewGrantInfo> views;
  auto made = [&](GrantRef creator, std::optional<int64_t> expires = std::nullopt) {
    ViewGrantInfo info;
    info.dataset = stream_id;
    info.grant.emplace();
    info.grant->creator = std::move(creator);
    info.grant->owner = ua;
    info.grant->expires_unix_s = expires;
    return info;
  };
  views["V1"] = made({GrantRef::Kind::kShare, "sh1"});
  views["V2"] = made(ua);
  views["V3"] = made({GrantRef::Kind::kView, "V2"});
  views["V4"] = made(ua, int64_t{1000});  // Long expired.
  views["V5"] = made(ua);
  views["V5"].grant.reset();  // Version 1: no grant.
  views["L1"] = made({GrantRef::Kind::kView, "L2"});
  views["L2"] = made({GrantRef::Kind::kView, "L1"});
  access.SetShareLookups(nullptr, [&](std::string_view id) -> std::optional<ShareGrantInfo> {
    auto it = shares.find(std::string(id));
    return it == shares.end() ? std::nullopt : std::optional<ShareGrantInfo>(it->second);
  });
  access.SetViewLookup([&](std::string_view id) -> std::optional<ViewGrantInfo> {
    auto it = views.find(std::string(id));
    return it == views.end() ? std::nullopt : std::optional<ViewGrantInfo>(it->second);
  });
  auto holds = [&](GrantRef::Kind kind, const std::string& id, std::string_view dataset = "") {
    return access.Check(GrantRef{kind, id}, dataset).holds;
  };
  EXPECT_TRUE(holds(GrantRef::Kind::kUser, "ua"));
  EXPECT_FALSE(holds(GrantRef::Kind::kUser, "alice"));  // Her name is not her id.
  EXPECT_TRUE(holds(GrantRef::Kind::kView, "V2"));
  EXPECT_TRUE(holds(GrantRef::Kind::kView, "V3"));
  EXPECT_FALSE(holds(GrantRef::Kind::kView, "V2", "other"));  // Scoped to its dataset.
  EXPECT_FALSE(holds(GrantRef::Kind::kShare, "sh1", "other"));
  const session::GrantVerdict expired = access.Check({GrantRef::Kind::kView, "V4"}, "");
  EXPECT_FALSE(expired.holds);
  EXPECT_EQ(expired.reason, "the view link expired");
  EXPECT_FALSE(holds(GrantRef::Kind::kView, "V5"));
  const session::GrantVerdict loop = access.Check({GrantRef::Kind::kView, "L1"}, "");
  EXPECT_FALSE(loop.holds);
  EXPECT_NE(loop.reason.find("too long"), std::string::npos);
  const session::GrantVerdict via = access.Check({GrantRef::Kind::kShare, "sh1"}, "");
  EXPECT_TRUE(via.via_share);
  EXPECT_EQ(via.owner, ua);
  // The share link is revoked: the view link made through it dies with it, the others stay.
  shares.clear();
  EXPECT_FALSE(holds(GrantRef::Kind::kView, "V1"));
  EXPECT_TRUE(holds(GrantRef::Kind::kView, "V2"));
  // A deleted view link takes the ones made in sessions opened through it along.
  views.erase("V2");
  EXPECT_FALSE(holds(GrantRef::Kind::kView, "V3"));
  // alice removed, then a new "alice" added (another id): nothing of the old one holds.
  views["V2"] = made(ua);
  access.ReplaceUsers({MakeUser("alice", "new-alice-token-012345", {"/srv/a"}, false, "ub")});
  EXPECT_FALSE(holds(GrantRef::Kind::kView, "V2"));
  EXPECT_EQ(access.Check({GrantRef::Kind::kUser, "ua"}, "").reason, "user removed");
  auto alice = access.Authenticate("Bearer new-alice-token-012345", "");
  ASSERT_TRUE(alice.has_value());
  EXPECT_EQ(alice->user_id, "ub");
  EXPECT_EQ(access.UserName("ub"), "alice");
  EXPECT_FALSE(access.UserName("ua").has_value());
  // Nor does the new alice see the old one's stream.
  EXPECT_FALSE(access.MayView(*alice, *stream));
  stream->Close();
  fs::remove_all(dir);
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
  users->push_back(MakeUser("root", "root-token-0123456789", {}, true));
  AccessControl access(*users);
  access.SetDatasetFinder([&](std::string_view id) { return (*registry)->Find(id); });
  const Principal alice = UserPrincipal("alice");
  EXPECT_TRUE(access.MayView(alice, *a));
  EXPECT_FALSE(access.MayView(alice, *a2));
  EXPECT_TRUE(access.MayView(UserPrincipal("root", true), *a2));
  EXPECT_FALSE(access.MayView(UserPrincipal("carol"), *a));  // Not (any more) a user.
  EXPECT_FALSE(access.MayView(Principal{}, *a));             // No credentials.
  // A share link of alice's session made for a2: it holds only while alice may see a2 (never).
  access.SetShareLookups(nullptr, [&](std::string_view) -> std::optional<ShareGrantInfo> {
    return ShareGrantInfo{"s1", GrantRef{GrantRef::Kind::kUser, "alice"}, a2->id()};
  });
  EXPECT_FALSE(access.Check({GrantRef::Kind::kShare, "s1"}, a2->id()).holds);
  // Made for a: it admits to a, and to nothing else.
  access.SetShareLookups(nullptr, [&](std::string_view) -> std::optional<ShareGrantInfo> {
    return ShareGrantInfo{"s1", GrantRef{GrantRef::Kind::kUser, "alice"}, a->id()};
  });
  EXPECT_TRUE(access.Check({GrantRef::Kind::kShare, "s1"}, a->id()).holds);
  EXPECT_FALSE(access.Check({GrantRef::Kind::kShare, "s1"}, a2->id()).holds);
  const Principal view{Principal::Kind::kView, "", false, "v", ""};
  EXPECT_FALSE(access.MayView(view, *a));  // No view hook.
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
