// Robot link round trips over loopback, per transport: the DaoAI socket, the
// GRI (v2 and official), and Modbus TCP against a real Modbus slave (the
// robot simulator's libmodbus server, binpick its master at the cell's
// poll_ms), against a minimal Boost.Asio echo of the DaoAI message sizes (48
// bytes in, 64 out) in the same run.
//
//   build/bin/bp_server_bench --benchmark_min_time=1
//
// Counters: p50_us / p99_us per round trip (client side, blocking socket, as a
// robot controller does), and items_per_second for 1 and 8 concurrent robots;
// the Modbus benchmark adds the handshake breakdown (docs/protocols.md
// "Latency"). The planner is the scripted test double: this measures the
// protocol path (decode, handler, queue pop, encode, syscalls / register I/O),
// not detection.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <boost/asio.hpp>
#include <chrono>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/gri_handler.h"
#include "comms/gri_message.h"
#include "comms/gri_server.h"
#include "comms/modbus_master.h"
#include "comms/modbus_robot_sim.h"
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

// GRI GET_NEXT_POSE on a ready queue, robot socket with default options.
// Arg 0: the format (0 v2, 1 official); arg 1: 0 the pose request alone, 1
// right after a STATUS request's answer (back to back; the timer covers the
// pose request only).
void BM_GriNextPose(benchmark::State& state) {
  const gri::Format format = state.range(0) == 0 ? gri::Format::kV2 : gri::Format::kOfficial;
  const bool after_status = state.range(1) != 0;
  PickServer s;
  GriHandler gri_handler(*s.handler);
  GriServerOptions go;
  go.v2_port = -1;
  go.official_port = -1;
  auto gri = std::move(GriServer::Start(gri_handler, go).value());
  auto robot = Connect(format == gri::Format::kV2 ? gri->v2_port() : gri->official_port(),
                       /*tcp_nodelay=*/false);
  auto request = [&](uint8_t action) {
    gri::Request r;
    r.format = format;
    r.action = action;
    r.job_id = 0;
    r.pose_format = 2;
    r.pose = {0, 0, 0, 0, 0, 0, 1};
    return gri::EncodeRequest(r).value();
  };
  const std::vector<uint8_t> next = request(gri::kGetNextPose);
  const std::vector<uint8_t> status = request(gri::kStatus);
  std::vector<uint8_t> response(gri::ResponseSize(format));
  int left = 0;
  std::vector<double> us;
  us.reserve(1 << 16);
  for (auto _ : state) {
    if (left == 0) {
      state.PauseTiming();
      (void)robot->SendBytes(request(gri::kTriggerJobSync).data(), next.size());
      (void)robot->ReceiveBytes(response.data(), response.size());  // waits for the detection
      // The scripted grasp i is at x = 0.5 + 0.01 i m; the official format
      // carries at most 2147 mm: capture again well before.
      left = 150;
      state.ResumeTiming();
    }
    if (after_status) {
      (void)robot->SendBytes(status.data(), status.size());
      (void)robot->ReceiveBytes(response.data(), response.size());
    }
    const auto t0 = Clock::now();
    (void)robot->SendBytes(next.data(), next.size());
    (void)robot->ReceiveBytes(response.data(), response.size());
    us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
    --left;
  }
  const Result<gri::Response> last = gri::DecodeResponse(response);
  if (!last.ok() || last->error_code != 0) state.SkipWithError("GET_NEXT_POSE did not return a pose");
  ReportPercentiles(state, us);
  gri->Stop();
}
BENCHMARK(BM_GriNextPose)->ArgNames({"official", "after_status"})->ArgsProduct({{0, 1}, {0, 1}})->UseRealTime();

