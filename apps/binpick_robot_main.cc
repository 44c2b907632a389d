// binpick-robot: standalone build of `binpick robot` (apps/robot_cmd.h).
#include "apps/robot_cmd.h"

int main(int argc, char** argv) { return bp::RunRobotCommand(argc, argv); }
