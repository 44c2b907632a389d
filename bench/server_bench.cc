// DaoAI server round trips over loopback, against a minimal Boost.Asio echo of
// the same message sizes (48 bytes in, 64 out) in the same run.
//
//   build/bin/bp_server_bench --benchmark_min_time=1
//
// Counters: p50_us / p99_us per round trip (client side, blocking socket, as a
// robot controller does), and items_per_second for 1 and 8 concurrent robots.
// The planner is the scripted test double: this measures the protocol path
// (decode, handler, queue pop, encode, two syscalls each way), not detection.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <boost/asio.hpp>
#include <chrono>
#include <memory>
#include <thread>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/robot_client.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using Clock = std::chrono::steady_clock;

constexpr int kQueueGrasps = 20000;

// A minimal asynchronous echo: reads 48 bytes, answers 64, one io thread.
class EchoServer {
 public:
  EchoServer() : acceptor_(io_, tcp::endpoint(asio::ip::make_address("127.0.0.1"), 0)) {
    Accept();
    thread_ = std::thread([this] { io_.run(); });
  }
  ~EchoServer() {
    io_.stop();
    thread_.join();
  }
  int port() const { return acceptor_.local_endpoint().port(); }

 private:
  struct Session : std::enable_shared_from_this<Session> {
    explicit Session(tcp::socket s) : socket(std::move(s)) {
      socket.set_option(tcp::no_delay(true));
    }
    void Read() {
      asio::async_read(socket, asio::buffer(in), [self = shared_from_this()](auto ec, size_t) {
        if (ec) return;
        std::copy(self->in.begin(), self->in.end(), self->out.begin());
        asio::async_write(self->socket, asio::buffer(self->out),
                          [self](auto ec2, size_t) {
                            if (!ec2) self->Read();
                          });
      });
    }
    tcp::socket socket;
    std::array<uint8_t, 48> in{};
    std::array<uint8_t, 64> out{};
  };
  void Accept() {
    acceptor_.async_accept([this](auto ec, tcp::socket s) {
      if (!ec) std::make_shared<Session>(std::move(s))->Read();
      Accept();
    });
  }
  asio::io_context io_;
  tcp::acceptor acceptor_;
  std::thread thread_;
};

struct PickServer {
  PickServer() {
    planner = std::make_shared<testing::ScriptedPlanner>();
    testing::ScriptedPlanner::Script s;
    s.grasps = kQueueGrasps;
    for (int task = 0; task < 2; ++task) planner->SetScript(task, s);
    handler = std::make_unique<RequestHandler>(testing::MakeTestCell(), planner, nullptr);
    DaoaiServerOptions o;
    o.port = 0;
    server = std::move(DaoaiServer::Start(*handler, o).value());
  }
  ~PickServer() {
    server->Stop();
    handler->Shutdown();
  }
  std::shared_ptr<testing::ScriptedPlanner> planner;
  std::unique_ptr<RequestHandler> handler;
  std::unique_ptr<DaoaiServer> server;
};

std::unique_ptr<RobotClient> Connect(int port, bool tcp_nodelay = true) {
  RobotClientOptions o;
  o.port = port;
  o.tcp_nodelay = tcp_nodelay;
  return std::move(RobotClient::Connect(o).value());
}

void ReportPercentiles(benchmark::State& state, std::vector<double>& us) {
  if (us.empty()) return;
  std::sort(us.begin(), us.end());
  state.counters["p50_us"] = us[us.size() / 2];
  state.counters["p99_us"] = us[std::min(us.size() - 1, us.size() * 99 / 100)];
}

// One pick pose (21) on a ready queue: send 48 bytes, read 64.
void BM_PickPoseRoundTrip(benchmark::State& state) {
  PickServer s;
  auto robot = Connect(s.server->port());
  int left = 0;
  std::vector<double> us;
  us.reserve(1 << 20);
  const auto request = daoai::EncodeRequest(robot->MakeRequest(daoai::kPickPose, 0));
  std::array<uint8_t, daoai::kResponseSize> response{};
  for (auto _ : state) {
    if (left == 0) {
      state.PauseTiming();
      (void)robot->Call(daoai::kCaptureAndProcess, 0);
      (void)robot->Call(daoai::kPickPose, 0);  // waits until the detection has finished
      left = kQueueGrasps - 1;
      state.ResumeTiming();
    }
    const auto t0 = Clock::now();
    (void)robot->SendBytes(request.data(), request.size());
    (void)robot->ReceiveBytes(response.data(), response.size());
    us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
    --left;
  }
  if (response[55] != daoai::kObjectsFound) state.SkipWithError("pick pose did not find objects");
  ReportPercentiles(state, us);
}
BENCHMARK(BM_PickPoseRoundTrip)->UseRealTime();

