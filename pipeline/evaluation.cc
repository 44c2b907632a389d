#include "pipeline/evaluation.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>
#include <random>
#include <set>

#include <Eigen/Geometry>

#include "core/mesh.h"
#include "pipeline/pose_estimator.h"

namespace bp {

namespace {

constexpr double kPi = 3.14159265358979323846;

std::vector<Eigen::Vector3f> SampleSurface(const TriangleMesh& mesh, int n, uint64_t seed) {
  std::vector<double> cumulative;
  cumulative.reserve(mesh.triangles.size());
  double total = 0.0;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3f a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], c = mesh.vertices[t[2]];
    total += 0.5 * static_cast<double>((b - a).cross(c - a).norm());
    cumulative.push_back(total);
  }
  std::vector<Eigen::Vector3f> out;
  if (!(total > 0.0)) return out;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int i = 0; i < n; ++i) {
    const double r = uni(rng) * total;
    const size_t k = static_cast<size_t>(std::lower_bound(cumulative.begin(), cumulative.end(), r) - cumulative.begin());
    const auto& t = mesh.triangles[std::min(k, mesh.triangles.size() - 1)];
    double s = uni(rng), q = uni(rng);
    if (s + q > 1.0) {
      s = 1.0 - s;
      q = 1.0 - q;
    }
    const Eigen::Vector3f a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], c = mesh.vertices[t[2]];
    out.push_back(a + static_cast<float>(s) * (b - a) + static_cast<float>(q) * (c - a));
  }
  return out;
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const double pos = q * static_cast<double>(v.size() - 1);
  const size_t lo = static_cast<size_t>(std::floor(pos));
  const size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (pos - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

const EvalPartModel* FindModel(const std::vector<EvalPartModel>& models, int class_id) {
  for (const EvalPartModel& m : models) {
    if (m.class_id == class_id) return &m;
  }
  return nullptr;
}

}  // namespace

Result<std::vector<EvalPartModel>> LoadEvalModels(const Cell& cell) {
  std::vector<EvalPartModel> out;
  for (const PartSpec& part : cell.parts) {
    Result<TriangleMesh> mesh = LoadMesh(part.mesh);
    if (!mesh.ok()) return mesh.status();
    EvalPartModel m;
    m.class_id = part.class_id;
    m.name = part.name;
    m.symmetry = part.symmetry;
    m.diameter = mesh->Diameter();
    m.points_O = SampleSurface(*mesh, 500, 7 + static_cast<uint64_t>(part.class_id));
    if (m.points_O.empty()) return Status::InvalidArgument("part '" + part.name + "': mesh has no area");
    out.push_back(std::move(m));
  }
  return out;
}

// The pose estimator's symmetry-aware errors (pipeline/pose_estimator.h), so
// that the tool and the estimator's own tests measure the same thing.
double SymmetryAwareRotationError(const Pose& X_BO_a, const Pose& X_BO_b, const Symmetry& symmetry) {
  return SymmetricRotationError(X_BO_a, X_BO_b, symmetry);
}

double SymmetryAwareTranslationError(const Pose& X_BO_a, const Pose& X_BO_b, const Symmetry& symmetry) {
  return SymmetricTranslationError(X_BO_a, X_BO_b, symmetry);
}

double AddSDistance(std::span<const Eigen::Vector3f> points_O, const Pose& X_BO_a, const Pose& X_BO_b) {
  return AddS(points_O, X_BO_a, X_BO_b);
}

const char* ToString(DetectionVerdict verdict) {
  switch (verdict) {
    case DetectionVerdict::kTrue: return "true";
    case DetectionVerdict::kGross: return "gross";
    case DetectionVerdict::kDuplicate: return "duplicate";
    case DetectionVerdict::kFalse: return "false";
  }
  return "?";
}

