#include "record/internal/replay_json.h"

#include <string>

namespace bp {
namespace record_internal {
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

OrderedJson CaptureJson(const CaptureReplay& c) {
  OrderedJson cj;
  cj["file"] = c.file;
  cj["task_id"] = c.task_id;
  cj["replayed"] = c.replayed;
  if (!c.error.empty()) cj["error"] = c.error;
  if (c.recorded_plan_ms >= 0.0) cj["recorded_plan_ms"] = c.recorded_plan_ms;
  if (c.replayed) {
    cj["plan_ms"] = c.plan_ms;
    OrderedJson stages = OrderedJson::object();
    for (const StageTime& s : c.result.stages) stages[s.stage] = s.ms;
    cj["stages_ms"] = stages;
    cj["result"] = ResultJson(c.result);
  }
  if (c.compared) {
    cj["recorded"] = ResultJson(c.recorded);
    cj["differences"] = c.differences;
    cj["max_position_diff_mm"] = c.max_position_diff_mm;
    cj["max_angle_diff_deg"] = c.max_angle_diff_deg;
  }
  return cj;
}

}  // namespace

OrderedJson ReplayReportToJson(const ReplayReport& report, const ReplayOptions& o) {
  OrderedJson j;
  j["dir"] = report.dir;
  j["cell"] = report.cell;
  j["cell_name"] = report.cell_name;
  j["kind"] = report.session ? "recorded session" : "frame files";
  j["tolerance"] = {{"mm", o.tolerance_mm}, {"deg", o.tolerance_deg}};
  OrderedJson captures = OrderedJson::array();
  int replayed = 0, compared = 0;
  for (const CaptureReplay& c : report.captures) {
    replayed += c.replayed ? 1 : 0;
    compared += c.compared ? 1 : 0;
    captures.push_back(CaptureJson(c));
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

}  // namespace record_internal

std::string ReplayReportJson(const ReplayReport& report, const ReplayOptions& options) {
  return record_internal::ReplayReportToJson(report, options).dump(2);
}

}  // namespace bp
