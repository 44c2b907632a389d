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

void AddBinOptions(CLI::App& sub, BinCliOptions* opt) {
  sub.add_flag("--bin-offset", opt->offset,
               "place each scene's bin off its nominal pose, drawn from the seed: the cell's source.bin_offset, "
               "else within +-50 mm, +-10 deg yaw and up to 2 deg tilt (docs/synthetic.md)");
  sub.add_option("--bin-detect", opt->detect, "bin detection mode instead of the cell's bin.detect")
      ->check(CLI::IsMember({"off", "on", "required"}));
}

void ApplyBinOptions(const BinCliOptions& opt, Cell& cell) {
  SourceSpec& s = cell.source;
  if (opt.offset && s.bin_offset_translation <= 0 && s.bin_offset_yaw_deg <= 0 && s.bin_offset_tilt_deg <= 0) {
    s.bin_offset_translation = 0.05;
    s.bin_offset_yaw_deg = 10.0;
    s.bin_offset_tilt_deg = 2.0;
  }
  if (opt.detect == "off") cell.bin.detect.mode = BinDetectSpec::Mode::kOff;
  if (opt.detect == "on") cell.bin.detect.mode = BinDetectSpec::Mode::kOn;
  if (opt.detect == "required") cell.bin.detect.mode = BinDetectSpec::Mode::kRequired;
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
                                         ReplayMergeCommand(), BenchCellCommand()};
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
