// Serving under contention and abuse (issue 39, docs/reliability.md "Load"):
// two measurements over loopback DaoAI connections.
//
//   build/bin/bp_soak --mode flood --seconds 30 [--flood-task 0 --pick-task 1]
//       One robot floods CAPTURE_AND_PROCESS_ASYNC (19) on task 0 at full
//       speed; a second robot runs capture (19) + pick pose (21) cycles on
//       task 1 (against binpickd's default cell use --pick-task 5: its task 1
//       is the in-hand check). Reports the second robot's pick-pose latency p50 / p99 under
//       the flood against a single plan time: the same robot's pick latency
//       measured alone first. Before issue 39 each 19 started a detection of
//       its own and the second robot waited behind all of them.
//       --flood-command 20 floods synchronous captures instead (each waits
//       for its image, so the flooded task's detections are not background).
//   build/bin/bp_soak --mode soak --requests 1000000 --robots 8
//       Mixed requests from N robots: captures (19 and 20), picks until the
//       queue is empty, pose updates, garbage (unknown commands, a bad
//       meta_2), reconnects. Every valid request must be answered as
//       expected; the grasps the robots received must be exactly the ones
//       the planner handed out (no loss, no duplicate); RSS, open
//       descriptors and /metrics (its series; bytes are reported, a counter
//       gains digits) are sampled after a warm-up and at the end, with the
//       robots gone.
//
// In-process the server is the DaoAI server with the scripted planner
// (tests/testing/scripted_planner.h: --plan-ms of detection, --grasps per
// detection) and binpickd's observers for /metrics (StatusState on a
// MetricsRegistry). With --port the robots talk to a running binpickd
// (flood mode only; its cell needs tasks 0 and 1). Exit 1 on any error.
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/request_handler.h"
#include "comms/robot_client.h"
#include "core/cell.h"
#include "tests/testing/process_stats.h"
#include "tests/testing/scripted_planner.h"
#include "web/metrics.h"
#include "web/server_metrics.h"
#include "web/status_state.h"

namespace bp {
namespace {

using Clock = std::chrono::steady_clock;

double Ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
  return v[i];
}

struct Options {
  std::string mode = "soak";
  int robots = 8;
  int64_t requests = 1000000;
  double seconds = 30;
  int port = 0;
  std::string host = "127.0.0.1";
  int grasps = 10;
  int plan_ms = 2;
  int seed = 39;
  int flood_task = 0;  // flood: the task the flooding robot captures on
  // flood: the flooding robot's capture, 19 (CAPTURE_AND_PROCESS_ASYNC,
  // answered at once) or 20 (CAPTURE_AND_PROCESS, answered once the image is
  // captured: a waiter, so its detection is planned at the normal priority).
  int flood_command = 19;
  int pick_task = 1;   // flood: the second robot's task (a pick task)
  // In-process: requests/s per connection (DaoaiServerOptions), binpickd's
  // default (the cell's endpoints.max_message_rate); 0: off.
  double max_message_rate = Endpoints{}.max_message_rate;
};

// The scripted planner, its hand-outs counted per (task, instance) instead
// of listed (ScriptedPlanner::handed_out keeps every one: 8 bytes a grasp,
// 6 MB over a 1M-request soak, which the RSS check would count as the
// server's growth).
class CountingPlanner final : public GraspPlanner {
 public:
  Result<CaptureHandle> Capture(const PlanRequest& request) override { return scripted.Capture(request); }
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override {
    return scripted.Plan(request, scene);
  }
  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override {
    std::lock_guard lock(mutex_);
    ++handed_out_[{task.id, grasp.instance_id}];
  }
  std::map<std::pair<int, int>, int64_t> handed_out() const {
    std::lock_guard lock(mutex_);
    return handed_out_;
  }
  testing::ScriptedPlanner scripted;

 private:
  mutable std::mutex mutex_;
  std::map<std::pair<int, int>, int64_t> handed_out_;  // GUARDED_BY(mutex_)
};

// The in-process server: scripted planner, handler with binpickd's
// observers, DaoAI server on an ephemeral port.
struct InProcess {
  std::shared_ptr<CountingPlanner> planner = std::make_shared<CountingPlanner>();
  MetricsRegistry metrics;
  std::shared_ptr<StatusState> status;
  std::unique_ptr<RequestHandler> handler;
  std::unique_ptr<DaoaiServer> server;

