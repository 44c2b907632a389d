// Files for tests: a fresh scratch directory per test (all of a process's
// under one root; each removed when its test ends, passed or failed), and
// whole-file reads and writes.
#pragma once

#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace bp::testing {

// This test process's scratch directory, /tmp/binpick_tests.<pid> (per
// process, so concurrent test runs on one machine do not share it).
inline std::filesystem::path ScratchRoot() {
  return std::filesystem::temp_directory_path() / ("binpick_tests." + std::to_string(::getpid()));
}

// Set BINPICK_KEEP_SCRATCH=1 to keep the scratch files for a look at what
// the tests wrote (their paths are printed); by default nothing is kept.
inline bool KeepScratch() {
  const char* keep = std::getenv("BINPICK_KEEP_SCRATCH");
  return keep != nullptr && *keep != '\0' && std::string(keep) != "0";
}

// The directories FreshDir made for the running test.
inline std::vector<std::filesystem::path>& RunningTestDirs() {
  static std::vector<std::filesystem::path> dirs;
  return dirs;
}

// Removes the scratch roots of test processes that no longer run (killed by
// a timeout, crashed, aborted by a sanitizer: no listener ran for them).
// /tmp/binpick_tests.<pid> of a live process, this one's included, stays.
inline void RemoveScratchOfDeadProcesses() {
  std::error_code ec;
  const std::string prefix = "binpick_tests.";
  for (std::filesystem::directory_iterator it(std::filesystem::temp_directory_path(ec), ec), end; !ec && it != end;
       it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.rfind(prefix, 0) != 0 || name.size() == prefix.size()) continue;
    const std::string digits = name.substr(prefix.size());
    if (digits.find_first_not_of("0123456789") != std::string::npos || digits.size() > 9) continue;
    const pid_t pid = static_cast<pid_t>(std::stol(digits));
    if (pid == ::getpid() || ::kill(pid, 0) == 0 || errno != ESRCH) continue;
    std::error_code remove_ec;
    std::filesystem::remove_all(it->path(), remove_ec);
  }
}

// Every test's FreshDir directories are removed when the test ends, passed
// or failed, and the process's whole scratch root (ScratchFile groups too)
// when its tests end; left-overs of dead test processes when it starts.
class ScratchCleanup : public ::testing::EmptyTestEventListener {
 public:
  void OnTestProgramStart(const ::testing::UnitTest&) override { RemoveScratchOfDeadProcesses(); }

  void OnTestEnd(const ::testing::TestInfo&) override {
    std::vector<std::filesystem::path> dirs;
    dirs.swap(RunningTestDirs());
    if (KeepScratch()) {
      for (const auto& dir : dirs) std::cerr << "scratch files kept in " << dir.string() << "\n";
      return;
    }
    const std::filesystem::path root = ScratchRoot();
    for (const auto& dir : dirs) {
      std::error_code ec;
      std::filesystem::remove_all(dir, ec);
      // A parameterised test's name holds '/': remove the parents it made.
      for (auto parent = dir.parent_path(); parent != root && parent.string().size() > root.string().size();
           parent = parent.parent_path()) {
        if (!std::filesystem::remove(parent, ec)) break;  // not empty: another group's
      }
    }
  }

  void OnTestProgramEnd(const ::testing::UnitTest&) override {
    std::error_code ec;
    const std::filesystem::path root = ScratchRoot();
    if (!std::filesystem::exists(root, ec)) return;
    if (KeepScratch()) {
      std::cerr << "scratch files kept in " << root.string() << "\n";
    } else {
      std::filesystem::remove_all(root, ec);
    }
  }
};
inline const bool kScratchCleanupInstalled = [] {
  ::testing::UnitTest::GetInstance()->listeners().Append(new ScratchCleanup);
  return true;
}();

// An empty directory for the running test, removed and recreated on each
// call, under ScratchRoot(); removed when the test ends.
inline std::string FreshDir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::filesystem::path dir =
      ScratchRoot() / (std::string(info->test_suite_name()) + "." + info->name() + "." + name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  RunningTestDirs().push_back(dir);
  return dir.string();
}

// A path `name` in the directory `group` under ScratchRoot() (created),
// shared by every test of the process that uses the same group; removed
// when the process's tests end.
inline std::string ScratchFile(const std::string& group, const std::string& name) {
  const std::filesystem::path dir = ScratchRoot() / group;
  std::filesystem::create_directories(dir);
  return (dir / name).string();
}

inline void WriteText(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

inline std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

}  // namespace bp::testing
