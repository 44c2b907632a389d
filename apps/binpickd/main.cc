// binpickd: the picking server. Loads a cell, builds the grasp planner and
// serves robots over the DaoAI socket protocol and the GRI until SIGINT / SIGTERM.
//
//   binpickd [--cell FILE] [--bind ADDR] [--daoai-port N]     (port 0 disables)
//            [--modbus-robot HOST:PORT]...  (Modbus master per robot slave;
//             default: the cell's robot.modbus, if any)
//            [--gri-port N] [--gri-official-port N] [--gri-timeout S]
//            [--max-connections N] [--max-message-rate R] [--allow IP]...
//
// Prints exactly one line on stdout when ready to accept robots (logs go to
// stderr):
//   binpickd ready: daoai 127.0.0.1:6969; gri v2 127.0.0.1:10000, official 127.0.0.1:7100
#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>
#include <pthread.h>
#include <string>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/modbus_master.h"
#include "comms/gri_server.h"
#include "comms/request_handler.h"
#include "core/cell.h"
#include "grasp/planner_factory.h"

int main(int argc, char** argv) {
  CLI::App app{"binpick picking server"};
  std::string cell_path;
  std::optional<std::string> bind;
  std::optional<int> daoai_port;
  std::optional<int> gri_port;
  std::optional<int> gri_official_port;
  double gri_timeout_s = 70.0;
  double read_timeout_s = 30.0;
  int detection_threads = 2;
  std::string log_level = "info";
  std::vector<std::string> modbus_robots;
  std::optional<int> modbus_poll_ms;
  std::optional<int> max_connections;
  std::optional<double> max_message_rate;
  std::vector<std::string> allow;
  app.add_option("--cell", cell_path, "cell file (default: the embedded default cell)");
  app.add_option("--bind", bind, "listen address (default: the cell's endpoints.bind)");
  app.add_option("--daoai-port", daoai_port, "DaoAI socket port, 0 disables (default: the cell's)");
  app.add_option("--gri-port", gri_port, "GRI protocol v2 port, 0 disables (default: the cell's)");
  app.add_option("--gri-official-port", gri_official_port,
                 "GRI official-format port, 0 disables (default: the cell's)");
  app.add_option("--gri-timeout", gri_timeout_s,
                 "seconds a GRI request may wait for its result before PROCESSING_TIMEOUT");
  app.add_option("--read-timeout", read_timeout_s,
                 "seconds without a complete request before an idle robot is disconnected");
  app.add_option("--detection-threads", detection_threads, "oneTBB arena size for detection");
  app.add_option("--log-level", log_level, "trace|debug|info|warn|error|off");
  app.add_option("--max-connections", max_connections,
                 "robot connections per listener, more are closed at accept; 0 unlimited "
                 "(default: the cell's endpoints.max_connections)");
  app.add_option("--max-message-rate", max_message_rate,
                 "requests/s per connection, faster robots are read no faster; 0 unlimited "
                 "(default: the cell's endpoints.max_message_rate)");
  app.add_option("--allow", allow,
                 "robot IP allowed to connect, repeatable; others are closed at accept "
                 "(default: the cell's endpoints.allowlist; none: any)");
  app.add_option("--modbus-robot", modbus_robots,
                 "HOST:PORT of a robot Modbus slave to serve as master (repeatable; default: the "
                 "cell's robot.modbus)");
  app.add_option("--modbus-poll-ms", modbus_poll_ms,
                 "Modbus request flag poll interval (default: the cell's robot.modbus.poll_ms)");
  CLI11_PARSE(app, argc, argv);
  // stdout carries only the ready line; logs go to stderr.
  spdlog::set_default_logger(spdlog::stderr_color_mt("binpickd"));
  spdlog::set_level(spdlog::level::from_str(log_level));

  // Block the stop signals before any thread starts; main waits for them.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  bp::Result<bp::Cell> cell = bp::LoadCellOrDefault(cell_path);
  if (!cell.ok()) {
    std::cerr << "binpickd: " << cell.status().ToString() << "\n";
    return 2;
  }
  bp::Result<std::unique_ptr<bp::GraspPlanner>> planner = bp::MakePlanner(*cell);
  if (!planner.ok()) {
    std::cerr << "binpickd: cannot start: " << planner.status().ToString() << "\n";
    return 3;
  }

  // oneTBB caps its workers at cores - 1; the detection arena asks for
  // detection_threads workers of its own, so allow them (plus this thread).
  const size_t parallelism = std::max<size_t>(
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism),
      static_cast<size_t>(detection_threads) + 1);
  tbb::global_control allow_workers(tbb::global_control::max_allowed_parallelism, parallelism);

  bp::RequestHandlerOptions handler_options;
  handler_options.detection_threads = detection_threads;
  bp::RequestHandler handler(*cell, std::shared_ptr<bp::GraspPlanner>(std::move(*planner)),
                             nullptr, handler_options);

  bp::DaoaiServerOptions daoai;
  daoai.bind = bind.value_or(cell->endpoints.bind);
  daoai.port = daoai_port.value_or(cell->endpoints.daoai_port);
  daoai.read_timeout = std::chrono::milliseconds(static_cast<int64_t>(read_timeout_s * 1000));
  daoai.max_connections = static_cast<size_t>(
      std::max(0, max_connections.value_or(cell->endpoints.max_connections)));
  daoai.max_message_rate = std::max(0.0, max_message_rate.value_or(cell->endpoints.max_message_rate));
  daoai.allowlist = allow.empty() ? cell->endpoints.allowlist : allow;
  if (!daoai.allowlist.empty()) {
    std::string list;
    for (const std::string& ip : daoai.allowlist) list += (list.empty() ? "" : ", ") + ip;
    spdlog::info("binpickd: robots allowed to connect: {}", list);
  }
  std::unique_ptr<bp::DaoaiServer> server;
  std::string ready = "binpickd ready: daoai ";
  if (daoai.port != 0) {
    auto started = bp::DaoaiServer::Start(handler, daoai);
    if (!started.ok()) {
      std::cerr << "binpickd: " << started.status().ToString() << "\n";
      return 2;
    }
    server = std::move(*started);
    ready += server->address();
  } else {
    ready += "disabled";
  }
  // One Modbus master per robot slave, sharing the handler.
  std::vector<std::unique_ptr<bp::ModbusMaster>> masters;
  {
    std::vector<bp::ModbusMasterOptions> robots;
    const bp::ModbusMasterOptions base = bp::ModbusMasterOptionsFromCell(cell->robot);
    for (const std::string& hp : modbus_robots) {
      bp::ModbusMasterOptions o = base;
      const size_t colon = hp.rfind(':');
      o.host = hp.substr(0, colon);
      if (o.host.size() > 2 && o.host.front() == '[' && o.host.back() == ']') {
        o.host = o.host.substr(1, o.host.size() - 2);  // [::1]:502
      }
      o.port = 0;
      if (colon != std::string::npos) {
        try {
          o.port = std::stoi(hp.substr(colon + 1));
        } catch (const std::exception&) {
        }
      }
      if (colon == std::string::npos || o.host.empty() || o.port <= 0) {
        std::cerr << "binpickd: --modbus-robot '" << hp << "' is not HOST:PORT\n";
        return 2;
      }
      robots.push_back(o);
    }
    if (modbus_robots.empty() && !cell->robot.modbus_host.empty()) robots.push_back(base);
    for (bp::ModbusMasterOptions& o : robots) {
      if (modbus_poll_ms) o.poll_interval = std::chrono::milliseconds(*modbus_poll_ms);
      auto started = bp::ModbusMaster::Start(handler, o);
      if (!started.ok()) {
        std::cerr << "binpickd: " << started.status().ToString() << "\n";
        return 2;
      }
      spdlog::info("binpickd: Modbus master for robot {}", (*started)->address());
      masters.push_back(std::move(*started));
    }
  }
  bp::GriHandler gri_handler(handler);
  bp::GriServerOptions gri;
  gri.bind = daoai.bind;
  gri.v2_port = gri_port.value_or(cell->endpoints.gri_port);
  gri.official_port = gri_official_port.value_or(cell->endpoints.gri_official_port);
  gri.read_timeout = daoai.read_timeout;
  gri.max_connections = daoai.max_connections;
  gri.max_message_rate = daoai.max_message_rate;
  gri.allowlist = daoai.allowlist;
  gri.processing_timeout = std::chrono::milliseconds(static_cast<int64_t>(gri_timeout_s * 1000));
  std::unique_ptr<bp::GriServer> gri_server;
  ready += "; gri ";
  if (gri.v2_port != 0 || gri.official_port != 0) {
    auto started = bp::GriServer::Start(gri_handler, gri);
    if (!started.ok()) {
      std::cerr << "binpickd: " << started.status().ToString() << "\n";
      return 2;
    }
    gri_server = std::move(*started);
    ready += gri_server->Describe();
  } else {
    ready += "disabled";
  }
  spdlog::info("binpickd: cell '{}' from {}", cell->name, cell->path);
  std::cout << ready << std::endl;

  int signal = 0;
  sigwait(&stop_signals, &signal);
  spdlog::info("binpickd: {} received, stopping", signal == SIGINT ? "SIGINT" : "SIGTERM");
  if (server) server->Stop();
  for (auto& master : masters) master->Stop();
  if (gri_server) gri_server->Stop();
  handler.Shutdown();
  server.reset();
  gri_server.reset();
  return 0;
}
