// binpickd: the picking server. Loads a cell, builds the grasp planner and
// serves robots over the DaoAI socket protocol and the GRI until SIGINT / SIGTERM.
//
//   binpickd [--cell FILE] [--bind ADDR] [--daoai-port N]     (port 0 disables)
//            [--modbus-robot HOST:PORT]...  (Modbus master per robot slave;
//             default: the cell's robot.modbus, if any)
//            [--gri-port N] [--gri-official-port N] [--gri-timeout S]
//            [--http-port N] [--http-bind ADDR]  (status page, JSON API and
//             /metrics: docs/status_page.md; port 0 or absent disables)
//            [--source synthetic|files:DIR|replay:DIR]  (default: the cell's source)
//            [--no-record] [--record-dir DIR] [--record-max-mb N]  (default: the cell's recording)
//            [--taught-grasps FILE]  (default: <cell file>.taught.yaml)
//            [--max-connections N] [--max-connections-per-peer N] [--max-message-rate R]
//            [--allow ADDR[/PREFIX]]... [--allow-config ADDR[/PREFIX]]...
//            [--http-allow ADDR[/PREFIX]]...   (docs/reliability.md "Threat model")
//
// Prints exactly one line on stdout when ready to accept robots (logs go to
// stderr):
//   binpickd ready: daoai 127.0.0.1:6969; gri v2 127.0.0.1:10000, official 127.0.0.1:7100
// with "; http 127.0.0.1:8080" appended when the status page is on.
#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <pthread.h>
#include <string>
#include <vector>

#include "calib/calibration_camera.h"
#include "calib/hand_eye_service.h"
#include "calib/hand_eye_state.h"
#include "calib/precision_check.h"
#include "comms/daoai_server.h"
#include "comms/gri_server.h"
#include "comms/modbus_master.h"
#include "comms/plane_calibration_service.h"
#include "comms/request_handler.h"
#include "core/address_list.h"
#include "core/cell.h"
#include "core/service_notify.h"
#include "grasp/planner_factory.h"
#include "twod/planner_2d.h"
#include "web/metrics.h"
#include "web/server_metrics.h"
#include "web/status_server.h"
#include "web/status_state.h"
#include "record/recorder.h"
#include "record/recorder_metrics.h"

