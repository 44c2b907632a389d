// binpickd itself with --http-port: the real server on the embedded default
// cell (synthetic pile, real perception), a simulated robot picking through
// the DaoAI socket, then the JSON API, /metrics and the page in Chromium
// checked against what the robot was told.
#include <signal.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <map>
#include <regex>
#include <thread>

#include "core/cell.h"
#include "tests/testing/binpickd.h"
#include "tests/testing/files.h"
#include "tests/testing/run_command.h"
#include "tests/web/web_test_util.h"

namespace bp {
namespace {

using json = nlohmann::json;

// Waits for binpickd's ready line and returns the HTTP port it names; -1
// (with a failure naming the line and the log) when there is none.
int HttpPortOnceReady(testing::BinpickdProcess& daemon, const std::string& log) {
  // Normally ready in about a second; under ASan, with another test binary
  // sharing the two cores, building the model tables alone took over 60 s.
  const std::string ready = daemon.ReadyLine(180000);
  std::smatch m;
  if (!std::regex_search(ready, m, std::regex(R"(; http 127\.0\.0\.1:(\d+))"))) {
    ADD_FAILURE() << "no http port in the ready line '" << ready << "'\n" << testing::ReadBytes(log);
    return -1;
  }
  return std::stoi(m[1]);
}

TEST(BinpickdHttp, StatusApiMetricsAndPageAgreeWithWhatTheRobotWasTold) {
  const std::string bin = std::string(BINPICK_BINARY_DIR) + "/bin/";
  const std::string dir = testing::FreshDir("binpickd");
  const int daoai_port = testing::FreeLoopbackTcpPort();
  testing::BinpickdProcess daemon({bin + "binpickd", "--daoai-port", std::to_string(daoai_port), "--gri-port", "0",
                 "--gri-official-port", "0", "--http-port", "-1", "--no-record"},
                dir + "/binpickd.log");
  const int http = HttpPortOnceReady(daemon, dir + "/binpickd.log");
  ASSERT_GT(http, 0);

  const test::CommandRun robot =
      test::RunCommand(bin + "binpick-robot --port " + std::to_string(daoai_port) +
                       " --flow pick --max-cycles 1 --no-empty-check");
  ASSERT_EQ(robot.exit_code, 0) << robot.out;
  std::smatch m;
  ASSERT_TRUE(std::regex_search(robot.out, m, std::regex(R"((\d+) picks)"))) << robot.out;
  const int picks = std::stoi(m[1]);
  ASSERT_GT(picks, 0);

  const webtest::HttpResult status = webtest::HttpRequest(http, "/api/status");
  ASSERT_EQ(status.status, 200) << status.error;
  const json j = json::parse(status.body);
  EXPECT_EQ(j["cell"], "default");
  EXPECT_EQ(j["detection"]["outcome"], "grasps");
  EXPECT_FALSE(j["detection"]["stages"].empty());
  // One capture: every grasp handed out, or withdrawn as stale when a part
  // it touched was picked (docs/protocols.md, "Stale grasps").
  const int withdrawn = j["queue"]["withdrawn"];
  EXPECT_EQ(j["queue"]["total"], picks + withdrawn);
  EXPECT_EQ(j["queue"]["remaining"], 0);
  ASSERT_EQ(j["robots"].size(), 1u);
  EXPECT_FALSE(j["robots"][0]["pose"].is_null());

  const webtest::HttpResult depth = webtest::HttpRequest(http, "/api/image/depth.png");
  EXPECT_EQ(depth.status, 200);
  EXPECT_EQ(depth.body.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));

  const webtest::HttpResult metrics = webtest::HttpRequest(http, "/metrics");
  std::map<std::string, double> s;
  const auto problems = webtest::CheckPrometheusText(metrics.body, &s);
  EXPECT_TRUE(problems.empty()) << ::testing::PrintToString(problems);
  EXPECT_EQ(s["binpick_grasps_served_total{status=\"2\"}"], picks);
  EXPECT_EQ(s["binpick_captures_total{result=\"ok\"}"], 1.0);
  EXPECT_EQ(s["binpick_connections_accepted_total{server=\"daoai\"}"], 1.0);
  EXPECT_EQ(s["binpick_queue_grasps{task=\"0\"}"], 0.0);

