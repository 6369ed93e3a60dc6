// The command-line wrapper against what its callers rely on: values land in the bound variables,
// each check refuses what it must (exit status 2, nothing assigned silently), given() tells an
// option typed on the command line from a default, subcommands parse their own options.
#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <vector>

#include "storetrack/cli/command_line.hpp"

namespace {

using storetrack::cli::Command;
using storetrack::cli::kExitUsage;

// parse() takes argv as a C program gets it.
int parse(Command& cmd, std::vector<std::string> words) {
  words.insert(words.begin(), "prog");
  std::vector<char*> argv;
  for (std::string& w : words)
    argv.push_back(w.data());
  return cmd.parse(static_cast<int>(argv.size()), argv.data());
}

TEST(CommandLine, ValuesOfEachTypeReachTheirVariables) {
  Command cmd{"test"};
  std::string name;
  double rate = 0;
  int count = 0;
  std::uint8_t camera = 0;
  std::uint64_t seed = 0;
  std::vector<unsigned> lines;
  std::vector<std::string> udp;
  bool verbose = false;
  cmd.option("--name", name, "");
  cmd.option("--rate", rate, "");
  cmd.option("-n,--count", count, "");
  cmd.option("--camera", camera, "");
  cmd.option("--seed", seed, "");
  cmd.option("--lines", lines, "").delimiter(',');
  cmd.option("--udp", udp, "");
  cmd.flag("-v,--verbose", verbose, "");
  ASSERT_EQ(parse(cmd, {"--name", "a b", "--rate", "2.5e2", "-n", "-7", "--camera", "254", "--seed",
                        "18446744073709551615", "--lines", "1,2,3", "--udp", "x:1", "--udp", "y:2",
                        "-v"}),
            -1);
  EXPECT_EQ(name, "a b");
  EXPECT_EQ(rate, 250.0);
  EXPECT_EQ(count, -7);
  EXPECT_EQ(camera, 254);
  EXPECT_EQ(seed, UINT64_MAX);
  EXPECT_EQ(lines, (std::vector<unsigned>{1, 2, 3}));
  EXPECT_EQ(udp, (std::vector<std::string>{"x:1", "y:2"}));
  EXPECT_TRUE(verbose);
  EXPECT_TRUE(cmd.given("--rate"));
  EXPECT_TRUE(cmd.given("--count"));
}

TEST(CommandLine, AnOptionNotTypedIsNotGivenAndKeepsItsDefault) {
  Command cmd{"test"};
  double rate = 50;
  cmd.option("--rate", rate, "").show_default();
  ASSERT_EQ(parse(cmd, {}), -1);
  EXPECT_FALSE(cmd.given("--rate"));
  EXPECT_EQ(rate, 50.0);
}

TEST(CommandLine, EachCheckRefusesWhatItMust) {
  struct Case {
    const char* what;
    std::vector<std::string> words;
  };
  const std::vector<Case> refused = {
      {"integer above range", {"--camera", "256"}},
      {"integer below range", {"--camera", "-1"}},
      {"real above range", {"--p", "0.51"}},
      {"zero for positive", {"--rate", "0"}},
      {"negative for non-negative", {"--start", "-1"}},
      {"not a member", {"--mode", "xml"}},
      {"missing file", {"--file", "/nonexistent/storetrack"}},
      {"a file for a directory", {"--dir", "/proc/self/status"}},
      {"two values for three", {"--step", "1,2"}},
      {"not a number", {"--rate", "fast"}},
      {"unknown option", {"--bogus"}},
  };
  for (const Case& c : refused) {
    Command cmd{"test"};
    int camera = 0, start = 0;
    double p = 0, rate = 1;
    std::string mode = "csv", file, dir;
    std::vector<long> step;
    cmd.option("--camera", camera, "").range(0, 255);
    cmd.option("--p", p, "").range(0.0, 0.5);
    cmd.option("--rate", rate, "").positive();
    cmd.option("--start", start, "").non_negative();
    cmd.option("--mode", mode, "").one_of({"csv", "json"});
    cmd.option("--file", file, "").existing_file();
    cmd.option("--dir", dir, "").existing_directory();
    cmd.option("--step", step, "").delimiter(',').expected(3);
    EXPECT_EQ(parse(cmd, c.words), kExitUsage) << c.what;
  }
}

TEST(CommandLine, RequiredOptionsAndHelp) {
  {
    Command cmd{"test"};
    std::string out;
    cmd.option("--out", out, "").required();
    EXPECT_EQ(parse(cmd, {}), kExitUsage);
  }
  {
    Command cmd{"test"};
    std::string out;
    cmd.option("--out", out, "").required();
    EXPECT_EQ(parse(cmd, {"--help"}), 0);
  }
}

TEST(CommandLine, SubcommandsParseTheirOwnOptions) {
  Command cmd{"test"};
  cmd.require_subcommand(1);
  int a = 0, b = 0;
  Command& run = cmd.subcommand("run", "");
  run.option("--a", a, "");
  Command& snap = cmd.subcommand("snap", "");
  snap.option("--b", b, "");
  ASSERT_EQ(parse(cmd, {"snap", "--b", "3"}), -1);
  EXPECT_TRUE(snap.parsed());
  EXPECT_FALSE(run.parsed());
  EXPECT_TRUE(cmd.got_subcommand("snap"));
  EXPECT_TRUE(snap.given("--b"));
  EXPECT_EQ(b, 3);

  Command none{"test"};
  none.require_subcommand(1);
  none.subcommand("run", "");
  EXPECT_EQ(parse(none, {}), kExitUsage);
}

}  // namespace
