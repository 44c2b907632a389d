// `binpick calib [--cell FILE] --flow manual|auto [--version 1|2]`: a full
// hand-eye calibration against the simulator over the real protocol path: an
// in-process server (RequestHandler + DaoAI socket on an ephemeral loopback
// port, the HandEyeCalibrationService binpickd uses) and the simulated robot
// playing the seed's calibration program. Prints the solution's residuals
// and its error against the cell's true transform (calibration.true_pose).
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <future>
#include <vector>
#include <iostream>
#include <memory>
#include <sstream>

#include "apps/binpick/command.h"
#include "calib/calibration_camera.h"
#include "calib/hand_eye_service.h"
#include "calib/precision_check.h"
#include "comms/daoai_server.h"
#include "comms/request_handler.h"
#include "comms/robot_client.h"
#include "comms/robot_flows.h"
#include "core/cell.h"
#include "grasp/planner.h"

namespace bp::cli {
namespace {

// The calibration commands never capture for picking: a planner that has nothing.
class NoPartsPlanner final : public GraspPlanner {
 public:
  Result<CaptureHandle> Capture(const PlanRequest&) override {
    return Status::Unavailable("binpick calib serves calibration only");
  }
  Result<PlanResult> Plan(const PlanRequest&, const CapturedScene&) override { return PlanResult{}; }
};

struct Args {
  std::string cell_path;
  std::string flow = "auto";
  int version = 2;
  std::string result_file;
  bool verbose = false;
  int precision_checks = 0;
};

int Run(const Args& a) {
  spdlog::set_level(a.verbose ? spdlog::level::info : spdlog::level::warn);
  Result<Cell> cell = LoadCellOrDefault(a.cell_path);
  if (!cell.ok()) return Fail("calib", cell.status());
  if (!cell->calibration) {
    return Fail("calib", Status::InvalidArgument(cell->path + ": the cell has no calibration section"));
  }
  const bool eih = cell->camera.eye_in_hand;
  auto camera = std::make_shared<SimulatedCalibrationCamera>(cell->camera, *cell->calibration);
  auto state = std::make_shared<HandEyeState>(eih ? cell->camera.X_FC : cell->camera.X_BC);
  const Pose before = state->Get();
  HandEyeServiceOptions so;
  so.result_file = a.result_file.empty() ? cell->camera.hand_eye_file : a.result_file;
  auto service = std::make_unique<HandEyeCalibrationService>(*cell, camera, state, nullptr, so);
  HandEyeCalibrationService* svc = service.get();
  auto planner = std::make_shared<PrecisionCheckPlanner>(std::make_shared<NoPartsPlanner>(), *cell, camera, state);
  RequestHandler handler(*cell, planner, std::move(service));
  DaoaiServerOptions server_options;
  server_options.port = 0;
  Result<std::unique_ptr<DaoaiServer>> server = DaoaiServer::Start(handler, server_options);
  if (!server.ok()) return Fail("calib", server.status());

  RobotClientOptions ro;
  ro.port = (*server)->port();
  ro.version = a.version;
  ro.robot_type = cell->robot.model.type;
  ro.convention = cell->robot.model.convention;
  ro.position_scale = cell->robot.position_scale;
  Result<std::unique_ptr<RobotClient>> robot = RobotClient::Connect(ro);
  if (!robot.ok()) return Fail("calib", robot.status());
  FlowOptions fo;
  fo.flow = a.flow == "manual" ? "calib-manual" : "calib-auto";
  fo.calib_start_X_BF = BoardFacingStartPose(*cell);
  std::ostringstream steps;
  Result<FlowSummary> summary = RunFlow(**robot, fo, steps);
  if (a.verbose) std::cout << steps.str();
  if (!summary.ok()) return Fail("calib", summary.status());
  // Version 2's last calibration step has no answer: a round trip (RC 69,
  // the current camera config) makes sure the server has read it, and
  // RunCalibration that the solve has run.
  (void)(*robot)->Call(daoai::kSwitchConfig, cell->camera.default_config);
  {
    std::promise<void> solved;
    if (!handler.RunCalibration([&solved](CalibrationService&) { solved.set_value(); })) solved.set_value();
    solved.get_future().wait();
  }
  // Precision checks (RC 50) after the calibration: the first defines the
  // reference, the others measure against it (pure repeatability).
  std::vector<double> checks;
  int precision_task = cell->tasks.front().id;
  for (const TaskSpec& t : cell->tasks) {
    if (t.kind == TaskSpec::Kind::kPrecision) precision_task = t.id;
  }
  for (int i = 0; i <= a.precision_checks && a.precision_checks > 0; ++i) {
    (*robot)->SetPose(fo.calib_start_X_BF.value());
    Result<RobotReply> r = (*robot)->Call(daoai::kPrecisionCheck, precision_task);
    if (!r.ok()) return Fail("calib", r.status());
    if (r->status != daoai::kPrecisionCheckSuccess) {
      std::cerr << "binpick calib: precision check answered " << r->status << "\n";
      return kExitFailure;
    }
    if (i > 0) checks.push_back(r->payload[0]);
  }
  (*robot)->Close();
  handler.Shutdown();

  const std::optional<HandEyeSolution> sol = svc->last_solution();
  if (!sol) {
    std::cerr << "binpick calib: no calibration was solved (" << summary->steps
              << " protocol steps; run with --verbose for the log)\n";
    return kExitFailure;
  }
  const Pose& truth = cell->calibration->true_pose;
  const char* frame = eih ? "X_FC" : "X_BC";
  std::printf("flow %s, protocol version %d, %s camera: %d poses, %d pairs, %s\n", a.flow.c_str(), a.version,
              eih ? "eye-in-hand" : "eye-to-hand", sol->poses, sol->pairs, sol->method.c_str());
  std::printf("residuals: %.4f mm / %.5f deg RMS, %.4f mm / %.5f deg max; reprojection %.4f px RMS\n",
              sol->residual_rms_mm, sol->residual_rms_deg, sol->residual_max_mm, sol->residual_max_deg,
              sol->reprojection_rms_px);
  std::printf("error vs true %s: %.4f mm, %.5f deg (the cell's nominal pose was %.3f mm, %.4f deg off)\n", frame,
              TranslationErrorMm(sol->X, truth), RotationErrorDeg(sol->X, truth), TranslationErrorMm(before, truth),
              RotationErrorDeg(before, truth));
  if (!checks.empty()) {
    double sum = 0, worst = 0;
    for (double c : checks) {
      sum += c;
      worst = std::max(worst, c);
    }
    std::printf("precision check (task %d): %zu checks after the defining one: mean %.4f mm, max %.4f mm\n",
                precision_task, checks.size(), sum / checks.size(), worst);
  }
  std::printf("result: %s\n", so.result_file.empty() ? "(not saved: no camera.hand_eye_file)" : so.result_file.c_str());
  return kExitOk;
}

}  // namespace

Command CalibCommand() {
  return {"calib", "hand-eye calibration against the simulator over the DaoAI protocol; prints the error vs truth",
          [](CLI::App& sub) -> std::function<int()> {
            auto a = std::make_shared<Args>();
            sub.add_option("--cell", a->cell_path, "cell file (default: the embedded default cell)");
            sub.add_option("--flow", a->flow, "manual | auto")->check(CLI::IsMember({"manual", "auto"}));
            sub.add_option("--version", a->version, "DaoAI protocol version of the robot (1 or 2)")
                ->check(CLI::IsMember({1, 2}));
            sub.add_option("--result", a->result_file, "result file (default: the cell's camera.hand_eye_file)");
            sub.add_option("--precision-checks", a->precision_checks,
                           "then run N precision checks (RC 50) and print their errors (repeatability)");
            sub.add_flag("--verbose", a->verbose, "print every protocol step and the server log");
            return [a] { return Run(*a); };
          }};
}

}  // namespace bp::cli
