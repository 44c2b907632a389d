// `binpick calib` end to end: a cell on disk, a full auto calibration over the
// DaoAI socket against the simulator, the printed error vs the true transform,
// the result file the next run's cell load picks up.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <regex>
#include <string>

#include "tests/testing/files.h"
#include "tests/testing/run_command.h"

namespace bp {
namespace {

// The default cell, saved in `dir` with absolute asset paths.
std::string WriteDefaultCell(const std::string& dir) {
  std::string yaml = testing::ReadBytes(std::string(BINPICK_SOURCE_DIR) + "/assets/cells/default.yaml");
  const std::string assets = std::string(BINPICK_SOURCE_DIR) + "/assets/";
  for (size_t at = yaml.find("../"); at != std::string::npos; at = yaml.find("../", at)) {
    yaml.replace(at, 3, assets);
  }
  const std::string path = dir + "/cell.yaml";
  testing::WriteText(path, yaml);
  return path;
}

TEST(CalibCli, AutoCalibrationPrintsItsErrorAgainstTheTruth) {
  const std::string dir = testing::FreshDir("cli");
  const std::string cell = WriteDefaultCell(dir);
  const std::string binpick = std::string(BINPICK_BINARY_DIR) + "/bin/binpick";
  const test::CommandRun run =
      test::RunCommand(binpick + " calib --cell " + cell + " --flow auto --precision-checks 5");
  ASSERT_EQ(run.exit_code, 0) << run.out;
  std::smatch m;
  const std::regex error_line(R"(error vs true X_BC: ([0-9.]+) mm, ([0-9.]+) deg)");
  ASSERT_TRUE(std::regex_search(run.out, m, error_line)) << run.out;
  EXPECT_LT(std::stod(m[1]), 0.5) << run.out;
  EXPECT_LT(std::stod(m[2]), 0.05) << run.out;
  const std::regex precision_line(R"(5 checks after the defining one: mean ([0-9.]+) mm, max ([0-9.]+) mm)");
  ASSERT_TRUE(std::regex_search(run.out, m, precision_line)) << run.out;
  EXPECT_LT(std::stod(m[2]), 0.1) << run.out;
  EXPECT_TRUE(std::filesystem::exists(cell + ".calibration.yaml"));
  // The second run starts from the saved calibration (the cell loads it).
  const test::CommandRun again = test::RunCommand(binpick + " calib --cell " + cell + " --flow manual --version 1");
  ASSERT_EQ(again.exit_code, 0) << again.out;
  const std::regex nominal(R"(nominal pose was ([0-9.]+) mm)");
  ASSERT_TRUE(std::regex_search(again.out, m, nominal)) << again.out;
  EXPECT_LT(std::stod(m[1]), 0.5) << again.out;  // was 4 mm before calibrating
  EXPECT_TRUE(std::filesystem::exists(cell + ".calibration.yaml.bak"));
}

TEST(CalibCli, ACellWithoutCalibrationSectionIsBadInput) {
  const std::string dir = testing::FreshDir("nocal");
  std::string yaml = testing::ReadBytes(WriteDefaultCell(dir));
  const size_t from = yaml.find("calibration:\n");
  const size_t to = yaml.find("\nsource:");
  ASSERT_NE(from, std::string::npos);
  yaml.erase(from, to - from);
  testing::WriteText(dir + "/cell.yaml", yaml);
  const test::CommandRun run = test::RunCommand(std::string(BINPICK_BINARY_DIR) + "/bin/binpick calib --cell " + dir +
                                                "/cell.yaml --flow auto");
  EXPECT_EQ(run.exit_code, 2) << run.out;
  EXPECT_NE(run.out.find("no calibration section"), std::string::npos) << run.out;
}

}  // namespace
}  // namespace bp