namespace {

// The angle about unit axis `a` that turns u's component normal to `a` onto
// v's; nullopt when either component is (nearly) zero.
std::optional<double> AngleAbout(const Vec3& a, const Vec3& u, const Vec3& v) {
  const Vec3 ur = u - u.dot(a) * a, vr = v - v.dot(a) * a;
  if (ur.norm() < 1e-9 || vr.norm() < 1e-9) return std::nullopt;
  return std::atan2(a.dot(ur.cross(vr)), ur.dot(vr));
}

double AngleBetween(const Vec3& u, const Vec3& v) { return std::atan2(u.cross(v).norm(), u.dot(v)); }

// How far a landing is from a grasp, in metres: position error plus 10 mm per
// radian of approach error (1 mm per 5.7 deg). A copy approached tens of
// degrees off costs several millimetres more, so it never wins by being a
// little nearer; between copies approached alike, position decides. Choosing
// by position alone picked, for a grasp point near a 2-fold axis, the copy
// across the axis, approached from the other side.
double LandingCost(double position, double approach) { return position + 0.01 * approach; }

}  // namespace

GraspLanding LandOnTruth(const Pose& X_BT, const Vec3& p_O, const Vec3& a_O, int class_id, const Symmetry& symmetry,
                         std::span<const PartTruth> parts) {
  GraspLanding best;
  best.position_error = std::numeric_limits<double>::infinity();
  best.approach_error = std::numeric_limits<double>::infinity();
  const Vec3 t_B = X_BT.translation();
  const Vec3 z_B = X_BT.linear().col(2);
  const Vec3 axis = symmetry.axis.normalized();
  std::vector<Pose> extras{Pose::Identity()};
  extras.insert(extras.end(), symmetry.extra.begin(), symmetry.extra.end());
  for (const PartTruth& part : parts) {
    if (part.class_id != class_id) continue;
    for (const Pose& E : extras) {
      // The tool in the frame of this symmetric copy of the part: X_BO E.
      const Pose X_OB = (part.X_BO * E).inverse();
      const Vec3 q = X_OB * t_B;
      const Vec3 z = X_OB.linear() * z_B;
      std::vector<Mat3> rotations;
      switch (symmetry.kind) {
        case Symmetry::Kind::kNone: rotations.push_back(Mat3::Identity()); break;
        case Symmetry::Kind::kDiscrete: {
          const int n = std::max(1, symmetry.order);
          for (int k = 0; k < n; ++k) rotations.push_back(Eigen::AngleAxisd(2 * kPi * k / n, axis).toRotationMatrix());
          break;
        }
        case Symmetry::Kind::kRevolute: {
          // The point decides the angle; a point on the axis leaves it to the approach.
          std::optional<double> angle = AngleAbout(axis, p_O, q);
          if (!angle) angle = AngleAbout(axis, a_O, z);
          rotations.push_back(Eigen::AngleAxisd(angle.value_or(0.0), axis).toRotationMatrix());
          break;
        }
      }
      for (const Mat3& R : rotations) {
        const double position = (q - R * p_O).norm();
        const double approach = AngleBetween(z, R * a_O);
        if (LandingCost(position, approach) < LandingCost(best.position_error, best.approach_error) - 1e-12) {
          best.truth_instance = part.instance_id;
          best.position_error = position;
          best.approach_error = approach;
        }
      }
    }
  }
  if (best.truth_instance < 0) best.position_error = best.approach_error = 0.0;
  return best;
}