namespace {

// Parses the three allowlists so that a bad entry stops the start with one
// message (nullopt, printed), logs the lists, and warns when a listener binds
// beyond loopback without one: industrial protocols carry no authentication,
// so the allowlists are the control (docs/reliability.md "Threat model").
// `http_bind` is loopback when the status page is off.
// @returns the config allowlist (empty: every robot may change the cell).
std::optional<bp::AddressList> CheckAllowlists(const std::vector<std::string>& robot_list,
                                               const std::vector<std::string>& config_list,
                                               const std::vector<std::string>& http_list,
                                               const std::string& robot_bind,
                                               const std::string& http_bind) {
  bp::Result<bp::AddressList> robots = bp::AddressList::Parse(robot_list);
  bp::Result<bp::AddressList> config = bp::AddressList::Parse(config_list);
  bp::Result<bp::AddressList> browsers = bp::AddressList::Parse(http_list);
  for (const auto& [flag, list] : {std::pair{"--allow / endpoints.allowlist", &robots},
                                   std::pair{"--allow-config / endpoints.config_allowlist", &config},
                                   std::pair{"--http-allow / endpoints.http_allowlist", &browsers}}) {
    if (!list->ok()) {
      std::cerr << "binpickd: " << flag << ": " << list->status().message() << "\n";
      return std::nullopt;
    }
  }
  if (!robots->empty()) spdlog::info("binpickd: robots allowed to connect: {}", robots->Describe());
  if (!config->empty()) spdlog::info("binpickd: peers allowed to change the cell: {}", config->Describe());
  if (!bp::IsLoopbackAddress(robot_bind)) {
    if (robots->empty()) {
      spdlog::warn("binpickd: the robot ports listen on {} with no allowlist: any host that "
                   "reaches them can take grasps and, with no config allowlist, recalibrate "
                   "the camera; give --allow ADDR[/PREFIX] (endpoints.allowlist) and "
                   "--allow-config (docs/reliability.md \"Threat model\")", robot_bind);
    } else if (config->empty()) {
      spdlog::warn("binpickd: every allowed robot may change the cell (calibration, teach, "
                   "camera config); give --allow-config ADDR[/PREFIX] "
                   "(endpoints.config_allowlist) to restrict it");
    }
  }
  if (!bp::IsLoopbackAddress(http_bind) && browsers->empty()) {
    spdlog::warn("binpickd: the status page listens on {} with no allowlist: any host that "
                 "reaches it can read the cell's state; give --http-allow ADDR[/PREFIX] "
                 "(endpoints.http_allowlist)", http_bind);
  }
  return std::move(config).value();
}

// The command line. An unset optional (or empty list) takes the cell's value.
struct Flags {
  std::string cell_path;
  std::optional<std::string> bind;
  std::optional<int> daoai_port;
  std::optional<int> gri_port;
  std::optional<int> gri_official_port;
  double gri_timeout_s = 70.0;
  double read_timeout_s = 30.0;
  int detection_threads = 2;
  std::string log_level = "info";
  std::vector<std::string> modbus_robots;  // HOST:PORT each
  std::optional<int> modbus_poll_ms;
  int http_port = 0;  // 0 off, -1 ephemeral
  std::string http_bind = "127.0.0.1";
  std::string source;  // synthetic | files:DIR | replay:DIR
  std::string dialect;
  bool no_record = false;
  std::string record_dir;
  std::optional<int64_t> record_max_mb;
  std::optional<int> max_connections;
  std::optional<int> max_connections_per_peer;
  std::optional<double> max_message_rate;
  std::vector<std::string> allow;
  std::string taught_grasps;
  std::vector<std::string> allow_config;
  std::vector<std::string> http_allow;
};

void AddFlags(CLI::App& app, Flags& f) {
  app.add_option("--cell", f.cell_path, "cell file (default: the embedded default cell)");
  app.add_option("--bind", f.bind, "listen address (default: the cell's endpoints.bind)");
  app.add_option("--daoai-port", f.daoai_port, "DaoAI socket port, 0 disables (default: the cell's)");
  app.add_option("--gri-port", f.gri_port, "GRI protocol v2 port, 0 disables (default: the cell's)");
  app.add_option("--gri-official-port", f.gri_official_port,
                 "GRI official-format port, 0 disables (default: the cell's)");
  app.add_option("--gri-timeout", f.gri_timeout_s,
                 "seconds a GRI request may wait for its result before PROCESSING_TIMEOUT");
  app.add_option("--read-timeout", f.read_timeout_s,
                 "seconds without a complete request before an idle robot is disconnected");
  app.add_option("--detection-threads", f.detection_threads, "oneTBB arena size for detection");
  app.add_option("--log-level", f.log_level, "trace|debug|info|warn|error|off");
  app.add_option("--max-connections", f.max_connections,
                 "robot connections per listener, more are closed at accept; 0 unlimited "
                 "(default: the cell's endpoints.max_connections)");
  app.add_option("--max-message-rate", f.max_message_rate,
                 "requests/s per connection, faster robots are read no faster; 0 unlimited "
                 "(default: the cell's endpoints.max_message_rate)");
  app.add_option("--max-connections-per-peer", f.max_connections_per_peer,
                 "robot connections one address may hold per listener, more are closed at "
                 "accept; 0 unlimited (default: the cell's endpoints.max_connections_per_peer)");
  app.add_option("--allow", f.allow,
                 "robot address or ADDR/PREFIX network allowed to connect, repeatable; others are "
                 "closed at accept (default: the cell's endpoints.allowlist; none: any)");
  app.add_option("--allow-config", f.allow_config,
                 "address or ADDR/PREFIX network allowed to change the cell (calibration, GRI "
                 "HEC, teach, camera config), repeatable; others get the protocol's refusal "
                 "(default: the cell's endpoints.config_allowlist; none: any robot)");
  app.add_option("--http-allow", f.http_allow,
                 "address or ADDR/PREFIX network allowed on the status page / metrics port, "
                 "repeatable (default: the cell's endpoints.http_allowlist; none: any)");
  app.add_option("--modbus-robot", f.modbus_robots,
                 "HOST:PORT of a robot Modbus slave to serve as master (repeatable; default: the "
                 "cell's robot.modbus)");
  app.add_option("--modbus-poll-ms", f.modbus_poll_ms,
                 "Modbus request flag poll interval (default: the cell's robot.modbus.poll_ms)");
  app.add_option("--http-port", f.http_port,
                 "status page, JSON API and /metrics port; 0 disables (default), -1 ephemeral");
  app.add_option("--http-bind", f.http_bind, "status page listen address");
  app.add_option("--source", f.source,
                 "capture source: synthetic, files:DIR or replay:DIR (a recorded session or a directory of "
                 "frames; default: the cell's source)");
  app.add_option("--taught-grasps", f.taught_grasps,
                 "file of the grasps taught with command 30 (default: <cell file>.taught.yaml; the package's "
                 "service keeps it in /var/lib/binpick)");
  app.add_option("--dialect", f.dialect,
                 "DaoAI rules the robot program follows: vision_pilot (seed 000/003) or socket_v1 "
                 "(seed 004) (default: the cell's robot.dialect)");
  app.add_flag("--no-record", f.no_record, "do not record captures and answers (default: the cell's recording)");
  app.add_option("--record-dir", f.record_dir, "directory of the recording sessions (default: the cell's)");
  app.add_option("--record-max-mb", f.record_max_mb, "disk cap of the recordings in MiB (default: the cell's)")
      ->check(CLI::PositiveNumber);
}

// Exit codes: 2 for a bad flag, cell or listener, 3 when the planning side
// (planner, 2D setup, precision references) cannot be built.
constexpr int kBadConfig = 2;
constexpr int kCannotPlan = 3;

// Prints "binpickd: <message>" and returns `code`, for `return Fail(...)`.
int Fail(int code, const std::string& message) {
  std::cerr << "binpickd: " << message << "\n";
  return code;
}

// Applies --dialect and --source to the loaded cell. @returns 0 or kBadConfig.
int ApplyCellFlags(const Flags& f, bp::Cell& cell) {
  if (!f.dialect.empty()) {
    const std::optional<bp::DaoaiDialect> d = bp::ParseDaoaiDialect(f.dialect);
    if (!d) return Fail(kBadConfig, "--dialect '" + f.dialect + "' is not vision_pilot or socket_v1");
    cell.robot.dialect = *d;
  }
  if (f.source.empty()) return 0;
  const size_t colon = f.source.find(':');
  const std::string kind = f.source.substr(0, colon);
  const std::string dir = colon == std::string::npos ? "" : f.source.substr(colon + 1);
  if (kind == "synthetic" && dir.empty()) {
    cell.source.kind = bp::SourceSpec::Kind::kSynthetic;
  } else if ((kind == "files" || kind == "replay") && !dir.empty()) {
    cell.source.kind = kind == "files" ? bp::SourceSpec::Kind::kFiles : bp::SourceSpec::Kind::kReplay;
    cell.source.dir = dir;
  } else {
    return Fail(kBadConfig, "--source '" + f.source + "' is not synthetic, files:DIR or replay:DIR");
  }
  return 0;
}

// What the request handler plans and calibrates with.
struct Planning {
  // The hand-eye transform in use when the cell has a calibration section
  // (camera.pose, or camera.hand_eye_file loaded by the cell loader): written
  // by the calibration service, read by every capture of the pick camera, the
  // precision check and the status page (docs/architecture.md "Hand-eye
  // state"). Null without a calibration section.
  std::shared_ptr<bp::HandEyeState> hand_eye;
  // The grasp planner (null for a cell of pick_2d tasks only), wrapped by the
  // precision check (RC 50) when there is a hand-eye state.
  std::shared_ptr<bp::GraspPlanner> planner;
  // Hand-eye calibration, wrapping the 2D plane calibration (RC 11/12) if any.
  std::unique_ptr<bp::CalibrationService> calibration;
};

// Builds the planners and calibration services of `cell`; gives the status
// page (if any) its calibration rows. @returns 0 or kCannotPlan.
int BuildPlanning(const bp::Cell& cell, const Flags& f, bp::StatusState* status, Planning& out) {
  bp::HandEyeProvider hand_eye_provider;
  if (cell.calibration) {
    std::error_code ec;
    const bool from_file =
        !cell.camera.hand_eye_file.empty() && std::filesystem::exists(cell.camera.hand_eye_file, ec);
    out.hand_eye = std::make_shared<bp::HandEyeState>(cell.camera.eye_in_hand ? cell.camera.X_FC : cell.camera.X_BC,
                                                      from_file ? cell.camera.hand_eye_file : "camera.pose");
    hand_eye_provider = [hand_eye = out.hand_eye] { return hand_eye->Get(); };
  }
  // A cell of pick_2d tasks only needs no 3D planner.
  bp::Result<std::unique_ptr<bp::GraspPlanner>> planner =
      bp::OnlyPick2DTasks(cell) ? std::unique_ptr<bp::GraspPlanner>()
                                : bp::MakePlanner(cell, hand_eye_provider, f.taught_grasps);
  if (!planner.ok()) return Fail(kCannotPlan, "cannot start: " + planner.status().ToString());
  // 2D tasks (twod/): their planner by task kind, RC 11/12 on the plane calibration.
  if (bp::HasPick2DTask(cell)) {
    bp::Result<bp::Plane2DSetup> two_d = bp::MakePlane2DSetup(cell);
    if (!two_d.ok()) return Fail(kCannotPlan, "cannot start: " + two_d.status().ToString());
    planner = bp::WithPlane2DPlanner(cell, std::move(*planner), *two_d);
    bp::PlaneCalibrationOptions plane_options;
    plane_options.file = cell.camera.plane_calibration_file;
    out.calibration = std::make_unique<bp::PlaneCalibrationService>(two_d->camera, two_d->store, plane_options);
  }
  out.planner = std::move(*planner);
  if (!out.hand_eye) return 0;
  // Hand-eye calibration and the precision check (RC 50): the simulated
  // calibration camera and the hand-eye state above.
  auto camera = std::make_shared<bp::SimulatedCalibrationCamera>(cell.camera, *cell.calibration);
  bp::HandEyeServiceOptions calib_options;
  calib_options.result_file = cell.camera.hand_eye_file;
  out.calibration = std::make_unique<bp::HandEyeCalibrationService>(cell, camera, out.hand_eye,
                                                                    std::move(out.calibration), calib_options);
  if (out.planner) {
    bp::PrecisionCheckOptions check_options;
    check_options.reference_file = bp::PrecisionReferenceFile(cell);
    auto check = std::make_shared<bp::PrecisionCheckPlanner>(out.planner, cell, camera, out.hand_eye, check_options);
    if (bp::Status s = check->LoadReferences(); !s.ok()) return Fail(kCannotPlan, "cannot start: " + s.ToString());
    out.planner = std::move(check);
  }
  if (status) {
    status->SetCalibrationProbe([hand_eye = out.hand_eye, eih = cell.camera.eye_in_hand] {
      return bp::HandEyeStatusRows(hand_eye->Snapshot(), eih);
    });
  }
  return 0;
}

// The recorder observes every detection and answer; it owns its writer
// thread and the session directory (docs/architecture.md "Recording").
// @returns null when recording is off or cannot start (logged: serving goes on).
std::shared_ptr<bp::Recorder> StartRecorder(const bp::Cell& cell, const Flags& f) {
  if (!cell.recording.enabled || f.no_record) return nullptr;
  bp::RecorderOptions options = bp::RecorderOptionsFromCell(cell);
  if (!f.record_dir.empty()) options.directory = f.record_dir;
  if (f.record_max_mb) options.max_disk_bytes = *f.record_max_mb << 20;
  auto started = bp::Recorder::Start(cell, options);
  if (!started.ok()) {
    spdlog::error("binpickd: recording disabled: {}", started.status().ToString());
    return nullptr;
  }
  return *started;
}

bp::DaoaiServerOptions DaoaiOptions(const bp::Cell& cell, const Flags& f) {
  bp::DaoaiServerOptions o;
  o.bind = f.bind.value_or(cell.endpoints.bind);
  o.port = f.daoai_port.value_or(cell.endpoints.daoai_port);
  o.read_timeout = std::chrono::milliseconds(static_cast<int64_t>(f.read_timeout_s * 1000));
  o.max_connections = static_cast<size_t>(std::max(0, f.max_connections.value_or(cell.endpoints.max_connections)));
  o.max_connections_per_peer = static_cast<size_t>(
      std::max(0, f.max_connections_per_peer.value_or(cell.endpoints.max_connections_per_peer)));
  o.max_message_rate = std::max(0.0, f.max_message_rate.value_or(cell.endpoints.max_message_rate));
  o.allowlist = f.allow.empty() ? cell.endpoints.allowlist : f.allow;
  o.config_allowlist = f.allow_config.empty() ? cell.endpoints.config_allowlist : f.allow_config;
  return o;
}

// The GRI listeners share the DaoAI listener's address, limits and allowlists.
bp::GriServerOptions GriOptions(const bp::Cell& cell, const Flags& f, const bp::DaoaiServerOptions& daoai) {
  bp::GriServerOptions o;
  o.bind = daoai.bind;
  o.v2_port = f.gri_port.value_or(cell.endpoints.gri_port);
  o.official_port = f.gri_official_port.value_or(cell.endpoints.gri_official_port);
  o.read_timeout = daoai.read_timeout;
  o.max_connections = daoai.max_connections;
  o.max_connections_per_peer = daoai.max_connections_per_peer;
  o.max_message_rate = daoai.max_message_rate;
  o.allowlist = daoai.allowlist;
  o.config_allowlist = daoai.config_allowlist;
  o.processing_timeout = std::chrono::milliseconds(static_cast<int64_t>(f.gri_timeout_s * 1000));
  return o;
}

// One Modbus master per robot slave: the --modbus-robot HOST:PORT list
// ([::1]:502 for IPv6), else the cell's robot.modbus if it names a host.
// @returns nullopt on a malformed entry (printed).
std::optional<std::vector<bp::ModbusMasterOptions>> ModbusRobots(const bp::Cell& cell, const Flags& f,
                                                                 const bp::AddressList& config_allowed) {
  std::vector<bp::ModbusMasterOptions> robots;
  const bp::ModbusMasterOptions base = bp::ModbusMasterOptionsFromCell(cell.robot);
  for (const std::string& hp : f.modbus_robots) {
    bp::ModbusMasterOptions o = base;
    const size_t colon = hp.rfind(':');
    o.host = hp.substr(0, colon);
    if (o.host.size() > 2 && o.host.front() == '[' && o.host.back() == ']') {
      o.host = o.host.substr(1, o.host.size() - 2);
    }
    o.port = 0;
    if (colon != std::string::npos) {
      try {
        o.port = std::stoi(hp.substr(colon + 1));
      } catch (const std::exception&) {
      }
    }
    if (colon == std::string::npos || o.host.empty() || o.port <= 0) {
      Fail(kBadConfig, "--modbus-robot '" + hp + "' is not HOST:PORT");
      return std::nullopt;
    }
    robots.push_back(o);
  }
  if (f.modbus_robots.empty() && !cell.robot.modbus_host.empty()) robots.push_back(base);
  for (bp::ModbusMasterOptions& o : robots) {
    if (f.modbus_poll_ms) o.poll_interval = std::chrono::milliseconds(*f.modbus_poll_ms);
    // The robot's address as configured (a host name is never listed).
    o.may_change_cell = config_allowed.Contains(o.host);
    if (!o.may_change_cell) {
      spdlog::info("binpickd: Modbus robot {}:{} is not in the config allowlist: its "
                   "calibration, teach and camera config requests are refused", o.host, o.port);
    }
  }
  return robots;
}

// Every transport serving the one request handler, and the status page.
// Stop() stops them in the order that lets each finish what it started: the
// status page first (it reads the others), then the robot links.
struct Transports {
  std::unique_ptr<bp::DaoaiServer> daoai;
  std::vector<std::unique_ptr<bp::ModbusMaster>> modbus;
  std::unique_ptr<bp::GriServer> gri;
  std::unique_ptr<bp::StatusServer> http;

