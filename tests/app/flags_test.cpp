#include "app/flags.h"

#include <gtest/gtest.h>

namespace octoscope::app {
namespace {

Flags MakeFlags() {
  Flags flags("tool INPUT", "Does things.");
  flags.SetPositionals("INPUT", 1, 1);
  flags.AddSwitch("json", "print JSON");
  flags.AddValue("series", "N", "which series", "0");
  flags.AddValue("scale", "F", "a factor");
  return flags;
}

TEST(FlagsTest, ParsesSwitchesValuesAndPositionals) {
  Flags flags = MakeFlags();
  std::vector<std::string> args = {"--json", "in.tif", "--series", "3", "--scale=0.5"};
  ASSERT_TRUE(flags.Parse(args).ok());
  EXPECT_TRUE(flags.Has("json"));
  EXPECT_EQ(*flags.GetInt("series", 0, 0, 10), 3);
  EXPECT_DOUBLE_EQ(*flags.GetDouble("scale", 1), 0.5);
  EXPECT_EQ(flags.positionals(), std::vector<std::string>{"in.tif"});
}

TEST(FlagsTest, CommandIsTheUsageLinesFirstTwoWords) {
  EXPECT_EQ(Flags("octoscope info INPUT [--json]", "").command(), "octoscope info");
  EXPECT_EQ(Flags("octoscope build", "").command(), "octoscope build");
  EXPECT_EQ(Flags("tool", "").command(), "tool");
}

TEST(FlagsTest, DefaultsWhenAbsent) {
  Flags flags = MakeFlags();
  std::vector<std::string> args = {"in.tif"};
  ASSERT_TRUE(flags.Parse(args).ok());
  EXPECT_FALSE(flags.Has("json"));
  EXPECT_EQ(*flags.GetInt("series", 7, 0, 10), 7);
}

TEST(FlagsTest, RejectsMistakes) {
  for (std::vector<std::string> args :
       std::vector<std::vector<std::string>>{{"in.tif", "--bogus"},     // Unknown flag.
                                             {"in.tif", "--series"},    // Missing value.
                                             {"in.tif", "--json=yes"},  // Switch with value.
                                             {},                        // Missing positional.
                                             {"a.tif", "b.tif"}}) {     // Too many positionals.
    Flags flags = MakeFlags();
    EXPECT_FALSE(flags.Parse(args).ok()) << args.size();
  }
  Flags flags = MakeFlags();
  std::vector<std::string> args = {"in.tif", "--series", "x1", "--scale", "1e999x"};
  ASSERT_TRUE(flags.Parse(args).ok());
  EXPECT_FALSE(flags.GetInt("series", 0, 0, 10).ok());
  EXPECT_FALSE(flags.GetDouble("scale", 0).ok());
  Flags range = MakeFlags();
  std::vector<std::string> big = {"in.tif", "--series", "11"};
  ASSERT_TRUE(range.Parse(big).ok());
  EXPECT_EQ(range.GetInt("series", 0, 0, 10).status().code(), StatusCode::kInvalidArgument);
}

TEST(FlagsTest, HelpListsEveryFlag) {
  Flags flags = MakeFlags();
  std::vector<std::string> args = {"--help"};
  ASSERT_TRUE(flags.Parse(args).ok());
  EXPECT_TRUE(flags.help_requested());
  std::string help = flags.Help();
  for (const char* word :
       {"usage: tool INPUT", "--json", "--series N", "(default: 0)", "--scale F"}) {
    EXPECT_NE(help.find(word), std::string::npos) << word;
  }
}

}  // namespace
}  // namespace octoscope::app
