// Files for tests: a fresh scratch directory per test (all of a process's
// under one root, removed when its tests pass), and whole-file reads and
// writes.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <string>

#include <gtest/gtest.h>

namespace bp::testing {

// This test process's scratch directory, /tmp/binpick_tests.<pid> (per
// process, so concurrent test runs on one machine do not share it). It is
// removed when every test of the process passed, and kept after a failure
// for a look at what the failing test wrote (its path is printed).
inline std::filesystem::path ScratchRoot() {
  return std::filesystem::temp_directory_path() / ("binpick_tests." + std::to_string(::getpid()));
}

class ScratchCleanup : public ::testing::Environment {
 public:
  void TearDown() override {
    std::error_code ec;
    const std::filesystem::path root = ScratchRoot();
    if (!std::filesystem::exists(root, ec)) return;
    if (::testing::UnitTest::GetInstance()->Passed()) {
      std::filesystem::remove_all(root, ec);
    } else {
      std::cerr << "scratch files of the failed tests kept in " << root.string() << "\n";
    }
  }
};
inline ::testing::Environment* const kScratchCleanup = ::testing::AddGlobalTestEnvironment(new ScratchCleanup);

// An empty directory for the running test, removed and recreated on each
// call, under ScratchRoot().
inline std::string FreshDir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::filesystem::path dir =
      ScratchRoot() / (std::string(info->test_suite_name()) + "." + info->name() + "." + name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

// A path `name` in the directory `group` under ScratchRoot() (created),
// shared by every test of the process that uses the same group.
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