  Status Start(const Options& o, int tasks) {
    Cell cell = testing::MakeTestCell();
    cell.tasks.clear();
    for (int i = 0; i < tasks; ++i) {
      TaskSpec t;
      t.id = i;
      t.kind = TaskSpec::Kind::kPick;
      t.name = "task" + std::to_string(i);
      cell.tasks.push_back(t);
      testing::ScriptedPlanner::Script s;
      s.grasps = o.grasps;
      s.plan_delay = std::chrono::milliseconds(o.plan_ms);
      planner->scripted.SetScript(i, s);
    }
    status = std::make_shared<StatusState>(cell, metrics);
    handler = std::make_unique<RequestHandler>(cell, planner, nullptr);
    handler->AddObserver(status);
    DaoaiServerOptions so;
    so.port = 0;
    so.max_connections = 0;
    so.max_connections_per_peer = 0;  // every robot is 127.0.0.1
    so.max_message_rate = o.max_message_rate;
    auto started = DaoaiServer::Start(*handler, so);
    if (!started.ok()) return started.status();
    server = std::move(*started);
    AddTransportMetrics(metrics, "daoai", [this] { return server->stats(); });
    AddQueueMetrics(metrics, *handler);
    AddHandlerMetrics(metrics, *handler);
    return Status::Ok();
  }
  void Stop() {
    if (server) server->Stop();
    if (handler) handler->Shutdown();
  }
};

Result<std::unique_ptr<RobotClient>> Connect(const Options& o, int port) {
  RobotClientOptions ro;
  ro.host = o.host;
  ro.port = port;
  ro.timeout = std::chrono::milliseconds(30000);
  return RobotClient::Connect(ro);
}

// ------------------------------------------------------------------ flood

// Pick-pose latencies (ms) of `cycles` capture + pick cycles on `task`.
std::vector<double> PickLatencies(RobotClient& robot, int task, int cycles, const std::atomic<bool>* stop,
                                  std::string* error) {
  std::vector<double> out;
  for (int i = 0; i < cycles && !(stop && *stop); ++i) {
    Result<RobotReply> cap = robot.Call(daoai::kCaptureAndProcessAsync, task);
    if (!cap.ok() || cap->status != daoai::kDetection) {
      *error = "capture: " + (cap.ok() ? "status " + std::to_string(cap->status) : cap.status().ToString());
      return out;
    }
    const auto t0 = Clock::now();
    Result<RobotReply> pick = robot.Call(daoai::kPickPose, task);
    out.push_back(Ms(Clock::now() - t0));
    if (!pick.ok() || (pick->status != daoai::kObjectsFound && pick->status != daoai::kNoObjectFound &&
                       pick->status != daoai::kNoCollisionFreePose)) {
      *error = "pick: " + (pick.ok() ? "status " + std::to_string(pick->status) : pick.status().ToString());
      return out;
    }
  }
  return out;
}

int Flood(const Options& o) {
  InProcess local;
  int port = o.port;
  if (port == 0) {
    if (Status s = local.Start(o, std::max(o.flood_task, o.pick_task) + 1); !s.ok()) {
      std::cerr << "bp_soak: " << s.ToString() << "\n";
      return 2;
    }
    port = local.server->port();
  }
  auto second = Connect(o, port);
  if (!second.ok()) {
    std::cerr << "bp_soak: " << second.status().ToString() << "\n";
    return 2;
  }
  std::string error;
  // A single plan time: the second robot alone, after 10 cycles of warm-up
  // (the first detections of a binpickd are slower).
  (void)PickLatencies(**second, o.pick_task, 10, nullptr, &error);
  const std::vector<double> alone = PickLatencies(**second, o.pick_task, 30, nullptr, &error);
  if (!error.empty()) {
    std::cerr << "bp_soak: alone: " << error << "\n";
    return 1;
  }
  const double single = Percentile(alone, 0.5);

  std::atomic<bool> stop{false};
  std::atomic<int64_t> flood_requests{0};
  std::string flood_error;
  std::thread flooder([&] {
    auto robot = Connect(o, port);
    if (!robot.ok()) {
      flood_error = robot.status().ToString();
      return;
    }
    while (!stop) {
      Result<RobotReply> r = (*robot)->Call(o.flood_command, o.flood_task);
      if (!r.ok() || r->status != daoai::kDetection) {
        flood_error = r.ok() ? "status " + std::to_string(r->status) : r.status().ToString();
        return;
      }
      ++flood_requests;
    }
  });
  const auto end = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                      std::chrono::duration<double>(o.seconds));
  std::vector<double> flooded;
  std::thread timer([&] {
    while (Clock::now() < end && !stop) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    stop = true;
  });
  while (!stop && error.empty()) {
    std::vector<double> some = PickLatencies(**second, o.pick_task, 1, &stop, &error);
    flooded.insert(flooded.end(), some.begin(), some.end());
  }
  stop = true;
  timer.join();
  flooder.join();
  const RequestHandlerStats hs = local.handler ? local.handler->stats() : RequestHandlerStats{};
  std::string in_process;
  if (local.handler) {
    const Result<RequestHandler::TaskSnapshot> flooded = local.handler->Snapshot(o.flood_task);
    in_process = ", " + std::to_string(hs.captures_coalesced) + " coalesced, " +
                 std::to_string(flooded.ok() ? flooded->finished : 0) + " detections of the flooded task (" +
                 std::to_string(hs.background_detections) + " planned in the background)";
  }
  local.Stop();
  std::printf("bp_soak flood: %.0f s, flooding robot sent %lld captures (%d, %.0f/s)%s\n", o.seconds,
              static_cast<long long>(flood_requests.load()), o.flood_command,
              static_cast<double>(flood_requests.load()) / o.seconds, in_process.c_str());
  std::printf("bp_soak flood: single plan time (second robot alone, pick p50 of %zu): %.2f ms\n",
              alone.size(), single);
  std::printf("bp_soak flood: second robot under the flood: %zu picks, p50 %.2f ms, p99 %.2f ms, "
              "max %.2f ms; p99 / single plan time = %.2f\n",
              flooded.size(), Percentile(flooded, 0.5), Percentile(flooded, 0.99),
              Percentile(flooded, 1.0), single > 0 ? Percentile(flooded, 0.99) / single : 0.0);
  if (!error.empty() || !flood_error.empty()) {
    std::printf("bp_soak flood: error: %s %s\n", error.c_str(), flood_error.c_str());
    return 1;
  }
  return 0;
}

