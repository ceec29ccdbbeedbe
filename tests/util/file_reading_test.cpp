#include "util/file_reading.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace octoscope {
namespace {

namespace fs = std::filesystem;

class FileReadingTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("octoscope-file-reading-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  fs::path Write(const std::string& name, const std::string& content) {
    fs::path path = dir_ / name;
    std::ofstream(path, std::ios::binary) << content;
    return path;
  }

  fs::path dir_;
};

TEST_F(FileReadingTest, ReadFullyReadsAtOffset) {
  std::string content;
  for (int i = 0; i < 5000; ++i) content += static_cast<char>('a' + i % 26);
  const fs::path path = Write("data.bin", content);
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  ASSERT_GE(fd, 0);
  std::vector<std::byte> out(1000);
  ASSERT_TRUE(ReadFully(fd, 1234, out, path.string()).ok());
  for (size_t i = 0; i < out.size(); ++i) {
    ASSERT_EQ(static_cast<char>(out[i]), content[1234 + i]) << i;
  }
  // Exactly up to the end of the file is fine; an empty read anywhere is too.
  std::vector<std::byte> tail(6);
  EXPECT_TRUE(ReadFully(fd, 4994, tail, path.string()).ok());
  EXPECT_EQ(static_cast<char>(tail[5]), content[4999]);
  EXPECT_TRUE(ReadFully(fd, 99999, std::span<std::byte>(), path.string()).ok());
  ::close(fd);
}

TEST_F(FileReadingTest, ReadFullyPastTheEndIsCorruptAndNamesTheFile) {
  const fs::path path = Write("short.bin", "0123456789");
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  ASSERT_GE(fd, 0);
  std::vector<std::byte> out(8);
  Status st = ReadFully(fd, 5, out, path.string());
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  EXPECT_NE(st.message().find(path.string()), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("offset 10"), std::string::npos) << st.message();
  ::close(fd);
}

TEST_F(FileReadingTest, ReadFullyOnABadDescriptorIsAnIoError) {
  // A descriptor open for writing only: pread fails with EBADF.
  const fs::path path = Write("w.bin", "abc");
  const int fd = ::open(path.c_str(), O_WRONLY | O_CLOEXEC);
  ASSERT_GE(fd, 0);
  std::vector<std::byte> out(2);
  Status st = ReadFully(fd, 0, out, "w.bin");
  EXPECT_EQ(st.code(), StatusCode::kIoError);
  EXPECT_NE(st.message().find("w.bin"), std::string::npos) << st.message();
  ::close(fd);
}

TEST_F(FileReadingTest, ReadSmallFileReadsEverything) {
  std::string content = "line one\n";
  content += std::string(3, '\0');  // Binary bytes survive.
  content += "end";
  const fs::path path = Write("a.txt", content);
  Result<std::string> text = ReadSmallFile(path, 100);
  ASSERT_TRUE(text.ok()) << text.status().ToString();
  EXPECT_EQ(*text, content);
  EXPECT_EQ(*ReadSmallFile(Write("empty.txt", ""), 0), "");
  // Exactly at the limit is allowed.
  EXPECT_TRUE(ReadSmallFile(path, content.size()).ok());
}

TEST_F(FileReadingTest, ReadSmallFileErrors) {
  const fs::path big = Write("big.txt", std::string(101, 'x'));
  Result<std::string> r = ReadSmallFile(big, 100);
  EXPECT_EQ(r.status().code(), StatusCode::kResourceExhausted);
  EXPECT_NE(r.status().message().find("big.txt"), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("101"), std::string::npos) << r.status().message();

  r = ReadSmallFile(dir_ / "missing.txt", 100);
  EXPECT_EQ(r.status().code(), StatusCode::kNotFound);
  EXPECT_NE(r.status().message().find("missing.txt"), std::string::npos) << r.status().message();

  r = ReadSmallFile(dir_, 100);  // A folder.
  EXPECT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find(dir_.string()), std::string::npos) << r.status().message();
}

}  // namespace
}  // namespace octoscope
