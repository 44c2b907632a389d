// The status page's HTTP server over real loopback connections, fed by a
// RequestHandler driving a scripted planner with real frames.
#include "web/status_server.h"

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>

#include <sys/socket.h>

#include <cerrno>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <thread>

#include "comms/request_handler.h"
#include "tests/testing/files.h"
#include "tests/testing/run_command.h"
#include "tests/web/web_test_util.h"
#include "web/status_state.h"

namespace bp {
namespace {

testing::ScriptedPlanner::Script Grasps(int n) {
  testing::ScriptedPlanner::Script s;
  s.grasps = n;
  return s;
}

using json = nlohmann::json;
namespace http = boost::beast::http;

daoai::Request Req(int32_t command, int32_t task = 0) {
  daoai::Request r;
  r.command = command;
  r.payload_1 = task;
  r.meta_1 = static_cast<int32_t>(RobotType::kUR);
  r.meta_2 = 2;  // protocol version
  // Some robot pose; the handler scales it to metres (ClientContext::X_BF).
  r.position = {3000, 2000, 5000};
  return r;
}

// One binpickd-like stack in process: handler, status state, HTTP server.
struct Stack {
  std::shared_ptr<testing::ScriptedPlanner> script = std::make_shared<testing::ScriptedPlanner>();
  MetricsRegistry metrics;
  std::shared_ptr<StatusState> status;
  std::unique_ptr<RequestHandler> handler;
  std::unique_ptr<StatusServer> server;