FrameEvaluation EvaluateFrame(const PerceptionResult& result, const GroundTruth& truth,
                              const std::vector<EvalPartModel>& models, const EvalOptions& options) {
  FrameEvaluation out;
  out.timings = result.timings;
  out.total_ms = result.TotalMs();
  for (const PartTruth& p : truth.parts) {
    if (p.visible_fraction >= options.min_visible_fraction) ++out.targets[p.class_id];
  }
  std::vector<size_t> order(result.detections.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](size_t a, size_t b) { return result.detections[a].score > result.detections[b].score; });
  std::vector<uint8_t> taken(truth.parts.size(), 0);
  for (size_t k : order) {
    const Detection& d = result.detections[k];
    DetectionOutcome o;
    o.detection = k;
    o.class_id = d.class_id;
    const EvalPartModel* model = FindModel(models, d.class_id);
    if (model != nullptr) {
      // The closest part in tolerance (unmatched first), and the nearest origin.
      double best_free = std::numeric_limits<double>::infinity(), best_taken = best_free;
      int free_index = -1, taken_index = -1, near_index = -1;
      double near_distance = options.gross_relative_distance * model->diameter;
      for (size_t g = 0; g < truth.parts.size(); ++g) {
        const PartTruth& p = truth.parts[g];
        if (p.class_id != d.class_id) continue;
        const double t = SymmetryAwareTranslationError(d.X_BO, p.X_BO, model->symmetry);
        const double r = SymmetryAwareRotationError(d.X_BO, p.X_BO, model->symmetry);
        if (t <= options.translation_tolerance && r <= options.rotation_tolerance) {
          const double relative = t / options.translation_tolerance + r / options.rotation_tolerance;
          double& best = taken[g] ? best_taken : best_free;
          if (relative < best) {
            best = relative;
            (taken[g] ? taken_index : free_index) = static_cast<int>(g);
          }
        }
        const double dist = (p.X_BO.translation() - d.X_BO.translation()).norm();
        if (dist < near_distance) {
          near_distance = dist;
          near_index = static_cast<int>(g);
        }
      }
      int errors_to = -1;
      if (free_index >= 0) {
        o.verdict = DetectionVerdict::kTrue;
        errors_to = free_index;
        const PartTruth& p = truth.parts[static_cast<size_t>(free_index)];
        taken[static_cast<size_t>(free_index)] = 1;
        o.truth_instance = p.instance_id;
        o.target = p.visible_fraction >= options.min_visible_fraction;
        if (o.target) ++out.targets_found[p.class_id];
      } else if (taken_index >= 0) {
        o.verdict = DetectionVerdict::kDuplicate;
        errors_to = taken_index;
      } else if (near_index >= 0) {
        o.verdict = DetectionVerdict::kGross;
        errors_to = near_index;
      }
      if (errors_to >= 0) {
        const PartTruth& p = truth.parts[static_cast<size_t>(errors_to)];
        o.near_instance = p.instance_id;
        o.translation_error = SymmetryAwareTranslationError(d.X_BO, p.X_BO, model->symmetry);
        o.rotation_error = SymmetryAwareRotationError(d.X_BO, p.X_BO, model->symmetry);
        o.adds = AddSDistance(model->points_O, d.X_BO, p.X_BO);
        o.adds_ok = o.adds < options.adds_relative * model->diameter;
        if (o.verdict == DetectionVerdict::kGross) {
          for (const Pose& X_BO : d.alternatives_X_BO) {
            o.carried |= SymmetryAwareTranslationError(X_BO, p.X_BO, model->symmetry) <= options.translation_tolerance &&
                         SymmetryAwareRotationError(X_BO, p.X_BO, model->symmetry) <= options.rotation_tolerance;
          }
        }
      }
      o.alternatives = static_cast<int>(d.alternatives_X_BO.size());
    }
    out.detections.push_back(o);
  }
  return out;
}

SegmentationFigures EvaluateSegmentation(const Frame& frame, const PerceptionResult& result, const Cell& /*cell*/,
                                         const EvalOptions& options) {
  SegmentationFigures out;
  if (!frame.truth || frame.truth->labels.empty() || !frame.organized()) return out;
  // Each ROI point's pixel: its projection (the pipeline deprojected it from
  // that pixel's centre, possibly from smoothed depth, so it rounds back).
  const Intrinsics& K = frame.intrinsics;
  const Pose X_CB = frame.X_BC.inverse();
  const int w = frame.depth.width, h = frame.depth.height;
  int max_segment = -1;
  for (int32_t s : result.segment_of_point) max_segment = std::max(max_segment, s);
  out.segments = max_segment + 1;
  // counts[segment][instance]
  std::map<int, std::map<int, int>> by_segment;
  std::map<int, std::map<int, int>> by_instance;
  const size_t n = std::min(result.roi_points_B.size(), result.segment_of_point.size());
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d q = X_CB * result.roi_points_B[i].cast<double>();
    if (!(q.z() > 0.0)) continue;
    const long u = std::lround(K.fx * q.x() / q.z() + K.cx), v = std::lround(K.fy * q.y() / q.z() + K.cy);
    if (u < 0 || v < 0 || u >= w || v >= h) continue;
    const uint16_t label = frame.truth->labels.data[static_cast<size_t>(v) * w + static_cast<size_t>(u)];
    const int32_t s = result.segment_of_point[i];
    if (label == 0 || label == GroundTruth::kBinLabel) {
      if (s >= 0) ++by_segment[s][0];
      continue;
    }
    ++by_instance[label][s];
    if (s >= 0) ++by_segment[s][label];
  }
  for (const PartTruth& p : frame.truth->parts) {
    if (p.visible_fraction < options.min_visible_fraction) continue;
    const auto it = by_instance.find(p.instance_id);
    if (it == by_instance.end()) continue;
    int total = 0, segmented = 0, best = 0, best_segment = -1;
    for (const auto& [s, n] : it->second) {
      total += n;
      if (s < 0) continue;
      segmented += n;
      if (n > best) {
        best = n;
        best_segment = s;
      }
    }
    if (total < 50) continue;
    ++out.parts;
    if (segmented == 0 || best < 0.8 * segmented) ++out.split;
    if (best_segment >= 0) {
      const auto& seg = by_segment[best_segment];
      int seg_total = 0, other = 0;
      for (const auto& [inst, n] : seg) {
        seg_total += n;
        if (inst != p.instance_id && inst != 0) other = std::max(other, n);
      }
      if (other >= 0.2 * seg_total) ++out.merged;
    }
  }
  return out;
}

