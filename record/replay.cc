#include "record/replay.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>

#include <nlohmann/json.hpp>

#include "grasp/bin_picking_planner.h"
#include "pipeline/file_source.h"
#include "pipeline/frame_io.h"
#include "pipeline/perception.h"
#include "pipeline/recording.h"
#include "record/internal/record_json.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

Result<std::unique_ptr<GraspPlanner>> DefaultPlanner(const Cell& cell, std::unique_ptr<CaptureSource> source) {
  Result<std::unique_ptr<Perception>> perception = Perception::Build(cell);
  if (!perception.ok()) return perception.status();
  auto planner = BinPickingPlanner::Create(cell, std::shared_ptr<const Perception>(std::move(*perception)),
                                           std::move(source));
  if (!planner.ok()) return planner.status();
  return std::unique_ptr<GraspPlanner>(std::move(*planner));
}

Result<json> ReadJsonFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status::NotFound("'" + path + "': cannot open");
  json j = json::parse(in, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) return Status::Corruption("'" + path + "': not a JSON object");
  return j;
}

// Compares `a` (recorded) with `b` (replayed) pose-wise; updates the maxima.
void ComparePose(const std::string& what, const Pose& a, const Pose& b, const ReplayOptions& o, CaptureReplay& c) {
  const double mm = (a.translation() - b.translation()).norm() * 1000.0;
  const double deg = RotationAngle(a.linear().transpose() * b.linear()) * 180.0 / M_PI;
  c.max_position_diff_mm = std::max(c.max_position_diff_mm, mm);
  c.max_angle_diff_deg = std::max(c.max_angle_diff_deg, deg);
  if (mm > o.tolerance_mm || deg > o.tolerance_deg) {
    char buf[160];
    std::snprintf(buf, sizeof(buf), "%s moved %.3f mm, %.3f deg (tolerance %.3f mm, %.3f deg)", what.c_str(), mm, deg,
                  o.tolerance_mm, o.tolerance_deg);
    c.differences.push_back(buf);
  }
}

void Compare(const ReplayOptions& o, CaptureReplay& c) {
  const PlanResult& a = c.recorded;
  const PlanResult& b = c.result;
  if (a.outcome != b.outcome) {
    c.differences.push_back("outcome: recorded " + std::string(ToString(a.outcome)) + ", replayed " +
                            std::string(ToString(b.outcome)));
  }
  if (a.detections != b.detections) {
    c.differences.push_back("detections: recorded " + std::to_string(a.detections) + ", replayed " +
                            std::to_string(b.detections));
  }
  if (a.parts.size() != b.parts.size()) {
    c.differences.push_back("parts: recorded " + std::to_string(a.parts.size()) + ", replayed " +
                            std::to_string(b.parts.size()));
  }
  for (size_t i = 0; i < std::min(a.parts.size(), b.parts.size()); ++i) {
    const std::string what = "parts[" + std::to_string(i) + "]";
    if (a.parts[i].class_id != b.parts[i].class_id) {
      c.differences.push_back(what + ": class recorded " + std::to_string(a.parts[i].class_id) + ", replayed " +
                              std::to_string(b.parts[i].class_id));
    }
    ComparePose(what, a.parts[i].X_BO, b.parts[i].X_BO, o, c);
  }
  if (a.grasps.size() != b.grasps.size()) {
    c.differences.push_back("grasp queue: recorded " + std::to_string(a.grasps.size()) + " grasps, replayed " +
                            std::to_string(b.grasps.size()));
  }
  for (size_t i = 0; i < std::min(a.grasps.size(), b.grasps.size()); ++i) {
    const std::string what = "grasps[" + std::to_string(i) + "]";
    if (a.grasps[i].class_id != b.grasps[i].class_id || a.grasps[i].name != b.grasps[i].name) {
      c.differences.push_back(what + ": recorded " + a.grasps[i].name + " of class " +
                              std::to_string(a.grasps[i].class_id) + ", replayed " + b.grasps[i].name +
                              " of class " + std::to_string(b.grasps[i].class_id));
    }
    ComparePose(what, a.grasps[i].X_BT, b.grasps[i].X_BT, o, c);
  }
}

void PlanFrame(GraspPlanner& planner, const PlanRequest& request, Frame frame, CaptureReplay& c) {
  const CapturedFrame scene(std::move(frame));
  const auto t0 = std::chrono::steady_clock::now();
  Result<PlanResult> plan = planner.Plan(request, scene);
  c.plan_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (!plan.ok()) {
    c.error = "plan failed: " + plan.status().ToString();
    return;
  }
  c.result = std::move(*plan);
  c.replayed = true;
}