  explicit Stack(StatusServerOptions options = {}) {
    const Cell cell = testing::MakeTestCell();
    status = std::make_shared<StatusState>(cell, metrics);
    handler = std::make_unique<RequestHandler>(cell, std::make_shared<webtest::FramePlanner>(script),
                                               nullptr);
    status->SetQueueProbe([h = handler.get()](int task) { return h->QueueSize(task); });
    status->SetQueueContentsProbe([h = handler.get()](int task) { return h->QueueContents(task); });
    handler->AddObserver(status);
    options.port = 0;
    auto started = StatusServer::Start(*status, metrics, options);
    EXPECT_TRUE(started.ok()) << started.status().ToString();
    server = std::move(*started);
  }
  ~Stack() {
    server->Stop();
    handler->Shutdown();
  }
  int port() const { return server->port(); }
};

json GetJson(int port, const std::string& target) {
  const webtest::HttpResult r = webtest::HttpRequest(port, target);
  EXPECT_EQ(r.error, "");
  EXPECT_EQ(r.status, 200);
  EXPECT_EQ(r.content_type, "application/json");
  return json::parse(r.body);
}

// Grasps 1 and 3 touch part 0 (Grasp::stale_after): once 0 is handed out the
// page shows them withdrawn, not handed out, and 2 next.
TEST(StatusServer, GraspsWithdrawnAsStaleAreShownWithdrawnNotServed) {
  Stack s;
  ClientContext robot;
  testing::ScriptedPlanner::Script five = Grasps(5);
  five.stale_after = {{1, {0}}, {3, {0}}};
  s.script->SetScript(1, five);
  ASSERT_TRUE(s.handler->Handle(Req(daoai::kCaptureAndProcess, 1), robot).has_value());
  const auto pick = s.handler->Handle(Req(daoai::kPickPose, 1), robot);
  ASSERT_TRUE(pick.has_value());
  ASSERT_EQ(pick->status, daoai::kObjectsFound);
  const json q = GetJson(s.port(), "/api/status")["queue"];
  EXPECT_EQ(q["total"], 5);
  EXPECT_EQ(q["remaining"], 2);
  EXPECT_EQ(q["withdrawn"], 2);
  std::vector<std::string> states;
  for (const json& g : q["grasps"]) states.push_back(g["state"]);
  EXPECT_EQ(states, (std::vector<std::string>{"served", "withdrawn", "next", "withdrawn", "queued"}));
  EXPECT_EQ(webtest::HttpRequest(s.port(), "/api/image/depth.png").status, 200);
}

TEST(StatusServer, JsonApiShowsTheQueueRobotsAndStages) {
  Stack s;
  json before = GetJson(s.port(), "/api/status");
  EXPECT_TRUE(before["queue"].is_null());
  EXPECT_TRUE(before["detection"].is_null());
  EXPECT_EQ(webtest::HttpRequest(s.port(), "/api/image/depth.png").status, 404);

  ClientContext robot;
  robot.id = 7;
  robot.peer = "10.0.0.5:40000";
  s.script->SetScript(1, Grasps(4));
  ASSERT_TRUE(s.handler->Handle(Req(daoai::kCaptureAndProcess, 1), robot).has_value());
  const auto pick = s.handler->Handle(Req(daoai::kPickPose, 1), robot);
  ASSERT_TRUE(pick.has_value());
  ASSERT_EQ(pick->status, daoai::kObjectsFound);

  json j = GetJson(s.port(), "/api/status?x=1");
  EXPECT_EQ(j["detection"]["queued"], true);
  EXPECT_EQ(j["cell"], "test");
  EXPECT_EQ(j["detection"]["task"], 1);
  EXPECT_EQ(j["detection"]["outcome"], "grasps");
  EXPECT_EQ(j["detection"]["parts"].size(), 4u);
  ASSERT_EQ(j["detection"]["stages"].size(), 4u);
  EXPECT_EQ(j["detection"]["stages"][2]["stage"], "pose");
  EXPECT_EQ(j["detection"]["stages"][2]["ms"], 12.5);
  const json& q = j["queue"];
  EXPECT_EQ(q["task"], 1);
  EXPECT_EQ(q["total"], 4);
  EXPECT_EQ(q["remaining"], 3);
  ASSERT_EQ(q["grasps"].size(), 4u);
  EXPECT_EQ(q["grasps"][0]["state"], "served");
  EXPECT_EQ(q["grasps"][1]["state"], "next");
  EXPECT_EQ(q["grasps"][3]["state"], "queued");
  for (int i = 0; i < 4; ++i) {
    const Vec3 t = testing::ScriptedPlanner::GraspPose(1, i).translation();
    const json& p = q["grasps"][i]["position_m"];
    EXPECT_NEAR(p[0].get<double>(), t.x(), 1e-12);
    EXPECT_NEAR(p[1].get<double>(), t.y(), 1e-12);
    EXPECT_NEAR(p[2].get<double>(), t.z(), 1e-12);
    EXPECT_EQ(q["grasps"][i]["instance_id"], i);
  }
  // Tasks with their live queue sizes.
  bool found = false;
  for (const json& t : j["tasks"]) {
    if (t["id"] == 1) {
      EXPECT_EQ(t["queue_size"], 3);
      found = true;
    }
  }
  EXPECT_TRUE(found);
  // The robot, with the pose it sent last.
  ASSERT_EQ(j["robots"].size(), 1u);
  const json& r = j["robots"][0];
  EXPECT_EQ(r["peer"], "10.0.0.5:40000");
  EXPECT_EQ(r["client_id"], 7);
  EXPECT_EQ(r["answers"], 2);
  EXPECT_EQ(r["last_command"], daoai::kPickPose);
  EXPECT_EQ(r["last_status"], daoai::kObjectsFound);
  ASSERT_TRUE(robot.X_BF.has_value());
  EXPECT_NEAR(r["pose"]["position_m"][0].get<double>(), robot.X_BF->translation().x(), 1e-12);
  EXPECT_NEAR(r["pose"]["position_m"][2].get<double>(), robot.X_BF->translation().z(), 1e-12);
  EXPECT_EQ(j["calibration"][0]["name"], "mode");
  EXPECT_EQ(j["calibration"][0]["value"], "none");

  // An empty-box check is the latest detection but leaves the queue alone.
  s.script->SetScript(1, Grasps(2));
  EXPECT_EQ(s.handler->Handle(Req(daoai::kCheckEmptyBox, 1), robot)->status, daoai::kBoxNotEmpty);
  j = GetJson(s.port(), "/api/status");
  EXPECT_EQ(j["detection"]["seq"], 2);
  EXPECT_EQ(j["detection"]["queued"], false);
  EXPECT_EQ(j["detection"]["parts"].size(), 2u);
  EXPECT_EQ(j["queue"]["seq"], 1);
  EXPECT_EQ(j["queue"]["total"], 4);
  EXPECT_EQ(j["queue"]["remaining"], 3);
}

TEST(StatusServer, ShowsTheCalibrationStateSeenInAnswersOrTheProbes) {
  Stack s;
  ClientContext robot;
  auto row = [&](const json& j, const std::string& name) -> std::string {
    for (const json& r : j["calibration"]) {
      if (r["name"] == name) return r["value"];
    }
    return "<missing>";
  };
  EXPECT_EQ(s.handler->Handle(Req(daoai::kStartAutoCalibration), robot)->status,
            daoai::kModeAutoCalibration);
  EXPECT_EQ(s.handler->Handle(Req(daoai::kAutoAccumulatePose), robot)->status,
            daoai::kModeAutoCalibration);
  EXPECT_EQ(s.handler->Handle(Req(daoai::kAutoAccumulatePose), robot)->status,
            daoai::kModeAutoCalibration);
  json j = GetJson(s.port(), "/api/status");
  EXPECT_EQ(row(j, "mode"), "auto");
  EXPECT_EQ(row(j, "poses accumulated"), "2");
  EXPECT_EQ(row(j, "calibrations completed"), "0");
  // The calibration engine's own rows replace the inferred ones.
  s.status->SetCalibrationProbe([] {
    return std::vector<std::pair<std::string, std::string>>{{"X_BC residual (mm)", "0.41"}};
  });
  j = GetJson(s.port(), "/api/status");
  ASSERT_EQ(j["calibration"].size(), 1u);
  EXPECT_EQ(row(j, "X_BC residual (mm)"), "0.41");
}

// PNG: signature, then IHDR with width and height (big-endian).
void ExpectPng(const std::string& body, uint32_t width, uint32_t height) {
  ASSERT_GT(body.size(), 33u);
  EXPECT_EQ(body.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));
  EXPECT_EQ(body.substr(12, 4), "IHDR");
  auto be32 = [&](size_t at) {
    return (uint32_t(uint8_t(body[at])) << 24) | (uint32_t(uint8_t(body[at + 1])) << 16) |
           (uint32_t(uint8_t(body[at + 2])) << 8) | uint32_t(uint8_t(body[at + 3]));
  };
  EXPECT_EQ(be32(16), width);
  EXPECT_EQ(be32(20), height);
}

TEST(StatusServer, ServesDepthAndIntensityPngsOfTheLatestCapture) {
  Stack s;
  ClientContext robot;
  s.script->SetScript(0, Grasps(2));
  ASSERT_TRUE(s.handler->Handle(Req(daoai::kCaptureAndProcess, 0), robot).has_value());
  s.handler->Handle(Req(daoai::kPickPose, 0), robot);  // waits for the plan
  for (const char* name : {"/api/image/depth.png", "/api/image/intensity.png"}) {
    const webtest::HttpResult r = webtest::HttpRequest(s.port(), name);
    ASSERT_EQ(r.status, 200) << name;
    EXPECT_EQ(r.content_type, "image/png");
    ExpectPng(r.body, 160, 120);
  }
  // The overlay is drawn: the intensity image with marks differs from one
  // without (no detected parts, no grasps).
  const auto marked = s.status->RenderIntensityPng();
  ASSERT_TRUE(marked.has_value());
  s.script->SetScript(0, Grasps(0));
  ASSERT_TRUE(s.handler->Handle(Req(daoai::kCaptureAndProcess, 0), robot).has_value());
  s.handler->Handle(Req(daoai::kPickPose, 0), robot);
  const auto plain = s.status->RenderIntensityPng();
  ASSERT_TRUE(plain.has_value());
  EXPECT_NE(*marked, *plain);
}

TEST(StatusServer, BadRequestsGet4xxAndTheServerKeepsServing) {
  StatusServerOptions options;
  options.max_request_bytes = 4096;
  options.idle_timeout = std::chrono::milliseconds(300);
  Stack s(options);
  EXPECT_EQ(webtest::HttpRequest(s.port(), "/nope").status, 404);
  EXPECT_EQ(webtest::HttpRequest(s.port(), "/api/status", "POST").status, 405);
  EXPECT_EQ(webtest::HttpRequest(s.port(), "/api/status", "DELETE").status, 405);
  const webtest::HttpResult head = webtest::HttpRequest(s.port(), "/api/status", "HEAD");
  EXPECT_EQ(head.status, 200);
  EXPECT_EQ(head.body, "");

  EXPECT_EQ(webtest::RawExchange(s.port(), "garbage\r\n\r\n").substr(0, 12), "HTTP/1.1 400");
  EXPECT_EQ(webtest::RawExchange(s.port(), "GET / HTTP/1.1\r\nX: " + std::string(10000, 'a') +
                                               "\r\n\r\n")
                .substr(0, 12),
            "HTTP/1.1 413");
  EXPECT_EQ(webtest::RawExchange(s.port(), "POST /api/status HTTP/1.1\r\nContent-Length: 100000\r\n\r\n")
                .substr(0, 12),
            "HTTP/1.1 413");
  // Half a request, then silence: closed after the idle timeout, no answer.
  EXPECT_EQ(webtest::RawExchange(s.port(), "GET /api/sta"), "");
  EXPECT_EQ(GetJson(s.port(), "/api/status")["cell"], "test");
}

TEST(StatusServer, RefusesConnectionsOverTheLimitWith503) {
  StatusServerOptions options;
  options.max_connections = 2;
  Stack s(options);
  boost::asio::io_context io;
  std::vector<std::unique_ptr<boost::asio::ip::tcp::socket>> idle;
  for (int i = 0; i < 2; ++i) {
    idle.push_back(std::make_unique<boost::asio::ip::tcp::socket>(io));
    idle.back()->connect({boost::asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(s.port())});
  }
  // The server accepts in connection order: these two come first.
  const webtest::HttpResult refused = webtest::HttpRequest(s.port(), "/api/status");
  EXPECT_EQ(refused.status, 503);
  idle.clear();  // the idle browsers leave
  json j;
  for (int i = 0; i < 200; ++i) {
    const webtest::HttpResult r = webtest::HttpRequest(s.port(), "/api/status");
    if (r.status == 200) {
      j = json::parse(r.body);
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(j["cell"], "test");
  std::map<std::string, double> samples;
  const webtest::HttpResult m = webtest::HttpRequest(s.port(), "/metrics");
  EXPECT_EQ(webtest::CheckPrometheusText(m.body, &samples), std::vector<std::string>{});
  // At least the one above; retries above may have met the closing idle ones.
  EXPECT_GE(samples["binpick_http_refused_connections_total{reason=\"max_connections\"}"], 1);
  EXPECT_EQ(samples["binpick_http_refused_connections_total{reason=\"allowlist\"}"], 0);
}

// A browser that keeps its connection open between requests.
class KeepAliveClient {
 public:
  explicit KeepAliveClient(int port) : socket_(io_) {
    socket_.connect({boost::asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)});
  }
  int Get(const std::string& target) {
    http::request<http::empty_body> req(http::verb::get, target, 11);
    req.set(http::field::host, "127.0.0.1");
    req.keep_alive(true);
    boost::system::error_code ec;
    http::write(socket_, req, ec);
    if (ec) return -1;
    http::response<http::string_body> res;
    http::read(socket_, buffer_, res, ec);
    return ec ? -1 : static_cast<int>(res.result_int());
  }

 private:
  boost::asio::io_context io_;
  boost::asio::ip::tcp::socket socket_;
  boost::beast::flat_buffer buffer_;
};

// Connects from `from` and waits for the server: @returns the bytes it sent
// before closing, or "<open>" if it kept the connection open for 0.5 s.
std::string BytesBeforeClose(int port, const std::string& from) {
  boost::asio::io_context io;
  boost::asio::ip::tcp::socket socket(io);
  socket.open(boost::asio::ip::tcp::v4());
  socket.bind({boost::asio::ip::make_address(from), 0});
  socket.connect({boost::asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)});
  const timeval tv{0, 500000};
  ::setsockopt(socket.native_handle(), SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  std::string out;
  char buf[256];
  for (;;) {
    const ssize_t n = ::recv(socket.native_handle(), buf, sizeof(buf), 0);
    if (n > 0) {
      out.append(buf, static_cast<size_t>(n));
      continue;
    }
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return "<open>";
    return out;  // EOF or reset
  }
}

std::map<std::string, double> Samples(int port) {
  const webtest::HttpResult r = webtest::HttpRequest(port, "/metrics");
  EXPECT_EQ(r.status, 200) << r.error;
  std::map<std::string, double> samples;
  EXPECT_EQ(webtest::CheckPrometheusText(r.body, &samples), std::vector<std::string>{});
  return samples;
}

TEST(StatusServer, PeersNotInTheAllowlistAreClosedAtAcceptAndCounted) {
  StatusServerOptions options;
  options.allowlist = {"127.0.0.1"};
  Stack s(options);
  // A browser already on the page, from an allowed address.
  KeepAliveClient browser(s.port());
  ASSERT_EQ(browser.Get("/api/status"), 200);
  // 127.0.0.2 is not listed: closed before a byte is read or written (a
  // request would get no answer either).
  for (int i = 0; i < 5; ++i) EXPECT_EQ(BytesBeforeClose(s.port(), "127.0.0.2"), "") << i;
  const webtest::HttpResult refused = webtest::HttpRequest(s.port(), "/api/status", "GET", "127.0.0.2");
  EXPECT_EQ(refused.status, 0);
  EXPECT_NE(refused.error, "");
  // The allowed browser is unaffected, on its open connection and on new ones.
  EXPECT_EQ(browser.Get("/api/status"), 200);
  EXPECT_EQ(webtest::HttpRequest(s.port(), "/api/status", "GET", "127.0.0.1").status, 200);
  const std::map<std::string, double> samples = Samples(s.port());
  EXPECT_EQ(samples.at("binpick_http_refused_connections_total{reason=\"allowlist\"}"), 6);
  EXPECT_EQ(samples.at("binpick_http_refused_connections_total{reason=\"max_connections\"}"), 0);
}

TEST(StatusServer, AnAllowlistWithoutTheLoopbackPeerRefusesItAndServesTheListedOne) {
  StatusServerOptions options;
  options.allowlist = {"::ffff:127.0.0.2"};  // IPv4-mapped: compared as 127.0.0.2
  Stack s(options);
  EXPECT_EQ(BytesBeforeClose(s.port(), "127.0.0.1"), "");
  EXPECT_NE(webtest::HttpRequest(s.port(), "/metrics").error, "");
  const webtest::HttpResult r = webtest::HttpRequest(s.port(), "/metrics", "GET", "127.0.0.2");
  ASSERT_EQ(r.status, 200) << r.error;
  std::map<std::string, double> samples;
  EXPECT_EQ(webtest::CheckPrometheusText(r.body, &samples), std::vector<std::string>{});
  EXPECT_EQ(samples.at("binpick_http_refused_connections_total{reason=\"allowlist\"}"), 2);
  // Without an allowlist the same peer is served (the list is what refused it).
  Stack open;
  EXPECT_EQ(BytesBeforeClose(open.port(), "127.0.0.1"), "<open>");
  EXPECT_EQ(webtest::HttpRequest(open.port(), "/api/status").status, 200);
}

TEST(StatusServer, ABadAllowlistEntryIsRefusedAtStart) {
  const Cell cell = testing::MakeTestCell();
  MetricsRegistry metrics;
  StatusState state(cell, metrics);
  StatusServerOptions options;
  options.port = 0;
  options.allowlist = {"127.0.0.1", "browser.local"};
  auto started = StatusServer::Start(state, metrics, options);
  ASSERT_FALSE(started.ok());
  EXPECT_EQ(started.status().code(), Status::Code::kInvalidArgument);
  EXPECT_NE(started.status().message().find("'browser.local'"), std::string::npos) << started.status().ToString();
}

TEST(StatusServer, KeepsTheLastWarningsAndErrors) {
  Stack s;
  auto logger = std::make_shared<spdlog::logger>("web_test", s.status->LogSink());
  logger->info("not kept");
  logger->warn("camera {} is slow", 3);
  logger->error("capture failed");
  const json j = GetJson(s.port(), "/api/status");
  ASSERT_EQ(j["errors"].size(), 2u);
  EXPECT_EQ(j["errors"][0]["level"], "warning");
  EXPECT_EQ(j["errors"][0]["message"], "camera 3 is slow");
  EXPECT_EQ(j["errors"][1]["level"], "error");
  EXPECT_EQ(j["errors"][1]["logger"], "web_test");
  std::map<std::string, double> samples;
  webtest::CheckPrometheusText(webtest::HttpRequest(s.port(), "/metrics").body, &samples);
  EXPECT_EQ(samples["binpick_log_messages_total{level=\"warning\"}"], 1.0);
  EXPECT_EQ(samples["binpick_log_messages_total{level=\"error\"}"], 1.0);
}

TEST(StatusServer, MetricsParseAsPrometheusTextAndCountWhatHappened) {
  Stack s;
  ClientContext robot;
  s.script->SetScript(0, Grasps(2));
  testing::ScriptedPlanner::Script fails;
  fails.capture_fails = true;
  s.script->SetScript(3, fails);
  ASSERT_TRUE(s.handler->Handle(Req(daoai::kCaptureAndProcess, 0), robot).has_value());
  EXPECT_EQ(s.handler->Handle(Req(daoai::kPickPose, 0), robot)->status, daoai::kObjectsFound);
  EXPECT_EQ(s.handler->Handle(Req(daoai::kPickPose, 0), robot)->status, daoai::kObjectsFound);
  const int32_t third = s.handler->Handle(Req(daoai::kPickPose, 0), robot)->status;
  EXPECT_NE(third, daoai::kObjectsFound);
  s.handler->Handle(Req(daoai::kCaptureAndProcess, 3), robot);
  s.handler->Handle(Req(daoai::kPickPose, 3), robot);

  const webtest::HttpResult r = webtest::HttpRequest(s.port(), "/metrics");
  ASSERT_EQ(r.status, 200);
  EXPECT_EQ(r.content_type, "text/plain; version=0.0.4; charset=utf-8");
  std::map<std::string, double> m;
  const std::vector<std::string> problems = webtest::CheckPrometheusText(r.body, &m);
  EXPECT_TRUE(problems.empty()) << ::testing::PrintToString(problems) << "\n" << r.body;
  EXPECT_EQ(m["binpick_captures_total{result=\"ok\"}"], 1.0);
  EXPECT_EQ(m["binpick_captures_total{result=\"failed\"}"], 1.0);
  EXPECT_EQ(m["binpick_detections_total{task=\"0\",outcome=\"grasps\"}"], 1.0);
  EXPECT_EQ(m["binpick_detections_total{task=\"3\",outcome=\"capture_failed\"}"], 1.0);
  EXPECT_EQ(m["binpick_grasps_planned_total{task=\"0\"}"], 2.0);
  EXPECT_EQ(m["binpick_parts_detected_total{task=\"0\"}"], 2.0);
  EXPECT_EQ(m["binpick_grasps_served_total{status=\"2\"}"], 2.0);
  EXPECT_EQ(m["binpick_grasps_served_total{status=\"" + std::to_string(third) + "\"}"] >= 1.0, true);
  EXPECT_EQ(m["binpick_responses_total{command=\"20\",status=\"5\"}"], 1.0);
  EXPECT_EQ(m["binpick_stage_seconds_count{stage=\"pose\"}"], 1.0);
  EXPECT_NEAR(m["binpick_stage_seconds_sum{stage=\"pose\"}"], 0.0125, 1e-15);
  EXPECT_EQ(m["binpick_stage_seconds_bucket{stage=\"pose\",le=\"0.01\"}"], 0.0);
  EXPECT_EQ(m["binpick_stage_seconds_bucket{stage=\"pose\",le=\"0.025\"}"], 1.0);
  EXPECT_EQ(m["binpick_capture_seconds_count"], 2.0);
  EXPECT_EQ(m["binpick_plan_seconds_count"], 1.0);

  // The reference parser, where Debian's python3-prometheus-client is installed.
  if (test::RunCommand("/usr/bin/python3 -c 'import prometheus_client'").exit_code == 0) {
    const std::string dir = testing::FreshDir("web_metrics");
    const std::string file = dir + "/metrics.txt";
    std::ofstream(file) << r.body;
    const test::CommandRun py = test::RunCommand(
        "/usr/bin/python3 -c 'import sys\n"
        "from prometheus_client.parser import text_string_to_metric_families as p\n"
        "fams = list(p(open(sys.argv[1]).read()))\n"
        "print(len(fams), sum(len(f.samples) for f in fams))' " + file);
    EXPECT_EQ(py.exit_code, 0) << py.out;
    EXPECT_NE(py.out.find(' '), std::string::npos) << py.out;
  } else {
    std::cout << "python3-prometheus-client absent: only the built-in checker ran\n";
  }
}

}  // namespace
}  // namespace bp

