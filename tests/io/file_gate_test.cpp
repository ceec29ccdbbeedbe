// FileGate: the default gate admits every path as the process may read it; a confined gate admits
// only paths that stay inside its folder while they are resolved component by component
// (symbolic links followed, `..` stepping up), and refuses every other path with one status that
// names nothing, whether what the path names exists or not.
#include "io/file_gate.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

constexpr char kRefusal[] = "permission denied: it refers to a file outside its own folder";

class FileGateTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::MakeTempDir("file-gate");
    own_ = dir_ / "own";
    outside_ = dir_ / "outside";
    fs::create_directories(own_ / "sub");
    fs::create_directories(outside_);
    std::ofstream(own_ / "a.txt") << "inside";
    std::ofstream(outside_ / "secret.txt") << "secret";
    Result<FileGate> gate = FileGate::Within(own_);
    ASSERT_TRUE(gate.ok()) << gate.status().ToString();
    gate_ = *gate;
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Every operation of `gate` on `path` is the one refusal.
  static void ExpectRefused(const FileGate& gate, const fs::path& path) {
    EXPECT_EQ(gate.Resolve(path).status().ToString(), kRefusal) << path;
    EXPECT_EQ(gate.Type(path).status().ToString(), kRefusal) << path;
    EXPECT_EQ(gate.OpenForReading(path).status().ToString(), kRefusal) << path;
    EXPECT_EQ(gate.ReadSmallFile(path, 1 << 20).status().ToString(), kRefusal) << path;
  }

  static std::string Read(const FileGate& gate, const fs::path& path) {
    Result<std::string> text = gate.ReadSmallFile(path, 1 << 20);
    EXPECT_TRUE(text.ok()) << path << ": " << text.status().ToString();
    return text.ok() ? *text : std::string();
  }

  fs::path dir_, own_, outside_;
  FileGate gate_;
};

TEST_F(FileGateTest, DefaultGateAdmitsEveryPath) {
  const FileGate open;
  EXPECT_FALSE(open.confined());
  EXPECT_TRUE(gate_.confined());
  EXPECT_EQ(*open.Resolve(own_ / ".." / "outside" / "secret.txt"),
            own_ / ".." / "outside" / "secret.txt");
  EXPECT_EQ(Read(open, own_ / ".." / "outside" / "secret.txt"), "secret");
  EXPECT_EQ(*open.Type(outside_), fs::file_type::directory);
  EXPECT_EQ(*open.Type(outside_ / "none"), fs::file_type::not_found);
  EXPECT_EQ(open.OpenForReading(outside_ / "none").status().ToString(),
            "not found: " + (outside_ / "none").string() + ": no such file");
  EXPECT_EQ(open.OpenForReading(outside_).status().ToString(),
            "unsupported: " + outside_.string() + ": not a regular file");
}

TEST_F(FileGateTest, PathsInsideResolveAndOpen) {
  const fs::path real = fs::canonical(own_);
  EXPECT_EQ(*gate_.Resolve(own_ / "a.txt"), real / "a.txt");
  EXPECT_EQ(*gate_.Resolve(own_ / "sub" / ".." / "." / "a.txt"), real / "a.txt");
  EXPECT_EQ(*gate_.Resolve(own_), real);
  EXPECT_EQ(Read(gate_, own_ / "sub" / ".." / "a.txt"), "inside");
  EXPECT_EQ(*gate_.Type(own_ / "sub"), fs::file_type::directory);
  EXPECT_EQ(*gate_.Type(own_ / "a.txt"), fs::file_type::regular);
  // What is missing inside is reported precisely: it is the dataset's own business.
  EXPECT_EQ(*gate_.Type(own_ / "none" / "x"), fs::file_type::not_found);
  EXPECT_EQ(*gate_.Resolve(own_ / "none" / "x"), real / "none" / "x");
  EXPECT_EQ(gate_.OpenForReading(own_ / "none").status().ToString(),
            "not found: " + (own_ / "none").string() + ": no such file");
  EXPECT_EQ(gate_.OpenForReading(own_ / "a.txt" / "x").status().code(), StatusCode::kNotFound);
  EXPECT_EQ(gate_.OpenForReading(own_ / "sub").status().ToString(),
            "unsupported: " + (own_ / "sub").string() + ": not a regular file");
}

