// Connections and protocol errors counted by the robot-facing servers, as
// /metrics reports them, over real loopback sockets.
#include "web/server_metrics.h"

#include <gtest/gtest.h>

#include <boost/asio.hpp>

#include <thread>

#include "comms/daoai_server.h"
#include "comms/gri_server.h"
#include "tests/web/web_test_util.h"

namespace bp {
namespace {

namespace asio = boost::asio;
using asio::ip::tcp;

std::map<std::string, double> Scrape(const MetricsRegistry& metrics) {
  std::map<std::string, double> samples;
  const std::string text = metrics.Render();
  EXPECT_TRUE(webtest::CheckPrometheusText(text, &samples).empty()) << text;
  return samples;
}

// Waits until `done` holds (the servers count on their own threads).
template <typename F>
bool Eventually(F done) {
  for (int i = 0; i < 400; ++i) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return done();
}

tcp::socket Connect(asio::io_context& io, int port) {
  tcp::socket s(io);
  s.connect({asio::ip::make_address("127.0.0.1"), static_cast<uint16_t>(port)});
  return s;
}

TEST(ServerMetrics, CountsConnectionsAndProtocolErrorsPerServer) {
  auto script = std::make_shared<testing::ScriptedPlanner>();
  RequestHandler handler(testing::MakeTestCell(), script, nullptr);
  GriHandler gri_handler(handler);
  DaoaiServerOptions daoai_options;
  daoai_options.port = 0;
  daoai_options.max_queued_requests = 1;
  auto daoai = DaoaiServer::Start(handler, daoai_options);
  ASSERT_TRUE(daoai.ok()) << daoai.status().ToString();
  GriServerOptions gri_options;
  gri_options.v2_port = -1;
  gri_options.official_port = 0;
  auto gri = GriServer::Start(gri_handler, gri_options);
  ASSERT_TRUE(gri.ok()) << gri.status().ToString();

  MetricsRegistry metrics;
  AddTransportMetrics(metrics, "daoai", [&] { return (*daoai)->stats(); });
  AddTransportMetrics(metrics, "gri", [&] { return (*gri)->stats(); });
  AddQueueMetrics(metrics, handler);
  auto m = Scrape(metrics);
  EXPECT_EQ(m.at("binpick_connections{server=\"daoai\"}"), 0.0);
  EXPECT_EQ(m.at("binpick_protocol_errors_total{server=\"gri\"}"), 0.0);
  EXPECT_EQ(m.at("binpick_queue_grasps{task=\"0\"}"), 0.0);

  asio::io_context io;
  // GRI: a first byte that is neither format is answered and the connection closed.
  tcp::socket gri_robot = Connect(io, (*gri)->v2_port());
  const uint8_t garbage = 0x55;
  asio::write(gri_robot, asio::buffer(&garbage, 1));
  // DaoAI: with plans held, a pick pose waits; more requests than the queue
  // holds close the connection.
  script->HoldPlans(true);
  tcp::socket daoai_robot = Connect(io, (*daoai)->port());
  tcp::socket idle_robot = Connect(io, (*daoai)->port());
  std::vector<uint8_t> bytes;
  for (int32_t command : {daoai::kCaptureAndProcessAsync, daoai::kPickPose, daoai::kPickPose,
                          daoai::kPickPose, daoai::kPickPose}) {
    daoai::Request r;
    r.command = command;
    r.meta_1 = static_cast<int32_t>(RobotType::kUR);
    r.meta_2 = 2;
    const auto encoded = daoai::EncodeRequest(r);
    bytes.insert(bytes.end(), encoded.begin(), encoded.end());
  }
  asio::write(daoai_robot, asio::buffer(bytes));

  EXPECT_TRUE(Eventually([&] {
    const TransportStats d = (*daoai)->stats(), g = (*gri)->stats();
    return d.protocol_errors == 1 && g.protocol_errors == 1 && d.open == 1 && g.open == 0;
  }));
  m = Scrape(metrics);
  EXPECT_EQ(m.at("binpick_protocol_errors_total{server=\"gri\"}"), 1.0);
  EXPECT_EQ(m.at("binpick_protocol_errors_total{server=\"daoai\"}"), 1.0);
  EXPECT_EQ(m.at("binpick_connections_accepted_total{server=\"daoai\"}"), 2.0);
  EXPECT_EQ(m.at("binpick_connections_accepted_total{server=\"gri\"}"), 1.0);
  EXPECT_EQ(m.at("binpick_connections{server=\"daoai\"}"), 1.0);  // the idle robot
  EXPECT_EQ(m.at("binpick_connections{server=\"gri\"}"), 0.0);
  EXPECT_EQ(m.at("binpick_read_timeouts_total{server=\"daoai\"}"), 0.0);
  script->HoldPlans(false);
  (*daoai)->Stop();
  (*gri)->Stop();
  handler.Shutdown();
}

TEST(ServerMetrics, CountsReadTimeouts) {
  auto script = std::make_shared<testing::ScriptedPlanner>();
  RequestHandler handler(testing::MakeTestCell(), script, nullptr);
  DaoaiServerOptions options;
  options.port = 0;
  options.read_timeout = std::chrono::milliseconds(100);
  auto daoai = DaoaiServer::Start(handler, options);
  ASSERT_TRUE(daoai.ok());
  MetricsRegistry metrics;
  AddTransportMetrics(metrics, "daoai", [&] { return (*daoai)->stats(); });
  asio::io_context io;
  tcp::socket silent = Connect(io, (*daoai)->port());
  EXPECT_TRUE(Eventually([&] { return (*daoai)->stats().read_timeouts == 1; }));
  EXPECT_EQ(Scrape(metrics).at("binpick_read_timeouts_total{server=\"daoai\"}"), 1.0);
  (*daoai)->Stop();
  handler.Shutdown();
}

}  // namespace
}  // namespace bp