namespace bp {
namespace {

AnswerEvent Answer(int32_t command, int32_t task, int32_t status, int32_t payload_1 = 0) {
  AnswerEvent e;
  e.peer = "127.0.0.1:5000";
  e.request = Req(command, task);
  e.response.status = status;
  e.response.payload[0] = payload_1;
  return e;
}

TEST(StatusState, ExportsThePrecisionErrorAndCountsEmptyBoxFlipsPerTask) {
  MetricsRegistry metrics;
  StatusState state(testing::MakeTestCell(), metrics);
  state.OnAnswer(Answer(daoai::kPrecisionCheck, 0, daoai::kPrecisionCheckSuccess, 3500));  // 0.35 mm
  state.OnAnswer(Answer(daoai::kPrecisionCheck, 0, daoai::kPrecisionCheckFail));  // keeps the last error
  // Task 0: empty, empty, not empty, empty: two flips. Task 1: one answer, no flip.
  for (const int32_t s : {daoai::kBoxEmpty, daoai::kBoxEmpty, daoai::kBoxNotEmpty, daoai::kBoxEmpty}) {
    state.OnAnswer(Answer(daoai::kCheckEmptyBox, 0, s));
  }
  state.OnAnswer(Answer(daoai::kCheckEmptyBox, 1, daoai::kBoxNotEmpty));
  state.OnAnswer(Answer(daoai::kCheckEmptyBox, 1, -1));  // task not in the cell: no answer to compare
  std::map<std::string, double> m;
  const std::vector<std::string> problems = webtest::CheckPrometheusText(metrics.Render(), &m);
  EXPECT_TRUE(problems.empty()) << ::testing::PrintToString(problems);
  EXPECT_DOUBLE_EQ(m["binpick_precision_error_mm{task=\"0\"}"], 0.35);
  EXPECT_EQ(m["binpick_empty_box_flips_total{task=\"0\"}"], 2.0);
  EXPECT_EQ(m["binpick_empty_box_flips_total{task=\"1\"}"], 0.0);
  EXPECT_EQ(m.count("binpick_empty_box_flips_total{task=\"1\"}"), 1u);
}

TEST(StatusState, ShowsTheMeasuredBinAndTheFillLevelInItsJsonAndMetrics) {
  MetricsRegistry metrics;
  StatusState state(testing::MakeTestCell(), metrics);
  DetectionEvent e;
  e.task_id = 0;
  PlanResult plan;
  BinDetection bin;
  bin.found = true;
  bin.offset = 0.0214;
  bin.offset_deg = 4.0;
  bin.warn = true;
  plan.bin = bin;
  FillLevel fill;
  fill.mean_height = 0.031;
  fill.max_height = 0.094;
  fill.occupied_fraction = 0.62;
  plan.fill = fill;
  e.plan = plan;
  state.OnDetection(e);
  std::map<std::string, double> m;
  std::vector<std::string> problems = webtest::CheckPrometheusText(metrics.Render(), &m);
  EXPECT_TRUE(problems.empty()) << ::testing::PrintToString(problems);
  EXPECT_EQ(m["binpick_bin_found{task=\"0\"}"], 1.0);
  EXPECT_DOUBLE_EQ(m["binpick_bin_offset_mm{task=\"0\"}"], 21.4);
  EXPECT_DOUBLE_EQ(m["binpick_bin_offset_deg{task=\"0\"}"], 4.0);
  EXPECT_EQ(m["binpick_bin_offset_warnings_total{task=\"0\"}"], 1.0);
  EXPECT_DOUBLE_EQ(m["binpick_bin_fill_mean_height_m{task=\"0\"}"], 0.031);
  EXPECT_DOUBLE_EQ(m["binpick_bin_fill_max_height_m{task=\"0\"}"], 0.094);
  EXPECT_DOUBLE_EQ(m["binpick_bin_fill_occupied_ratio{task=\"0\"}"], 0.62);
  json j = json::parse(state.StatusJson());
  EXPECT_EQ(j["detection"]["bin"]["found"], true);
  EXPECT_DOUBLE_EQ(j["detection"]["bin"]["offset_mm"].get<double>(), 21.4);
  EXPECT_EQ(j["detection"]["bin"]["warning"], true);
  EXPECT_DOUBLE_EQ(j["detection"]["fill"]["occupied_fraction"].get<double>(), 0.62);

  // The next plan did not find the bin: the gauge drops, the counter counts, the page says why.
  bin = BinDetection{};
  bin.reason = "no rim: 3 points near the rim's height within the search window";
  e.plan->bin = bin;
  e.plan->fill.reset();
  state.OnDetection(e);
  m.clear();
  problems = webtest::CheckPrometheusText(metrics.Render(), &m);
  EXPECT_TRUE(problems.empty()) << ::testing::PrintToString(problems);
  EXPECT_EQ(m["binpick_bin_found{task=\"0\"}"], 0.0);
  EXPECT_EQ(m["binpick_bin_not_found_total{task=\"0\"}"], 1.0);
  EXPECT_EQ(m["binpick_bin_offset_warnings_total{task=\"0\"}"], 1.0);
  j = json::parse(state.StatusJson());
  EXPECT_EQ(j["detection"]["bin"]["found"], false);
  EXPECT_EQ(j["detection"]["bin"]["reason"], bin.reason);
  EXPECT_TRUE(j["detection"]["fill"].is_null());
}

// Issue 39: a robot sending distinct unknown command numbers must not grow
// /metrics (each one used to become a series of binpick_responses_total).
TEST(StatusServer, MetricsLabelsComeFromClosedSetsSoUnknownCommandsDoNotGrowThem) {
  Stack s;
  ClientContext robot;
  auto send = [&](int32_t command) {
    const auto r = s.handler->Handle(Req(command, 0), robot);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->status, daoai::kUnknownCommand);
  };
  // The series (name and labels) before and after; only counts change.
  auto series = [&](std::map<std::string, double>* values) {
    std::map<std::string, double> m;
    EXPECT_TRUE(webtest::CheckPrometheusText(s.metrics.Render(), &m).empty());
    std::vector<std::string> keys;
    for (const auto& [k, v] : m) keys.push_back(k);
    if (values) *values = m;
    return keys;
  };
  send(1000);
  const std::vector<std::string> before = series(nullptr);
  for (int32_t command = 1001; command < 3000; ++command) send(command);
  send(-7);
  send(std::numeric_limits<int32_t>::max());
  std::map<std::string, double> m;
  EXPECT_EQ(series(&m), before);
  EXPECT_EQ(m["binpick_responses_total{command=\"other\",status=\"-1\"}"], 2002.0);
  // Known commands keep their number.
  EXPECT_EQ(s.handler->Handle(Req(daoai::kSwitchConfig, 2), robot)->status,
            daoai::kSwitchConfigSuccess);
  webtest::CheckPrometheusText(s.metrics.Render(), &m);
  EXPECT_EQ(m["binpick_responses_total{command=\"69\",status=\"66\"}"], 1.0);
}

}  // namespace
}  // namespace bp
