#include "apps/robot_cmd.h"

#include <CLI/CLI.hpp>

#include <iostream>
#include <string>

#include "calib/calibration_camera.h"
#include "comms/modbus_robot_sim.h"
#include "comms/robot_client.h"
#include "comms/robot_flows.h"
#include "core/cell.h"
#include "core/conventions.h"

namespace bp {

int RunRobotCommand(int argc, char** argv) {
  CLI::App app{"Plays the robot side of the DaoAI socket protocol, as the seed robot scripts do."};
  std::string host = "127.0.0.1";
  int port = 6969;
  std::string robot = "ur";
  int version = 2;
  double position_scale = 1.0;
  int timeout_ms = 30000;
  FlowOptions flow;
  std::string flows;
  for (const auto& f : FlowNames()) flows += (flows.empty() ? "" : "|") + f;
  app.add_option("--host", host, "server address");
  app.add_option("--port", port, "DaoAI port");
  app.add_option("--robot", robot, "robot type (ur, abb, kuka, fanuc, yaskawa, ...): meta_1 and "
                                   "orientation convention");
  app.add_option("--protocol-version", version, "meta_2 (the seeds' own scripts send 1)");
  std::string dialect = "vision_pilot";
  app.add_option("--dialect", dialect,
                 "the seed script the robot plays: vision_pilot (seed 000/003) or socket_v1 (seed 004); "
                 "the server's cell must name the same robot.dialect");
  app.add_option("--position-scale", position_scale, "metres per wire unit (0.001 for mm)");
  app.add_option("--flow", flow.flow, flows)->required();
  app.add_option("--task", flow.task_id, "task id (payload_1)");
  app.add_option("--place-task", flow.place_task_id, "pick-place: the place task id");
  app.add_option("--in-hand-task", flow.in_hand_task_id, "pick-correct-place: the in_hand task id");
  app.add_option("--place-area-task", flow.place_area_task_id, "pick-correct-place: the place_area task id");
  app.add_option("--config", flow.config_id, "switch-config: camera config id");
  app.add_option("--max-cycles", flow.max_cycles, "pick: capture cycles at most");
  app.add_option("--poses", flow.manual_poses, "calib-manual / calib-guidance: poses to send");
  app.add_option("--timeout-ms", timeout_ms, "per-response timeout");
  std::string cell_path;
  app.add_option("--cell", cell_path,
                 "calib-manual / calib-auto / calib-guidance: the server's cell (default: the embedded "
                 "default cell); with a calibration section the robot starts where the board faces the "
                 "camera, as `binpick calib` does. pick-correct-place: the taught obj_in_Place is the "
                 "place_area task's fixture taught pose * part_pose");
  bool modbus = false;
  int unit_id = 1;
  int wait_master_s = 60;
  app.add_flag("--modbus", modbus,
               "be a Modbus TCP slave (seed 000 UR Modbus) listening on --host:--port (default "
               "502) and play the flow through its registers once binpickd connects");
  app.add_option("--unit-id", unit_id, "--modbus: the slave's unit id");
  app.add_option("--wait-master", wait_master_s, "--modbus: seconds to wait for the master");
  bool no_empty_check = false;
  app.add_flag("--no-empty-check", no_empty_check, "pick: skip the final empty-box check");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  flow.check_empty = !no_empty_check;
  if (flow.flow == "calib-manual" || flow.flow == "calib-auto" || flow.flow == "calib-guidance") {
    Result<Cell> cell = LoadCellOrDefault(cell_path);
    if (!cell.ok()) {
      std::cerr << "binpick robot: " << cell.status().ToString() << "\n";
      return 2;
    }
    if (cell->calibration) flow.calib_start_X_BF = BoardFacingStartPose(*cell);
  }
  if (flow.flow == "pick-correct-place") {
    Result<Cell> cell = LoadCellOrDefault(cell_path);
    const TaskSpec* task = cell.ok() ? cell->FindTask(flow.place_area_task_id) : nullptr;
    const FixtureSpec* fixture = task ? cell->FindFixture(task->fixture) : nullptr;
    if (fixture == nullptr) {
      std::cerr << "binpick robot: "
                << (cell.ok() ? "task " + std::to_string(flow.place_area_task_id) + " of the cell has no fixture"
                              : cell.status().ToString())
                << "\n";
      return 2;
    }
    flow.obj_in_place = fixture->X_BP_taught * fixture->X_PO;
  }
  const std::optional<RobotModel> model = FindRobotModel(robot);
  if (!model) {
    std::cerr << "binpick robot: unknown robot '" << robot << "'\n";
    return 2;
  }
  const std::optional<DaoaiDialect> parsed_dialect = ParseDaoaiDialect(dialect);
  if (!parsed_dialect) {
    std::cerr << "binpick robot: unknown dialect '" << dialect << "' (vision_pilot or socket_v1)\n";
    return 2;
  }
  RobotClientOptions options;
  options.dialect = *parsed_dialect;
  options.host = host;
  options.port = port;
  options.robot_type = model->type;
  options.convention = model->convention;
  options.version = version;
  options.position_scale = position_scale;
  options.timeout = std::chrono::milliseconds(timeout_ms);
  if (modbus) {
    ModbusRobotSimOptions so;
    so.bind = host;
    so.port = app.count("--port") ? port : 502;
    so.unit_id = unit_id;
    auto sim = ModbusRobotSim::Start(so);
    if (!sim.ok()) {
      std::cerr << "binpick robot: " << sim.status().ToString() << "\n";
      return 2;
    }
    std::cout << "robot " << model->name << " Modbus slave listening on " << host << ":"
              << (*sim)->port() << " (unit " << unit_id << "), waiting for binpickd" << std::endl;
    if (!(*sim)->WaitForMaster(std::chrono::seconds(wait_master_s))) {
      std::cerr << "binpick robot: no Modbus master connected within " << wait_master_s << " s\n";
      return 2;
    }
    std::unique_ptr<RobotClient> client = RobotClient::Over((*sim)->Transport(), options);
    std::cout << "robot " << model->name << " (meta_1 " << static_cast<int>(model->type)
              << ", version " << version << ") over Modbus, flow " << flow.flow << "\n";
    Result<FlowSummary> summary = RunFlow(*client, flow, std::cout);
    client.reset();
    if (!summary.ok()) {
      std::cerr << "binpick robot: " << summary.status().ToString() << "\n";
      return 2;
    }
    return summary->ok ? 0 : 1;
  }
  auto client = RobotClient::Connect(options);
  if (!client.ok()) {
    std::cerr << "binpick robot: " << client.status().ToString() << "\n";
    return 2;
  }
  std::cout << "robot " << model->name << " (meta_1 " << static_cast<int>(model->type)
            << ", version " << version << ") connected to " << host << ":" << port
            << ", flow " << flow.flow << "\n";
  Result<FlowSummary> summary = RunFlow(**client, flow, std::cout);
  if (!summary.ok()) {
    std::cerr << "binpick robot: " << summary.status().ToString() << "\n";
    return 2;
  }
  return summary->ok ? 0 : 1;
}

}  // namespace bp
