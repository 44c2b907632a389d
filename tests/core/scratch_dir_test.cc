// The tests' scratch directories (tests/testing/files.h): each test's
// FreshDir is gone when the test ends, passed or failed, and so is its
// process's root; a dead test process's root is removed by the next test
// process. Checked on a child run of this binary with two DISABLED_ tests
// (they only run when asked for).
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>

#include <gtest/gtest.h>

#include "tests/testing/files.h"
#include "tests/testing/run_command.h"

namespace bp {
namespace {

namespace fs = std::filesystem;

std::string& FirstTestsDir() {
  static std::string dir;
  return dir;
}

// Child run only: writes a file into its FreshDir and a ScratchFile group,
// prints the paths, and fails.
TEST(ScratchDirChild, DISABLED_AFailingTestWritesItsDirectory) {
  FirstTestsDir() = testing::FreshDir("written");
  testing::WriteText(FirstTestsDir() + "/a.txt", "a");
  testing::WriteText(testing::ScratchFile("group", "b.txt"), "b");
  std::cout << "fresh_dir=" << FirstTestsDir() << "\n" << std::flush;
  ADD_FAILURE() << "fails on purpose (child run of ScratchDir tests)";
}

// Child run only, after the test above: its directory is gone already.
TEST(ScratchDirChild, DISABLED_TheNextTestNoLongerSeesIt) {
  ASSERT_FALSE(FirstTestsDir().empty());
  EXPECT_FALSE(fs::exists(FirstTestsDir()));
  EXPECT_TRUE(fs::exists(testing::ScratchRoot() / "group" / "b.txt"));
}

struct ChildRun {
  test::CommandRun run;
  fs::path fresh_dir;  // the failing test's FreshDir, as it printed it
};

ChildRun RunChild(const std::string& env) {
  const fs::path self = fs::read_symlink("/proc/self/exe");
  ChildRun c;
  c.run = test::RunCommand(env + " '" + self.string() +
                           "' --gtest_filter='ScratchDirChild.*' --gtest_also_run_disabled_tests --gtest_brief=0");
  const auto at = c.run.out.find("fresh_dir=");
  if (at != std::string::npos) {
    const auto from = at + std::string("fresh_dir=").size();
    c.fresh_dir = c.run.out.substr(from, c.run.out.find('\n', from) - from);
  }
  return c;
}

// A pid that no process has now: a child that exited and was reaped.
pid_t DeadPid() {
  const pid_t pid = ::fork();
  if (pid == 0) ::_exit(0);
  int status = 0;
  ::waitpid(pid, &status, 0);
  return pid;
}

TEST(ScratchDir, AFailedTestsDirectoryIsRemovedWhenItEndsAndTheRootWhenTheProcessEnds) {
  const ChildRun c = RunChild("env -u BINPICK_KEEP_SCRATCH");
  EXPECT_EQ(c.run.exit_code, 1) << c.run.out;
  EXPECT_NE(c.run.out.find("[  FAILED  ] ScratchDirChild.DISABLED_AFailingTestWritesItsDirectory"), std::string::npos)
      << c.run.out;
  EXPECT_NE(c.run.out.find("[       OK ] ScratchDirChild.DISABLED_TheNextTestNoLongerSeesIt"), std::string::npos)
      << c.run.out;
  ASSERT_FALSE(c.fresh_dir.empty()) << c.run.out;
  EXPECT_FALSE(fs::exists(c.fresh_dir));
  EXPECT_FALSE(fs::exists(c.fresh_dir.parent_path())) << "the child's scratch root";
}

TEST(ScratchDir, TheScratchOfADeadTestProcessIsRemovedByTheNextOne) {
  const fs::path left = fs::temp_directory_path() / ("binpick_tests." + std::to_string(DeadPid()));
  fs::create_directories(left / "Suite.Test.dir");
  testing::WriteText((left / "Suite.Test.dir" / "x").string(), "x");
  const std::string ours = testing::ScratchFile("alive", "x");  // this running process's root
  testing::WriteText(ours, "x");
  RunChild("env -u BINPICK_KEEP_SCRATCH");
  EXPECT_FALSE(fs::exists(left));
  EXPECT_EQ(testing::ReadBytes(ours), "x") << "a running process's scratch stays";
}

TEST(ScratchDir, BinpickKeepScratchKeepsAFailedTestsFiles) {
  const ChildRun c = RunChild("BINPICK_KEEP_SCRATCH=1");
  EXPECT_EQ(c.run.exit_code, 1) << c.run.out;
  ASSERT_FALSE(c.fresh_dir.empty()) << c.run.out;
  EXPECT_EQ(testing::ReadBytes((c.fresh_dir / "a.txt").string()), "a");
  EXPECT_NE(c.run.out.find("scratch files kept in " + c.fresh_dir.string()), std::string::npos) << c.run.out;
  fs::remove_all(c.fresh_dir.parent_path());
}

}  // namespace
}  // namespace bp
