#include "pipeline/internal/part_settings.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "pipeline/internal/model_sampling.h"

namespace bp::internal {

namespace {

// Plausible part sizes: a mesh outside these is in the wrong unit.
constexpr double kMinDiameter = 0.002;
constexpr double kMaxDiameter = 2.0;
// Depth assumed for an eye-in-hand camera (its pose is known per capture only).
constexpr double kEyeInHandDepth = 1.0;
// The floor band stays this far (or 2 sigma_floor) below the lowest upward
// face of a part lying flat: about 1% of that face's points erased at the
// reference camera's sigma (0.44 mm).
constexpr double kFloorBandMargin = 0.001;
// The fewest grid points a scaled min_segment_points asks for (unless the
// options' own count is fewer).
constexpr int kMinSegmentFloor = 30;

std::string Mm(double metres) {
  char b[32];
  std::snprintf(b, sizeof b, "%.2f mm", metres * 1000.0);
  return b;
}

}  // namespace

CameraFigures CameraFiguresOf(const Cell& cell, const PerceptionOptions& options) {
  CameraFigures out;
  double z_floor = kEyeInHandDepth;
  if (!cell.camera.eye_in_hand) z_floor = std::abs((cell.camera.X_BC.inverse() * cell.bin.X_BW.translation()).z());
  for (const CameraConfig& c : cell.camera.configs) {
    out.sigma_floor = std::max(out.sigma_floor, c.noise.axial_sigma_base + c.noise.axial_sigma_quadratic * z_floor * z_floor);
    if (!(c.intrinsics.fx > 0)) continue;
    const double footprint = z_floor / c.intrinsics.fx;
    const int stride = std::clamp(static_cast<int>(std::lround(options.grid_spacing / std::max(footprint, 1e-6))), 1, 8);
    out.view_spacing = std::max(out.view_spacing, footprint * stride);
  }
  if (!(out.view_spacing > 0)) out.view_spacing = options.grid_spacing;
  return out;
}

PartGeometry MeasureMesh(const TriangleMesh& mesh) {
  PartGeometry g;
  g.diameter = PointSetDiameter(mesh.vertices);
  return g;
}

Status CheckMeshScale(const PartGeometry& geometry, const std::string& unit_hint, const std::string& path) {
  if (!unit_hint.empty() && unit_hint != "metres") {
    return Status::InvalidArgument("mesh '" + path + "' declares its unit as " + unit_hint +
                                   "; binpick meshes are in metres: convert it (and remove the unit from its header)");
  }
  const double d = geometry.diameter;
  if (d >= kMinDiameter && d <= kMaxDiameter) return Status::Ok();
  char size[64];
  std::snprintf(size, sizeof size, "%.6g", d);
  std::string likely;
  if (d > kMaxDiameter) {
    // The usual mistakes, most common first: the unit whose scale brings
    // the part into range.
    struct Unit {
      const char* name;
      double scale;
      const char* factor;
    };
    for (const Unit& u : {Unit{"millimetres", 0.001, "0.001"}, Unit{"centimetres", 0.01, "0.01"},
                          Unit{"inches", 0.0254, "0.0254"}}) {
      if (d * u.scale >= kMinDiameter && d * u.scale <= kMaxDiameter) {
        likely = std::string("; it is likely in ") + u.name + " (" + Mm(d * u.scale) + " across): scale it by " +
                 u.factor;
        break;
      }
    }
  } else {
    likely = "; was it scaled to metres twice (millimetres divided by 1000 again)?";
  }
  return Status::InvalidArgument("mesh '" + path + "' spans " + size + " m, outside the 2 mm - 2 m of a part" +
                                 likely);
}

PoseEstimatorOptions ScaledEstimatorOptions(const PartGeometry& geometry, const CameraFigures& camera,
                                            const PartPerception& overrides, const PoseEstimatorOptions& reference) {
  PoseEstimatorOptions o = reference;
  const double D = geometry.diameter;
  const double sigma = camera.sigma_floor;
  // The PPF step is relative to the model diameter (ppf_relative_sampling);
  // a step below the views' sample spacing only thins the table's matches.
  const double step = std::max(reference.ppf_relative_sampling * D, camera.view_spacing);
  o.icp_model_spacing = std::max(reference.icp_model_spacing, D / 300.0);
  // Verification samples are drawn from the dense ones: never finer.
  o.verify_model_spacing = std::max(o.icp_model_spacing, std::min(reference.verify_model_spacing, D / 15.0));
  o.support_distance = std::max(reference.support_distance, kSupportSigmas * sigma);
  o.free_space_distance = std::max(reference.free_space_distance, 6.8 * sigma);
  o.icp_final_distance = std::max(reference.icp_final_distance, 4.5 * sigma);
  double ppf_step = step;
  if (overrides.ppf_step) ppf_step = *overrides.ppf_step;
  if (overrides.icp_spacing) o.icp_model_spacing = *overrides.icp_spacing;
  if (overrides.verify_spacing) o.verify_model_spacing = *overrides.verify_spacing;
  if (overrides.support_distance) o.support_distance = *overrides.support_distance;
  if (overrides.free_space_distance) o.free_space_distance = *overrides.free_space_distance;
  if (overrides.min_score) o.min_score = *overrides.min_score;
  // The estimator takes the step relative to its own (sampled) diameter;
  // D here is the vertices' and can differ in the last digits: keep the
  // reference ratio unless the step moved. The ratio stays in the range
  // PoseEstimatorOptions accepts, (0.005, 0.2].
  if (ppf_step != reference.ppf_relative_sampling * D && D > 0) {
    o.ppf_relative_sampling = std::clamp(ppf_step / D, 0.0051, 0.2);
  }
  return o;
}

std::string ScaleToClasses(const std::vector<ClassFigures>& classes, const CameraFigures& camera,
                           PerceptionOptions* options) {
  if (options->min_segment_spacing < 0) options->min_segment_spacing = camera.view_spacing;
  if (classes.empty()) return "";
  double d_min = classes.front().diameter, h_min = classes.front().flat_height;
  int n_min = 0;
  for (const ClassFigures& c : classes) {
    d_min = std::min(d_min, c.diameter);
    h_min = std::min(h_min, c.flat_height);
    if (c.min_view_points > 0) n_min = n_min == 0 ? c.min_view_points : std::min(n_min, c.min_view_points);
  }
  std::string changed;
  const double s = camera.view_spacing;
  const int reference_points = options->min_segment_points;
  int points = std::clamp(static_cast<int>(std::lround(0.15 * d_min * d_min / (s * s))),
                          std::min(kMinSegmentFloor, reference_points),
                          reference_points);
  if (n_min > 0) points = n_min;
  if (points != reference_points) {
    const double ratio = static_cast<double>(points) / reference_points;
    options->min_segment_points = points;
    options->second_look_min_points = std::max(points, static_cast<int>(std::lround(options->second_look_min_points * ratio)));
    std::vector<int> waves;
    for (const int w : options->view_waves) {
      const int scaled = std::max(points, static_cast<int>(std::lround(w * ratio)));
      if (waves.empty() || scaled < waves.back()) waves.push_back(scaled);
    }
    options->view_waves = waves;
    changed += "min_segment_points " + std::to_string(points) + " (views of the smallest part, " +
               Mm(d_min) + " across), second_look_min_points " + std::to_string(options->second_look_min_points) +
               "; ";
  }
  const double noise_band = 3.0 * camera.sigma_floor;
  const double margin = std::max(kFloorBandMargin, 2.0 * camera.sigma_floor);
  // Rounded to 0.1 mm: the samples' heights carry float error.
  const double below_face = std::round((h_min - margin) * 1e4) / 1e4;
  const double band = std::clamp(below_face, noise_band, std::max(options->floor_band, noise_band));
  if (band != options->floor_band) {
    options->floor_band = band;
    changed += "floor band " + Mm(band) + " (the lowest upward face of a part lying flat is " + Mm(h_min) + " high); ";
  }
  return changed;
}

int FrameMinSegmentPoints(int min_segment_points, double min_segment_spacing, double spacing) {
  if (!(min_segment_spacing > 0) || !(spacing > min_segment_spacing)) return min_segment_points;
  const double ratio = min_segment_spacing / spacing;
  const int points = static_cast<int>(std::lround(min_segment_points * ratio * ratio));
  return std::max(points, std::min(kMinSegmentFloor, min_segment_points));
}

}  // namespace bp::internal