  if (std::filesystem::exists("/usr/bin/chromium")) {
    const test::CommandRun dom = test::RunCommand(
        "{ /usr/bin/chromium --headless --disable-gpu --no-sandbox --no-first-run "
        "--disable-dev-shm-usage --user-data-dir=" + dir + "/profile --virtual-time-budget=3000 "
        "--dump-dom http://127.0.0.1:" + std::to_string(http) + "/ 2>" + dir + "/chromium.log; }");
    ASSERT_EQ(dom.exit_code, 0);
    size_t served = 0;
    for (size_t at = dom.out.find("<tr class=\"grasp served\""); at != std::string::npos;
         at = dom.out.find("<tr class=\"grasp served\"", at + 1)) {
      ++served;
    }
    EXPECT_EQ(served, static_cast<size_t>(picks)) << dom.out;
    size_t withdrawn_rows = 0;
    for (size_t at = dom.out.find("<tr class=\"grasp withdrawn\""); at != std::string::npos;
         at = dom.out.find("<tr class=\"grasp withdrawn\"", at + 1)) {
      ++withdrawn_rows;
    }
    EXPECT_EQ(withdrawn_rows, static_cast<size_t>(withdrawn)) << dom.out;
  } else {
    std::cout << "chromium absent: the page was not loaded in a browser here\n";
  }
  EXPECT_EQ(daemon.Stop(), 0);
}

// The cell's http_allowlist and the recorder's metrics reach the daemon's
// HTTP listener: a peer not listed is closed at accept and counted; the
// listed one reads /metrics.
TEST(BinpickdHttp, CellHttpAllowlistRefusesOtherPeersAndMetricsShowTheRecorder) {
  const std::string bin = std::string(BINPICK_BINARY_DIR) + "/bin/";
  const std::string dir = testing::FreshDir("binpickd_allow");
  std::string cell = testing::ReadBytes(std::string(BINPICK_SOURCE_DIR) + "/assets/cells/default.yaml");
  const std::string assets = std::string(BINPICK_SOURCE_DIR) + "/assets/";
  for (size_t at = cell.find("../"); at != std::string::npos; at = cell.find("../", at)) cell.replace(at, 3, assets);
  const size_t at = cell.find("  http_port: 0\n");
  ASSERT_NE(at, std::string::npos);
  cell.insert(at, "  http_allowlist: [127.0.0.2]\n");
  testing::WriteText(dir + "/cell.yaml", cell);
  testing::BinpickdProcess daemon({bin + "binpickd", "--cell", dir + "/cell.yaml", "--daoai-port", std::to_string(testing::FreeLoopbackTcpPort()),
                 "--gri-port", "0", "--gri-official-port", "0", "--http-port", "-1", "--record-dir",
                 dir + "/rec"},
                dir + "/binpickd.log");
  const int http = HttpPortOnceReady(daemon, dir + "/binpickd.log");
  ASSERT_GT(http, 0);
  const webtest::HttpResult refused = webtest::HttpRequest(http, "/metrics", "GET",
                                                           "127.0.0.1");
  EXPECT_EQ(refused.status, 0);
  EXPECT_NE(refused.error, "");
  const webtest::HttpResult metrics = webtest::HttpRequest(http, "/metrics", "GET",
                                                           "127.0.0.2");
  ASSERT_EQ(metrics.status, 200) << metrics.error;
  std::map<std::string, double> s;
  EXPECT_EQ(webtest::CheckPrometheusText(metrics.body, &s), std::vector<std::string>{});
  EXPECT_EQ(s["binpick_http_refused_connections_total{reason=\"allowlist\"}"], 1.0);
  EXPECT_EQ(s.count("binpick_recording_paused"), 1u);
  EXPECT_EQ(s["binpick_recording_paused"], 0.0);
  EXPECT_EQ(s.count("binpick_recording_captures_total{result=\"failed\"}"), 1u);
  EXPECT_EQ(daemon.Stop(), 0);
  EXPECT_NE(testing::ReadBytes(dir + "/binpickd.log").find("http: refused a connection from 127.0.0.1"),
            std::string::npos);
}

// The "Calibration" rows show the live hand-eye state: the transform in use
// and where it came from, then a bad guidance pose's reason (13), then an
// auto calibration's result (the new X_BC, its time and residuals), all in
// the same binpickd process.
TEST(BinpickdHttp, CalibrationRowsFollowTheLiveHandEyeState) {
  const std::string bin = std::string(BINPICK_BINARY_DIR) + "/bin/";
  const std::string dir = testing::FreshDir("binpickd_calib");
  const int daoai_port = testing::FreeLoopbackTcpPort();
  // Seed 004's rules (socket_v1): guidance poses are answered 12 / 13 / 32.
  testing::BinpickdProcess daemon({bin + "binpickd", "--daoai-port", std::to_string(daoai_port), "--gri-port", "0",
                 "--gri-official-port", "0", "--http-port", "-1", "--no-record", "--dialect", "socket_v1"},
                dir + "/binpickd.log");
  const int http = HttpPortOnceReady(daemon, dir + "/binpickd.log");
  ASSERT_GT(http, 0);
  auto rows = [http] {
    std::map<std::string, std::string> r;
    const webtest::HttpResult status = webtest::HttpRequest(http, "/api/status");
    if (status.status != 200) return r;
    const json j = json::parse(status.body);
    for (const json& row : j["calibration"]) r[row["name"]] = row["value"];
    return r;
  };
  // xyz (mm) of the "hand-eye X_BC in use" row.
  auto xyz_mm = [](const std::string& text) {
    std::smatch x;
    if (!std::regex_search(text, x, std::regex(R"(xyz \[([-0-9.]+), ([-0-9.]+), ([-0-9.]+)\] mm)"))) {
      return Vec3(NAN, NAN, NAN);
    }
    return Vec3(std::stod(x[1]), std::stod(x[2]), std::stod(x[3]));
  };
  const Cell cell = LoadDefaultCell().value();

  std::map<std::string, std::string> r = rows();
  EXPECT_EQ(r["hand-eye from"], "camera.pose");
  EXPECT_EQ(r["last calibration"], "none since start");
  EXPECT_EQ(r.count("last bad guidance pose (13)"), 0u);
  EXPECT_LT((xyz_mm(r["hand-eye X_BC in use"]) - cell.camera.X_BC.translation() * 1000).norm(), 0.01)
      << r["hand-eye X_BC in use"];

  // Seed 004 guidance from a robot that never moves: the second pose adds
  // nothing and is answered 13 with the reason.
  test::RunCommand(bin + "binpick-robot --port " + std::to_string(daoai_port) +
                   " --protocol-version 1 --dialect socket_v1 --flow calib-guidance");
  r = rows();
  EXPECT_NE(r["last bad guidance pose (13)"].find("of a pose already kept"), std::string::npos)
      << r["last bad guidance pose (13)"];
  EXPECT_EQ(r["mode"], "guidance");

  const test::CommandRun calib =
      test::RunCommand(bin + "binpick-robot --port " + std::to_string(daoai_port) + " --flow calib-auto");
  ASSERT_EQ(calib.exit_code, 0) << calib.out;
  // The solve runs on the calibration sequence after the last answer: poll.
  for (int i = 0; i < 100 && rows()["hand-eye from"] != "calibration"; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  r = rows();
  EXPECT_EQ(r["hand-eye from"], "calibration");
  EXPECT_EQ(r["mode"], "none");
  EXPECT_TRUE(std::regex_search(r["last calibration"], std::regex(R"(^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ \(auto, \d+ poses)")))
      << r["last calibration"];
  std::smatch res;
  ASSERT_TRUE(std::regex_search(r["residuals rms / max"], res, std::regex(R"(^([0-9.]+) / ([0-9.]+) mm)")))
      << r["residuals rms / max"];
  EXPECT_GT(std::stod(res[1]), 0.0);
  EXPECT_LT(std::stod(res[1]), 1.0);
  // The transform shown is the solved one: near the camera's true pose, away from the nominal one.
  const Vec3 shown = xyz_mm(r["hand-eye X_BC in use"]);
  EXPECT_LT((shown - cell.calibration->true_pose.translation() * 1000).norm(), 0.5) << r["hand-eye X_BC in use"];
  EXPECT_GT((shown - cell.camera.X_BC.translation() * 1000).norm(), 2.0);
  EXPECT_EQ(daemon.Stop(), 0);
}

}  // namespace
}  // namespace bp
