// ViewStore: view links on disk (docs/protocol.md "View links"): saved atomically with mode 0600,
// read back to exactly the saved state, across a reopen; corrupt files are clear errors.
#include "session/view_store.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <set>

#include "render/camera.h"
#include "render/render_params.h"

namespace octoscope::session {
namespace {

namespace fs = std::filesystem;

protocol::ViewState TestState() {
  const render::Box3 bounds = render::PhysicalBounds({40, 30, 20}, render::Vec3{0.5, 0.5, 2});
  auto camera = render::Camera::Standard(render::StandardView::kIso,
                                         render::Projection::kPerspective, bounds, 1, 1);
  EXPECT_TRUE(camera.ok());
  protocol::ViewState state{
      *camera,
      render::DefaultRenderParams(2, volume::DataType::kUint16, render::RenderMode::kDvr),
      {1.25, 2.5, 3.75},
      protocol::ViewId::kY};
  state.params.channels[1].enabled = false;
  state.params.channels[0].window = 1234.5;
  return state;
}

const protocol::ViewLinkGrant kGrant{{protocol::GrantRef::Kind::kUser, "u00000000000000a1"},
                                     {protocol::GrantRef::Kind::kUser, "u00000000000000a1"},
                                     1764072000,
                                     std::nullopt};

// The state a view link reproduces: its parts over any defaults.
protocol::ViewState Reproduce(const protocol::ViewLink& link, const protocol::ViewState& base) {
  protocol::ViewState state = base;
  state.camera = *link.state.camera;
  auto params = protocol::ApplyParams(
      *link.state.params_json,
      render::DefaultRenderParams(2, volume::DataType::kUint16, render::RenderMode::kMip));
  EXPECT_TRUE(params.ok()) << params.status().ToString();
  state.params = *params;
  state.slice_position_um = *link.state.slice_position_um;
  state.maximized = link.state.layout->maximized;
  return state;
}

class ViewStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("octoscope-view-store-" + std::to_string(getpid()));
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(ViewStoreTest, SavedViewsReadBackExactlyAfterAReopen) {
  const protocol::ViewState state = TestState();
  std::string id;
  {
    auto store = ViewStore::Open(dir_);
    ASSERT_TRUE(store.ok()) << store.status().ToString();
    auto saved = (*store)->Save("embryo-1", state, kGrant);
    ASSERT_TRUE(saved.ok()) << saved.status().ToString();
    id = *saved;
    EXPECT_TRUE(std::regex_match(id, std::regex("[A-Za-z0-9_-]{22}")));
    EXPECT_TRUE((*store)->Find(id).has_value());
  }
  struct stat st {};
  ASSERT_EQ(::stat((dir_ / "views" / (id + ".json")).c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  ASSERT_EQ(::stat((dir_ / "views").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0700u);
  EXPECT_FALSE(fs::exists(dir_ / "views" / (id + ".json.tmp")));

  auto store = ViewStore::Open(dir_);
  ASSERT_TRUE(store.ok());
  // The index holds the dataset and grant of every link, read back at Open.
  const auto entry = (*store)->Find(id);
  ASSERT_TRUE(entry.has_value());
  EXPECT_EQ(entry->dataset, "embryo-1");
  ASSERT_TRUE(entry->grant.has_value());
  EXPECT_EQ(entry->grant->creator, kGrant.creator);
  EXPECT_EQ(entry->grant->created_unix_s, kGrant.created_unix_s);
  EXPECT_EQ((*store)->OwnedBy(kGrant.owner), 1u);
  EXPECT_EQ((*store)->OwnedBy({protocol::GrantRef::Kind::kUser, "other"}), 0u);
  auto link = (*store)->Load(id);
  ASSERT_TRUE(link.ok()) << link.status().ToString();
  EXPECT_EQ(link->dataset, "embryo-1");
  auto text = (*store)->LoadText(id);
  ASSERT_TRUE(text.ok());
  EXPECT_EQ(*text, protocol::ViewLinkJson("embryo-1", state, kGrant));
  // The state a session opens from the link reads exactly as stored (the camera canonical).
  const protocol::ViewState reopened = Reproduce(*link, state);
  EXPECT_EQ(protocol::ViewLinkJson("embryo-1", reopened, kGrant), *text);
  EXPECT_NE(text->find(protocol::StateJson(reopened)), std::string::npos);
  // Everything but the camera's last digits is the saved state itself.
  protocol::ViewState expected = state;
  expected.camera = reopened.camera;
  EXPECT_EQ(protocol::StateJson(reopened), protocol::StateJson(expected));
  EXPECT_NEAR(reopened.camera.position().x, state.camera.position().x, 1e-9);
  EXPECT_NEAR(reopened.camera.forward().y, state.camera.forward().y, 1e-12);
}

TEST_F(ViewStoreTest, IdsAreRandomAndUnknownOnesAreNotFound) {
  auto store = ViewStore::Open(dir_);
  ASSERT_TRUE(store.ok());
  std::set<std::string> ids;
  for (int i = 0; i < 50; ++i) ids.insert(*(*store)->Save("d", TestState(), kGrant));
  EXPECT_EQ(ids.size(), 50u);
  EXPECT_EQ((*store)->List().size(), 50u);
  EXPECT_EQ((*store)->OwnedBy(kGrant.owner), 50u);
  EXPECT_EQ((*store)->Load("AAAAAAAAAAAAAAAAAAAAAA").status().code(), StatusCode::kNotFound);
  EXPECT_EQ((*store)->Load("../../../etc/passwd").status().code(), StatusCode::kNotFound);
  EXPECT_FALSE((*store)->Find("../x").has_value());
}

TEST_F(ViewStoreTest, DeletedViewsAreGoneFromDiskAndIndexAcrossAReopen) {
  auto store = ViewStore::Open(dir_);
  ASSERT_TRUE(store.ok());
  const std::string keep = *(*store)->Save("d", TestState(), kGrant);
  const std::string gone = *(*store)->Save("d", TestState(), kGrant);
  ASSERT_TRUE((*store)->Delete(gone).ok());
  EXPECT_FALSE((*store)->Find(gone).has_value());
  EXPECT_EQ((*store)->Load(gone).status().code(), StatusCode::kNotFound);
  EXPECT_FALSE(fs::exists(dir_ / "views" / (gone + ".json")));
  EXPECT_EQ((*store)->Delete(gone).code(), StatusCode::kNotFound);
  EXPECT_EQ((*store)->Delete("../../x").code(), StatusCode::kNotFound);
  auto again = ViewStore::Open(dir_);
  ASSERT_TRUE(again.ok());
  EXPECT_TRUE((*again)->Find(keep).has_value());
  EXPECT_FALSE((*again)->Find(gone).has_value());
}

TEST_F(ViewStoreTest, CorruptFilesAreClearErrors) {
  fs::create_directories(dir_ / "views");
  const std::string truncated = "AAAAAAAAAAAAAAAAAAAAAA", partial = "BBBBBBBBBBBBBBBBBBBBBB",
                    huge = "CCCCCCCCCCCCCCCCCCCCCC", future = "DDDDDDDDDDDDDDDDDDDDDD";
  std::ofstream(dir_ / "views" / (truncated + ".json")) << "{\"version\":1,\"data";
  std::ofstream(dir_ / "views" / (partial + ".json"))
      << R"({"version":1,"dataset":"d","state":{"layout":{"maximized":null}}})";
  std::ofstream(dir_ / "views" / (huge + ".json")) << std::string(kMaxViewDocumentBytes + 1, ' ');
  std::string next_version = protocol::ViewLinkJson("d", TestState(), kGrant);
  next_version[11] = '3';  // {"version":3,...
  std::ofstream(dir_ / "views" / (future + ".json")) << next_version;
  auto store = ViewStore::Open(dir_);
  ASSERT_TRUE(store.ok());
  for (const std::string& id : {truncated, partial, huge, future}) {
    EXPECT_TRUE((*store)->Find(id).has_value());
    EXPECT_FALSE((*store)->Find(id)->grant.has_value());
    auto link = (*store)->Load(id);
    ASSERT_FALSE(link.ok()) << id;
    EXPECT_EQ(link.status().code(), StatusCode::kCorrupt) << link.status().ToString();
    EXPECT_NE(link.status().message().find(id), std::string::npos) << link.status().message();
  }
  EXPECT_NE((*store)->Load(partial).status().message().find("camera"), std::string::npos);
  EXPECT_NE((*store)->Load(future).status().message().find("version"), std::string::npos);
}

TEST_F(ViewStoreTest, AStateFolderThatCannotBeCreatedIsAnError) {
  fs::create_directories(dir_);
  std::ofstream(dir_ / "file") << "x";
  auto store = ViewStore::Open(dir_ / "file");
  ASSERT_FALSE(store.ok());
  EXPECT_NE(store.status().message().find("file"), std::string::npos);
}

}  // namespace
}  // namespace octoscope::session