  void Stop() {
    if (http) http->Stop();
    if (daoai) daoai->Stop();
    for (auto& master : modbus) master->Stop();
    if (gri) gri->Stop();
  }
};

// Starts the robot transports of `cell` on `handler`. Appends each listener's
// address to `ready`. @returns 0 or kBadConfig (printed).
int StartRobotLinks(const bp::Cell& cell, const Flags& f, const bp::DaoaiServerOptions& daoai,
                    const bp::AddressList& config_allowed, bp::RequestHandler& handler,
                    bp::GriHandler& gri_handler, Transports& out, std::string& ready) {
  ready += "daoai ";
  if (daoai.port != 0) {
    auto started = bp::DaoaiServer::Start(handler, daoai);
    if (!started.ok()) return Fail(kBadConfig, started.status().ToString());
    out.daoai = std::move(*started);
    ready += out.daoai->address();
  } else {
    ready += "disabled";
  }
  std::optional<std::vector<bp::ModbusMasterOptions>> robots = ModbusRobots(cell, f, config_allowed);
  if (!robots) return kBadConfig;
  for (const bp::ModbusMasterOptions& o : *robots) {
    auto started = bp::ModbusMaster::Start(handler, o);
    if (!started.ok()) return Fail(kBadConfig, started.status().ToString());
    spdlog::info("binpickd: Modbus master for robot {}", (*started)->address());
    out.modbus.push_back(std::move(*started));
  }
  const bp::GriServerOptions gri = GriOptions(cell, f, daoai);
  ready += "; gri ";
  if (gri.v2_port != 0 || gri.official_port != 0) {
    auto started = bp::GriServer::Start(gri_handler, gri);
    if (!started.ok()) return Fail(kBadConfig, started.status().ToString());
    out.gri = std::move(*started);
    ready += out.gri->Describe();
  } else {
    ready += "disabled";
  }
  return 0;
}

// Starts the status page, JSON API and /metrics; the metrics read the
// transports, handler and recorder at scrape time (the HTTP server stops
// first). Appends "; http ADDR" to `ready`. @returns 0 or kBadConfig (printed).
int StartStatusPage(const bp::Cell& cell, const Flags& f, const std::vector<std::string>& http_allowlist,
                    bp::StatusState& status, bp::MetricsRegistry& metrics, const bp::RequestHandler& handler,
                    const bp::Recorder* recorder, Transports& transports, std::string& ready) {
  if (transports.daoai) {
    bp::AddTransportMetrics(metrics, "daoai", [server = transports.daoai.get()] { return server->stats(); });
  }
  if (transports.gri) {
    bp::AddTransportMetrics(metrics, "gri", [server = transports.gri.get()] { return server->stats(); });
  }
  for (const auto& master : transports.modbus) bp::AddModbusMetrics(metrics, *master);
  bp::AddQueueMetrics(metrics, handler);
  bp::AddHandlerMetrics(metrics, handler);
  if (recorder) bp::AddRecorderMetrics(metrics, *recorder);
  bp::StatusServerOptions http_options;
  http_options.bind = f.http_bind;
  http_options.port = f.http_port < 0 ? 0 : f.http_port;
  http_options.max_connections = static_cast<size_t>(cell.endpoints.http_max_connections);
  http_options.allowlist = http_allowlist;
  auto started = bp::StatusServer::Start(status, metrics, http_options);
  if (!started.ok()) return Fail(kBadConfig, started.status().ToString());
  transports.http = std::move(*started);
  ready += "; http " + transports.http->address();
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"binpick picking server"};
  Flags flags;
  AddFlags(app, flags);
  CLI11_PARSE(app, argc, argv);
  // stdout carries only the ready line; logs go to stderr.
  spdlog::set_default_logger(spdlog::stderr_color_mt("binpickd"));
  // Status page state and metrics exist before anything logs or serves.
  bp::MetricsRegistry metrics;
  std::shared_ptr<bp::StatusState> status;
  spdlog::set_level(spdlog::level::from_str(flags.log_level));

