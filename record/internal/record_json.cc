#include "record/internal/record_json.h"

namespace bp::record_internal {
namespace {

using json = nlohmann::json;

PlanResult::Outcome OutcomeFromString(const std::string& s, bool* ok) {
  for (PlanResult::Outcome o : {PlanResult::Outcome::kGrasps, PlanResult::Outcome::kNoObjects,
                                PlanResult::Outcome::kNoCollisionFree, PlanResult::Outcome::kCaptureFailed}) {
    if (ToString(o) == s) return o;
  }
  *ok = false;
  return PlanResult::Outcome::kNoObjects;
}

}  // namespace

OrderedJson PlanResultJson(const PlanResult& result) {
  OrderedJson j;
  j["outcome"] = std::string(ToString(result.outcome));
  j["detections"] = result.detections;
  j["roi_points"] = result.roi_points;
  j["largest_region_points"] = result.largest_region_points;
  OrderedJson parts = OrderedJson::array();
  for (const DetectedPart& p : result.parts) {
    parts.push_back({{"class_id", p.class_id}, {"score", p.score}, {"X_BO", PoseToJson(p.X_BO)}});
  }
  j["parts"] = parts;
  OrderedJson grasps = OrderedJson::array();
  for (const Grasp& g : result.grasps) {
    OrderedJson related = OrderedJson::array();
    for (const Pose& X : g.related_X_B) related.push_back(PoseToJson(X));
    grasps.push_back({{"name", g.name},
                      {"class_id", g.class_id},
                      {"instance_id", g.instance_id},
                      {"score", g.score},
                      {"X_BT", PoseToJson(g.X_BT)},
                      {"X_BT_pre", PoseToJson(g.X_BT_pre)},
                      {"X_BO", PoseToJson(g.X_BO)},
                      {"related_X_B", related}});
  }
  j["grasps"] = grasps;
  OrderedJson stages = OrderedJson::array();
  for (const StageTime& s : result.stages) stages.push_back({{"stage", s.stage}, {"ms", s.ms}});
  j["stages"] = stages;
  j["message"] = result.message;
  return j;
}

Result<PlanResult> PlanResultFromJson(const json& j, const std::string& what) {
  try {
    PlanResult r;
    bool ok = true;
    r.outcome = OutcomeFromString(j.at("outcome").get<std::string>(), &ok);
    if (!ok) return Status::Corruption(what + ": unknown outcome");
    r.detections = j.at("detections").get<int>();
    r.roi_points = j.at("roi_points").get<int64_t>();
    r.largest_region_points = j.at("largest_region_points").get<int64_t>();
    for (const json& p : j.at("parts")) {
      DetectedPart part;
      part.class_id = p.at("class_id").get<int>();
      part.score = p.at("score").get<double>();
      Result<Pose> X = PoseFromJson(p.at("X_BO"), what + ".parts[].X_BO");
      if (!X.ok()) return X.status();
      part.X_BO = *X;
      r.parts.push_back(part);
    }
    for (const json& g : j.at("grasps")) {
      Grasp grasp;
      grasp.name = g.at("name").get<std::string>();
      grasp.class_id = g.at("class_id").get<int>();
      grasp.instance_id = g.at("instance_id").get<int>();
      grasp.score = g.at("score").get<double>();
      const std::pair<const char*, Pose*> poses[] = {
          {"X_BT", &grasp.X_BT}, {"X_BT_pre", &grasp.X_BT_pre}, {"X_BO", &grasp.X_BO}};
      for (const auto& [key, field] : poses) {
        Result<Pose> X = PoseFromJson(g.at(key), what + ".grasps[]." + key);
        if (!X.ok()) return X.status();
        *field = *X;
      }
      for (const json& rel : g.at("related_X_B")) {
        Result<Pose> X = PoseFromJson(rel, what + ".grasps[].related_X_B[]");
        if (!X.ok()) return X.status();
        grasp.related_X_B.push_back(*X);
      }
      r.grasps.push_back(std::move(grasp));
    }
    for (const json& s : j.at("stages")) r.stages.push_back({s.at("stage").get<std::string>(), s.at("ms").get<double>()});
    r.message = j.value("message", "");
    return r;
  } catch (const json::exception& e) {
    return Status::Corruption(what + ": " + e.what());
  }
}

OrderedJson RequestJson(const daoai::Request& q) {
  return {{"command", q.command},     {"payload_1", q.payload_1}, {"payload_2", q.payload_2},
          {"meta_1", q.meta_1},       {"meta_2", q.meta_2},       {"position", q.position},
          {"orientation", q.orientation}};
}

OrderedJson ResponseJson(const daoai::Response& r) {
  return {{"status", r.status}, {"payload", r.payload},         {"meta_1", r.meta_1},
          {"meta_2", r.meta_2}, {"position", r.position}, {"orientation", r.orientation}};
}

}  // namespace bp::record_internal