TEST_F(FileGateTest, PathsOutOfTheFolderAreRefusedAlikeWhetherOrNotTheyExist) {
  for (const fs::path& path : {own_ / ".." / "outside" / "secret.txt",
                               own_ / ".." / "outside" / "none.txt", outside_ / "secret.txt",
                               outside_ / "none.txt", own_ / "sub" / ".." / ".." / "own" / "a.txt",
                               own_ / "none" / ".." / ".." / "outside" / "secret.txt",
                               fs::path("/etc/passwd"), fs::path("/no/such/file"), dir_}) {
    ExpectRefused(gate_, path);
  }
}

TEST_F(FileGateTest, LinksAreFollowedWhileTheyStayInside) {
  fs::create_symlink("a.txt", own_ / "relative");
  fs::create_symlink(own_ / "a.txt", own_ / "absolute");
  fs::create_symlink("../relative", own_ / "sub" / "chain");
  fs::create_directory_symlink("sub", own_ / "subl");
  EXPECT_EQ(Read(gate_, own_ / "relative"), "inside");
  EXPECT_EQ(Read(gate_, own_ / "absolute"), "inside");
  EXPECT_EQ(Read(gate_, own_ / "sub" / "chain"), "inside");
  // ".." after a link steps up from where the link leads, as the kernel resolves it.
  EXPECT_EQ(Read(gate_, own_ / "subl" / ".." / "a.txt"), "inside");
  EXPECT_EQ(*gate_.Resolve(own_ / "subl" / "chain"), fs::canonical(own_) / "a.txt");

  fs::create_symlink("../outside/secret.txt", own_ / "out");
  fs::create_symlink("../outside/none.txt", own_ / "out-missing");
  fs::create_symlink(outside_ / "secret.txt", own_ / "abs-out");
  fs::create_symlink(outside_ / "none.txt", own_ / "abs-out-missing");
  fs::create_directory_symlink("../outside", own_ / "dir-out");
  fs::create_symlink("../out", own_ / "sub" / "via");
  for (const fs::path& path :
       {own_ / "out", own_ / "out-missing", own_ / "abs-out", own_ / "abs-out-missing",
        own_ / "dir-out" / "secret.txt", own_ / "dir-out" / "none.txt", own_ / "dir-out",
        // Nothing beyond the link is looked at, even a way back in.
        own_ / "dir-out" / ".." / "own" / "a.txt", own_ / "sub" / "via"}) {
    ExpectRefused(gate_, path);
  }
  fs::create_symlink("loop2", own_ / "loop1");
  fs::create_symlink("loop1", own_ / "loop2");
  EXPECT_EQ(gate_.OpenForReading(own_ / "loop1").status().code(), StatusCode::kIoError);
}

TEST_F(FileGateTest, TheFolderMayBeSpelledThroughALink) {
  fs::create_directory_symlink(own_, dir_ / "alias");
  Result<FileGate> gate = FileGate::Within(dir_ / "alias");
  ASSERT_TRUE(gate.ok());
  EXPECT_EQ(Read(*gate, dir_ / "alias" / "a.txt"), "inside");
  EXPECT_EQ(Read(*gate, own_ / "a.txt"), "inside");
  fs::create_symlink(dir_ / "alias" / "a.txt", own_ / "via-alias");
  EXPECT_EQ(Read(*gate, own_ / "via-alias"), "inside");
  ExpectRefused(*gate, dir_ / "alias" / ".." / "outside" / "secret.txt");
}

TEST_F(FileGateTest, AFolderReplacedByALinkLaterIsRefused) {
  std::ofstream(own_ / "sub" / "x.txt") << "x";
  Result<FileGate> gate = FileGate::Within(own_ / "sub");
  ASSERT_TRUE(gate.ok());
  EXPECT_EQ(Read(*gate, own_ / "sub" / "x.txt"), "x");
  fs::rename(own_ / "sub", own_ / "sub.old");
  fs::create_directory_symlink("../outside", own_ / "sub");
  ExpectRefused(*gate, own_ / "sub" / "secret.txt");
  ExpectRefused(*gate, own_ / "sub" / "x.txt");
  // A folder that is gone: nothing is there.
  fs::remove(own_ / "sub");
  EXPECT_EQ(*gate->Type(own_ / "sub" / "x.txt"), fs::file_type::not_found);
}

