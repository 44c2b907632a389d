// Bounded load test of the DaoAI server (docs/reliability.md "Load"): N
// robots, each on its own pick task, loop "capture, then pick poses until the
// queue is empty" for a fixed time over loopback. Any transport error or
// unexpected status is an error; exits 1 if there was one.
//
//   build/bin/bp_load --robots 8 --seconds 10
//   build/bin/bp_load --robots 8 --seconds 10 --port 6969   (a running binpickd;
//       its cell needs pick tasks 0..N-1, e.g. --task-base)
//
// In-process (no --port) the planner is the scripted test double
// (tests/testing/scripted_planner.h) with --grasps grasps per detection and
// --plan-ms of detection time: this loads the protocol path, the request
// handler, the queues and the network threads, not perception.
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/request_handler.h"
#include "comms/robot_client.h"
#include "tests/testing/scripted_planner.h"

namespace {

using Clock = std::chrono::steady_clock;

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
  return v[i];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"bounded load test: N robots capture and pick in a loop"};
  int robots = 8;
  double seconds = 10;
  int port = 0;
  std::string host = "127.0.0.1";
  int task_base = 100;
  int grasps = 5;
  int plan_ms = 5;
  double max_message_rate = 0;
  int io_threads = 1;
  app.add_option("--robots", robots, "robots (connections), each on its own task")->check(CLI::Range(1, 256));
  app.add_option("--seconds", seconds, "duration")->check(CLI::PositiveNumber);
  app.add_option("--host", host, "server address with --port");
  app.add_option("--port", port, "a running server's DaoAI port (default: one in-process)");
  app.add_option("--task-base", task_base, "robot i uses pick task task_base + i");
  app.add_option("--grasps", grasps, "in-process: grasps per detection");
  app.add_option("--plan-ms", plan_ms, "in-process: detection time, ms");
  app.add_option("--max-message-rate", max_message_rate, "in-process: the server's limit");
  app.add_option("--io-threads", io_threads, "in-process: network threads");
  std::string log_level = "warn";
  app.add_option("--log-level", log_level, "server log level in-process (default warn)");
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::from_str(log_level));

  // As in binpickd: oneTBB caps its workers at cores - 1, and the handler's
  // detection arena asks for detection_threads workers of its own (without
  // this, on 2 cores, one detection ran at a time and oneTBB warned).
  const size_t parallelism = std::max<size_t>(
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism),
      static_cast<size_t>(bp::RequestHandlerOptions{}.detection_threads) + 1);
  tbb::global_control allow_workers(tbb::global_control::max_allowed_parallelism, parallelism);

  std::shared_ptr<bp::testing::ScriptedPlanner> planner;
  std::unique_ptr<bp::RequestHandler> handler;
  std::unique_ptr<bp::DaoaiServer> server;
  if (port == 0) {
    planner = std::make_shared<bp::testing::ScriptedPlanner>();
    bp::Cell cell = bp::testing::MakeTestCell();
    for (int i = 0; i < robots; ++i) {
      bp::TaskSpec t;
      t.id = task_base + i;
      t.kind = bp::TaskSpec::Kind::kPick;
      t.name = "load" + std::to_string(i);
      cell.tasks.push_back(t);
      bp::testing::ScriptedPlanner::Script s;
      s.grasps = grasps;
      s.plan_delay = std::chrono::milliseconds(plan_ms);
      planner->SetScript(t.id, s);
    }
    handler = std::make_unique<bp::RequestHandler>(cell, planner, nullptr);
    bp::DaoaiServerOptions o;
    o.port = 0;
    o.max_connections = static_cast<size_t>(robots);
    o.max_connections_per_peer = 0;  // every robot is 127.0.0.1
    o.max_message_rate = max_message_rate;
    o.io_threads = io_threads;
    auto started = bp::DaoaiServer::Start(*handler, o);
    if (!started.ok()) {
      std::cerr << "bp_load: " << started.status().ToString() << "\n";
      return 2;
    }
    server = std::move(*started);
    port = server->port();
  }

  std::mutex mutex;
  std::vector<double> capture_ms, pick_ms;
  std::atomic<int64_t> errors{0}, cycles{0}, picks{0};
  std::vector<std::string> first_errors;
  const auto end = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                      std::chrono::duration<double>(seconds));
  auto error = [&](const std::string& what) {
    ++errors;
    std::lock_guard lock(mutex);
    if (first_errors.size() < 5) first_errors.push_back(what);
  };
  std::vector<std::thread> threads;
  for (int r = 0; r < robots; ++r) {
    threads.emplace_back([&, r] {
      bp::RobotClientOptions o;
      o.host = host;
      o.port = port;
      o.timeout = std::chrono::milliseconds(10000);
      auto client = bp::RobotClient::Connect(o);
      if (!client.ok()) {
        error("robot " + std::to_string(r) + ": " + client.status().ToString());
        return;
      }
      const int task = task_base + r;
      std::vector<double> caps, pks;
      while (Clock::now() < end) {
        auto t0 = Clock::now();
        bp::Result<bp::RobotReply> cap = (*client)->Call(bp::daoai::kCaptureAndProcess, task);
        caps.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        if (!cap.ok() || cap->status != bp::daoai::kDetection) {
          error("robot " + std::to_string(r) + " capture: " +
                (cap.ok() ? "status " + std::to_string(cap->status) : cap.status().ToString()));
          return;
        }
        ++cycles;
        for (;;) {
          t0 = Clock::now();
          bp::Result<bp::RobotReply> pick = (*client)->Call(bp::daoai::kPickPose, task);
          pks.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
          if (!pick.ok()) {
            error("robot " + std::to_string(r) + " pick: " + pick.status().ToString());
            return;
          }
          if (pick->status == bp::daoai::kNoObjectFound) break;
          if (pick->status != bp::daoai::kObjectsFound) {
            error("robot " + std::to_string(r) + " pick: status " + std::to_string(pick->status));
            return;
          }
          ++picks;
        }
      }
      std::lock_guard lock(mutex);
      capture_ms.insert(capture_ms.end(), caps.begin(), caps.end());
      pick_ms.insert(pick_ms.end(), pks.begin(), pks.end());
    });
  }
  for (auto& t : threads) t.join();
  // After Stop: a grasp counts as handed out once its answer's write
  // completed, which can lag the robot's read of it.
  if (server) server->Stop();
  if (handler) handler->Shutdown();
  int64_t handed_out = planner ? static_cast<int64_t>(planner->handed_out().size()) : picks.load();

  const size_t requests = capture_ms.size() + pick_ms.size();
  std::vector<double> all = capture_ms;
  all.insert(all.end(), pick_ms.begin(), pick_ms.end());
  std::printf("bp_load: %d robots, %.1f s: %zu requests (%.0f/s), %lld cycles, %lld picks, "
              "%lld handed out, %lld errors\n",
              robots, seconds, requests, static_cast<double>(requests) / seconds,
              static_cast<long long>(cycles.load()), static_cast<long long>(picks.load()),
              static_cast<long long>(handed_out), static_cast<long long>(errors.load()));
  std::printf("bp_load: latency ms   p50 %.3f  p99 %.3f  max %.3f (all requests)\n",
              Percentile(all, 0.5), Percentile(all, 0.99), Percentile(all, 1.0));
  std::printf("bp_load: capture ms   p50 %.3f  p99 %.3f;  pick ms p50 %.3f  p99 %.3f\n",
              Percentile(capture_ms, 0.5), Percentile(capture_ms, 0.99), Percentile(pick_ms, 0.5),
              Percentile(pick_ms, 0.99));
  for (const std::string& e : first_errors) std::printf("bp_load: error: %s\n", e.c_str());
  if (planner && handed_out != picks.load()) {
    std::printf("bp_load: error: %lld grasps handed out for %lld picks received\n",
                static_cast<long long>(handed_out), static_cast<long long>(picks.load()));
    return 1;
  }
  return errors.load() == 0 ? 0 : 1;
}