// ------------------------------------------------------------------- soak

struct Sample {
  int64_t requests = 0;
  int64_t rss_bytes = 0;
  int fds = 0;
  size_t metrics_bytes = 0;
  size_t metrics_series = 0;  // sample lines: a counter's value may gain digits, the set may not grow
};

// One robot of the soak: its own task, a seeded mix of requests.
class SoakRobot {
 public:
  SoakRobot(const Options& o, int id, int port, std::atomic<int64_t>& budget)
      : o_(o), id_(id), port_(port), budget_(budget), rng_(static_cast<uint32_t>(o.seed * 1000 + id)) {}

  void Run() {
    if (!Reconnect()) return;
    while (budget_.fetch_sub(1) > 0) {
      if (!Step()) break;
    }
    client_.reset();  // the robot leaves: its descriptors are not the server's
  }

  int64_t requests = 0;
  int64_t reconnects = 0;
  std::vector<std::string> errors;
  std::map<std::pair<int, int>, int64_t> received;  // (task, instance) -> count

 private:
  bool Fail(const std::string& what) {
    errors.push_back("robot " + std::to_string(id_) + ": " + what);
    return false;
  }
  bool Reconnect() {
    client_.reset();
    auto c = Connect(o_, port_);
    if (!c.ok()) return Fail(c.status().ToString());
    client_ = std::move(*c);
    ++reconnects;
    return true;
  }
  Result<RobotReply> Call(int32_t command, int32_t payload_1) {
    ++requests;
    return client_->Call(command, payload_1);
  }

