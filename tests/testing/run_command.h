// Runs a shell command from a test and collects its exit code and combined
// stdout + stderr (the CLI, the robot simulator, Python tools).
#pragma once

#include <sys/wait.h>

#include <cstdio>
#include <string>

namespace bp::test {

struct CommandRun {
  int exit_code = -1;  // -1: could not start, or did not exit normally
  std::string out;     // stdout and stderr
};

inline CommandRun RunCommand(const std::string& command) {
  CommandRun r;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return r;
  char buf[4096];
  size_t n = 0;
  while ((n = fread(buf, 1, sizeof(buf), pipe)) > 0) r.out.append(buf, n);
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

}  // namespace bp::test
