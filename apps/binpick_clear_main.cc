// binpick-clear: `binpick clear` as a standalone executable (for the bench
// scripts; binpick registers the same command).
#include <CLI/CLI.hpp>
#include <functional>

#include "apps/binpick/command.h"

int main(int argc, char** argv) {
  CLI::App app{"binpick-clear: closed-loop bin clearing on synthetic scenes"};
  const bp::cli::Command command = bp::cli::ClearCommand();
  std::function<int()> run = command.setup(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? bp::cli::kExitOk : bp::cli::kExitBadInput;
  }
  return run();
}