  // One request (a pick cycle's picks count one each against the budget).
  bool Step() {
    const uint32_t dice = rng_() % 1000;
    if (dice < 5) return Reconnect();
    if (dice < 25) {  // garbage: an unknown command, answered -1
      Result<RobotReply> r = Call(static_cast<int32_t>(1000 + rng_() % 100000), 0);
      if (!r.ok() || r->status != daoai::kUnknownCommand) return Fail("garbage not answered -1");
      return true;
    }
    if (dice < 35) {  // garbage: a protocol version that does not exist
      daoai::Request bad = client_->MakeRequest(daoai::kPickPose, id_);
      bad.meta_2 = 7;
      const auto bytes = daoai::EncodeRequest(bad);
      ++requests;
      if (!client_->SendBytes(bytes.data(), bytes.size()).ok()) return Fail("send");
      Result<RobotReply> r = client_->Receive();
      if (!r.ok() || r->status != daoai::kUnknownCommand) return Fail("bad meta_2 not answered -1");
      return true;
    }
    if (dice < 85) {  // pose update: no answer
      ++requests;
      return client_->Send(daoai::kNoCommand, 0).ok() || Fail("pose update");
    }
    if (!capturing_) {
      const bool sync = dice % 2 == 0;
      Result<RobotReply> r = Call(sync ? daoai::kCaptureAndProcess : daoai::kCaptureAndProcessAsync, id_);
      if (!r.ok() || r->status != daoai::kDetection) {
        return Fail("capture: " + (r.ok() ? "status " + std::to_string(r->status) : r.status().ToString()));
      }
      capturing_ = true;
      return true;
    }
    Result<RobotReply> pick = Call(daoai::kPickPose, id_);
    if (!pick.ok()) return Fail("pick: " + pick.status().ToString());
    if (pick->status == daoai::kNoObjectFound) {
      capturing_ = false;  // the queue is empty: capture again
      return true;
    }
    if (pick->status != daoai::kObjectsFound || !pick->X_BT) {
      return Fail("pick: status " + std::to_string(pick->status));
    }
    // The scripted planner puts grasp i at x = 0.5 + 0.01 i.
    const int instance = static_cast<int>(std::lround((pick->X_BT->translation().x() - 0.5) / 0.01));
    ++received[{id_, instance}];
    return true;
  }

  const Options& o_;
  const int id_;
  const int port_;
  std::atomic<int64_t>& budget_;
  std::mt19937 rng_;
  std::unique_ptr<RobotClient> client_;
  bool capturing_ = false;  // a capture was answered and its queue not yet emptied
};

Sample Measure(InProcess& s, int64_t requests) {
  Sample m;
  m.requests = requests;
  m.rss_bytes = testing::ResidentBytes();
  m.fds = testing::OpenFdCount();
  const std::string text = s.metrics.Render();
  m.metrics_bytes = text.size();
  for (size_t at = 0; at < text.size();) {
    const size_t end = std::min(text.find('\n', at), text.size());
    if (end > at && text[at] != '#') ++m.metrics_series;
    at = end + 1;
  }
  return m;
}

int Soak(const Options& o) {
  if (o.port != 0) {
    std::cerr << "bp_soak: the soak runs in-process (it counts the planner's grasps)\n";
    return 2;
  }
  InProcess s;
  if (Status st = s.Start(o, o.robots); !st.ok()) {
    std::cerr << "bp_soak: " << st.ToString() << "\n";
    return 2;
  }
  const int port = s.server->port();
  // Warm-up: 2% of the requests (threads, allocator arenas, every metric
  // series that a closed label set allows), then the baseline.
  auto run = [&](int64_t total, std::vector<std::unique_ptr<SoakRobot>>& robots) {
    std::atomic<int64_t> budget{total};
    std::vector<std::thread> threads;
    for (int r = 0; r < o.robots; ++r) {
      robots.push_back(std::make_unique<SoakRobot>(o, r, port, budget));
      threads.emplace_back([robot = robots.back().get()] { robot->Run(); });
    }
    for (auto& t : threads) t.join();
  };
  std::vector<std::unique_ptr<SoakRobot>> warm, main;
  const int64_t warm_requests = std::max<int64_t>(1000, o.requests / 50);
  run(warm_requests, warm);
  // The robots have left; the server closes their connections asynchronously.
  testing::WaitUntil([&] { return s.server->connection_count() == 0; });
  const Sample before = Measure(s, warm_requests);
  const auto t0 = Clock::now();
  run(o.requests, main);
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  // The server's connections of the last robots close asynchronously.
  testing::WaitUntil([&] { return s.server->connection_count() == 0; });
  const Sample after = Measure(s, o.requests);
  const RequestHandlerStats hs = s.handler->stats();
  s.Stop();

  std::map<std::pair<int, int>, int64_t> received, handed_out;
  int64_t requests = 0, reconnects = 0;
  std::vector<std::string> errors;
  for (auto* list : {&warm, &main}) {
    for (const auto& r : *list) {
      for (const auto& [k, n] : r->received) received[k] += n;
      requests += r->requests;
      reconnects += r->reconnects;
      errors.insert(errors.end(), r->errors.begin(), r->errors.end());
    }
  }
  handed_out = s.planner->handed_out();
  int64_t lost = 0, duplicated = 0, grasps = 0;
  for (const auto& [k, n] : handed_out) {
    const int64_t got = received.count(k) ? received[k] : 0;
    lost += std::max<int64_t>(0, n - got);
    grasps += n;
  }
  for (const auto& [k, n] : received) {
    const int64_t out = handed_out.count(k) ? handed_out[k] : 0;
    duplicated += std::max<int64_t>(0, n - out);
  }
  const double rss_growth = 100.0 * static_cast<double>(after.rss_bytes - before.rss_bytes) /
                            static_cast<double>(before.rss_bytes);
  std::printf("bp_soak: %d robots, max_message_rate %g/s per connection, %lld requests (+%lld warm-up) in "
              "%.1f s (%.0f/s), %lld reconnects, %lld grasps handed out, %llu captures coalesced\n",
              o.robots, o.max_message_rate, static_cast<long long>(o.requests), static_cast<long long>(warm_requests),
              seconds, static_cast<double>(o.requests) / seconds, static_cast<long long>(reconnects),
              static_cast<long long>(grasps), static_cast<unsigned long long>(hs.captures_coalesced));
  std::printf("bp_soak: %lld requests sent by the robots (a pick cycle counts each pick), "
              "errors %zu, grasps lost %lld, duplicated %lld\n",
              static_cast<long long>(requests), errors.size(), static_cast<long long>(lost),
              static_cast<long long>(duplicated));
  std::printf("bp_soak: RSS %.1f -> %.1f MiB (%+.2f%%), fds %d -> %d, /metrics %zu -> %zu series, "
              "%zu -> %zu bytes\n",
              static_cast<double>(before.rss_bytes) / (1 << 20),
              static_cast<double>(after.rss_bytes) / (1 << 20), rss_growth, before.fds, after.fds,
              before.metrics_series, after.metrics_series, before.metrics_bytes, after.metrics_bytes);
  for (size_t i = 0; i < std::min<size_t>(errors.size(), 5); ++i) {
    std::printf("bp_soak: error: %s\n", errors[i].c_str());
  }
  const bool ok = errors.empty() && lost == 0 && duplicated == 0 && rss_growth < 1.0 &&
                  after.fds <= before.fds && after.metrics_series == before.metrics_series;
  std::printf("bp_soak: %s\n", ok ? "PASS" : "FAIL");
  return ok ? 0 : 1;
}

}  // namespace
}  // namespace bp

