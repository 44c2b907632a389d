// binpick replay DIR [--json OUT] [--cell FILE] [--tol-mm X] [--tol-deg Y]
// Reruns the pipeline over a recorded session (or any directory of PCD / PLY
// / depth PNG files) and prints, per capture, the per-stage latency, the
// detections and the differences from what was recorded (record/replay.h).
// Exit codes: 0 same within tolerances, 1 some capture differs or failed to
// replay (a regression), 2 bad input (no such directory, bad cell).
#include <cstdio>
#include <fstream>

#include <nlohmann/json.hpp>

#include "apps/binpick/command.h"
#include "record/replay.h"

namespace bp::cli {
namespace {

using OrderedJson = nlohmann::ordered_json;

OrderedJson PoseJson(const Pose& X) {
  const Vec3 t = X.translation();
  const Quat q(X.linear());
  return {{"xyz", {t.x(), t.y(), t.z()}}, {"quat_wxyz", {q.w(), q.x(), q.y(), q.z()}}};
}

OrderedJson ResultJson(const PlanResult& r) {
  OrderedJson j;
  j["outcome"] = std::string(ToString(r.outcome));
  j["detections"] = r.detections;
  j["roi_points"] = r.roi_points;
  OrderedJson parts = OrderedJson::array();
  for (const DetectedPart& p : r.parts) {
    parts.push_back({{"class_id", p.class_id}, {"score", p.score}, {"X_BO", PoseJson(p.X_BO)}});
  }
  j["parts"] = parts;
  OrderedJson grasps = OrderedJson::array();
  for (const Grasp& g : r.grasps) {
    grasps.push_back({{"name", g.name}, {"class_id", g.class_id}, {"score", g.score}, {"X_BT", PoseJson(g.X_BT)}});
  }
  j["grasps"] = grasps;
  return j;
}

OrderedJson ReportJson(const ReplayReport& report, const ReplayOptions& o) {
  OrderedJson j;
  j["dir"] = report.dir;
  j["cell"] = report.cell;
  j["kind"] = report.session ? "recorded session" : "frame files";
  j["tolerance"] = {{"mm", o.tolerance_mm}, {"deg", o.tolerance_deg}};
  OrderedJson captures = OrderedJson::array();
  int replayed = 0, compared = 0;
  for (const CaptureReplay& c : report.captures) {
    OrderedJson cj;
    cj["file"] = c.file;
    cj["task_id"] = c.task_id;
    cj["replayed"] = c.replayed;
    if (!c.error.empty()) cj["error"] = c.error;
    if (c.replayed) {
      ++replayed;
      cj["plan_ms"] = c.plan_ms;
      OrderedJson stages = OrderedJson::object();
      for (const StageTime& s : c.result.stages) stages[s.stage] = s.ms;
      cj["stages_ms"] = stages;
      cj["result"] = ResultJson(c.result);
    }
    if (c.compared) {
      ++compared;
      cj["recorded"] = ResultJson(c.recorded);
      cj["differences"] = c.differences;
      cj["max_position_diff_mm"] = c.max_position_diff_mm;
      cj["max_angle_diff_deg"] = c.max_angle_diff_deg;
    }
    captures.push_back(cj);
  }
  j["captures"] = captures;
  j["skipped"] = report.skipped;
  j["summary"] = {{"captures", report.captures.size()},
                  {"replayed", replayed},
                  {"compared", compared},
                  {"differing", report.differing},
                  {"skipped", report.skipped.size()}};
  return j;
}

void PrintCapture(const CaptureReplay& c) {
  const std::string name = c.file.substr(c.file.find_last_of('/') + 1);
  if (!c.replayed) {
    std::printf("%s task %d: not replayed: %s\n", name.c_str(), c.task_id, c.error.c_str());
    return;
  }
  std::printf("%s task %d: %s, %d detections, %zu grasps; %.1f ms (", name.c_str(), c.task_id,
              std::string(ToString(c.result.outcome)).c_str(), c.result.detections, c.result.grasps.size(),
              c.plan_ms);
  for (size_t i = 0; i < c.result.stages.size(); ++i) {
    std::printf("%s%s %.1f", i ? ", " : "", c.result.stages[i].stage.c_str(), c.result.stages[i].ms);
  }
  std::printf(")");
  if (!c.compared) {
    std::printf("; nothing recorded to compare\n");
  } else if (c.differences.empty()) {
    std::printf("; same as recorded (max %.3g mm, %.3g deg)\n", c.max_position_diff_mm, c.max_angle_diff_deg);
  } else {
    std::printf("; DIFFERS from the recording:\n");
    for (const std::string& d : c.differences) std::printf("    %s\n", d.c_str());
  }
}

}  // namespace

Command ReplayCommand() {
  return {"replay", "rerun the pipeline over a recorded session or a directory of frames; compare with the recording",
          [](CLI::App& sub) -> std::function<int()> {
            auto dir = std::make_shared<std::string>();
            auto json_out = std::make_shared<std::string>();
            auto options = std::make_shared<ReplayOptions>();
            sub.add_option("dir", *dir, "session directory (or a directory of PCD / PLY / depth PNG files)")
                ->required();
            sub.add_option("--json", *json_out, "write the full report as JSON to this file");
            sub.add_option("--cell", options->cell_path,
                           "cell file (default: the session's cell.yaml, else the embedded default)");
            sub.add_option("--tol-mm", options->tolerance_mm, "position tolerance for parts and grasps (mm)");
            sub.add_option("--tol-deg", options->tolerance_deg, "rotation tolerance for parts and grasps (deg)");
            return [dir, json_out, options]() -> int {
              Result<ReplayReport> report = ReplayDirectory(*dir, *options);
              if (!report.ok()) return Fail("replay", report.status());
              std::printf("replay %s (%s) with cell %s\n", dir->c_str(),
                          report->session ? "recorded session" : "frame files", report->cell.c_str());
              for (const std::string& s : report->skipped) std::printf("skipped: %s\n", s.c_str());
              for (const CaptureReplay& c : report->captures) PrintCapture(c);
              std::printf("%zu captures, %d differing, %zu skipped\n", report->captures.size(), report->differing,
                          report->skipped.size());
              if (!json_out->empty()) {
                std::ofstream out(*json_out);
                out << ReportJson(*report, *options).dump(2) << "\n";
                if (!out) return Fail("replay", Status::Internal("'" + *json_out + "': cannot write"));
              }
              return report->differing == 0 ? kExitOk : kExitFailure;
            };
          }};
}

}  // namespace bp::cli