TEST_F(FileGateTest, APinnedGateResolvesFromTheFolderItHolds) {
  std::ofstream(own_ / "sub" / "x.txt") << "x";
  Result<FileGate> gate = FileGate::Within(own_ / "sub");
  ASSERT_TRUE(gate.ok());
  Result<FileGate> pinned = gate->Pinned();
  ASSERT_TRUE(pinned.ok()) << pinned.status().ToString();
  EXPECT_EQ(Read(*pinned, own_ / "sub" / "x.txt"), "x");
  ExpectRefused(*pinned, own_ / "sub" / ".." / "a.txt");
  // Moved and replaced by a link out: the pinned gate still reads the folder it holds.
  fs::rename(own_ / "sub", own_ / "moved");
  fs::create_directory_symlink("../outside", own_ / "sub");
  EXPECT_EQ(Read(*pinned, own_ / "sub" / "x.txt"), "x");
  EXPECT_EQ(*pinned->Type(own_ / "sub" / "secret.txt"), fs::file_type::not_found);
  ExpectRefused(*gate, own_ / "sub" / "x.txt");
  EXPECT_EQ(gate->Pinned().status().ToString(), kRefusal);
  EXPECT_FALSE(FileGate().Pinned()->confined());
}

TEST_F(FileGateTest, AFifoIsNotARegularFileAndNeverBlocks) {
  ASSERT_EQ(::mkfifo((own_ / "fifo").c_str(), 0600), 0);
  EXPECT_EQ(gate_.OpenForReading(own_ / "fifo").status().code(), StatusCode::kUnsupported);
  EXPECT_EQ(FileGate().OpenForReading(own_ / "fifo").status().code(), StatusCode::kUnsupported);
  EXPECT_EQ(*gate_.Type(own_ / "fifo"), fs::file_type::fifo);
}

TEST_F(FileGateTest, ADatasetIsConfinedToItsOwnFolder) {
  // A file: the folder holding it.
  Result<FileGate> file = FileGate::ForDataset(own_ / "a.txt");
  ASSERT_TRUE(file.ok());
  EXPECT_EQ(Read(*file, own_ / "a.txt"), "inside");
  EXPECT_EQ(*file->Type(own_ / "sub"), fs::file_type::directory);
  ExpectRefused(*file, outside_ / "secret.txt");
  // A folder: the folder itself.
  std::ofstream(own_ / "sub" / "x.txt") << "x";
  Result<FileGate> folder = FileGate::ForDataset(own_ / "sub");
  ASSERT_TRUE(folder.ok());
  EXPECT_EQ(Read(*folder, own_ / "sub" / "x.txt"), "x");
  ExpectRefused(*folder, own_ / "a.txt");
  // A file that is a link: within the folder it really is in, which must be the folder it is
  // listed in.
  fs::create_symlink("a.txt", own_ / "same-folder");
  Result<FileGate> linked = FileGate::ForDataset(own_ / "same-folder");
  ASSERT_TRUE(linked.ok());
  EXPECT_EQ(Read(*linked, own_ / "same-folder"), "inside");
  for (const char* target : {"../outside/secret.txt", "../outside/none.txt", "sub/x.txt"}) {
    const fs::path link = own_ / ("to-" + fs::path(target).filename().string());
    fs::create_symlink(target, link);
    Result<FileGate> elsewhere = FileGate::ForDataset(link);
    ASSERT_TRUE(elsewhere.ok());
    ExpectRefused(*elsewhere, link);
  }
}

TEST(OutsideFolderError, NamesOnlyTheDataset) {
  const Status refusal = OutsideFolderError();
  EXPECT_TRUE(IsOutsideFolderError(refusal));
  EXPECT_EQ(refusal.message(), kOutsideFolderMessage);
  EXPECT_EQ(OutsideFolderErrorOf(refusal.WithContext("/d/own/x.tif: (plane z 3)"), "/d/own/a.ome")
                .ToString(),
            "permission denied: /d/own/a.ome: it refers to a file outside its own folder");
  const Status other = NotFoundError("/d/own/b.tif: no such file");
  EXPECT_FALSE(IsOutsideFolderError(other));
  EXPECT_EQ(OutsideFolderErrorOf(other, "/d/own/a.ome").ToString(), other.ToString());
}

}  // namespace
}  // namespace octoscope::io