int main(int argc, char** argv) {
  CLI::App app{"serving under contention and abuse: capture flood latency, 1M-request soak"};
  bp::Options o;
  app.add_option("--mode", o.mode, "flood or soak")->check(CLI::IsMember({"flood", "soak"}));
  app.add_option("--robots", o.robots, "soak: robots, each on its own task")->check(CLI::Range(1, 64));
  app.add_option("--requests", o.requests, "soak: requests after the warm-up")->check(CLI::PositiveNumber);
  app.add_option("--seconds", o.seconds, "flood: duration")->check(CLI::PositiveNumber);
  app.add_option("--host", o.host, "server address with --port");
  app.add_option("--port", o.port, "flood: a running binpickd's DaoAI port (default: in-process)");
  app.add_option("--grasps", o.grasps, "in-process: grasps per detection");
  app.add_option("--max-message-rate", o.max_message_rate,
                 "in-process: requests/s per connection (default binpickd's, the cell's "
                 "endpoints.max_message_rate; 0: off)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--plan-ms", o.plan_ms, "in-process: detection time, ms");
  app.add_option("--seed", o.seed, "soak: the robots' random mix");
  app.add_option("--flood-task", o.flood_task, "flood: the flooding robot's task")->check(CLI::Range(0, 99));
  app.add_option("--flood-command", o.flood_command, "flood: the flooding robot's capture, 19 (async) or 20")
      ->check(CLI::IsMember({19, 20}));
  app.add_option("--pick-task", o.pick_task, "flood: the second robot's pick task (with --port, one of the "
                 "cell's pick tasks: on the default cell task 1 is the in-hand check)")->check(CLI::Range(0, 99));
  std::string log_level = "error";
  app.add_option("--log-level", log_level, "in-process server log level");
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::from_str(log_level));
  // As binpickd: room for the detection arena's workers.
  const size_t parallelism = std::max<size_t>(
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism),
      static_cast<size_t>(bp::RequestHandlerOptions{}.detection_threads) + 1);
  tbb::global_control allow_workers(tbb::global_control::max_allowed_parallelism, parallelism);
  return o.mode == "flood" ? bp::Flood(o) : bp::Soak(o);
}
