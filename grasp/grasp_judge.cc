#include "grasp/grasp_judge.h"

#include <cmath>
#include <limits>

namespace bp {

namespace {

// The grasp in the part frame as the cell defines it (a "~v" / "~v+45" turn undone),
// or as planned when the name is not a cell grasp (taught grasps).
Pose NominalGraspInPart(const GraspPlanningModel& model, const std::string& gripper, const Grasp& grasp) {
  std::string name = grasp.name;
  if (const size_t turn = name.find('~'); turn != std::string::npos) name.resize(turn);
  for (const TaughtGrasp& g : model.CellGrasps(grasp.class_id, gripper)) {
    if (g.name == name) return g.X_OG;
  }
  return grasp.X_BO.inverse() * grasp.X_BT;
}

}  // namespace

GraspOutcome JudgeGrasp(const GraspPlanningModel& model, const std::string& gripper, const Grasp& grasp,
                        std::span<const PartTruth> truth, const GraspJudgeOptions& options) {
  GraspOutcome out;
  out.class_id = grasp.class_id;
  out.name = grasp.name;
  out.X_BT = grasp.X_BT;
  const PartSpec* part = model.cell().FindPart(grasp.class_id);
  const GripperSpec* spec = model.cell().FindGripper(gripper);
  if (part == nullptr || spec == nullptr) {
    out.failure = "no_part";
    return out;
  }
  // The contact point is where the tool centre was planned (a "~v" turn keeps it).
  const Vec3 p_O = grasp.X_BO.inverse() * grasp.X_BT.translation();
  const Vec3 a_O = NominalGraspInPart(model, gripper, grasp).linear().col(2);
  const GraspLanding landing = LandOnTruth(grasp.X_BT, p_O, a_O, grasp.class_id, part->symmetry, truth);
  out.truth_instance = landing.truth_instance;
  out.position_error = landing.position_error;
  out.approach_error = landing.approach_error;
  const double max_approach = spec->kind == GripperSpec::Kind::kSuction
                                  ? model.options().suction_compliance_deg * M_PI / 180.0
                                  : options.parallel_jaw_approach;
  if (landing.truth_instance < 0) {
    out.failure = "no_part";
  } else if (landing.position_error > options.max_position) {
    out.failure = "off_part";
  } else if (landing.approach_error > max_approach + 1e-9) {
    out.failure = "approach";
  } else {
    out.on_part = true;
  }
  return out;
}

PickContact CheckPickOnTruth(const GraspPlanningModel& model, const std::string& gripper, const Grasp& grasp,
                             std::span<const PartTruth> truth, const GraspOutcome& outcome, const Pose& X_BW) {
  PickContact out;
  const Vec3 tool_B = grasp.X_BT.translation();
  double nearest = std::numeric_limits<double>::infinity();
  out.parts.reserve(truth.size());
  for (size_t i = 0; i < truth.size(); ++i) {
    const PartTruth& t = truth[i];
    if (outcome.on_part) {
      if (t.instance_id == outcome.truth_instance) out.touched = static_cast<int>(i);
    } else if (const std::optional<double> d = model.SurfaceDistance(t.class_id, t.X_BO, tool_B);
               d && *d <= model.options().contact_margin && *d < nearest) {
      nearest = *d;
      out.touched = static_cast<int>(i);
    }
    Detection d;
    d.class_id = t.class_id;
    d.X_BO = t.X_BO;
    out.parts.push_back(std::move(d));
  }
  out.hit = model.CheckAgainstParts(gripper, grasp.X_BT, out.parts, out.touched, X_BW);
  return out;
}

}  // namespace bp
