// The status page in a real browser: headless Chromium (Debian's `chromium`,
// installed by scripts/install_deps.sh) loads the page from a server with a
// scripted queue, runs its polling script, and we assert on the DOM it
// produced and on its screenshot.
#include <gtest/gtest.h>

#include <filesystem>
#include <regex>

#include "comms/request_handler.h"
#include "tests/testing/files.h"
#include "tests/testing/run_command.h"
#include "tests/web/web_test_util.h"
#include "web/status_server.h"
#include "web/status_state.h"

namespace bp {
namespace {

testing::ScriptedPlanner::Script Grasps(int n) {
  testing::ScriptedPlanner::Script s;
  s.grasps = n;
  return s;
}

std::string FindChromium() {
  for (const char* path : {"/usr/bin/chromium", "/usr/bin/chromium-browser"}) {
    if (std::filesystem::exists(path)) return path;
  }
  return "";
}

size_t Count(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

TEST(StatusPageBrowser, ChromiumShowsTheCurrentQueue) {
  const std::string chromium = FindChromium();
  if (chromium.empty()) {
    GTEST_SKIP() << "chromium is not installed (scripts/install_deps.sh installs it): the status "
                    "page was not tested in a browser";
  }
  auto script = std::make_shared<testing::ScriptedPlanner>();
  MetricsRegistry metrics;
  const Cell cell = testing::MakeTestCell();
  auto status = std::make_shared<StatusState>(cell, metrics);
  RequestHandler handler(cell, std::make_shared<webtest::FramePlanner>(script), nullptr);
  status->SetQueueProbe([&handler](int task) { return handler.QueueSize(task); });
  handler.AddObserver(status);
  StatusServerOptions options;
  options.port = 0;
  auto server = StatusServer::Start(*status, metrics, options);
  ASSERT_TRUE(server.ok()) << server.status().ToString();

  // Task 1: five grasps planned, two handed out.
  script->SetScript(1, Grasps(5));
  ClientContext robot;
  robot.peer = "10.1.2.3:5555";
  daoai::Request req;
  req.meta_1 = static_cast<int32_t>(RobotType::kUR);
  req.meta_2 = 2;  // protocol version
  req.payload_1 = 1;
  req.position = {4000, -1000, 6000};
  req.command = daoai::kCaptureAndProcess;
  ASSERT_TRUE(handler.Handle(req, robot).has_value());
  req.command = daoai::kPickPose;
  ASSERT_EQ(handler.Handle(req, robot)->status, daoai::kObjectsFound);
  ASSERT_EQ(handler.Handle(req, robot)->status, daoai::kObjectsFound);
  ASSERT_EQ(handler.QueueSize(1), 3);

  const std::string dir = testing::FreshDir("chromium");
  const std::string url = "http://127.0.0.1:" + std::to_string((*server)->port()) + "/";
  const std::string flags = " --headless --disable-gpu --no-sandbox --no-first-run "
                            "--disable-dev-shm-usage --user-data-dir=" + dir + "/profile "
                            "--virtual-time-budget=4000 --window-size=1280,1100 ";
  const test::CommandRun dom =
      test::RunCommand("{ " + chromium + flags + "--dump-dom " + url + " 2>" + dir + "/dom.log; }");
  ASSERT_EQ(dom.exit_code, 0) << dom.out;
  const std::string& html = dom.out;
  // The script ran and filled the tables from /api/status.
  EXPECT_NE(html.find("<small id=\"conn\" class=\"\">live</small>"), std::string::npos) << html;
  EXPECT_NE(html.find("(task 1: 3 of 5 left)"), std::string::npos) << html;
  EXPECT_EQ(Count(html, "<tr class=\"grasp "), 5u) << html;
  EXPECT_EQ(Count(html, "<tr class=\"grasp served\""), 2u);
  EXPECT_EQ(Count(html, "<tr class=\"grasp next\""), 1u);
  EXPECT_EQ(Count(html, "<tr class=\"grasp queued\""), 2u);
  // Each queued grasp's position as the table shows it (x = 0.5 + 0.01 i).
  for (int i = 0; i < 5; ++i) {
    const Vec3 t = testing::ScriptedPlanner::GraspPose(1, i).translation();
    char x[32];
    std::snprintf(x, sizeof(x), "<td>%.3f</td>", t.x());
    EXPECT_NE(html.find(x), std::string::npos) << x;
  }
  const std::regex third_row(
      R"(<tr class="grasp next" data-index="3"><td>3</td><td class="l">next</td>)");
  EXPECT_TRUE(std::regex_search(html, third_row)) << html;
  // The robot and its pose, the images pointing at the latest capture.
  EXPECT_NE(html.find("10.1.2.3:5555"), std::string::npos);
  EXPECT_NE(html.find("src=\"/api/image/depth.png?seq="), std::string::npos);

  const std::string png = dir + "/page.png";
  const test::CommandRun shot = test::RunCommand("{ " + chromium + flags + "--screenshot=" + png +
                                                 " " + url + " 2>" + dir + "/shot.log; }");
  ASSERT_EQ(shot.exit_code, 0) << shot.out;
  const std::string bytes = testing::ReadBytes(png);
  ASSERT_GT(bytes.size(), 1000u);
  EXPECT_EQ(bytes.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));
  (*server)->Stop();
  handler.Shutdown();
}

}  // namespace
}  // namespace bp
