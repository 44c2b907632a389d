// scripts/binpick_client.py (standard library only) against the server with
// the scripted test-double planner, run by /usr/bin/python3.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>

#include "comms/daoai_server.h"
#include "tests/testing/run_command.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

using testing::MakeTestCell;
using testing::ScriptedPlanner;

test::CommandRun RunClient(int port, const std::string& args) {
  return test::RunCommand("/usr/bin/python3 " BINPICK_SOURCE_DIR "/scripts/binpick_client.py --port " +
                             std::to_string(port) + " " + args);
}

TEST(PythonClient, ClearsTheBinAndSeesItEmpty) {
  if (!std::filesystem::exists("/usr/bin/python3")) GTEST_SKIP() << "no /usr/bin/python3";
  auto planner = std::make_shared<ScriptedPlanner>();
  ScriptedPlanner::Script pile;
  pile.grasps = 3;
  pile.pile = 4;
  planner->SetScript(0, pile);
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  DaoaiServerOptions options;
  options.port = 0;
  auto server = std::move(DaoaiServer::Start(handler, options).value());

  const test::CommandRun pick = RunClient(server->port(), "pick --task 0");
  EXPECT_EQ(pick.exit_code, 0) << pick.out;
  EXPECT_NE(pick.out.find("OBJECTS_FOUND remaining=3 class=0 position=(0.5, -0.1, 0.1)"),
            std::string::npos) << pick.out;
  EXPECT_NE(pick.out.find("picks: 4"), std::string::npos) << pick.out;
  EXPECT_NE(pick.out.find("BOX_EMPTY"), std::string::npos) << pick.out;

  const test::CommandRun config = RunClient(server->port(), "switch-config --config 7");
  EXPECT_EQ(config.exit_code, 1) << config.out;
  EXPECT_NE(config.out.find("SWITCH_CONFIG_FAIL"), std::string::npos) << config.out;
  const test::CommandRun teach = RunClient(server->port(), "teach --task 0");
  EXPECT_EQ(teach.exit_code, 0) << teach.out;
  // Teaching has no response: the client may exit before the server has even
  // read its request, so give the server a moment before stopping it.
  for (int i = 0; i < 200 && planner->taught().empty(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  server->Stop();
  handler.Shutdown();
  EXPECT_EQ(planner->taught().size(), 1u);
}

}  // namespace
}  // namespace bp
