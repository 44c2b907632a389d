#include "core/atomic_file.h"

#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "tests/testing/files.h"

namespace bp {
namespace {

using testing::FreshDir;
using testing::ReadBytes;

TEST(AtomicFile, WritesANewFileWithTheRequestedMode) {
  const std::string path = FreshDir("new") + "/calib.yaml";
  AtomicWriteOptions o;
  o.mode = 0600;
  ASSERT_TRUE(WriteFileAtomic(path, "a: 1\n", o).ok());
  EXPECT_EQ(ReadBytes(path), "a: 1\n");
  struct stat st{};
  ASSERT_EQ(::stat(path.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  EXPECT_FALSE(std::filesystem::exists(AtomicTempPath(path)));
  EXPECT_FALSE(std::filesystem::exists(AtomicBackupPath(path)));
}

// docs/reliability.md "Security": calibrations, taught grasps and
// recordings are not world-readable, even when they replace a file that was.
TEST(AtomicFile, DefaultModeIsNotWorldReadableAndReplacesAWiderMode) {
  const std::string path = FreshDir("mode") + "/hand_eye.yaml";
  const mode_t old_mask = ::umask(022);
  { std::ofstream(path) << "old\n"; }
  ASSERT_EQ(::chmod(path.c_str(), 0666), 0);
  ASSERT_TRUE(WriteFileAtomic(path, "new\n").ok());
  ::umask(old_mask);
  struct stat st{};
  ASSERT_EQ(::stat(path.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0640u);
  EXPECT_EQ(ReadBytes(path), "new\n");
}

TEST(AtomicFile, KeepsThePreviousVersionAsBackup) {
  const std::string path = FreshDir("backup") + "/calib.yaml";
  AtomicWriteOptions o;
  o.keep_backup = true;
  ASSERT_TRUE(WriteFileAtomic(path, "first", o).ok());
  EXPECT_FALSE(std::filesystem::exists(AtomicBackupPath(path)));  // nothing to back up
  ASSERT_TRUE(WriteFileAtomic(path, "second", o).ok());
  ASSERT_TRUE(WriteFileAtomic(path, "third", o).ok());
  EXPECT_EQ(ReadBytes(path), "third");
  EXPECT_EQ(ReadBytes(AtomicBackupPath(path)), "second");
}

TEST(AtomicFile, CrashBeforeTheRenameLeavesTheOldFileIntact) {
  const std::string path = FreshDir("crash") + "/calib.yaml";
  ASSERT_TRUE(WriteFileAtomic(path, "old calibration").ok());
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    AtomicWriteOptions o;
    o.keep_backup = true;
    o.before_rename = [] { ::_exit(3); };  // the process dies here
    (void)WriteFileAtomic(path, "new calibration, never committed", o);
    ::_exit(0);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 3);
  EXPECT_EQ(ReadBytes(path), "old calibration");
  // The leftover temporary file is complete but never read; the next write
  // replaces it.
  EXPECT_TRUE(std::filesystem::exists(AtomicTempPath(path)));
  ASSERT_TRUE(WriteFileAtomic(path, "next").ok());
  EXPECT_EQ(ReadBytes(path), "next");
  EXPECT_FALSE(std::filesystem::exists(AtomicTempPath(path)));
}

TEST(AtomicFile, FailureNamesThePathAndLeavesTheOldFile) {
  const std::string dir = FreshDir("fail");
  const Status missing = WriteFileAtomic(dir + "/no/such/dir/calib.yaml", "x");
  EXPECT_EQ(missing.code(), Status::Code::kInternal);
  EXPECT_NE(missing.message().find("no/such/dir/calib.yaml.tmp"), std::string::npos)
      << missing.message();
  EXPECT_EQ(WriteFileAtomic("", "x").code(), Status::Code::kInvalidArgument);
  // A target that is a directory cannot be replaced: the temp file goes away.
  const std::string target = dir + "/is_a_dir";
  std::filesystem::create_directories(target + "/child");
  EXPECT_FALSE(WriteFileAtomic(target, "x").ok());
  EXPECT_TRUE(std::filesystem::is_directory(target + "/child"));
  EXPECT_FALSE(std::filesystem::exists(AtomicTempPath(target)));
}

}  // namespace
}  // namespace bp
