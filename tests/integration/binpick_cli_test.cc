// Runs the built binpick binary (build/bin/binpick) as a user would.
#include <sys/wait.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "pipeline/frame_io.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

struct RunResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr
};

RunResult RunBinpick(const std::string& args) {
  const std::string binary = std::string(BINPICK_BINARY_DIR) + "/bin/binpick";
  RunResult r;
  if (!fs::exists(binary)) {
    r.output = "binpick binary not built: " + binary;
    return r;
  }
  FILE* pipe = popen((binary + " " + args + " 2>&1").c_str(), "r");
  if (!pipe) return r;
  char buf[4096];
  size_t n = 0;
  while ((n = fread(buf, 1, sizeof(buf), pipe)) > 0) r.output.append(buf, n);
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

std::string FreshDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::temp_directory_path() / "binpick_tests" / (std::string("cli.") + info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

TEST(BinpickCli, HelpListsSubcommands) {
  const RunResult r = RunBinpick("--help");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_THAT(r.output, HasSubstr("render"));
  EXPECT_THAT(r.output, HasSubstr("info"));
}

TEST(BinpickCli, UnknownSubcommandPrintsUsageAndFails) {
  const RunResult r = RunBinpick("frobnicate");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_THAT(r.output, HasSubstr("render"));  // usage lists the real subcommands
}

TEST(BinpickCli, InfoOnTruncatedCloudFailsWithBadInputNamingTheFile) {
  const std::string dir = FreshDir();
  const std::string path = dir + "/broken_cloud.pcd";
  std::ofstream(path) << "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                         "WIDTH 100\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100\nDATA binary\nxyz";
  const RunResult r = RunBinpick("info " + path);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_THAT(r.output, HasSubstr("broken_cloud.pcd"));
  EXPECT_THAT(r.output, HasSubstr("truncated"));
}

TEST(BinpickCli, InfoOnMissingFileFailsWithBadInput) {
  const RunResult r = RunBinpick("info /nonexistent/nothing.pcd");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_THAT(r.output, HasSubstr("nothing.pcd"));
}

TEST(BinpickCli, InfoDescribesMeshesAndCells) {
  const std::string assets = std::string(BINPICK_SOURCE_DIR) + "/assets";
  RunResult r = RunBinpick("info " + assets + "/parts/pipe_tee.ply");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_THAT(r.output, HasSubstr("triangle mesh"));
  r = RunBinpick("info " + assets + "/cells/default.yaml");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_THAT(r.output, HasSubstr("pipe_tee"));
}

TEST(BinpickCli, InfoDescribesAnOrganizedDepthFrame) {
  const std::string dir = FreshDir();
  Frame f;
  f.intrinsics.width = 8;
  f.intrinsics.height = 6;
  f.intrinsics.fx = f.intrinsics.fy = 10;
  f.intrinsics.cx = 3.5;
  f.intrinsics.cy = 2.5;
  f.depth = DepthImage(8, 6, 1.25f);
  f.depth.at(0, 0) = 0.75f;
  ASSERT_TRUE(WriteDepthPng(f, dir + "/depth.png").ok());
  const RunResult r = RunBinpick("info " + dir + "/depth.png");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_THAT(r.output, HasSubstr("organized 8x6"));
  EXPECT_THAT(r.output, HasSubstr("48 valid of 48"));
  EXPECT_THAT(r.output, HasSubstr("0.7500 .. 1.2500 m"));
}

}  // namespace
}  // namespace bp