CaptureReplay ReplayRecord(const std::string& record, const Cell& cell, GraspPlanner& planner,
                           const ReplayOptions& options) {
  CaptureReplay c;
  c.file = record;
  Result<json> manifest = ReadJsonFile((fs::path(record) / kRecordManifestName).string());
  if (!manifest.ok()) {
    c.error = manifest.status().ToString();
    return c;
  }
  try {
    c.task_id = manifest->at("task_id").get<int>();
    PlanRequest request;
    const TaskSpec* task = cell.FindTask(c.task_id);
    if (task == nullptr) {
      c.error = "task " + std::to_string(c.task_id) + " is not in the cell";
      return c;
    }
    request.task = *task;
    request.camera_config_id = manifest->value("camera_config_id", 0);
    if (const json& X = manifest->at("X_BF"); !X.is_null()) {
      Result<Pose> X_BF = PoseFromJson(X, "X_BF");
      if (!X_BF.ok()) {
        c.error = X_BF.status().ToString();
        return c;
      }
      request.X_BF = *X_BF;
    }
    c.recorded_plan_ms = manifest->at("plan").value("ms", -1.0);
    const json& result = manifest->at("plan").at("result");
    if (!result.is_null()) {
      Result<PlanResult> recorded = record_internal::PlanResultFromJson(result, record + "/record.json plan.result");
      if (!recorded.ok()) {
        c.error = recorded.status().ToString();
        return c;
      }
      c.recorded = std::move(*recorded);
      c.compared = true;
    }
    const std::string frame_path = (fs::path(record) / kRecordFrameName).string();
    if (!fs::exists(frame_path)) {
      c.error = "no frame recorded (capture status: " + manifest->at("capture").value("status", "?") + ")";
      c.compared = false;
      return c;
    }
    Result<Frame> frame = LoadFrameFile(frame_path);
    if (!frame.ok()) {
      c.error = frame.status().ToString();
      return c;
    }
    PlanFrame(planner, request, std::move(*frame), c);
  } catch (const json::exception& e) {
    c.error = record + "/record.json: " + e.what();
    return c;
  }
  if (c.replayed && c.compared) Compare(options, c);
  return c;
}

Result<Cell> SessionCell(const std::string& dir, const ReplayOptions& options, std::string* origin) {
  if (!options.cell_path.empty()) {
    *origin = options.cell_path;
    return LoadCell(options.cell_path);
  }
  const fs::path cell_file = fs::path(dir) / kSessionCellName;
  std::ifstream in(cell_file, std::ios::binary);
  if (!in) {
    *origin = "<embedded default> (the session has no cell.yaml)";
    return LoadDefaultCell();
  }
  const std::string text((std::istreambuf_iterator<char>(in)), {});
  std::string recorded_path;
  if (Result<json> session = ReadJsonFile((fs::path(dir) / kSessionManifestName).string()); session.ok()) {
    recorded_path = session->value("cell_path", "");
  }
  *origin = cell_file.string();
  // Resolve relative paths as the recorded cell did (the embedded default's
  // resolve against the assets); fall back to the session directory.
  if (recorded_path == "<embedded default>") {
    Result<Cell> def = LoadDefaultCell();
    if (def.ok() && def->yaml_text == text) return def;
    return ParseCell(text, (fs::path(AssetsDir()) / "cells" / "recorded.yaml").string());
  }
  return ParseCell(text, recorded_path.empty() ? cell_file.string() : recorded_path);
}

}  // namespace

Result<ReplayReport> ReplayDirectory(const std::string& dir, const ReplayOptions& options) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return Status::NotFound("'" + dir + "': no such directory");
  ReplayReport report;
  report.dir = dir;
  report.session = IsRecordedSession(dir);
  Result<Cell> cell = Status::Internal("no cell");
  if (report.session) {
    cell = SessionCell(dir, options, &report.cell);
  } else {
    report.cell = options.cell_path.empty() ? "<embedded default>" : options.cell_path;
    cell = LoadCellOrDefault(options.cell_path);
  }
  if (!cell.ok()) return cell.status();
  report.cell_name = cell->name;
  if (cell->tasks.empty()) return Status::InvalidArgument(report.cell + ": the cell has no task");

  std::vector<std::string> items;
  if (report.session) {
    Result<RecordListing> listing = ListRecords(dir);
    if (!listing.ok()) return listing.status();
    items = std::move(listing->records);
    report.skipped = std::move(listing->skipped);
  } else {
    Result<std::vector<std::string>> files = ListFrameFiles(dir);
    if (!files.ok()) return files.status();
    items = std::move(*files);
  }
  for (const std::string& s : report.skipped) spdlog::warn("replay: skipping {}", s);
  if (items.empty()) return Status::NotFound("'" + dir + "': nothing to replay");

  Result<std::unique_ptr<CaptureSource>> source = MakeReplaySource(dir, *cell);
  if (!source.ok()) return source.status();
  const auto make = options.make_planner ? options.make_planner : DefaultPlanner;
  Result<std::unique_ptr<GraspPlanner>> planner = make(*cell, std::move(*source));
  if (!planner.ok()) return planner.status();

  for (const std::string& item : items) {
    CaptureReplay c;
    if (report.session) {
      c = ReplayRecord(item, *cell, **planner, options);
    } else {
      c.file = item;
      c.task_id = cell->tasks.front().id;
      PlanRequest request;
      request.task = cell->tasks.front();
      std::string assumption;
      Result<Frame> frame = LoadFrameForPerception(item, *cell, cell->camera.X_BC, &assumption);
      if (!assumption.empty()) spdlog::warn("replay: {}", assumption);
      if (frame.ok()) {
        PlanFrame(**planner, request, std::move(*frame), c);
      } else {
        c.error = frame.status().ToString();
      }
    }
    if (!c.error.empty()) spdlog::warn("replay: {}: {}", item, c.error);
    if (!c.differences.empty() || (!c.replayed && c.compared)) ++report.differing;
    report.captures.push_back(std::move(c));
  }
  return report;
}

}  // namespace bp