// Pick pose (21) on a ready queue over Modbus TCP: the robot is a libmodbus
// slave (ModbusRobotSim, seed 000's register functions; its wait for the
// response flag wakes at once, where a UR script polls once per 8 ms
// controller cycle), binpick its master polling every `poll_ms` (arg 0). Arg
// 1: a pose update (-1) written first (the simulator then waits for the
// master to take it before writing the pick pose; the timer covers both).
// The breakdown of the pick pose (p50, microseconds): robot_write (the
// robot's 12 registers and its flag, in its own memory), master_poll (flag
// written -> the master's read that saw it began: the poll interval's
// remainder), master_read (that FC3 read), take (marker and flag written),
// handle (the handler's answer), answer_write (response registers and flag),
// robot_read (flag set -> the robot has read the answer).
void BM_ModbusPickPose(benchmark::State& state) {
  PickServer s;
  auto sim = std::move(ModbusRobotSim::Start(ModbusRobotSimOptions{}).value());
  std::mutex mutex;
  std::vector<ModbusRequestTiming> timings;
  ModbusMasterOptions mo;
  mo.port = sim->port();
  mo.poll_interval = std::chrono::milliseconds(state.range(0));
  mo.on_request = [&](const ModbusRequestTiming& t) {
    std::lock_guard lock(mutex);
    timings.push_back(t);
  };
  auto master = std::move(ModbusMaster::Start(*s.handler, mo).value());
  if (!sim->WaitForMaster(std::chrono::seconds(5))) {
    state.SkipWithError("the master did not connect");
    return;
  }
  RobotClientOptions ro;
  ro.version = 1;  // as seed 000's script: 144 reads 1 after every answer
  auto robot = RobotClient::Over(sim->Transport(), ro);
  const daoai::Request request = robot->MakeRequest(daoai::kPickPose, 0);
  const daoai::Request update = robot->MakeRequest(daoai::kNoCommand);
  const bool update_first = state.range(1) != 0;
  int left = 0;
  int picks_sent = 0;  // every 21 the master sees, refills included
  std::vector<int> pick_index;  // of each timed request among them
  std::vector<double> round_us, write_us;
  std::vector<Clock::time_point> flagged, read;
  for (auto _ : state) {
    if (left == 0) {
      state.PauseTiming();
      (void)robot->Call(daoai::kCaptureAndProcess, 0);
      (void)robot->Call(daoai::kPickPose, 0);
      ++picks_sent;
      // The scripted grasp i is at x = 0.5 + 0.01 i m: past i = 277 it is
      // beyond the registers' 3.2767 m and stays queued (answered -1).
      left = 250;
      state.ResumeTiming();
    }
    const auto t0 = Clock::now();
    if (update_first) (void)sim->SendRobotData(update, false, std::chrono::seconds(5));
    const auto t_pick = Clock::now();
    (void)sim->SendRobotData(request, true, std::chrono::seconds(5));
    const auto t1 = Clock::now();
    const Result<daoai::Response> r = sim->RecvDaoaiData(std::chrono::seconds(5));
    const auto t2 = Clock::now();
    if (!r.ok() || r->status != daoai::kObjectsFound) {
      state.SkipWithError("pick pose did not find objects");
      break;
    }
    round_us.push_back(std::chrono::duration<double, std::micro>(t2 - t0).count());
    write_us.push_back(std::chrono::duration<double, std::micro>(t1 - t_pick).count());
    flagged.push_back(t1);
    read.push_back(t2);
    pick_index.push_back(picks_sent++);
    --left;
  }
  // The master reports a request after writing its answer, which the robot
  // may have read before: wait for the last report.
  for (int i = 0; i < 1000; ++i) {
    std::lock_guard lock(mutex);
    int n = 0;
    for (const ModbusRequestTiming& x : timings) n += x.command == daoai::kPickPose;
    if (n >= picks_sent) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  master->Stop();
  ReportPercentiles(state, round_us);
  std::vector<ModbusRequestTiming> t;
  {
    std::lock_guard lock(mutex);
    for (const ModbusRequestTiming& x : timings) {
      if (x.command == daoai::kPickPose) t.push_back(x);
    }
  }
  if (round_us.empty() || static_cast<int>(t.size()) < picks_sent) return;
  auto us = [](Clock::duration d) { return std::chrono::duration<double, std::micro>(d).count(); };
  std::vector<double> poll, fc3, take, handle, answer, robot_read;
  for (size_t i = 0; i < round_us.size(); ++i) {
    const ModbusRequestTiming& m = t[static_cast<size_t>(pick_index[i])];
    poll.push_back(std::max(0.0, us(m.read_start - flagged[i])));
    fc3.push_back(us(m.seen - m.read_start));
    take.push_back(us(m.taken - m.seen));
    handle.push_back(us(m.handled - m.taken));
    answer.push_back(us(m.written - m.handled));
    robot_read.push_back(std::max(0.0, us(read[i] - m.written)));
  }
  auto p50 = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  state.counters["robot_write"] = p50(write_us);
  state.counters["master_poll"] = p50(poll);
  state.counters["master_read"] = p50(fc3);
  state.counters["take"] = p50(take);
  state.counters["handle"] = p50(handle);
  state.counters["answer_write"] = p50(answer);
  state.counters["robot_read"] = p50(robot_read);
}
BENCHMARK(BM_ModbusPickPose)->ArgNames({"poll_ms", "update_first"})->Args({2, 0})->Args({2, 1})
    ->UseRealTime()->MinTime(2.0);

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
