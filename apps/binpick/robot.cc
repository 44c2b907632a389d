// `binpick robot ...`: the robot simulator (apps/robot_cmd.h). Its options are
// parsed by RunRobotCommand itself, so this subcommand passes them through.
#include <string>
#include <vector>

#include "apps/binpick/command.h"
#include "apps/robot_cmd.h"

namespace bp::cli {

Command RobotCommand() {
  return {"robot", "simulated robot: play a seed robot program against binpickd (see binpick robot --help)",
          [](CLI::App& sub) -> std::function<int()> {
            sub.prefix_command();  // everything after `robot` belongs to the simulator
            sub.set_help_flag();   // so is --help
            return [&sub] {
              std::vector<std::string> args = {"binpick robot"};
              for (const std::string& a : sub.remaining()) args.push_back(a);
              std::vector<char*> argv;
              for (std::string& a : args) argv.push_back(a.data());
              argv.push_back(nullptr);
              return RunRobotCommand(static_cast<int>(args.size()), argv.data());
            };
          }};
}

}  // namespace bp::cli
