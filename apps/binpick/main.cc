// binpick: the bin-picking vision server's command line. Subcommands are
// registered in kCommands; each one adds its options and returns its action.
#include <cstdio>
#include <memory>
#include <vector>

#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "apps/binpick/command.h"

namespace bp::cli {

int ExitCodeFor(const Status& status) {
  switch (status.code()) {
    case Status::Code::kOk: return kExitOk;
    case Status::Code::kInvalidArgument:
    case Status::Code::kNotFound:
    case Status::Code::kCorruption:
    case Status::Code::kOutOfRange: return kExitBadInput;
    default: return kExitFailure;
  }
}

int Fail(const std::string& command, const Status& status) {
  std::fprintf(stderr, "binpick %s: %s\n", command.c_str(), status.ToString().c_str());
  return ExitCodeFor(status);
}

}  // namespace bp::cli

int main(int argc, char** argv) {
  using namespace bp::cli;
  // Logs go to stderr so that stdout carries only results.
  spdlog::set_default_logger(spdlog::stderr_color_mt("binpick"));

  CLI::App app{"binpick: bin-picking vision server and tools"};
  app.require_subcommand(1);
  app.failure_message(CLI::FailureMessage::help);
  std::string log_level = "warn";
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, off")->capture_default_str();

  const std::vector<Command> commands = {RenderCommand(), InfoCommand(),  EvalCommand(),   ClearCommand(),
                                         PlaceCommand(),  RobotCommand(), CalibCommand(),  ReplayCommand(),
                                         ReplayMergeCommand()};
  std::function<int()> action;
  for (const Command& command : commands) {
    CLI::App* sub = app.add_subcommand(command.name, command.help);
    std::function<int()> run = command.setup(*sub);
    sub->callback([&action, run] { action = run; });
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? kExitOk : kExitBadInput;
  }
  spdlog::set_level(spdlog::level::from_str(log_level));
  return action ? action() : kExitBadInput;
}
