#include "core/atomic_file.h"

#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <thread>
#include <vector>

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
  EXPECT_TRUE(AtomicTempFiles(path).empty());
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
  // uses a name of its own and leaves nothing.
  const std::vector<std::string> leftover = AtomicTempFiles(path);
  ASSERT_EQ(leftover.size(), 1u);
  EXPECT_EQ(ReadBytes(leftover[0]), "new calibration, never committed");
  ASSERT_TRUE(WriteFileAtomic(path, "next").ok());
  EXPECT_EQ(ReadBytes(path), "next");
  EXPECT_EQ(AtomicTempFiles(path), leftover);
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
  EXPECT_TRUE(AtomicTempFiles(target).empty());
}

// Issue 39: two writers of one file each use a temporary file of their own,
// so the file is always one writer's complete data, never a mix or a
// truncation.
TEST(AtomicFile, ConcurrentWritersNeverShareATemporaryFile) {
  const std::string path = FreshDir("writers") + "/taught.yaml";
  ASSERT_TRUE(WriteFileAtomic(path, std::string(100, '0')).ok());
  std::set<std::string> valid{std::string(100, '0')};
  for (char c = 'a'; c < 'e'; ++c) valid.insert(std::string(1000 + 100 * (c - 'a'), c));
  std::atomic<bool> stop{false};
  std::atomic<int> bad_reads{0}, reads{0}, failures{0};
  std::thread reader([&] {
    while (!stop) {
      if (valid.count(ReadBytes(path)) == 0) ++bad_reads;
      ++reads;
    }
  });
  std::vector<std::thread> writers;
  for (char c = 'a'; c < 'e'; ++c) {
    writers.emplace_back([&, c] {
      for (int i = 0; i < 50; ++i) {
        if (!WriteFileAtomic(path, std::string(1000 + 100 * (c - 'a'), c)).ok()) ++failures;
      }
    });
  }
  for (auto& w : writers) w.join();
  stop = true;
  reader.join();
  EXPECT_EQ(failures.load(), 0);
  EXPECT_EQ(bad_reads.load(), 0) << "of " << reads.load() << " reads";
  EXPECT_EQ(valid.count(ReadBytes(path)), 1u);
  EXPECT_TRUE(AtomicTempFiles(path).empty());
}

// Issue 39: a symbolic link planted where the writer puts its temporary file
// (the fixed `<path>.tmp` of old) or its backup is never written through, and
// a target that is a link is refused with a message naming it.
TEST(AtomicFile, PlantedSymbolicLinksAreNeverFollowed) {
  const std::string dir = FreshDir("symlinks");
  const std::string victim = dir + "/victim.txt";
  testing::WriteText(victim, "precious");
  const std::string path = dir + "/hand_eye.yaml";
  std::filesystem::create_symlink(victim, AtomicTempPath(path));
  AtomicWriteOptions backup;
  backup.keep_backup = true;
  ASSERT_TRUE(WriteFileAtomic(path, "first", backup).ok());
  ASSERT_TRUE(WriteFileAtomic(path, "second", backup).ok());
  EXPECT_EQ(ReadBytes(path), "second");
  EXPECT_EQ(ReadBytes(AtomicBackupPath(path)), "first");
  EXPECT_EQ(ReadBytes(victim), "precious");

  const std::string linked = dir + "/linked.yaml";
  std::filesystem::create_symlink(victim, linked);
  const Status refused = WriteFileAtomic(linked, "overwritten");
  EXPECT_EQ(refused.code(), Status::Code::kInvalidArgument);
  EXPECT_NE(refused.message().find("linked.yaml' is a symbolic link"), std::string::npos)
      << refused.message();
  EXPECT_EQ(ReadBytes(victim), "precious");
  EXPECT_TRUE(std::filesystem::is_symlink(linked));

  const std::string with_bak = dir + "/calib.yaml";
  testing::WriteText(with_bak, "old");
  std::filesystem::create_symlink(victim, AtomicBackupPath(with_bak));
  EXPECT_EQ(WriteFileAtomic(with_bak, "new", backup).code(), Status::Code::kInvalidArgument);
  EXPECT_EQ(ReadBytes(with_bak), "old");
  EXPECT_EQ(ReadBytes(victim), "precious");
  EXPECT_TRUE(AtomicTempFiles(with_bak).empty());
}

}  // namespace
}  // namespace bp
