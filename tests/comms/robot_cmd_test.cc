// The binpick-robot executable (apps/robot_cmd.cc) against the server with
// the scripted test-double planner.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "comms/daoai_server.h"
#include "tests/testing/run_command.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

using testing::MakeTestCell;
using testing::ScriptedPlanner;

test::CommandRun RunRobot(const std::string& args) {
  return test::RunCommand(BINPICK_BINARY_DIR "/bin/binpick-robot " + args);
}

TEST(RobotCommand, ClearsTheBinPrintingEachPickAndExitsZero) {
  auto planner = std::make_shared<ScriptedPlanner>();
  ScriptedPlanner::Script pile;
  pile.grasps = 2;
  pile.pile = 3;
  planner->SetScript(0, pile);
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  DaoaiServerOptions options;
  options.port = 0;
  auto server = std::move(DaoaiServer::Start(handler, options).value());
  const std::string port = " --port " + std::to_string(server->port());

  const test::CommandRun pick = RunRobot("--flow pick" + port);
  EXPECT_EQ(pick.exit_code, 0) << pick.out;
  EXPECT_NE(pick.out.find("OBJECTS_FOUND(2) pose [0.5000 -0.1000 0.1000 | 0.0000 0.0000 1.5708 "
                          "0.0000] remaining 2 class 0"),
            std::string::npos) << pick.out;
  EXPECT_NE(pick.out.find("pick: 10 steps, 3 picks"), std::string::npos) << pick.out;
  EXPECT_NE(pick.out.find("BOX_EMPTY(41)"), std::string::npos) << pick.out;

  // The seeds' own scripts send meta_2 = 1: it is echoed, so no popup.
  const test::CommandRun v1 = RunRobot("--flow switch-config --config 2 --protocol-version 1" + port);
  EXPECT_EQ(v1.exit_code, 0) << v1.out;
  EXPECT_EQ(v1.out.find("popup"), std::string::npos) << v1.out;
  EXPECT_EQ(RunRobot("--flow pick --dialect seed_999" + port).exit_code, 2);
  EXPECT_EQ(RunRobot("--flow switch-config --config 9" + port).exit_code, 1);
  EXPECT_EQ(RunRobot("--flow pick --robot nonsense" + port).exit_code, 2);
  EXPECT_EQ(RunRobot("--flow dance" + port).exit_code, 2);
  server->Stop();
  handler.Shutdown();
}

}  // namespace
}  // namespace bp
