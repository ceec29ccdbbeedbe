#include "net/static_files.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

namespace octoscope::net {
namespace {

namespace fs = std::filesystem;

TEST(StaticFilesTest, MimeTypesByExtension) {
  EXPECT_EQ(MimeTypeFor("/a/index.html"), "text/html; charset=utf-8");
  EXPECT_EQ(MimeTypeFor("x.HTML"), "text/html; charset=utf-8");
  EXPECT_EQ(MimeTypeFor("app.js"), "text/javascript; charset=utf-8");
  EXPECT_EQ(MimeTypeFor("mod.mjs"), "text/javascript; charset=utf-8");
  EXPECT_EQ(MimeTypeFor("s.css"), "text/css; charset=utf-8");
  EXPECT_EQ(MimeTypeFor("i.png"), "image/png");
  EXPECT_EQ(MimeTypeFor("i.svg"), "image/svg+xml");
  EXPECT_EQ(MimeTypeFor("d.json"), "application/json");
  EXPECT_EQ(MimeTypeFor("f.woff2"), "font/woff2");
  EXPECT_EQ(MimeTypeFor("m.wasm"), "application/wasm");
  EXPECT_EQ(MimeTypeFor("README"), "application/octet-stream");
  EXPECT_EQ(MimeTypeFor("archive.js.gz"), "application/octet-stream");
}

TEST(StaticFilesTest, EtagMatching) {
  EXPECT_TRUE(EtagMatches("\"1-2\"", "\"1-2\""));
  EXPECT_TRUE(EtagMatches("W/\"1-2\"", "\"1-2\""));
  EXPECT_TRUE(EtagMatches("\"a\", \"1-2\" ,\"b\"", "\"1-2\""));
  EXPECT_TRUE(EtagMatches("*", "\"1-2\""));
  EXPECT_FALSE(EtagMatches("", "\"1-2\""));
  EXPECT_FALSE(EtagMatches("\"1-3\"", "\"1-2\""));
  EXPECT_FALSE(EtagMatches("1-2", "\"1-2\""));
}

class ResolveTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("octoscope-static-" + std::to_string(getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "web" / "sub");
    Write(dir_ / "web" / "index.html", "<html>");
    Write(dir_ / "web" / "sub" / "index.html", "<sub>");
    Write(dir_ / "web" / "sub" / "a.js", "1234567");
    Write(dir_ / "web" / ".env", "x");
    Write(dir_ / "secret", "s");
    fs::create_symlink(dir_ / "secret", dir_ / "web" / "out");
    fs::create_symlink(dir_ / "web" / "sub" / "a.js", dir_ / "web" / "in.js");
    root_ = fs::canonical(dir_ / "web");
  }
  void TearDown() override { fs::remove_all(dir_); }
  static void Write(const fs::path& p, const std::string& s) { std::ofstream(p) << s; }

  fs::path dir_, root_;
};

TEST_F(ResolveTest, MapsPathsBelowTheRoot) {
  auto index = ResolveStaticFile(root_, "/");
  ASSERT_TRUE(index.has_value());
  EXPECT_EQ(index->path, root_ / "index.html");
  EXPECT_EQ(index->size, 6u);
  auto sub = ResolveStaticFile(root_, "/sub/");
  ASSERT_TRUE(sub.has_value());
  EXPECT_EQ(sub->path, root_ / "sub" / "index.html");
  auto js = ResolveStaticFile(root_, "/sub/a.js");
  ASSERT_TRUE(js.has_value());
  EXPECT_EQ(js->size, 7u);
  EXPECT_EQ(js->etag.front(), '"');
  EXPECT_EQ(js->etag.back(), '"');
  // A symbolic link that stays inside the root is followed.
  auto link = ResolveStaticFile(root_, "/in.js");
  ASSERT_TRUE(link.has_value());
  EXPECT_EQ(link->path, root_ / "sub" / "a.js");
  EXPECT_EQ(link->etag, js->etag);
}

TEST_F(ResolveTest, RefusesEverythingElse) {
  for (const char* path : {"", "index.html", "/../secret", "/sub/../index.html", "/./index.html",
                           "//index.html", "/sub//a.js", "/.env", "/out", "/sub", "/missing",
                           "/sub/a.js/", "/sub\\a.js", "/\x01"}) {
    EXPECT_FALSE(ResolveStaticFile(root_, path).has_value()) << path;
  }
}

}  // namespace
}  // namespace octoscope::net
