// `binpick robot`: the robot simulator command (also built standalone as
// binpick-robot). Plays a seed robot program against a DaoAI server.
#pragma once

namespace bp {

// argv[0] is the command name. @returns the process exit code: 0 when the
// flow ended as its robot program expects, 1 when it did not (e.g. capture
// failed, box not empty), 2 for usage or connection errors.
int RunRobotCommand(int argc, char** argv);

}  // namespace bp