// A robot as controllers ship them: its socket with default options (Nagle
// on, no TCP_NODELAY). Arg 0: pick pose (21) alone; arg 1: a pose update (-1,
// no response) written right before each pick pose, whose answer the timer
// waits for. Without the server's immediate ACK of the update (docs/protocols.md
// "TCP options") the pick pose waits for the kernel's delayed ACK (>= 40 ms).
void BM_PickPoseDefaultSocket(benchmark::State& state) {
  const bool update_first = state.range(0) != 0;
  PickServer s;
  auto robot = Connect(s.server->port(), /*tcp_nodelay=*/false);
  int left = 0;
  std::vector<double> us;
  us.reserve(1 << 16);
  const auto update = daoai::EncodeRequest(robot->MakeRequest(daoai::kNoCommand));
  const auto request = daoai::EncodeRequest(robot->MakeRequest(daoai::kPickPose, 0));
  std::array<uint8_t, daoai::kResponseSize> response{};
  for (auto _ : state) {
    if (left == 0) {
      state.PauseTiming();
      (void)robot->Call(daoai::kCaptureAndProcess, 0);
      (void)robot->Call(daoai::kPickPose, 0);
      left = kQueueGrasps - 1;
      state.ResumeTiming();
    }
    const auto t0 = Clock::now();
    if (update_first) (void)robot->SendBytes(update.data(), update.size());
    (void)robot->SendBytes(request.data(), request.size());
    (void)robot->ReceiveBytes(response.data(), response.size());
    us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
    --left;
  }
  if (response[55] != daoai::kObjectsFound) state.SkipWithError("pick pose did not find objects");
  ReportPercentiles(state, us);
}
BENCHMARK(BM_PickPoseDefaultSocket)->ArgName("update_first")->Arg(0)->Arg(1)->UseRealTime();

void BM_EchoRoundTrip(benchmark::State& state) {
  EchoServer echo;
  auto robot = Connect(echo.port());
  const std::array<uint8_t, 48> request{};
  std::array<uint8_t, 64> response{};
  std::vector<double> us;
  us.reserve(1 << 20);
  for (auto _ : state) {
    const auto t0 = Clock::now();
    (void)robot->SendBytes(request.data(), request.size());
    (void)robot->ReceiveBytes(response.data(), response.size());
    us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
  }
  ReportPercentiles(state, us);
}
BENCHMARK(BM_EchoRoundTrip)->UseRealTime();

// Throughput: N robots, each on its own connection, each doing round trips
// for a fixed count; items = round trips. Pick robots share two tasks.
template <bool kEcho>
void BM_Throughput(benchmark::State& state) {
  const int robots = static_cast<int>(state.range(0));
  constexpr int kPerRobot = 2000;
  std::unique_ptr<PickServer> pick;
  std::unique_ptr<EchoServer> echo;
  int port = 0;
  if (kEcho) {
    echo = std::make_unique<EchoServer>();
    port = echo->port();
  } else {
    pick = std::make_unique<PickServer>();
    port = pick->server->port();
  }
  std::vector<std::unique_ptr<RobotClient>> clients;
  for (int i = 0; i < robots; ++i) clients.push_back(Connect(port));
  int64_t total = 0;
  for (auto _ : state) {
    if (!kEcho) {
      state.PauseTiming();
      (void)clients[0]->Call(daoai::kCaptureAndProcess, 0);
      (void)clients[0]->Call(daoai::kCaptureAndProcess, 1);
      (void)clients[0]->Call(daoai::kPickPose, 0);  // wait until both detections finished
      (void)clients[0]->Call(daoai::kPickPose, 1);
      state.ResumeTiming();
    }
    std::vector<std::thread> threads;
    for (int i = 0; i < robots; ++i) {
      threads.emplace_back([&, i] {
        const auto request = daoai::EncodeRequest(clients[i]->MakeRequest(daoai::kPickPose, i % 2));
        std::array<uint8_t, 64> response{};
        for (int k = 0; k < kPerRobot; ++k) {
          (void)clients[i]->SendBytes(request.data(), 48);
          (void)clients[i]->ReceiveBytes(response.data(), 64);
        }
      });
    }
    for (auto& t : threads) t.join();
    total += int64_t{robots} * kPerRobot;
  }
  state.SetItemsProcessed(total);
}
BENCHMARK(BM_Throughput<false>)->Name("BM_PickPoseThroughput")->Arg(1)->Arg(8)->UseRealTime()->Iterations(3);
BENCHMARK(BM_Throughput<true>)->Name("BM_EchoThroughput")->Arg(1)->Arg(8)->UseRealTime()->Iterations(3);

}  // namespace
}  // namespace bp

BENCHMARK_MAIN();