EvalReport Summarize(const std::vector<FrameEvaluation>& frames, const std::vector<EvalPartModel>& models) {
  EvalReport report;
  report.frames = static_cast<int>(frames.size());
  const auto figures = [&](const std::string& name, int class_id, bool all) {
    ClassFigures f;
    f.name = name;
    std::vector<double> t, r, r_near;
    int adds_ok = 0;
    for (const FrameEvaluation& fe : frames) {
      for (const auto& [c, n] : fe.targets) f.targets += (all || c == class_id) ? n : 0;
      for (const auto& [c, n] : fe.targets_found) f.found += (all || c == class_id) ? n : 0;
      for (const DetectionOutcome& o : fe.detections) {
        if (!all && o.class_id != class_id) continue;
        ++f.detections;
        adds_ok += o.adds_ok ? 1 : 0;
        switch (o.verdict) {
          case DetectionVerdict::kTrue: break;
          case DetectionVerdict::kGross:
            ++f.gross_errors;
            f.gross_carried += o.carried ? 1 : 0;
            r_near.push_back(o.rotation_error * 180.0 / kPi);
            continue;
          case DetectionVerdict::kDuplicate: ++f.duplicates; continue;
          case DetectionVerdict::kFalse: ++f.false_positives; continue;
        }
        ++f.true_positives;
        t.push_back(o.translation_error * 1000.0);
        r.push_back(o.rotation_error * 180.0 / kPi);
        r_near.push_back(o.rotation_error * 180.0 / kPi);
      }
    }
    f.recall = f.targets > 0 ? static_cast<double>(f.found) / f.targets : 1.0;
    f.precision = f.detections > 0 ? static_cast<double>(f.true_positives) / f.detections : 1.0;
    f.t_median_mm = Percentile(t, 0.5);
    f.t_p95_mm = Percentile(t, 0.95);
    f.r_median_deg = Percentile(r, 0.5);
    f.r_p95_deg = Percentile(r, 0.95);
    f.r_near_p95_deg = Percentile(r_near, 0.95);
    f.r_near_max_deg = r_near.empty() ? 0.0 : *std::max_element(r_near.begin(), r_near.end());
    f.gross_fraction = f.detections > 0 ? static_cast<double>(f.gross_errors) / f.detections : 0.0;
    f.adds_ok_fraction = f.detections > 0 ? static_cast<double>(adds_ok) / f.detections : 0.0;
    return f;
  };
  for (const EvalPartModel& m : models) report.classes.push_back(figures(m.name, m.class_id, false));
  report.classes.push_back(figures("all", -1, true));

  std::vector<std::string> stage_names;
  for (const FrameEvaluation& fe : frames) {
    for (const StageTiming& st : fe.timings) {
      if (std::find(stage_names.begin(), stage_names.end(), st.stage) == stage_names.end()) {
        stage_names.push_back(st.stage);
      }
    }
  }
  for (const std::string& name : stage_names) {
    std::vector<double> ms;
    for (const FrameEvaluation& fe : frames) {
      double sum = 0.0;
      for (const StageTiming& st : fe.timings) sum += st.stage == name ? st.ms : 0.0;
      ms.push_back(sum);
    }
    report.stages.push_back({name, Percentile(ms, 0.5), Percentile(ms, 0.95)});
  }
  std::vector<double> total;
  for (const FrameEvaluation& fe : frames) total.push_back(fe.total_ms);
  report.stages.push_back({"total", Percentile(total, 0.5), Percentile(total, 0.95)});

  GraspFigures& g = report.grasps;
  for (const FrameEvaluation& fe : frames) {
    if (!fe.grasps_planned) continue;
    ++g.frames;
    if (!fe.grasps.empty()) {
      ++g.frames_with_grasp;
      g.first_on_part += fe.grasps.front().on_part ? 1 : 0;
    }
    for (const GraspOutcome& o : fe.grasps) {
      ++g.grasps;
      if (o.on_part) {
        ++g.on_part;
      } else {
        ++g.failures[o.failure];
      }
    }
  }
  g.first_fraction = g.frames_with_grasp > 0 ? static_cast<double>(g.first_on_part) / g.frames_with_grasp : 1.0;
  g.all_fraction = g.grasps > 0 ? static_cast<double>(g.on_part) / g.grasps : 1.0;
  return report;
}

}  // namespace bp

