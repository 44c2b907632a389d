// The binpick command line: one Command per subcommand, registered in
// main.cc. Each lives in its own file (render.cc, info.cc, ...).
#pragma once

#include <functional>
#include <string>

#include <CLI/CLI.hpp>

#include "core/cell.h"
#include "core/status.h"

namespace bp::cli {

// Process exit codes shared by all subcommands.
enum ExitCode : int {
  kExitOk = 0,
  kExitFailure = 1,   // runtime failure (renderer, device, write error)
  kExitBadInput = 2,  // bad command line, missing / malformed input file
};

struct Command {
  std::string name;
  std::string help;
  // Adds the subcommand's options to `sub` and returns the action main runs
  // when this subcommand is chosen (options are parsed by then).
  std::function<std::function<int()>(CLI::App& sub)> setup;
};

Command RenderCommand();
Command InfoCommand();
Command RobotCommand();
Command EvalCommand();  // eval_cmd.cc
Command ClearCommand();  // clear_cmd.cc
Command PlaceCommand();  // place_cmd.cc
Command CalibCommand();  // calib_cmd.cc
Command ReplayCommand();  // replay_cmd.cc
Command ReplayMergeCommand();  // replay_merge_cmd.cc
Command BenchCellCommand();  // bench_cell_cmd.cc

// kExitBadInput for errors in what the user gave us (InvalidArgument,
// NotFound, Corruption, OutOfRange), kExitFailure otherwise.
int ExitCodeFor(const Status& status);
// Prints "binpick <command>: <status>" as one line on stderr and returns
// ExitCodeFor(status).
int Fail(const std::string& command, const Status& status);

// The scene options of issue 41 shared by eval and clear: --bin-offset
// (each scene's bin off nominal, drawn from its seed) and --bin-detect
// (the cell's bin.detect replaced).
struct BinCliOptions {
  bool offset = false;
  std::string detect;  // "" = the cell's
};
void AddBinOptions(CLI::App& sub, BinCliOptions* opt);
// Applies them to the cell: --bin-offset keeps the cell's source.bin_offset
// when it has one, else +-50 mm, +-10 deg yaw and up to 2 deg of tilt.
void ApplyBinOptions(const BinCliOptions& opt, Cell& cell);

}  // namespace bp::cli