  // Block the stop signals before any thread starts; main waits for them.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  bp::Result<bp::Cell> cell = bp::LoadCellOrDefault(flags.cell_path);
  if (!cell.ok()) return Fail(kBadConfig, cell.status().ToString());
  if (int code = ApplyCellFlags(flags, *cell); code != 0) return code;
  if (flags.http_port != 0) {
    status = std::make_shared<bp::StatusState>(*cell, metrics);
    spdlog::default_logger()->sinks().push_back(status->LogSink());
  }
  Planning planning;
  if (int code = BuildPlanning(*cell, flags, status.get(), planning); code != 0) return code;

  // oneTBB caps its workers at cores - 1; the detection arena asks for
  // detection_threads workers of its own, so allow them (plus this thread).
  const size_t parallelism = std::max<size_t>(
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism),
      static_cast<size_t>(flags.detection_threads) + 1);
  tbb::global_control allow_workers(tbb::global_control::max_allowed_parallelism, parallelism);

  bp::RequestHandlerOptions handler_options;
  handler_options.detection_threads = flags.detection_threads;
  bp::RequestHandler handler(*cell, planning.planner, std::move(planning.calibration), handler_options);
  if (status) {
    status->SetQueueProbe([&handler](int task_id) { return handler.QueueSize(task_id); });
    status->SetQueueContentsProbe([&handler](int task_id) { return handler.QueueContents(task_id); });
    handler.AddObserver(status);
  }
  std::shared_ptr<bp::Recorder> recorder = StartRecorder(*cell, flags);
  if (recorder) handler.AddObserver(recorder);

  const bp::DaoaiServerOptions daoai = DaoaiOptions(*cell, flags);
  const std::vector<std::string> http_allowlist =
      flags.http_allow.empty() ? cell->endpoints.http_allowlist : flags.http_allow;
  std::optional<bp::AddressList> config_allowed =
      CheckAllowlists(daoai.allowlist, daoai.config_allowlist, http_allowlist, daoai.bind,
                      flags.http_port != 0 ? flags.http_bind : std::string("127.0.0.1"));
  if (!config_allowed) return kBadConfig;
  bp::GriHandler gri_handler(handler);
  Transports transports;
  std::string ready = "binpickd ready: ";
  if (int code = StartRobotLinks(*cell, flags, daoai, *config_allowed, handler, gri_handler, transports, ready);
      code != 0) {
    return code;
  }
  if (status) {
    if (int code = StartStatusPage(*cell, flags, http_allowlist, *status, metrics, handler, recorder.get(),
                                   transports, ready);
        code != 0) {
      return code;
    }
  }
  spdlog::info("binpickd: cell '{}' from {}", cell->name, cell->path);
  std::cout << ready << std::endl;
  // Type=notify (deploy/debian/binpickd.service): every listener is up.
  if (bp::Status s = bp::NotifyServiceManager("READY=1\nSTATUS=" + ready); !s.ok()) {
    spdlog::warn("binpickd: {}", s.ToString());
  }

  int signal = 0;
  sigwait(&stop_signals, &signal);
  spdlog::info("binpickd: {} received, stopping", signal == SIGINT ? "SIGINT" : "SIGTERM");
  (void)bp::NotifyServiceManager("STOPPING=1");
  transports.Stop();
  handler.Shutdown();
  if (recorder) recorder->Stop();  // writes what is queued
  transports.daoai.reset();
  transports.gri.reset();
  return 0;
}