namespace bp {

std::vector<int> RoiPointOwners(const Frame& frame, const PerceptionResult& result) {
  std::vector<int> owners;
  if (!frame.truth || frame.truth->labels.empty() || !frame.organized()) return owners;
  // Each ROI point's pixel: its projection (deprojected from that pixel's
  // centre, possibly from smoothed depth, so it rounds back).
  const Intrinsics& K = frame.intrinsics;
  const Pose X_CB = frame.X_BC.inverse();
  const int w = frame.depth.width, h = frame.depth.height;
  owners.assign(result.roi_points_B.size(), -1);
  for (size_t i = 0; i < result.roi_points_B.size(); ++i) {
    const Eigen::Vector3d q = X_CB * result.roi_points_B[i].cast<double>();
    if (!(q.z() > 0.0)) continue;
    const long u = std::lround(K.fx * q.x() / q.z() + K.cx), v = std::lround(K.fy * q.y() / q.z() + K.cy);
    if (u < 0 || v < 0 || u >= w || v >= h) continue;
    owners[i] = frame.truth->labels.data[static_cast<size_t>(v) * w + static_cast<size_t>(u)];
  }
  return owners;
}

PartCut CutOfPart(int instance_id, std::span<const int> owners, std::span<const int32_t> segment_of_point) {
  PartCut cut;
  std::map<int32_t, int> own_by_segment, all_by_segment;
  const size_t n = std::min(owners.size(), segment_of_point.size());
  for (size_t i = 0; i < n; ++i) {
    const int32_t s = segment_of_point[i];
    if (s >= 0 && owners[i] >= 0) ++all_by_segment[s];
    if (owners[i] != instance_id) continue;
    ++cut.points;
    if (s < 0) {
      ++cut.unsegmented;
    } else {
      ++own_by_segment[s];
    }
  }
  int segmented = 0, best = 0;
  int32_t best_segment = -1;
  for (const auto& [s, c] : own_by_segment) {
    segmented += c;
    if (c > best) {
      best = c;
      best_segment = s;
    }
  }
  cut.segments = static_cast<int>(own_by_segment.size());
  cut.largest_share = segmented > 0 ? static_cast<double>(best) / segmented : 0.0;
  cut.largest_purity = best_segment >= 0 ? static_cast<double>(best) / all_by_segment[best_segment] : 0.0;
  return cut;
}

const char* ToString(MissCause cause) {
  switch (cause) {
    case MissCause::kWrongDetection: return "wrong_detection";
    case MissCause::kTruthScoresLow: return "truth_low";
    case MissCause::kUnsegmented: return "unsegmented";
    case MissCause::kSplit: return "split";
    case MissCause::kMerged: return "merged";
    case MissCause::kNotFound: return "not_found";
  }
  return "?";
}

MissCause ClassifyMiss(const PartCut& cut, bool wrong_detection_on_it, double truth_score, double min_score) {
  if (wrong_detection_on_it) return MissCause::kWrongDetection;
  if (truth_score < min_score) return MissCause::kTruthScoresLow;  // false for NaN
  if (2 * cut.unsegmented > cut.points) return MissCause::kUnsegmented;
  if (cut.largest_share < 0.8) return MissCause::kSplit;
  if (cut.largest_purity < 0.8) return MissCause::kMerged;
  return MissCause::kNotFound;
}

int SupportOwner(const Detection& detection, std::span<const int> owners) {
  std::map<int, int> by_owner;
  for (int32_t k : detection.support) {
    if (k < 0 || static_cast<size_t>(k) >= owners.size()) continue;
    ++by_owner[owners[static_cast<size_t>(k)]];
  }
  int best = 0, best_n = 0, total = 0;
  for (const auto& [owner, n] : by_owner) {
    total += n;
    if (owner > 0 && owner != GroundTruth::kBinLabel && n > best_n) {
      best = owner;
      best_n = n;
    }
  }
  return 2 * best_n > total ? best : 0;
}

const char* ToString(FalseCause cause) {
  switch (cause) {
    case FalseCause::kOnOtherClassFound: return "other_class_found";
    case FalseCause::kOnOtherClassMissed: return "other_class_missed";
    case FalseCause::kOnItsClass: return "its_class";
    case FalseCause::kOnNoPart: return "no_part";
  }
  return "?";
}

void AddFrameCauses(const Frame& frame, const PerceptionResult& result, const FrameEvaluation& fe,
                    const std::function<double(const PartTruth&, const std::vector<Eigen::Vector3f>&)>& truth_score,
                    CauseFigures& figures, const EvalOptions& options, int frame_index) {
  if (!frame.truth) return;
  const std::vector<int> owners = RoiPointOwners(frame, result);
  if (owners.empty()) return;
  std::set<int> found;
  std::map<int, const PartTruth*> parts;
  for (const PartTruth& p : frame.truth->parts) parts[p.instance_id] = &p;
  for (const DetectionOutcome& o : fe.detections) {
    if (o.verdict == DetectionVerdict::kTrue) found.insert(o.truth_instance);
  }
  // The parts a wrong detection sits on, and the false positives' causes.
  std::set<int> wrong_on;
  for (const DetectionOutcome& o : fe.detections) {
    if (o.verdict == DetectionVerdict::kTrue || o.detection >= result.detections.size()) continue;
    if (o.verdict == DetectionVerdict::kGross) wrong_on.insert(o.near_instance);
    const int owner = SupportOwner(result.detections[o.detection], owners);
    if (owner > 0) wrong_on.insert(owner);
    if (o.verdict != DetectionVerdict::kFalse) continue;
    FalseCause cause = FalseCause::kOnNoPart;
    const auto it = parts.find(owner);
    if (it != parts.end()) {
      if (it->second->class_id == o.class_id) {
        cause = FalseCause::kOnItsClass;
      } else {
        cause = found.count(owner) ? FalseCause::kOnOtherClassFound : FalseCause::kOnOtherClassMissed;
      }
    }
    ++figures.false_positives[o.class_id][static_cast<size_t>(cause)];
  }
  for (const PartTruth& p : frame.truth->parts) {
    if (p.visible_fraction < options.min_visible_fraction || found.count(p.instance_id)) continue;
    const PartCut cut = CutOfPart(p.instance_id, owners, result.segment_of_point);
    double score = std::numeric_limits<double>::quiet_NaN();
    if (!wrong_on.count(p.instance_id) && truth_score) {
      std::vector<Eigen::Vector3f> own;
      for (size_t i = 0; i < owners.size(); ++i) {
        if (owners[i] == p.instance_id) own.push_back(result.roi_points_B[i]);
      }
      if (!own.empty()) score = truth_score(p, own);
    }
    const MissCause cause = ClassifyMiss(cut, wrong_on.count(p.instance_id) > 0, score);
    ++figures.misses[p.class_id][static_cast<size_t>(cause)];
    figures.missed.push_back(MissRecord{frame_index, p.instance_id, p.class_id, cause});
  }
}

}  // namespace bp
