#include "grasp/grasp_planning.h"

#include <spdlog/spdlog.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>
#include <tuple>
#include <utility>

#include "collision/mesh_collider.h"
#include "collision/point_obstacle.h"
#include "core/mesh.h"
#include "core/mesh_gen.h"
#include "grasp/internal/contact_region.h"
#include "grasp/internal/occupancy_grid.h"
#include "grasp/internal/surface_depth.h"
#include "grasp/internal/support_cells.h"
#include "grasp/internal/surface_explanation.h"
#include "pipeline/evaluation.h"
#include "pipeline/internal/depth_window.h"
#include "pipeline/internal/part_settings.h"

namespace bp {

std::string_view ToString(RejectReason reason) {
  switch (reason) {
    case RejectReason::kTilt: return "tilt";
    case RejectReason::kWorkspace: return "workspace";
    case RejectReason::kUnplaceable: return "unplaceable";
    case RejectReason::kAmbiguous: return "ambiguous";
    case RejectReason::kUnseen: return "unseen";
    case RejectReason::kBin: return "bin";
    case RejectReason::kPart: return "part";
    case RejectReason::kSelf: return "self";
    case RejectReason::kPoints: return "points";
    case RejectReason::kHiddenSpace: return "hidden_space";
    case RejectReason::kHidden: return "hidden";
  }
  return "?";
}

std::string FilterStats::Describe() const {
  std::ostringstream os;
  os << candidates << " candidates, " << accepted << " collision-free";
  for (int r = 0; r < kNumRejectReasons; ++r) {
    if (rejected[r] > 0) os << "; " << ToString(static_cast<RejectReason>(r)) << " " << rejected[r];
  }
  os << " (" << filter_ms << " ms, obstacles " << obstacles_ms << " ms, neighbours " << neighbours_ms << " ms)";
  return os.str();
}

namespace {

Pose TranslateZ(double z) {
  Pose X = Pose::Identity();
  X.translation() = Vec3(0, 0, z);
  return X;
}

// The gripper swept along its approach (translated by 0 .. -distance in z).
//
// Exact and cheap when every connected component of the gripper mesh has
// horizontal cross-sections that never shrink toward -z (each contains the
// ones above it): then the sweep is the component with its lowest vertices
// moved down by `distance`. Recognised cases: prisms along z (every vertex on
// the component's lowest or highest z: boxes, cylinders) and solids of
// revolution about a z axis whose radius does not shrink toward -z (the
// shipped suction cup: a cup under a wider rod). Otherwise the sweep is the
// union of copies every `step` (many overlapping triangles, slower queries).
TriangleMesh SweepAlongApproach(const TriangleMesh& gripper_T, double distance, double step) {
  const int n = static_cast<int>(gripper_T.vertices.size());
  std::vector<int> parent(n);
  for (int i = 0; i < n; ++i) parent[i] = i;
  auto find = [&parent](int i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  for (const auto& t : gripper_T.triangles) {
    for (int k = 1; k < 3; ++k) parent[find(t[k])] = find(t[0]);
  }
  std::map<int, std::vector<int>> components;
  for (int i = 0; i < n; ++i) components[find(i)].push_back(i);
  constexpr double kEps = 1e-6;
  auto stretchable = [&](const std::vector<int>& vs) {
    double lo = 1e9, hi = -1e9;
    Eigen::Vector2d centre = Eigen::Vector2d::Zero();
    for (int i : vs) {
      const auto& v = gripper_T.vertices[i];
      lo = std::min(lo, static_cast<double>(v.z()));
      hi = std::max(hi, static_cast<double>(v.z()));
      centre += v.head<2>().cast<double>();
    }
    centre /= static_cast<double>(vs.size());
    bool prism = true;
    for (int i : vs) {
      const double z = gripper_T.vertices[i].z();
      prism = prism && (std::abs(z - lo) < kEps || std::abs(z - hi) < kEps);
    }
    if (prism) return true;
    // Revolved (assumed: sections are discs about the component's centre
    // axis): the largest radius per z level must not shrink going down.
    std::map<double, double, std::greater<double>> max_r;  // z (top first) -> radius
    for (int i : vs) {
      const auto& v = gripper_T.vertices[i];
      const double z = std::round(v.z() / kEps) * kEps;
      double& r = max_r[z];
      r = std::max(r, (v.head<2>().cast<double>() - centre).norm());
    }
    double previous = 0;
    for (const auto& [z, r] : max_r) {
      if (r + kEps < previous) return false;
      previous = r;
    }
    return true;
  };
  bool stretch = true;
  for (const auto& [root, vs] : components) stretch = stretch && stretchable(vs);
  if (stretch) {
    TriangleMesh out = gripper_T;
    for (const auto& [root, vs] : components) {
      float lo = 1e9f;
      for (int i : vs) lo = std::min(lo, out.vertices[i].z());
      for (int i : vs) {
        if (std::abs(out.vertices[i].z() - lo) < kEps) out.vertices[i].z() -= static_cast<float>(distance);
      }
    }
    return out;
  }
  TriangleMesh out;
  const int copies = std::max(1, static_cast<int>(std::ceil(distance / step - 1e-9))) + 1;
  out.vertices.reserve(gripper_T.vertices.size() * copies);
  out.triangles.reserve(gripper_T.triangles.size() * copies);
  for (int k = 0; k < copies; ++k) {
    const float dz = -static_cast<float>(std::min(distance, k * step));
    const int base = static_cast<int>(out.vertices.size());
    for (const auto& v : gripper_T.vertices) out.vertices.push_back(v + Eigen::Vector3f(0, 0, dz));
    for (const auto& t : gripper_T.triangles) out.triangles.push_back(t + Eigen::Vector3i::Constant(base));
  }
  return out;
}

// Boxes (in T) covering the swept mesh slab by slab along z: tighter than one
// box for the occupancy pre-filter of a long tilted gripper.
std::vector<Eigen::AlignedBox3d> SlabBoxes(const TriangleMesh& mesh, int slabs) {
  Eigen::AlignedBox3d all;
  for (const auto& v : mesh.vertices) all.extend(v.cast<double>());
  std::vector<Eigen::AlignedBox3d> boxes(slabs);
  const double z0 = all.min().z(), dz = std::max(1e-9, all.sizes().z() / slabs);
  for (const auto& t : mesh.triangles) {
    Eigen::AlignedBox3d tb;
    for (int i = 0; i < 3; ++i) tb.extend(mesh.vertices[t[i]].cast<double>());
    const int lo = std::clamp(static_cast<int>((tb.min().z() - z0) / dz), 0, slabs - 1);
    const int hi = std::clamp(static_cast<int>((tb.max().z() - z0) / dz), 0, slabs - 1);
    for (int s = lo; s <= hi; ++s) {
      Eigen::AlignedBox3d clipped = tb;
      clipped.min().z() = std::max(tb.min().z(), z0 + s * dz);
      clipped.max().z() = std::min(tb.max().z(), z0 + (s + 1) * dz);
      boxes[s].extend(clipped);
    }
  }
  boxes.erase(std::remove_if(boxes.begin(), boxes.end(), [](const auto& b) { return b.isEmpty(); }), boxes.end());
  return boxes;
}

// `mesh` grown outward by `by` (m): each vertex (welded by position) moves
// along its averaged face normal n far enough that every face around it
// moves out by at least `by` (by / min(n . n_face), capped at 3 * by on
// needle tips). A convex edge or corner reaches up to about sqrt(3) * by
// further than the exact offset surface; flat and smooth parts move by
// `by`. Colliding with the grown mesh is then "closer than `by`" to the
// original, at the cost of an FCL collision query (early exit) instead of a
// distance query.
TriangleMesh Inflated(const TriangleMesh& mesh, double by) {
  std::map<std::tuple<float, float, float>, int> weld;
  std::vector<int> position_of(mesh.vertices.size());
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Eigen::Vector3f& v = mesh.vertices[i];
    position_of[i] = weld.emplace(std::make_tuple(v.x(), v.y(), v.z()), static_cast<int>(weld.size())).first->second;
  }
  std::vector<Vec3> normal_sum(weld.size(), Vec3::Zero());
  std::vector<std::vector<Vec3>> face_normals(weld.size());
  for (const Eigen::Vector3i& t : mesh.triangles) {
    const Vec3 a = mesh.vertices[t[0]].cast<double>(), b = mesh.vertices[t[1]].cast<double>(),
               c = mesh.vertices[t[2]].cast<double>();
    const Vec3 n = (b - a).cross(c - a);
    if (n.norm() < 1e-15) continue;
    for (int k = 0; k < 3; ++k) {
      normal_sum[position_of[t[k]]] += n.normalized();
      face_normals[position_of[t[k]]].push_back(n.normalized());
    }
  }
  std::vector<Vec3> offset(weld.size(), Vec3::Zero());
  for (size_t p = 0; p < weld.size(); ++p) {
    if (normal_sum[p].norm() < 1e-12) continue;
    const Vec3 n = normal_sum[p].normalized();
    double least = 1.0;
    for (const Vec3& f : face_normals[p]) least = std::min(least, n.dot(f));
    offset[p] = n * (by / std::max(least, 1.0 / 3.0));
  }
  TriangleMesh out = mesh;
  for (size_t i = 0; i < out.vertices.size(); ++i) out.vertices[i] += offset[position_of[i]].cast<float>();
  return out;
}

Eigen::AlignedBox3d WorldBox(const Eigen::AlignedBox3d& local, const Pose& X_WL) {
  Eigen::AlignedBox3d box;
  for (int i = 0; i < 8; ++i) box.extend(X_WL * local.corner(static_cast<Eigen::AlignedBox3d::CornerType>(i)));
  return box;
}

// m between the samples of a part's surface that explain ROI points
// (GraspPlanningOptions::surface_explain_distance): a point is explained
// within that distance plus this of a sample (random samples of this
// density leave no gap much wider on a face).
constexpr double kSurfaceSpacing = 0.0005;
// Rays across and down a tile of a detection's hidden space built on demand
// (FrameObstacles::HiddenSpaces): 16 rays 2 mm apart on the floor, about
// half a cup's footprint.
constexpr int kHiddenTileRays = 16;
// m, the cells of a detection's own points' occupancy grid (the own-point
// check's pre-filter): about the size of the sweep's slab boxes' overlap
// with a part, so that a query walks tens of cells, not thousands.
constexpr double kOwnGridCell = 0.005;
// The explaining side faces the camera: its outward normal at most 10 deg
// past perpendicular to the line to the camera (grazing faces are seen at
// their edges, and a detection is up to the strict 5 deg off).
const float kFacingMinCos = static_cast<float>(-std::sin(10.0 * M_PI / 180.0));

// sigma_z (m) at the bin floor's depth of the cell's noisiest camera config,
// as perception's settings read it; 0 for a camera on the robot's hand.
double FloorSigma(const Cell& cell) {
  return cell.camera.eye_in_hand ? 0.0 : internal::CameraFiguresOf(cell, PerceptionOptions{}).sigma_floor;
}

}  // namespace

class GraspPlanningModel::Impl {
 public:
  struct Gripper {
    const GripperSpec* spec = nullptr;
    CollisionGeometryPtr sweep;               // swept along the approach, in T
    CollisionGeometryPtr sweep_margin;        // `sweep` grown by options.approach_margin
    // How far up (m, along -z of T) the point check holds the sweep:
    // contact_margin for a suction cup (it meets the surface at the grasp
    // point), 0 for a jaw (its open fingers touch nothing there).
    double points_lift = 0.0;
    std::vector<Eigen::AlignedBox3d> slabs;   // boxes covering `sweep`, in T
    internal::ContactShape contact;           // where it touches a part, in T
  };
  Cell cell;
  GraspPlanningOptions options;
  std::map<int, CollisionGeometryPtr> parts;     // by class id, in O
  std::map<int, CollisionGeometryPtr> parts_touch;  // `parts` grown by options.touch_distance
  std::map<int, CollisionGeometryPtr> parts_planning;  // `parts` grown by options.part_margin (the plan's other parts)
  std::map<int, TriangleMesh> part_meshes;       // by class id, in O (contact ray casts)
  // m: the shortest hidden stretch behind a detected part that can hold a
  // part (options.hidden_behind_parts): the smallest side of the cell's
  // part meshes' boxes (in O). 0 when off.
  double hidden_min_stretch = 0.0;
  // By class id, in O: the surfaces that explain ROI points
  // (options.surface_explain_distance; empty when it is 0).
  std::map<int, internal::PartSurface> surfaces;
  CollisionGeometryPtr bin;                      // in W
  CollisionGeometryPtr bin_planning;             // `bin` grown by options.bin_margin (the plan's walls)
  std::map<std::string, Gripper> grippers;       // by name
  // (class id, gripper) -> expanded cell grasps
  std::map<std::pair<int, std::string>, std::vector<TaughtGrasp>> cell_grasps;

  // The contact region of grasp g (in its frame G), or null when its
  // gripper's seen-contact rule is off or the class / gripper is unknown.
  std::shared_ptr<const internal::ContactRegion> SampleContact(const TaughtGrasp& g) const {
    auto gripper = grippers.find(g.gripper);
    auto mesh = part_meshes.find(g.class_id);
    if (gripper == grippers.end() || mesh == part_meshes.end() ||
        gripper->second.spec->seen_contact.when == SeenContactRule::When::kOff) {
      return nullptr;
    }
    return std::make_shared<const internal::ContactRegion>(
        internal::SampleContactRegion(gripper->second.contact, mesh->second, g.X_OG));
  }

  std::vector<TaughtGrasp> Expand(const TaughtGrasp& g) const {
    const PartSpec* part = cell.FindPart(g.class_id);
    std::vector<Mat3> axis_rotations{Mat3::Identity()};
    if (part != nullptr && part->symmetry.kind != Symmetry::Kind::kNone) {
      const Vec3 axis = part->symmetry.axis.normalized();
      const int n = part->symmetry.kind == Symmetry::Kind::kRevolute
                        ? std::max(1, static_cast<int>(std::lround(360.0 / options.revolute_step_deg)))
                        : std::max(1, part->symmetry.order);
      axis_rotations.clear();
      for (int k = 0; k < n; ++k) axis_rotations.push_back(Eigen::AngleAxisd(2 * M_PI * k / n, axis).toRotationMatrix());
    }
    std::vector<Pose> extras{Pose::Identity()};
    if (part != nullptr) extras.insert(extras.end(), part->symmetry.extra.begin(), part->symmetry.extra.end());
    std::vector<TaughtGrasp> out;
    int index = 0;
    for (const Pose& E : extras) {
      for (const Mat3& R : axis_rotations) {
        TaughtGrasp e = g;
        Pose X_R = Pose::Identity();
        X_R.linear() = R;
        e.X_OG = E * X_R * g.X_OG;
        if (axis_rotations.size() * extras.size() > 1) e.name = g.name + "@" + std::to_string(index);
        ++index;
        out.push_back(std::move(e));
      }
    }
    return out;
  }
};

GraspPlanningModel::GraspPlanningModel(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
GraspPlanningModel::~GraspPlanningModel() = default;
const Cell& GraspPlanningModel::cell() const { return impl_->cell; }
const GraspPlanningOptions& GraspPlanningModel::options() const { return impl_->options; }

std::vector<TaughtGrasp> GraspPlanningModel::Expand(const TaughtGrasp& grasp) const { return impl_->Expand(grasp); }

const std::vector<TaughtGrasp>& GraspPlanningModel::CellGrasps(int class_id, const std::string& gripper) const {
  static const std::vector<TaughtGrasp> kNone;
  auto it = impl_->cell_grasps.find({class_id, gripper});
  return it == impl_->cell_grasps.end() ? kNone : it->second;
}

Result<std::shared_ptr<const GraspPlanningModel>> GraspPlanningModel::Build(const Cell& cell,
                                                                            const GraspPlanningOptions& options) {
  if (!(options.approach_step > 0) || !(options.revolute_step_deg > 0) || !(options.octree_resolution > 0) ||
      !(options.contact_margin >= 0) || !(options.touch_distance >= 0) || !(options.approach_margin >= 0) ||
      !(options.bin_margin >= 0) || !(options.part_margin >= 0) || !(options.dropout_reach >= 0) ||
      !(options.surface_explain_distance >= 0)) {
    return Status::InvalidArgument(
        "grasp planning options: steps and resolution must be > 0, margins and distances >= 0");
  }
  if (!(options.suction_compliance_deg >= 0) || !(options.suction_compliance_margin_deg >= 0)) {
    return Status::InvalidArgument("grasp planning options: suction compliance and its margin must be >= 0");
  }
  for (double az : options.suction_turn_azimuths_deg) {
    if (!std::isfinite(az)) return Status::InvalidArgument("grasp planning options: suction turn azimuths must be finite");
  }
  if (!(options.ambiguity_max_position > 0) || !(options.ambiguity_jaw_approach_deg >= 0)) {
    return Status::InvalidArgument(
        "grasp planning options: ambiguity_max_position must be > 0, ambiguity_jaw_approach_deg >= 0");
  }
  auto impl = std::make_unique<Impl>();
  impl->cell = cell;
  impl->options = options;
  if (options.surface_explain_distance > 0) {
    impl->options.surface_explain_distance =
        std::max(options.surface_explain_distance, internal::kSupportSigmas * FloorSigma(cell));
  }
  if (options.mixed_on_part_rays > 0) {
    impl->options.mixed_on_part_rays = std::max(options.mixed_on_part_rays, internal::kSupportSigmas * FloorSigma(cell));
  }
  const Cell& c = impl->cell;
  for (const PartSpec& part : c.parts) {
    Result<TriangleMesh> mesh = LoadMesh(part.mesh);
    if (!mesh.ok()) return mesh.status();
    auto geometry = CollisionGeometry::FromMesh(*mesh);
    if (!geometry.ok()) return Status::InvalidArgument("part '" + part.name + "': " + geometry.status().message());
    impl->parts[part.class_id] = *geometry;
    auto grown = CollisionGeometry::FromMesh(Inflated(*mesh, options.touch_distance));
    if (!grown.ok()) return Status::InvalidArgument("part '" + part.name + "': " + grown.status().message());
    impl->parts_touch[part.class_id] = *grown;
    impl->parts_planning[part.class_id] = *geometry;
    if (options.part_margin > 0) {
      auto kept = CollisionGeometry::FromMesh(Inflated(*mesh, options.part_margin));
      if (!kept.ok()) return Status::InvalidArgument("part '" + part.name + "': " + kept.status().message());
      impl->parts_planning[part.class_id] = *kept;
    }
    if (impl->options.surface_explain_distance > 0) {
      impl->surfaces[part.class_id] = internal::PartSurface::Sample(
          *mesh, kSurfaceSpacing, impl->options.surface_explain_distance + kSurfaceSpacing);
    }
    if (options.hidden_behind_parts) {
      const double side = (*geometry)->local_bounds().sizes().minCoeff();
      impl->hidden_min_stretch = impl->hidden_min_stretch > 0 ? std::min(impl->hidden_min_stretch, side) : side;
    }
    impl->part_meshes[part.class_id] = std::move(*mesh);
  }
  TriangleMesh bin_mesh;
  if (c.bin.mesh.empty()) {
    bin_mesh = MakeBinMesh(c.bin);
  } else {
    Result<TriangleMesh> loaded = LoadMesh(c.bin.mesh);
    if (!loaded.ok()) return loaded.status();
    bin_mesh = std::move(*loaded);
  }
  auto bin = CollisionGeometry::FromMesh(bin_mesh);
  if (!bin.ok()) return Status::InvalidArgument("bin: " + bin.status().message());
  impl->bin = *bin;
  impl->bin_planning = *bin;
  if (options.bin_margin > 0) {
    auto grown = CollisionGeometry::FromMesh(Inflated(bin_mesh, options.bin_margin));
    if (!grown.ok()) return Status::InvalidArgument("bin: " + grown.status().message());
    impl->bin_planning = *grown;
  }
  for (const GripperSpec& g : c.grippers) {
    Result<TriangleMesh> mesh = LoadMesh(g.mesh);
    if (!mesh.ok()) return mesh.status();
    const TriangleMesh sweep = SweepAlongApproach(*mesh, g.approach_distance, options.approach_step);
    auto geometry = CollisionGeometry::FromMesh(sweep);
    if (!geometry.ok()) return Status::InvalidArgument("gripper '" + g.name + "': " + geometry.status().message());
    Result<internal::ContactShape> contact = internal::MakeContactShape(g, *mesh);
    if (!contact.ok()) return contact.status();
    Impl::Gripper entry;
    entry.spec = c.FindGripper(g.name);
    entry.sweep = *geometry;
    auto grown = CollisionGeometry::FromMesh(Inflated(sweep, options.approach_margin));
    if (!grown.ok()) return Status::InvalidArgument("gripper '" + g.name + "': " + grown.status().message());
    entry.sweep_margin = *grown;
    entry.points_lift = g.kind == GripperSpec::Kind::kSuction ? options.contact_margin : 0.0;
    entry.slabs = SlabBoxes(sweep, 12);
    entry.contact = *contact;
    impl->grippers[g.name] = std::move(entry);
  }
  for (const PartSpec& part : c.parts) {
    for (const GraspSpec& g : part.grasps) {
      auto& list = impl->cell_grasps[{part.class_id, g.gripper}];
      TaughtGrasp base{part.class_id, g.name, g.gripper, g.X_OG, nullptr};
      base.contact = impl->SampleContact(base);  // shared by the symmetric copies
      for (TaughtGrasp& e : impl->Expand(base)) list.push_back(std::move(e));
    }
  }
  return std::shared_ptr<const GraspPlanningModel>(new GraspPlanningModel(std::move(impl)));
}

namespace {

// A dropout ray (GraspPlanningOptions::dropout_reach; also
// the rays of a hidden space, hidden_behind_parts): the pixel (u, v) of
// an organized frame without a measurement, and the stretch of its ray
// (depth, m along the camera's z) that may hold an unseen surface.
struct DropoutRay {
  int u = 0, v = 0;
  float near = 0.f, far = 0.f;
};

// The pixel boxes of the detected parts in an organized frame and the
// stride of the rays through them (HiddenPixelBoxes).
struct HiddenPixels {
  std::vector<Eigen::AlignedBox2i> box;
  int stride = 0;
};

struct FrameObstacles {
  PointObstaclePtr points;      // ROI points no detection explains
  internal::OccupancyGrid grid; // the same points, for the pre-filter
  // Per detection (by index; empty when surface_explain_distance is 0): the
  // ROI points its model surface explains and no support did, in voxels of
  // kSurfaceSpacing, and their box grown by a voxel. Its part as measured
  // where the view it was matched in did not fit it: no obstacle for the
  // other grasps (its mesh is, kPart), but checked like its mesh against
  // its own grasps' lifted sweep (kSelf), so a pose a fraction of a degree
  // off there does not let the tool into the part.
  struct PointPatch {
    std::vector<Eigen::Vector3f> points;  // B
    Eigen::AlignedBox3d bounds;           // of the points, grown by a voxel
    internal::OccupancyGrid grid;  // `points` in cells of kOwnGridCell, the check's pre-filter
    double res = kSurfaceSpacing;  // m, the OcTree's voxel edge
    double reach = 2 * kSurfaceSpacing;  // m, AnyNear's grow: a voxel the sweep meets has a point this near a slab
    // The OcTree of `points`, built by the first check that reaches it
    // (most detections' never are: their grasps fail earlier, or no sweep
    // comes near those points); the same tree whenever it is built.
    mutable std::once_flag built;
    mutable PointObstaclePtr tree;
  };
  std::vector<std::unique_ptr<PointPatch>> own;  // null: none
  // Per detection, the space it hides from the camera (hidden_behind_parts):
  // the rays through it (FindHiddenRays) every octree_resolution / 2 inside
  // the ROI, voxel centres of octree_resolution. An obstacle for the other
  // detections' grasps, checked like the points. Built on demand
  // (hidden_space_on_demand): a detection's rays are cast by the first check
  // whose sweep is near its space (Near), and grouped in tiles of
  // kHiddenTileRays x kHiddenTileRays rays; a tile's voxels are built by the
  // first check whose sweep is near them (its rays' pixels and depths).
  // The union of the tiles' voxels is the space's, whichever checks build
  // them, so a sweep meets the space exactly when it meets a tile near it.
  // hidden_space_on_demand false: each detection's space whole, built before
  // any candidate is checked.
  class HiddenSpaces {
   public:
    // `frame` outlives this; `parts` by detection (mesh null: none).
    HiddenSpaces(const GraspPlanningModel::Impl& m, const Frame& frame, const Pose& X_BW,
                 std::vector<internal::PlacedMesh> parts);
    size_t size() const { return parts_.size(); }
    // The parts of detection p's space near a sweep in slab boxes
    // `boxes_B` whose footprints (Footprint, grown by two voxels) are
    // `footprints`: its tiles near them, built on their first call (its
    // whole space when not on demand). A sweep that meets none of them
    // does not meet the space.
    std::vector<const PointPatch*> NearParts(size_t p, std::span<const Eigen::AlignedBox3d> boxes_B,
                                             std::span<const Eigen::AlignedBox3d> footprints) const;
    // Where the points within `grow` m of `box_T` (in T) at X_BT lie in the
    // view: a box over (u, v) pixel coordinates (real) and depth z in C
    // (m); everything when a corner of it lies less than 1 mm in front of
    // the camera.
    Eigen::AlignedBox3d Footprint(const Eigen::AlignedBox3d& box_T, const Pose& X_BT, double grow) const;
    // Whether a sweep in slab boxes `boxes_B` (their boxes in B) whose
    // footprints (Footprint, grown by two voxels) are `footprints` may meet
    // detection p's space: a slab box meets its bounds and its footprint
    // meets p's view box (its pixel box, from its nearest vertex's depth to
    // the floor's farthest there). A voxel the sweep meets holds a point of
    // a ray through p's pixel box in that depth within a voxel of the sweep
    // along B's axes, so within two of its slab along T's.
    bool Near(size_t p, std::span<const Eigen::AlignedBox3d> boxes_B,
              std::span<const Eigen::AlignedBox3d> footprints) const;
    // How many detections' rays were cast so far, how many have bounds,
    // and the tiles built so far and those with rays (on demand).
    int built() const { return built_count_.load(); }
    int with_bounds() const {
      return static_cast<int>(std::count_if(bounds_.begin(), bounds_.end(), [](const auto& b) { return !b.isEmpty(); }));
    }
    int tiles_built() const { return tiles_built_.load(); }
    int tiles() const { return tile_count_.load(); }

   private:
    // A detection's rays by tile (on demand).
    struct Tiles {
      std::vector<std::vector<DropoutRay>> rays;  // per tile
      std::vector<Eigen::AlignedBox3d> view;      // per tile: its rays' (u, v, z in C); empty: no ray
      std::unique_ptr<std::once_flag[]> built;
      mutable std::vector<std::unique_ptr<PointPatch>> patch;  // null: none
    };
    bool Near(size_t p, std::span<const Eigen::AlignedBox3d> boxes_B, std::span<const Eigen::AlignedBox3d> footprints,
              const Eigen::AlignedBox3d& view) const;
    const PointPatch* Space(size_t p) const;
    const Tiles& TilesOf(size_t p) const;
    std::unique_ptr<PointPatch> PatchOf(std::span<const DropoutRay> rays) const;
    const GraspPlanningModel::Impl& m_;
    const Frame& frame_;
    const Pose X_BW_;
    const std::vector<internal::PlacedMesh> parts_;
    const HiddenPixels pixels_;
    std::vector<Eigen::AlignedBox3d> bounds_;
    std::vector<Eigen::AlignedBox3d> view_;  // (u, v, z in C): HiddenBounds
    std::unique_ptr<std::once_flag[]> built_;
    mutable std::vector<std::unique_ptr<PointPatch>> spaces_;  // not on demand
    mutable std::vector<Tiles> tiles_;                          // on demand
    mutable std::atomic<int> built_count_{0}, tiles_built_{0}, tile_count_{0};
  };
  std::unique_ptr<const HiddenSpaces> hidden;  // null: off, or no organized frame
};

// Whether a tool at X_BT, planned as the grasp X_OG_nominal
// on `det` at det.X_BO, lands on the part at each of the detection's
// alternative poses too: tool centre within max_position of the grasp's
// contact point there and approach within max_approach of its approach,
// both modulo the part's symmetry (LandOnTruth, the strict grasp judge's
// rule): the jaws close where they were planned to, whichever pose is true.
bool LandsUnderEveryAlternative(const Detection& det, const Symmetry& symmetry, const Pose& X_BT,
                                const Pose& X_OG_nominal, double max_position, double max_approach) {
  const Vec3 p_O = det.X_BO.inverse() * X_BT.translation();
  const Vec3 a_O = X_OG_nominal.linear().col(2);
  for (const Pose& X_BO : det.alternatives_X_BO) {
    const PartTruth at{0, det.class_id, {}, X_BO, 0, 0, 0.0};
    const GraspLanding l = LandOnTruth(X_BT, p_O, a_O, det.class_id, symmetry, std::span<const PartTruth>(&at, 1));
    if (l.truth_instance < 0 || l.position_error > max_position || l.approach_error > max_approach + 1e-9) {
      return false;
    }
  }
  return true;
}

// Suction: whether a cup at X_BT seals on the part at each of the
// detection's alternative poses. A cup does not care where on the part it
// lands, only that it meets the surface squarely enough: the tool centre
// within max_distance of the part's surface placed at the alternative, and
// the approach (+z of T, into the part) within max_angle of the inward
// normal of that surface at its nearest point. A cup that would meet air
// beside the part, or a flank steeper than its compliance, does not seal.
bool SealsUnderEveryAlternative(const Detection& det, const CollisionGeometry& part, const Pose& X_BT,
                                double max_distance, double max_angle) {
  const Vec3 centre_B = X_BT.translation();
  const Vec3 approach_B = X_BT.linear().col(2);
  const double min_cos = std::cos(max_angle);
  for (const Pose& X_BO : det.alternatives_X_BO) {
    const SurfacePoint s = NearestSurfacePoint(part, X_BO, centre_B);
    if (s.distance > max_distance || approach_B.dot(-s.normal_W) < min_cos - 1e-12) return false;
  }
  return true;
}

double TiltRad(const Pose& X_BT) {
  // Straight down: the tool's +z (into the part) is -z of the base.
  return std::acos(std::clamp(-X_BT.linear().col(2).z(), -1.0, 1.0));
}

}  // namespace

std::optional<RejectReason> GraspPlanningModel::CheckAgainstParts(const std::string& gripper, const Pose& X_BT,
                                                                  std::span<const Detection> parts,
                                                                  int target, const Pose& X_BW,
                                                                  bool with_bin) const {
  const Impl& m = *impl_;
  auto g = m.grippers.find(gripper);
  if (g == m.grippers.end()) return RejectReason::kPart;
  const CollisionGeometry& sweep = *g->second.sweep;
  if (with_bin && Collides(sweep, X_BT, *m.bin, X_BW)) return RejectReason::kBin;
  const Pose X_BT_lift = X_BT * TranslateZ(-m.options.contact_margin);
  for (int i = 0; i < static_cast<int>(parts.size()); ++i) {
    auto p = m.parts.find(parts[i].class_id);
    if (p == m.parts.end()) continue;
    if (i == target) {
      if (Collides(sweep, X_BT_lift, *p->second, parts[i].X_BO)) return RejectReason::kSelf;
    } else if (Collides(sweep, X_BT, *p->second, parts[i].X_BO)) {
      return RejectReason::kPart;
    }
  }
  return std::nullopt;
}

std::optional<double> GraspPlanningModel::SurfaceDistance(int class_id, const Pose& X_BO, const Vec3& p_B) const {
  auto p = impl_->parts.find(class_id);
  if (p == impl_->parts.end()) return std::nullopt;
  return NearestSurfacePoint(*p->second, X_BO, p_B).distance;
}

namespace {

using Gripper = GraspPlanningModel::Impl::Gripper;

// Whether the seen-contact rule of `rule` applies to grasps on `d`.
bool NeedsSeenContact(const SeenContactRule& rule, const Detection& d) {
  switch (rule.when) {
    case SeenContactRule::When::kAlways: return true;
    case SeenContactRule::When::kIfAmbiguous: return d.pose_ambiguous();
    case SeenContactRule::When::kOff: return false;
  }
  return false;
}

// Stage 1: every cell and taught grasp of the task's gripper on every wanted
// detection, plus the suction compliance variants.
std::vector<GraspCandidate> MakeCandidates(const GraspPlanningModel& model, const Gripper& gripper,
                                           const TaskSpec& task, std::span<const Detection> detections,
                                           std::span<const TaughtGrasp> taught,
                                           const std::function<bool(int)>& wanted) {
  const GraspPlanningModel::Impl& m = model.impl();
  // Taught grasps of the task's gripper, their contact regions sampled once
  // per plan (cell grasps were sampled at Build), expanded per class.
  std::map<int, std::vector<TaughtGrasp>> taught_by_class;
  for (const TaughtGrasp& t : taught) {
    if (t.gripper != task.gripper || !wanted(t.class_id)) continue;
    TaughtGrasp base = t;
    if (!base.contact) base.contact = m.SampleContact(base);
    for (TaughtGrasp& e : model.Expand(base)) taught_by_class[t.class_id].push_back(std::move(e));
  }
  // How far a "~v" variant turns toward vertical at most: the cup's
  // compliance less the margin kept for the pose error.
  const double compliance =
      gripper.spec->kind == GripperSpec::Kind::kSuction
          ? std::max(0.0, m.options.suction_compliance_deg - m.options.suction_compliance_margin_deg) * M_PI / 180.0
          : 0.0;
  const double max_tilt = task.max_tilt_deg * M_PI / 180.0;
  std::vector<GraspCandidate> candidates;
  for (int d = 0; d < static_cast<int>(detections.size()); ++d) {
    const Detection& det = detections[d];
    if (!wanted(det.class_id)) continue;
    auto add = [&](const TaughtGrasp& g) {
      GraspCandidate c;
      c.detection = d;
      c.class_id = det.class_id;
      c.name = g.name;
      c.X_OG = g.X_OG;
      c.X_BT = det.X_BO * g.X_OG;
      c.X_BT_pre = c.X_BT * TranslateZ(-gripper.spec->approach_distance);
      c.tilt_rad = TiltRad(c.X_BT);
      c.X_BG = c.X_BT;
      c.contact = g.contact;
      const bool turn = compliance > 0 && c.tilt_rad > 1e-3;
      GraspCandidate turned;
      if (turn) {
        turned = c;
        const Vec3 z_T = c.X_BT.linear().col(2);
        Vec3 axis = z_T.cross(Vec3(0, 0, -1));
        if (axis.norm() < 1e-9) axis = c.X_BT.linear().col(0);  // upside down: any horizontal axis
        const double angle = std::min(c.tilt_rad, compliance);
        turned.X_BT.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix() * c.X_BT.linear();
        turned.X_BT_pre = turned.X_BT * TranslateZ(-gripper.spec->approach_distance);
        turned.X_OG = det.X_BO.inverse() * turned.X_BT;
        turned.tilt_rad = TiltRad(turned.X_BT);
        turned.name += "~v";
      }
      // Too steep for "~v" to reach vertical: the same turn in other
      // directions (suction_turn_azimuths_deg), about the same point. None
      // when "~v" is past the task's tilt limit: every other turn is too.
      std::vector<GraspCandidate> sideways;
      if (turn && c.tilt_rad > compliance && c.tilt_rad - compliance <= max_tilt) {
        const Vec3 z_T = c.X_BT.linear().col(2);
        Vec3 toward_vertical = z_T.cross(Vec3(0, 0, -1));
        if (toward_vertical.norm() < 1e-9) toward_vertical = c.X_BT.linear().col(0);  // upside down
        toward_vertical.normalize();
        for (double az : m.options.suction_turn_azimuths_deg) {
          const Vec3 axis = Eigen::AngleAxisd(az * M_PI / 180.0, z_T) * toward_vertical;
          GraspCandidate t = c;
          t.X_BT.linear() = Eigen::AngleAxisd(compliance, axis).toRotationMatrix() * c.X_BT.linear();
          t.X_BT_pre = t.X_BT * TranslateZ(-gripper.spec->approach_distance);
          t.X_OG = det.X_BO.inverse() * t.X_BT;
          t.tilt_rad = TiltRad(t.X_BT);
          t.name += fmt::format("~v{:+.0f}", az);
          sideways.push_back(std::move(t));
        }
      }
      candidates.push_back(std::move(c));
      if (turn) candidates.push_back(std::move(turned));
      for (GraspCandidate& t : sideways) candidates.push_back(std::move(t));
    };
    for (const TaughtGrasp& g : model.CellGrasps(det.class_id, task.gripper)) add(g);
    if (auto it = taught_by_class.find(det.class_id); it != taught_by_class.end()) {
      for (const TaughtGrasp& g : it->second) add(g);
    }
  }
  return candidates;
}

// The distinct voxels of `points` (B frame) in the OcTree's grid, edge
// `res`: voxel k holds the coordinates c with floor(c / res) == k, as
// octomap keys them (PointObstacle), so an OcTree built from the returned
// centres is the one built from the points. Deduplicated on a dense bitmap
// over the points' voxel bounds: O(points + voxels of those bounds), which
// the ROI bounds whatever the image size.
std::vector<Eigen::Vector3f> VoxelCentres(std::span<const Eigen::Vector3f> points, double res) {
  const double inv = 1.0 / res;  // octomap's resolution_factor
  auto key = [inv](float c) { return static_cast<int64_t>(std::floor(inv * static_cast<double>(c))); };
  Eigen::Array3<int64_t> lo = Eigen::Array3<int64_t>::Constant(std::numeric_limits<int64_t>::max());
  Eigen::Array3<int64_t> hi = Eigen::Array3<int64_t>::Constant(std::numeric_limits<int64_t>::min());
  for (const Eigen::Vector3f& p : points) {
    if (!p.allFinite()) continue;
    const Eigen::Array3<int64_t> k(key(p.x()), key(p.y()), key(p.z()));
    lo = lo.min(k);
    hi = hi.max(k);
  }
  std::vector<Eigen::Vector3f> centres;
  if ((lo > hi).any()) return centres;
  const Eigen::Array3<int64_t> dims = hi - lo + 1;
  auto centre = [res](int64_t k) { return static_cast<float>((static_cast<double>(k) + 0.5) * res); };
  // Points spread beyond any bin (a bad ROI): sort instead of a bitmap.
  constexpr int64_t kMaxCells = int64_t{1} << 27;
  if (dims.x() > kMaxCells / dims.y() / dims.z()) {
    std::vector<std::array<int64_t, 3>> keys;
    keys.reserve(points.size());
    for (const Eigen::Vector3f& p : points) {
      if (p.allFinite()) keys.push_back({key(p.x()), key(p.y()), key(p.z())});
    }
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    for (const auto& k : keys) centres.emplace_back(centre(k[0]), centre(k[1]), centre(k[2]));
    return centres;
  }
  std::vector<uint8_t> seen(static_cast<size_t>(dims.prod()), 0);
  for (const Eigen::Vector3f& p : points) {
    if (!p.allFinite()) continue;
    const Eigen::Array3<int64_t> k = Eigen::Array3<int64_t>(key(p.x()), key(p.y()), key(p.z())) - lo;
    uint8_t& bit = seen[static_cast<size_t>((k.z() * dims.y() + k.y()) * dims.x() + k.x())];
    if (bit) continue;
    bit = 1;
    centres.emplace_back(centre(k.x() + lo.x()), centre(k.y() + lo.y()), centre(k.z() + lo.z()));
  }
  return centres;
}

// The occluded columns (GraspPlanningOptions::occluded_columns): for every
// (x, y) column of voxels of edge `res` in the bin frame W (z up from the
// floor) holding a point of `rest` (B frame), one point per voxel below the
// highest such point, down to the floor, appended to `rest`. `dense`: the
// column tops on a 2D array over the points' columns (O(points + columns));
// else sorted (O(points log points), the reference).
void AppendOccludedColumns(const Pose& X_BW_d, double res_d, bool dense, std::vector<Eigen::Vector3f>& rest) {
  const float res = static_cast<float>(res_d);
  const Eigen::Affine3f X_WB = X_BW_d.inverse().cast<float>();
  const Eigen::Affine3f X_BW = X_BW_d.cast<float>();
  auto cell_of = [res](float v) { return static_cast<int64_t>(std::floor(v / res)); };
  auto fill = [&](int64_t cx, int64_t cy, int64_t top) {
    for (int64_t cz = top - 1; cz >= 0; --cz) {
      rest.push_back(X_BW * Eigen::Vector3f((cx + 0.5f) * res, (cy + 0.5f) * res, (cz + 0.5f) * res));
    }
  };
  std::vector<std::tuple<int64_t, int64_t, int64_t>> tops;
  tops.reserve(rest.size());
  int64_t x0 = std::numeric_limits<int64_t>::max(), x1 = std::numeric_limits<int64_t>::min();
  int64_t y0 = x0, y1 = x1;
  for (const Eigen::Vector3f& p : rest) {
    const Eigen::Vector3f w = X_WB * p;
    tops.emplace_back(cell_of(w.x()), cell_of(w.y()), cell_of(w.z()));
    x0 = std::min(x0, std::get<0>(tops.back()));
    x1 = std::max(x1, std::get<0>(tops.back()));
    y0 = std::min(y0, std::get<1>(tops.back()));
    y1 = std::max(y1, std::get<1>(tops.back()));
  }
  constexpr int64_t kMaxColumns = int64_t{1} << 24;
  if (dense && !tops.empty() && (x1 - x0 + 1) <= kMaxColumns / (y1 - y0 + 1)) {
    // Per (x, y) column the highest voxel.
    const int64_t nx = x1 - x0 + 1, ny = y1 - y0 + 1;
    std::vector<int64_t> top(static_cast<size_t>(nx * ny), std::numeric_limits<int64_t>::min());
    for (const auto& [cx, cy, cz] : tops) {
      int64_t& t = top[static_cast<size_t>((cy - y0) * nx + (cx - x0))];
      t = std::max(t, cz);
    }
    for (int64_t cy = y0; cy <= y1; ++cy) {
      for (int64_t cx = x0; cx <= x1; ++cx) {
        const int64_t t = top[static_cast<size_t>((cy - y0) * nx + (cx - x0))];
        if (t != std::numeric_limits<int64_t>::min()) fill(cx, cy, t);
      }
    }
    return;
  }
  std::sort(tops.begin(), tops.end(), std::greater<>());
  for (size_t k = 0; k < tops.size();) {
    const auto [cx, cy, top] = tops[k];
    while (k < tops.size() && std::get<0>(tops[k]) == cx && std::get<1>(tops[k]) == cy) ++k;
    fill(cx, cy, top);
  }
}

// The dropout rays of `frame` beside the measured points no detection
// explains (`rest`, B): every pixel without a measurement within `reach` (m
// across the view on the bin floor: a window of (2r + 1)^2 pixels) of such a
// point's pixel, from the nearest unexplained depth in that window to the
// farthest depth measured there. `window`: the pixels within r of an
// unexplained point's pixel (clipped to the image), the rays' pixels flagged
// in window->wanted. O(rest + window pixels + rays * r^2).
std::vector<DropoutRay> FindDropoutRays(const Frame& frame, const Pose& X_BW, double reach,
                                        std::span<const Eigen::Vector3f> rest, internal::PixelWindow* window,
                                        std::vector<uint8_t>* wanted) {
  std::vector<DropoutRay> rays;
  const int w = frame.depth.width, h = frame.depth.height;
  const double z_floor = std::abs((frame.X_BC.inverse() * X_BW.translation()).z());
  if (w == 0 || h == 0 || !(z_floor > 0) || rest.empty()) return rays;
  const int r = std::clamp(static_cast<int>(std::ceil(reach * frame.intrinsics.fx / z_floor)), 1, 32);
  const auto measured = [&frame](int u, int v) {
    const float z = frame.depth.at(u, v);
    return std::isfinite(z) && z > 0.f;
  };
  // The unexplained points' pixels (their depth along the camera's z) and
  // the box of pixels within r of one.
  const Eigen::Isometry3f X_CB = frame.X_BC.inverse().cast<float>();
  const Intrinsics& K = frame.intrinsics;
  std::vector<std::tuple<int, int, float>> pixels;
  pixels.reserve(rest.size());
  int u0 = w, u1 = -1, v0 = h, v1 = -1;
  for (const Eigen::Vector3f& p : rest) {
    const Eigen::Vector3f c = X_CB * p;
    int u = 0, v = 0;
    if (!internal::PixelOf(K, frame.depth, c, &u, &v)) continue;
    pixels.emplace_back(u, v, c.z());
    u0 = std::min(u0, u - r);
    u1 = std::max(u1, u + r);
    v0 = std::min(v0, v - r);
    v1 = std::max(v1, v + r);
  }
  if (pixels.empty()) return rays;
  u0 = std::max(u0, 0), v0 = std::max(v0, 0), u1 = std::min(u1, w - 1), v1 = std::min(v1, h - 1);
  const int bw = u1 - u0 + 1, bh = v1 - v0 + 1;
  // The nearest unexplained depth per pixel of the box, and the count of
  // those pixels summed over rows and columns: an unmeasured pixel with none
  // within r is skipped in O(1) (most of them).
  constexpr float kNone = std::numeric_limits<float>::infinity();
  std::vector<float> unexplained(static_cast<size_t>(bw) * bh, kNone);
  for (const auto& [pu, pv, pz] : pixels) {
    float& z = unexplained[static_cast<size_t>(pv - v0) * bw + (pu - u0)];
    z = std::min(z, pz);
  }
  std::vector<int32_t> sum(static_cast<size_t>(bw + 1) * (bh + 1), 0);
  const auto at = [&sum, bw](int x, int y) -> int32_t& { return sum[static_cast<size_t>(y) * (bw + 1) + x]; };
  for (int v = 0; v < bh; ++v) {
    for (int u = 0; u < bw; ++u) {
      at(u + 1, v + 1) = (unexplained[static_cast<size_t>(v) * bw + u] < kNone ? 1 : 0) + at(u + 1, v) + at(u, v + 1) -
                         at(u, v);
    }
  }
  // The window's extremes row by row (separable): per pixel of a ray's
  // column, the nearest unexplained depth over its row's 2r + 1 pixels (in
  // the box, where they are) and the farthest measured one (in the image,
  // rows up to r above and below the box), each computed once, when a ray
  // first needs it (rays lie in blobs: about one row per ray, not 2r + 1).
  constexpr float kUnset = -1.f;  // depths are > 0, none is +inf / 0
  const int fv0 = std::max(0, v0 - r), fv1 = std::min(h - 1, v1 + r);
  std::vector<float> row_near(static_cast<size_t>(bw) * bh, kUnset);
  std::vector<float> row_far(static_cast<size_t>(bw) * (fv1 - fv0 + 1), kUnset);
  const auto near_in_row = [&](int u, int y) {  // y: image row in the box
    float& n = row_near[static_cast<size_t>(y - v0) * bw + (u - u0)];
    if (n == kUnset) {
      n = kNone;
      const float* line = &unexplained[static_cast<size_t>(y - v0) * bw];
      for (int x = std::max(u - r, u0); x <= std::min(u + r, u1); ++x) n = std::min(n, line[x - u0]);
    }
    return n;
  };
  const auto far_in_row = [&](int u, int y) {  // y: image row within r of the box
    float& f = row_far[static_cast<size_t>(y - fv0) * bw + (u - u0)];
    if (f == kUnset) {
      f = 0.f;
      for (int x = std::max(0, u - r); x <= std::min(w - 1, u + r); ++x) {
        if (measured(x, y)) f = std::max(f, frame.depth.at(x, y));
      }
    }
    return f;
  };
  wanted->assign(static_cast<size_t>(bw) * bh, 0);
  for (int v = v0; v <= v1; ++v) {
    for (int u = u0; u <= u1; ++u) {
      if (measured(u, v)) continue;
      const int a = std::max(u - r, u0) - u0, b = std::min(u + r, u1) - u0 + 1;
      const int c = std::max(v - r, v0) - v0, d = std::min(v + r, v1) - v0 + 1;
      if (at(b, d) - at(a, d) - at(b, c) + at(a, c) == 0) continue;
      float near = kNone, far = 0.f;
      for (int y = c + v0; y < d + v0; ++y) near = std::min(near, near_in_row(u, y));
      for (int y = std::max(0, v - r); y <= std::min(h - 1, v + r); ++y) far = std::max(far, far_in_row(u, y));
      rays.push_back({u, v, near, std::max(far, near)});
      (*wanted)[static_cast<size_t>(v - v0) * bw + (u - u0)] = 1;
    }
  }
  *window = internal::PixelWindow{u0, v0, bw, bh, *wanted};
  return rays;
}

// Ends each ray where it meets the surface of a detected part (`parts`, B;
// internal::NearestSurfaceDepth over the rays' pixels): the space behind it,
// seen from the camera, is that part, an obstacle of its own. A ray whose
// stretch starts behind such a surface is dropped.
void EndRaysAtParts(const Frame& frame, std::span<const internal::PlacedMesh> parts,
                    const internal::PixelWindow& window, std::vector<DropoutRay>& rays) {
  if (rays.empty() || parts.empty()) return;
  const std::vector<float> surface = internal::NearestSurfaceDepth(frame.intrinsics, frame.X_BC, parts, window);
  size_t kept = 0;
  for (const DropoutRay& ray : rays) {
    const float s = surface[static_cast<size_t>(ray.v - window.v0) * window.width + (ray.u - window.u0)];
    if (s < ray.near) continue;
    rays[kept] = ray;
    rays[kept].far = std::min(ray.far, s);
    ++kept;
  }
  rays.resize(kept);
}

// The unseen space along `rays` (FindDropoutRays) as points in B every
// `step` m from each ray's near to its far depth, kept inside the ROI
// (GraspPlanningOptions::dropout_reach has why). `columns` > 0: the occluded
// columns of that edge (m, in W) will fill the space below each point, and
// a ray's point is kept only where it enters another column. `voxel` > 0
// (m, and no columns): a ray's point is kept only where it enters another
// voxel of that edge in B (keyed as VoxelCentres keys them), so the points'
// voxels are those of every point, with fewer points.
std::vector<Eigen::Vector3f> DropoutPoints(const Frame& frame, const Cell& cell, const Pose& X_BW,
                                           std::span<const DropoutRay> rays, double step, float columns,
                                           double voxel = 0.0) {
  std::vector<Eigen::Vector3f> out;
  if (!(step > 0)) return out;
  const Intrinsics& K = frame.intrinsics;
  const Eigen::Isometry3f X_BC = frame.X_BC.cast<float>();
  const Eigen::Isometry3f X_WB = X_BW.inverse().cast<float>();
  const Eigen::Vector3f half(static_cast<float>(cell.bin.inner_size.x() / 2 - cell.roi.wall_margin),
                             static_cast<float>(cell.bin.inner_size.y() / 2 - cell.roi.wall_margin), 0.f);
  const auto in_roi = [&](const Eigen::Vector3f& p_B) {
    const Eigen::Vector3f p_W = X_WB * p_B;
    return std::abs(p_W.x()) <= half.x() && std::abs(p_W.y()) <= half.y() && p_W.z() >= cell.roi.floor_margin &&
           p_W.z() <= cell.roi.height;
  };
  const double inv = voxel > 0 ? 1.0 / voxel : 0.0;
  const auto key = [inv](float c) { return static_cast<int64_t>(std::floor(inv * static_cast<double>(c))); };
  for (const DropoutRay& r : rays) {
    const Eigen::Vector3f ray = Deproject(K, static_cast<float>(r.u), static_cast<float>(r.v), 1.f);
    Eigen::Array2i last(std::numeric_limits<int>::min(), 0);
    Eigen::Array3<int64_t> last_voxel = Eigen::Array3<int64_t>::Constant(std::numeric_limits<int64_t>::min());
    for (float z = r.near;; z += static_cast<float>(step)) {
      const Eigen::Vector3f p_B = X_BC * (ray * std::min(z, r.far));
      // With the columns, a point below another of the ray in its column adds nothing.
      const Eigen::Array2i column =
          columns > 0 ? ((X_WB * p_B).head<2>().array() / columns).floor().cast<int>().eval() : last + 1;
      // With the voxels, a point in the voxel of the ray's last kept point adds nothing.
      const Eigen::Array3<int64_t> k = voxel > 0 && p_B.allFinite()
                                           ? Eigen::Array3<int64_t>(key(p_B.x()), key(p_B.y()), key(p_B.z()))
                                           : last_voxel + 1;
      if (in_roi(p_B) && (column != last).any() && (k != last_voxel).any()) {
        out.push_back(p_B);
        last = column;
        last_voxel = k;
      }
      if (z >= r.far) break;
    }
  }
  return out;
}

// Whether the depth z (m) measured at pixel (u, v) is on no surface its
// neighbours see: more than `margin` from the depth of each measured
// 8-neighbour, and from the mean of each opposite pair of them (a surface
// seen steeply, its depth changing by more than `margin` a pixel, passes
// through such a mean).
bool OnNoNeighboursSurface(const DepthImage& depth, int u, int v, float z, float margin) {
  const auto at = [&](int x, int y) {
    return x < 0 || y < 0 || x >= depth.width || y >= depth.height ? std::numeric_limits<float>::quiet_NaN()
                                                                     : depth.at(x, y);
  };
  constexpr int kDu[] = {1, 0, 1, 1}, kDv[] = {0, 1, 1, -1};
  for (int k = 0; k < 4; ++k) {
    const float a = at(u + kDu[k], v + kDv[k]), b = at(u - kDu[k], v - kDv[k]);
    if (std::abs(a - z) <= margin || std::abs(b - z) <= margin || std::abs((a + b) / 2 - z) <= margin) return false;
  }
  return true;
}

// Removes from `rest` (the measured points no detection explains, B) the
// mixed pixels on a detected part's rays (GraspPlanningOptions::
// mixed_on_part_rays): a point of an organized frame whose pixel's ray
// meets a surface of `parts` (B) more than `margin` (m, along the camera's
// z) nearer or farther than the point, on no surface its neighbours see
// (OnNoNeighboursSurface). O(rest + the window of their pixels + the
// parts' triangles).
void DropMixedOnPartRays(const Frame& frame, std::span<const internal::PlacedMesh> parts, float margin,
                         std::vector<Eigen::Vector3f>& rest) {
  if (rest.empty() || parts.empty()) return;
  const int w = frame.depth.width, h = frame.depth.height;
  const Eigen::Isometry3f X_CB = frame.X_BC.inverse().cast<float>();
  std::vector<std::tuple<int, int, float>> pixels(rest.size(), {-1, -1, 0.f});
  int u0 = w, u1 = -1, v0 = h, v1 = -1;
  for (size_t i = 0; i < rest.size(); ++i) {
    const Eigen::Vector3f c = X_CB * rest[i];
    int u = 0, v = 0;
    if (!internal::PixelOf(frame.intrinsics, frame.depth, c, &u, &v)) continue;
    pixels[i] = {u, v, c.z()};
    u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
  }
  if (u1 < u0) return;
  const int bw = u1 - u0 + 1, bh = v1 - v0 + 1;
  std::vector<uint8_t> wanted(static_cast<size_t>(bw) * bh, 0);
  for (const auto& [u, v, z] : pixels) {
    if (u >= 0) wanted[static_cast<size_t>(v - v0) * bw + (u - u0)] = 1;
  }
  const std::vector<float> surface =
      internal::NearestSurfaceDepth(frame.intrinsics, frame.X_BC, parts, internal::PixelWindow{u0, v0, bw, bh, wanted});
  size_t kept = 0;
  for (size_t i = 0; i < rest.size(); ++i) {
    const auto [u, v, z] = pixels[i];
    bool mixed = false;
    if (u >= 0) {
      const float s = surface[static_cast<size_t>(v - v0) * bw + (u - u0)];
      // s is +inf where the ray meets no part.
      mixed = std::isfinite(s) && std::abs(z - s) > margin && OnNoNeighboursSurface(frame.depth, u, v, z, margin);
    }
    if (!mixed) rest[kept++] = rest[i];
  }
  rest.resize(kept);
}

// The pixel boxes of `parts` (B, by detection) in an organized frame: the
// box of each part's vertices projected, clipped to the image (empty for a
// null mesh or a vertex behind the camera), and the pixel stride of rays
// `step` m apart across the view on the bin floor (W's z = 0, X_BW; 0:
// the camera is not above the floor).
HiddenPixels HiddenPixelBoxes(const Frame& frame, std::span<const internal::PlacedMesh> parts, const Pose& X_BW,
                              double step) {
  HiddenPixels out;
  out.box.resize(parts.size());
  const int w = frame.depth.width, h = frame.depth.height;
  const Intrinsics& K = frame.intrinsics;
  const Pose X_CB = frame.X_BC.inverse();
  const double z_floor = std::abs((X_CB * X_BW.translation()).z());
  if (w == 0 || h == 0 || !(z_floor > 0)) return out;
  out.stride = std::max(1, static_cast<int>(step * K.fx / z_floor));
  for (size_t p = 0; p < parts.size(); ++p) {
    if (parts[p].mesh_O == nullptr) continue;
    const Pose X_CO = X_CB * parts[p].X_BO;
    Eigen::AlignedBox2d px;
    bool behind = false;
    for (const Eigen::Vector3f& v : parts[p].mesh_O->vertices) {
      const Vec3 c = X_CO * v.cast<double>();
      behind = behind || !(c.z() > 1e-3);
      px.extend(Eigen::Vector2d(K.fx * c.x() / c.z() + K.cx, K.fy * c.y() / c.z() + K.cy));
    }
    if (behind || px.isEmpty()) continue;
    const Eigen::Vector2i lo(std::max(0, static_cast<int>(std::floor(px.min().x()))),
                             std::max(0, static_cast<int>(std::floor(px.min().y()))));
    const Eigen::Vector2i hi(std::min(w - 1, static_cast<int>(std::ceil(px.max().x()))),
                             std::min(h - 1, static_cast<int>(std::ceil(px.max().y()))));
    if ((lo.array() <= hi.array()).all()) out.box[p] = Eigen::AlignedBox2i(lo, hi);
  }
  return out;
}

// The space part p of `parts` (B, by detection) hides from the camera of an
// organized frame (GraspPlanningOptions::hidden_behind_parts), as rays: on
// the pixels of its box (HiddenPixelBoxes) every `pixels.stride`, those
// whose ray meets the part, from the depth where it leaves the part to the
// bin floor (W's z = 0, X_BW) or the nearest surface of another part
// beyond that, kept where that stretch is at least `min_stretch` m long
// along the ray and the pixel measured no depth more than `seen` m beyond
// the part's far side (the camera saw through it there). O(its pixel box /
// stride^2 + the triangles of the part and of the parts whose boxes meet
// its box).
std::vector<DropoutRay> FindHiddenRays(const Frame& frame, std::span<const internal::PlacedMesh> parts,
                                       const HiddenPixels& pixels, size_t p, const Pose& X_BW, double min_stretch,
                                       float seen) {
  std::vector<DropoutRay> rays;
  const std::vector<Eigen::AlignedBox2i>& box = pixels.box;
  const int stride = pixels.stride;
  if (stride <= 0 || box[p].isEmpty()) return rays;
  const Intrinsics& K = frame.intrinsics;
  const Pose X_WC = X_BW.inverse() * frame.X_BC;
  const int u0 = box[p].min().x(), v0 = box[p].min().y();
  const int bw = box[p].sizes().x() + 1, bh = box[p].sizes().y() + 1;
  std::vector<uint8_t> wanted(static_cast<size_t>(bw) * bh, 0);
  for (int v = v0 + (stride - v0 % stride) % stride; v < v0 + bh; v += stride) {
    for (int u = u0 + (stride - u0 % stride) % stride; u < u0 + bw; u += stride) {
      wanted[static_cast<size_t>(v - v0) * bw + (u - u0)] = 1;
    }
  }
  const internal::PixelWindow window{u0, v0, bw, bh, wanted};
  const std::vector<float> far = internal::FarthestSurfaceDepth(K, frame.X_BC, parts.subspan(p, 1), window);
  std::vector<internal::PlacedMesh> others;
  for (size_t q = 0; q < parts.size(); ++q) {
    if (q != p && !box[q].isEmpty() && box[q].intersects(box[p])) others.push_back(parts[q]);
  }
  const std::vector<float> other = internal::NearestSurfaceDepth(K, frame.X_BC, others, window);
  for (int v = v0; v < v0 + bh; ++v) {
    for (int u = u0; u < u0 + bw; ++u) {
      const size_t i = static_cast<size_t>(v - v0) * bw + (u - u0);
      const float start = far[i];
      if (!wanted[i] || !(start > 0)) continue;
      const float z = frame.depth.at(u, v);
      if (std::isfinite(z) && z > start + seen) continue;
      const Vec3 ray_C((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      const double down = (X_WC.linear() * ray_C).z();
      if (!(down < 0)) continue;
      float end = static_cast<float>(-X_WC.translation().z() / down);
      if (other[i] > start) end = std::min(end, other[i]);
      if ((end - start) * ray_C.norm() < min_stretch) continue;
      rays.push_back({u, v, start, end});
    }
  }
  return rays;
}

// A box (B) holding every point of the space part p hides (FindHiddenRays
// on `pixels`, the points inside the ROI, voxelised in `res`) grown by a
// voxel as PointPatch::bounds is: the rays through its pixel box between
// the nearest depth of its vertices and the farthest depth of the bin floor
// over that box (the floor's depth along a ray is c / -down, down linear
// over the box, so extreme at a corner), within the ROI's box; each grown
// by two voxels (a voxel centre lies within half a voxel of its points).
// Empty when the part hides nothing. `view`: the same rays' stretch over
// (u, v) pixel coordinates and depth z in C (m), not grown.
Eigen::AlignedBox3d HiddenBounds(const Frame& frame, const Cell& cell, const Pose& X_BW,
                                 const internal::PlacedMesh& part, const HiddenPixels& pixels, size_t p, double res,
                                 Eigen::AlignedBox3d* view) {
  Eigen::AlignedBox3d bounds;
  if (pixels.stride <= 0 || pixels.box[p].isEmpty()) return bounds;
  const Intrinsics& K = frame.intrinsics;
  const Pose X_CO = frame.X_BC.inverse() * part.X_BO;
  double z_near = std::numeric_limits<double>::infinity();
  for (const Eigen::Vector3f& v : part.mesh_O->vertices) z_near = std::min(z_near, (X_CO * v.cast<double>()).z());
  // The ROI in W (DropoutPoints' in_roi), its corners' box in B.
  const Vec3 half(cell.bin.inner_size.x() / 2 - cell.roi.wall_margin, cell.bin.inner_size.y() / 2 - cell.roi.wall_margin,
                  0.0);
  Eigen::AlignedBox3d roi;
  const Eigen::AlignedBox3d roi_W(Vec3(-half.x(), -half.y(), cell.roi.floor_margin),
                                  Vec3(half.x(), half.y(), cell.roi.height));
  for (int i = 0; i < 8; ++i) roi.extend(X_BW * roi_W.corner(static_cast<Eigen::AlignedBox3d::CornerType>(i)));
  const Pose X_WC = X_BW.inverse() * frame.X_BC;
  std::array<Vec3, 4> rays;
  double z_far = 0.0;
  bool floor_below = true;  // every corner's ray meets the floor
  for (int k = 0; k < 4; ++k) {
    const Eigen::Vector2i px = pixels.box[p].corner(static_cast<Eigen::AlignedBox2i::CornerType>(k));
    rays[k] = Vec3((px.x() - K.cx) / K.fx, (px.y() - K.cy) / K.fy, 1.0);
    const double down = (X_WC.linear() * rays[k]).z();
    floor_below = floor_below && down < 0;
    if (down < 0) z_far = std::max(z_far, -X_WC.translation().z() / down);
  }
  const Eigen::Vector2d lo = pixels.box[p].min().cast<double>(), hi = pixels.box[p].max().cast<double>();
  *view = Eigen::AlignedBox3d(Vec3(lo.x(), lo.y(), z_near),
                              Vec3(hi.x(), hi.y(), floor_below ? z_far : std::numeric_limits<double>::infinity()));
  if (floor_below && z_far > z_near) {
    for (const Vec3& ray : rays) {
      bounds.extend(frame.X_BC * (ray * z_near));
      bounds.extend(frame.X_BC * (ray * z_far));
    }
    bounds = bounds.intersection(roi);
  } else if (floor_below) {
    return Eigen::AlignedBox3d();  // the part lies below the floor: no ray's stretch is positive
  } else {
    bounds = roi;
  }
  if (bounds.isEmpty()) return bounds;
  bounds.min().array() -= 2 * res;
  bounds.max().array() += 2 * res;
  return bounds;
}

FrameObstacles::HiddenSpaces::HiddenSpaces(const GraspPlanningModel::Impl& m, const Frame& frame, const Pose& X_BW,
                                           std::vector<internal::PlacedMesh> parts)
    : m_(m), frame_(frame), X_BW_(X_BW), parts_(std::move(parts)),
      pixels_(HiddenPixelBoxes(frame, parts_, X_BW, m.options.octree_resolution / 2)),
      bounds_(parts_.size()), view_(parts_.size()), built_(std::make_unique<std::once_flag[]>(parts_.size())), spaces_(parts_.size()),
      tiles_(parts_.size()) {
  for (size_t p = 0; p < parts_.size(); ++p) {
    if (parts_[p].mesh_O != nullptr) {
      bounds_[p] = HiddenBounds(frame, m.cell, X_BW, parts_[p], pixels_, p, m.options.octree_resolution, &view_[p]);
    }
  }
  if (!m.options.hidden_space_on_demand) {
    for (size_t p = 0; p < parts_.size(); ++p) {
      if (!bounds_[p].isEmpty()) Space(p);
    }
  }
}

const FrameObstacles::PointPatch* FrameObstacles::HiddenSpaces::Space(size_t p) const {
  std::call_once(built_[p], [this, p] {
    spaces_[p] = PatchOf(FindHiddenRays(frame_, parts_, pixels_, p, X_BW_, m_.hidden_min_stretch,
                                        static_cast<float>(m_.options.mixed_on_part_rays)));
    ++built_count_;
  });
  return spaces_[p].get();
}

const FrameObstacles::HiddenSpaces::Tiles& FrameObstacles::HiddenSpaces::TilesOf(size_t p) const {
  std::call_once(built_[p], [this, p] {
    Tiles& t = tiles_[p];
    const std::vector<DropoutRay> rays = FindHiddenRays(frame_, parts_, pixels_, p, X_BW_, m_.hidden_min_stretch,
                                                        static_cast<float>(m_.options.mixed_on_part_rays));
    const Eigen::AlignedBox2i& box = pixels_.box[p];
    const int edge = kHiddenTileRays * pixels_.stride;
    const int nx = box.sizes().x() / edge + 1, ny = box.sizes().y() / edge + 1;
    t.rays.resize(static_cast<size_t>(nx) * ny);
    t.view.resize(t.rays.size());
    for (const DropoutRay& r : rays) {
      const size_t k = static_cast<size_t>((r.v - box.min().y()) / edge) * nx + (r.u - box.min().x()) / edge;
      t.rays[k].push_back(r);
      t.view[k].extend(Vec3(r.u, r.v, r.near));
      t.view[k].extend(Vec3(r.u, r.v, r.far));
    }
    t.built = std::make_unique<std::once_flag[]>(t.rays.size());
    t.patch.resize(t.rays.size());
    tile_count_ += static_cast<int>(std::count_if(t.rays.begin(), t.rays.end(), [](const auto& r) { return !r.empty(); }));
    ++built_count_;
  });
  return tiles_[p];
}

std::vector<const FrameObstacles::PointPatch*> FrameObstacles::HiddenSpaces::NearParts(
    size_t p, std::span<const Eigen::AlignedBox3d> boxes_B, std::span<const Eigen::AlignedBox3d> footprints) const {
  std::vector<const PointPatch*> near;
  if (bounds_[p].isEmpty() || !Near(p, boxes_B, footprints, view_[p])) return near;
  if (!m_.options.hidden_space_on_demand) {
    if (const PointPatch* space = Space(p); space != nullptr) near.push_back(space);
    return near;
  }
  const Tiles& t = TilesOf(p);
  for (size_t k = 0; k < t.rays.size(); ++k) {
    if (t.view[k].isEmpty() || !Near(p, boxes_B, footprints, t.view[k])) continue;
    std::call_once(t.built[k], [this, &t, k] {
      t.patch[k] = PatchOf(t.rays[k]);
      ++tiles_built_;
    });
    if (t.patch[k]) near.push_back(t.patch[k].get());
  }
  return near;
}

Eigen::AlignedBox3d FrameObstacles::HiddenSpaces::Footprint(const Eigen::AlignedBox3d& box_T, const Pose& X_BT,
                                                             double grow) const {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  const Intrinsics& K = frame_.intrinsics;
  const Pose X_CT = frame_.X_BC.inverse() * X_BT;
  Eigen::AlignedBox3d grown = box_T;
  grown.min().array() -= grow;
  grown.max().array() += grow;
  Eigen::AlignedBox3d view;
  for (int i = 0; i < 8; ++i) {
    const Vec3 c = X_CT * grown.corner(static_cast<Eigen::AlignedBox3d::CornerType>(i));
    if (!(c.z() > 1e-3)) return Eigen::AlignedBox3d(Vec3::Constant(-kInf), Vec3::Constant(kInf));
    view.extend(Vec3(K.fx * c.x() / c.z() + K.cx, K.fy * c.y() / c.z() + K.cy, c.z()));
  }
  return view;
}

// A slab box meets p's bounds and its footprint meets `view` (p's, or a
// tile's: the (u, v, z in C) of rays of p).
bool FrameObstacles::HiddenSpaces::Near(size_t p, std::span<const Eigen::AlignedBox3d> boxes_B,
                                        std::span<const Eigen::AlignedBox3d> footprints,
                                        const Eigen::AlignedBox3d& view) const {
  for (size_t i = 0; i < boxes_B.size(); ++i) {
    if (boxes_B[i].intersects(bounds_[p]) && footprints[i].intersects(view)) return true;
  }
  return false;
}

// The points of `rays` inside the ROI every octree_resolution / 2,
// voxelised (null: none).
std::unique_ptr<FrameObstacles::PointPatch> FrameObstacles::HiddenSpaces::PatchOf(
    std::span<const DropoutRay> rays) const {
  const double res = m_.options.octree_resolution;
  if (rays.empty()) return nullptr;
  std::vector<Eigen::Vector3f> points = VoxelCentres(
      DropoutPoints(frame_, m_.cell, X_BW_, rays, res / 2, 0.f, m_.options.hidden_space_on_demand ? res : 0.0), res);
  if (points.empty()) return nullptr;
  auto patch = std::make_unique<PointPatch>();
  for (const Eigen::Vector3f& q : points) patch->bounds.extend(q.cast<double>());
  patch->bounds.min().array() -= res;
  patch->bounds.max().array() += res;
  patch->grid = internal::OccupancyGrid(points, kOwnGridCell);
  patch->res = res;
  patch->reach = res;  // voxel centres: a voxel lies within sqrt(3) / 2 of an edge of its centre
  patch->points = std::move(points);
  return patch;
}

// Stage 2: the points no detection explains (and the occluded columns
// under them) as an OcTree and an occupancy grid (the other parts' meshes,
// grown by part_margin, are the model's: CandidateFilter places them).
FrameObstacles BuildObstacles(const GraspPlanningModel::Impl& m, const PerceptionResult& perception,
                              const Frame* frame) {
  const auto& detections = perception.detections;
  FrameObstacles obstacles;
  std::vector<uint8_t> explained(perception.roi_points_B.size(), 0);
  for (const Detection& det : detections) {
    for (int32_t i : det.support) {
      if (i >= 0 && static_cast<size_t>(i) < explained.size()) explained[i] = 1;
    }
  }
  if (m.options.support_grid_spacing > 0) {
    internal::ExplainSupportCells(perception.roi_points_B, 2.0 * m.options.support_grid_spacing, explained);
  }
  if (m.options.surface_explain_distance > 0) {
    std::vector<internal::PlacedSurface> surfaces;
    std::vector<size_t> surface_of;  // detection index of surfaces[k]
    for (size_t d = 0; d < detections.size(); ++d) {
      if (auto s = m.surfaces.find(detections[d].class_id); s != m.surfaces.end()) {
        surfaces.push_back({&s->second, detections[d].X_BO});
        surface_of.push_back(d);
      }
    }
    std::optional<Eigen::Vector3f> eye_B;
    if (frame != nullptr) {
      eye_B = frame->X_BC.translation().cast<float>();
    } else if (!m.cell.camera.eye_in_hand) {
      eye_B = m.cell.camera.X_BC.translation().cast<float>();
    }
    std::vector<std::vector<uint32_t>> owned;
    internal::ExplainBySurfaces(perception.roi_points_B, surfaces,
                                static_cast<float>(m.options.surface_explain_distance + kSurfaceSpacing), eye_B,
                                kFacingMinCos, explained, &owned);
    obstacles.own.resize(detections.size());
    for (size_t k = 0; k < owned.size(); ++k) {
      if (owned[k].empty()) continue;
      auto own = std::make_unique<FrameObstacles::PointPatch>();
      own->points.reserve(owned[k].size());
      for (uint32_t i : owned[k]) {
        own->points.push_back(perception.roi_points_B[i]);
        own->bounds.extend(own->points.back().cast<double>());
      }
      own->bounds.min().array() -= kSurfaceSpacing;
      own->bounds.max().array() += kSurfaceSpacing;
      own->grid = internal::OccupancyGrid(own->points, kOwnGridCell);
      obstacles.own[surface_of[k]] = std::move(own);
    }
  }
  std::vector<Eigen::Vector3f> rest;
  rest.reserve(perception.roi_points_B.size());
  for (size_t i = 0; i < explained.size(); ++i) {
    if (!explained[i]) rest.push_back(perception.roi_points_B[i]);
  }
  // The detected parts' meshes at their poses, for the mixed pixels on
  // their rays and the dropout rays' ends.
  std::vector<internal::PlacedMesh> parts;
  if (frame != nullptr && frame->organized()) {
    for (const Detection& d : detections) {
      if (auto mesh = m.part_meshes.find(d.class_id); mesh != m.part_meshes.end()) parts.push_back({&mesh->second, d.X_BO});
    }
    if (m.options.mixed_on_part_rays > 0) {
      DropMixedOnPartRays(*frame, parts, static_cast<float>(m.options.mixed_on_part_rays), rest);
    }
    if (m.hidden_min_stretch > 0) {
      std::vector<internal::PlacedMesh> by_detection(detections.size());  // mesh null: a class the cell lacks
      for (size_t d = 0; d < detections.size(); ++d) {
        if (auto mesh = m.part_meshes.find(detections[d].class_id); mesh != m.part_meshes.end()) {
          by_detection[d] = {&mesh->second, detections[d].X_BO};
        }
      }
      obstacles.hidden = std::make_unique<const FrameObstacles::HiddenSpaces>(
          m, *frame, BinPoseOf(perception, m.cell.bin), std::move(by_detection));
    }
  }
  // The unseen space along the dropout rays beside them (dropout_reach),
  // ended at the detected parts' surfaces (dropout_ends_at_parts).
  if (frame != nullptr && frame->organized() && m.options.dropout_reach > 0) {
    const double res = m.options.octree_resolution;
    const Pose& X_BW = BinPoseOf(perception, m.cell.bin);
    internal::PixelWindow window;
    std::vector<uint8_t> wanted;
    std::vector<DropoutRay> rays = FindDropoutRays(*frame, X_BW, m.options.dropout_reach, rest, &window, &wanted);
    if (m.options.dropout_ends_at_parts) EndRaysAtParts(*frame, parts, window, rays);
    const std::vector<Eigen::Vector3f> dropout =
        DropoutPoints(*frame, m.cell, X_BW, rays, res / 2, m.options.occluded_columns ? static_cast<float>(res) : 0.f);
    rest.insert(rest.end(), dropout.begin(), dropout.end());
  }
  const double res = m.options.octree_resolution;
  // The columns from the points themselves (their cells in W), then every
  // point voxelised in the OcTree's grid (B).
  if (m.options.occluded_columns && !rest.empty()) {
    AppendOccludedColumns(BinPoseOf(perception, m.cell.bin), res, m.options.voxelised_obstacles, rest);
  }
  if (m.options.voxelised_obstacles) rest = VoxelCentres(rest, res);
  auto points = PointObstacle::FromPoints(rest, res);
  if (points.ok()) obstacles.points = *points;
  // 1 cm cells of the points (voxel centres when voxelised) for the point
  // check's pre-filter (CandidateFilter::Verdict).
  obstacles.grid = internal::OccupancyGrid(rest, 0.01);
  return obstacles;
}

// The least seen share over a grasp's contacts (0 without a contact region).
double SeenShare(const GraspCandidate& c, const internal::SeenSurface& seen) {
  if (!c.contact || c.contact->contacts.empty()) return 0.0;
  double least = 1.0;
  for (const auto& samples : c.contact->contacts) least = std::min(least, internal::SeenFraction(samples, c.X_BG, seen));
  return least;
}

// True when a part at X_BO held with the tool at X_BT, placed at X_BO_place
// (the tool then at X_BO_place * X_BO^-1 * X_BT, seed 003's tool_in_base with
// the fixture at its taught pose), keeps the flange inside `workspace` at the
// place and at its approach (approach_distance back along the tool's z).
bool Placeable(const Pose& X_BO_place, const Pose& X_BO, const Pose& X_BT, double approach_distance, const Pose& X_TF,
               const Eigen::AlignedBox3d& workspace) {
  const Pose X_BT_place = X_BO_place * X_BO.inverse() * X_BT;
  const Pose X_BT_approach = X_BT_place * TranslateZ(-approach_distance);
  return workspace.contains((X_BT_place * X_TF).translation()) &&
         workspace.contains((X_BT_approach * X_TF).translation());
}

// Stage 3: each candidate's verdict, cheapest check first. `seen` is null
// when no grasp needs it. Everything a verdict reads is built once per plan
// here; Verdict is const and runs concurrently on different candidates.
class CandidateFilter {
 public:
  CandidateFilter(const GraspPlanningModel::Impl& m, const Gripper& gripper, const TaskSpec& task, const Pose& X_BW,
                  std::span<const Detection> detections, const FrameObstacles& obstacles,
                  const internal::SeenSurface* seen)
      : m_(m), gripper_(gripper), X_BW_(X_BW), detections_(detections), obstacles_(obstacles), seen_(seen) {
    const Cell& cell = m.cell;
    max_tilt_ = task.max_tilt_deg * M_PI / 180.0;
    X_TF_ = gripper.spec->X_FT.inverse();
    // task.place_on: where the held part goes (taught pose * part_pose, X_BO').
    if (const FixtureSpec* f = task.place_on.empty() ? nullptr : cell.FindFixture(task.place_on); f != nullptr) {
      place_ = Pose(f->X_BP_taught * f->X_PO);
    }
    // Pose ambiguity: a candidate must land at its grasp point under every
    // alternative pose of its detection (the judge's rule: the gripper's
    // approach limit, the part's symmetry per detection). A suction candidate
    // that misses its grasp point under one but whose cup still seals on the
    // surface under each (within the compliance less the margin kept for that
    // pose's own error) is kept as a last resort (seal_only).
    suction_ = gripper.spec->kind == GripperSpec::Kind::kSuction;
    seal_angle_ =
        std::max(0.0, m.options.suction_compliance_deg - m.options.suction_compliance_margin_deg) * M_PI / 180.0;
    land_approach_ = suction_ ? m.options.suction_compliance_deg * M_PI / 180.0
                              : m.options.ambiguity_jaw_approach_deg * M_PI / 180.0;
    // The grid holds voxel centres (voxelised_obstacles): a voxel lies
    // within sqrt(3) / 2 of an edge of its centre; else the points: their
    // voxel within sqrt(3) edges. Rounded up (an edge, two).
    points_reach_ = m.options.octree_resolution * (m.options.voxelised_obstacles ? 1.0 : 2.0);
    // The generated bin (MakeBinMesh) lies outside the open prism over its
    // inner floor (|x| < x / 2, |y| < y / 2, z > 0 in W) and below its rim
    // (z <= z size); grown by bin_margin (Inflated: no point moves further
    // than 3 * bin_margin), outside the prism shrunk by 3 * bin_margin and
    // below the rim raised by as much. A sweep whose every slab box lies in
    // one of those two meets none of its triangles. A bin mesh from a file:
    // none.
    X_WB_ = X_BW.inverse();
    if (cell.bin.mesh.empty()) {
      constexpr double kInf = std::numeric_limits<double>::infinity();
      const double in = 3.0 * m.options.bin_margin + 1e-4;
      const Vec3 half = cell.bin.inner_size / 2;
      bin_free_W_ = {Eigen::AlignedBox3d(Vec3(-half.x() + in, -half.y() + in, in), Vec3(half.x() - in, half.y() - in, kInf)),
                     Eigen::AlignedBox3d(Vec3(-kInf, -kInf, cell.bin.inner_size.z() + in), Vec3(kInf, kInf, kInf))};
    }
    // The other parts: each detection's grown mesh, its poses (the
    // estimated one, then its alternatives: ambiguous_poses_block) and
    // their bounds in B.
    parts_.assign(detections.size(), nullptr);
    part_poses_.resize(detections.size());
    part_bounds_.resize(detections.size());
    for (size_t d = 0; d < detections.size(); ++d) {
      if (auto p = m.parts_planning.find(detections[d].class_id); p != m.parts_planning.end()) {
        parts_[d] = p->second.get();
        part_poses_[d] = {detections[d].X_BO};
        if (m.options.ambiguous_poses_block) {
          part_poses_[d].insert(part_poses_[d].end(), detections[d].alternatives_X_BO.begin(),
                                detections[d].alternatives_X_BO.end());
        }
        for (const Pose& X_BO : part_poses_[d]) part_bounds_[d].push_back(parts_[d]->WorldBounds(X_BO));
      }
    }
    symmetry_.resize(detections.size());
    for (size_t d = 0; d < detections.size(); ++d) {
      if (const PartSpec* part = cell.FindPart(detections[d].class_id); part != nullptr) symmetry_[d] = part->symmetry;
    }
  }

  // Whether each slab box of the swept gripper at X_BT lies in one of
  // bin_free_W_ (its 8 corners): then it does not collide with the plan's
  // bin.
  bool ClearOfTheBin(const Pose& X_BT) const {
    if (bin_free_W_.empty()) return false;
    const Pose X_WT = X_WB_ * X_BT;
    return std::all_of(gripper_.slabs.begin(), gripper_.slabs.end(), [&](const Eigen::AlignedBox3d& slab) {
      std::array<Vec3, 8> corners;
      for (int i = 0; i < 8; ++i) corners[i] = X_WT * slab.corner(static_cast<Eigen::AlignedBox3d::CornerType>(i));
      return std::any_of(bin_free_W_.begin(), bin_free_W_.end(), [&](const Eigen::AlignedBox3d& free) {
        return std::all_of(corners.begin(), corners.end(), [&](const Vec3& p) { return free.contains(p); });
      });
    });
  }

  // Whether the swept gripper at c.X_BT meets another detected part (grown
  // by part_margin) at one of its poses: FCL on the poses whose bounds meet
  // one of its slabs' (a sweep's triangle lies in its slab's box).
  bool HitsAnotherPart(const GraspCandidate& c) const {
    std::vector<Eigen::AlignedBox3d> boxes;
    boxes.reserve(gripper_.slabs.size());
    for (const auto& slab : gripper_.slabs) boxes.push_back(WorldBox(slab, c.X_BT));
    for (size_t d = 0; d < parts_.size(); ++d) {
      if (static_cast<int>(d) == c.detection || parts_[d] == nullptr) continue;
      for (size_t k = 0; k < part_poses_[d].size(); ++k) {
        const bool near = std::any_of(boxes.begin(), boxes.end(),
                                      [&](const Eigen::AlignedBox3d& b) { return b.intersects(part_bounds_[d][k]); });
        if (near && Collides(*gripper_.sweep, c.X_BT, *parts_[d], part_poses_[d][k])) return true;
      }
    }
    return false;
  }

  // Whether the swept gripper at X_BT meets `patch`: FCL when a slab's box
  // meets its box and the pre-filter finds a point near a slab.
  bool HitsPatch(const FrameObstacles::PointPatch& patch, const Pose& X_BT) const {
    const bool near = std::any_of(gripper_.slabs.begin(), gripper_.slabs.end(), [&](const Eigen::AlignedBox3d& slab) {
      return WorldBox(slab, X_BT).intersects(patch.bounds);
    });
    if (!near || !std::any_of(gripper_.slabs.begin(), gripper_.slabs.end(), [&](const Eigen::AlignedBox3d& slab) {
          return patch.grid.AnyNear(slab, X_BT, patch.reach);
        })) {
      return false;
    }
    std::call_once(patch.built, [&patch] {
      if (auto p = PointObstacle::FromPoints(patch.points, patch.res); p.ok()) patch.tree = *p;
    });
    return patch.tree && patch.tree->Collides(*gripper_.sweep, X_BT);
  }

  // Whether the swept gripper at X_BT_lift (lifted like the self check)
  // meets the points only detection d's surface explains
  // (FrameObstacles::own). Exact: a voxel (edge kSurfaceSpacing) the sweep
  // meets holds a point within sqrt(3) edges of the sweep, so within two of
  // a slab box along each of the tool's axes (PointPatch::reach, raw points).
  bool HitsItsOwnPoints(int d, const Pose& X_BT_lift) const {
    if (d < 0 || static_cast<size_t>(d) >= obstacles_.own.size() || !obstacles_.own[d]) return false;
    return HitsPatch(*obstacles_.own[d], X_BT_lift);
  }

  // Whether the swept gripper at X_BT_points (lifted like the point check)
  // enters the space another detection than d hides from the camera
  // (FrameObstacles::hidden).
  // Only the parts of the spaces near the sweep (HiddenSpaces::NearParts).
  bool EntersHiddenSpace(int d, const Pose& X_BT_points) const {
    if (!obstacles_.hidden) return false;
    const FrameObstacles::HiddenSpaces& hidden = *obstacles_.hidden;
    std::vector<Eigen::AlignedBox3d> boxes;
    std::vector<Eigen::AlignedBox3d> footprints;
    boxes.reserve(gripper_.slabs.size());
    footprints.reserve(gripper_.slabs.size());
    for (const auto& slab : gripper_.slabs) {
      boxes.push_back(WorldBox(slab, X_BT_points));
      footprints.push_back(hidden.Footprint(slab, X_BT_points, 2 * m_.options.octree_resolution));
    }
    for (size_t k = 0; k < hidden.size(); ++k) {
      if (static_cast<int>(k) == d) continue;
      for (const FrameObstacles::PointPatch* part : hidden.NearParts(k, boxes, footprints)) {
        if (HitsPatch(*part, X_BT_points)) return true;
      }
    }
    return false;
  }

  // The first check `c` fails, nullopt when it passes every one. Sets
  // c.deferred, c.seal_only and c.seen_fraction on the way.
  std::optional<RejectReason> Verdict(GraspCandidate& c) const {
    const Detection& det = detections_[c.detection];
    c.deferred = det.visible_fraction < m_.options.defer_below_visible;
    const Eigen::AlignedBox3d& workspace = m_.cell.robot.workspace;
    if (c.tilt_rad > max_tilt_ + 1e-9) return RejectReason::kTilt;
    if (!workspace.contains((c.X_BT * X_TF_).translation()) || !workspace.contains((c.X_BT_pre * X_TF_).translation())) {
      return RejectReason::kWorkspace;
    }
    if (place_ && !Placeable(*place_, det.X_BO, c.X_BT, gripper_.spec->approach_distance, X_TF_, workspace)) {
      return RejectReason::kUnplaceable;
    }
    // X_BG: the grasp before any "~v" turn, whose approach the judge holds.
    if (!det.alternatives_X_BO.empty() &&
        !LandsUnderEveryAlternative(det, symmetry_[c.detection], c.X_BT, det.X_BO.inverse() * c.X_BG,
                                    m_.options.ambiguity_max_position, land_approach_)) {
      auto part = m_.parts.find(det.class_id);
      if (!suction_ || part == m_.parts.end() ||
          !SealsUnderEveryAlternative(det, *part->second, c.X_BT, m_.options.ambiguity_max_position, seal_angle_)) {
        return RejectReason::kAmbiguous;
      }
      c.seal_only = true;
    }
    const SeenContactRule& rule = gripper_.spec->seen_contact;
    if (seen_ != nullptr && NeedsSeenContact(rule, det)) {
      c.seen_fraction = SeenShare(c, *seen_);
      if (c.seen_fraction < rule.min_fraction) return RejectReason::kUnseen;
    }
    const CollisionGeometry& sweep = *gripper_.sweep;
    if (!ClearOfTheBin(c.X_BT) && Collides(sweep, c.X_BT, *m_.bin_planning, X_BW_)) return RejectReason::kBin;
    if (HitsAnotherPart(c)) return RejectReason::kPart;
    const Pose X_BT_lift = c.X_BT * TranslateZ(-m_.options.contact_margin);
    if (auto p = m_.parts.find(det.class_id); p != m_.parts.end() && Collides(sweep, X_BT_lift, *p->second, det.X_BO)) {
      return RejectReason::kSelf;
    }
    if (HitsItsOwnPoints(c.detection, X_BT_lift)) return RejectReason::kSelf;
    if (obstacles_.points) {
      const Pose X_BT_points = c.X_BT * TranslateZ(-gripper_.points_lift);
      // The sweep lies in its slabs (in T); a voxel it meets has a point of
      // the grid within points_reach_ of one (each axis of T).
      const bool near = std::any_of(gripper_.slabs.begin(), gripper_.slabs.end(), [&](const auto& slab) {
        return obstacles_.grid.AnyNear(slab, X_BT_points, points_reach_);
      });
      if (near && obstacles_.points->Collides(sweep, X_BT_points)) return RejectReason::kPoints;
    }
    if (EntersHiddenSpace(c.detection, c.X_BT * TranslateZ(-gripper_.points_lift))) return RejectReason::kHiddenSpace;
    return std::nullopt;
  }

 private:
  const GraspPlanningModel::Impl& m_;
  const Gripper& gripper_;
  const Pose X_BW_;
  std::span<const Detection> detections_;
  const FrameObstacles& obstacles_;
  const internal::SeenSurface* seen_;
  double max_tilt_ = 0;
  Pose X_TF_ = Pose::Identity();
  std::optional<Pose> place_;
  bool suction_ = false;
  double seal_angle_ = 0, land_approach_ = 0;
  double points_reach_ = 0;  // m, OccupancyGrid::AnyNear's grow for the point check's pre-filter
  Pose X_WB_ = Pose::Identity();
  std::vector<Eigen::AlignedBox3d> bin_free_W_;  // where the swept gripper cannot meet the plan's bin (W)
  std::vector<const CollisionGeometry*> parts_;     // by detection: grown by part_margin, null for an unknown class
  std::vector<std::vector<Pose>> part_poses_;       // by detection: its pose, then its alternatives
  std::vector<std::vector<Eigen::AlignedBox3d>> part_bounds_;  // by detection, per pose, in B
  std::vector<Symmetry> symmetry_;
};

// Stage 3 for the candidates not checked yet (`checked` 0), in parallel over
// candidates (the caller's arena).
void FilterCandidates(const CandidateFilter& filter, std::vector<GraspCandidate>& candidates,
                      const std::vector<uint8_t>& checked) {
  tbb::parallel_for(size_t{0}, candidates.size(), [&](size_t i) {
    if (!checked[i]) candidates[i].rejected = filter.Verdict(candidates[i]);
  });
}

// A candidate's ranking score (task.ranking): it depends on the candidate
// alone, never on which others pass.
double CandidateScore(const GraspCandidate& c, const TaskSpec& task, const Pose& X_WB, double bin_height,
                      std::span<const Detection> detections) {
  const double max_tilt = task.max_tilt_deg * M_PI / 180.0;
  const double z_W = (X_WB * c.X_BT).translation().z();
  const double tilt_norm = max_tilt > 0 ? c.tilt_rad / max_tilt : 0.0;
  return task.ranking.height * (z_W / std::max(1e-6, bin_height)) +
         task.ranking.detection * detections[c.detection].score - task.ranking.tilt * tilt_norm;
}

Eigen::AlignedBox3d Grown(Eigen::AlignedBox3d b, double by) {
  b.min().array() -= by;
  b.max().array() += by;
  return b;
}

// Each detection's part for the touch and approach tests: its mesh, the
// mesh grown for touch_distance (parts_touch) and the mesh's bounds in B
// at the estimated pose; null / empty for a class without a mesh.
struct PartsAtPoses {
  std::vector<const CollisionGeometry*> part, part_touch;
  std::vector<Eigen::AlignedBox3d> box;
};

PartsAtPoses PartsAt(const GraspPlanningModel::Impl& m, std::span<const Detection> detections) {
  const size_t n = detections.size();
  PartsAtPoses out{std::vector<const CollisionGeometry*>(n, nullptr), std::vector<const CollisionGeometry*>(n, nullptr),
                   std::vector<Eigen::AlignedBox3d>(n)};
  for (size_t i = 0; i < n; ++i) {
    auto p = m.parts.find(detections[i].class_id);
    if (p == m.parts.end()) continue;
    out.part[i] = p->second.get();
    out.part_touch[i] = m.parts_touch.at(detections[i].class_id).get();
    out.box[i] = out.part[i]->WorldBounds(detections[i].X_BO);
  }
  return out;
}

// The parts that may move when the part of detection `head` is handed out,
// under GraspQueue's transitive stale rule: the head's part and the parts
// touch-connected to it (within touch_distance at their estimated poses,
// MarkStaleNeighbours' pair test, either way round since the queue's order
// is not known yet), over every detection: parts with a queued grasp and
// without one (GraspPlan::ungrasped_touching) pass staleness on alike, so
// the group holds every part that rule can make move. @returns whether each
// detection is in the group.
std::vector<bool> TouchGroup(const GraspPlanningModel::Impl& m, std::span<const Detection> detections, int head) {
  const size_t n = detections.size();
  const PartsAtPoses at = PartsAt(m, detections);
  const auto& part = at.part;
  const auto& part_touch = at.part_touch;
  const auto& box = at.box;
  std::vector<bool> in(n, false);
  in[static_cast<size_t>(head)] = true;
  std::vector<size_t> frontier = {static_cast<size_t>(head)};
  while (!frontier.empty()) {
    const size_t i = frontier.back();
    frontier.pop_back();
    if (part[i] == nullptr) continue;
    for (size_t j = 0; j < n; ++j) {
      if (in[j] || part[j] == nullptr || !Grown(box[i], m.options.touch_distance).intersects(box[j])) continue;
      if (Collides(*part_touch[i], detections[i].X_BO, *part[j], detections[j].X_BO) ||
          Collides(*part_touch[j], detections[j].X_BO, *part[i], detections[i].X_BO)) {
        in[j] = true;
        frontier.push_back(j);
      }
    }
  }
  return in;
}

// Whether `c`, were it its part's primary grasp, may be withdrawn when the
// head is handed out: its part is in the head's touch group (`group`), or
// its swept gripper passes within approach_margin of a part of the group
// (MarkStaleNeighbours' bounding-box pairs and queries). A part outside the
// group touches none in it, so nothing else makes its grasp stale.
bool StaleAfterHead(const GraspPlanningModel::Impl& m, const Gripper& gripper, std::span<const Detection> detections,
                    const GraspCandidate& c, const std::vector<bool>& group) {
  if (group[static_cast<size_t>(c.detection)]) return true;
  std::vector<Eigen::AlignedBox3d> sweep_boxes;
  for (const auto& slab : gripper.slabs) sweep_boxes.push_back(Grown(WorldBox(slab, c.X_BT), m.options.approach_margin));
  for (size_t j = 0; j < detections.size(); ++j) {
    if (!group[j]) continue;
    const auto part = m.parts.find(detections[j].class_id);
    if (part == m.parts.end()) continue;
    const Eigen::AlignedBox3d box = part->second->WorldBounds(detections[j].X_BO);
    const bool near = std::any_of(sweep_boxes.begin(), sweep_boxes.end(),
                                  [&box](const Eigen::AlignedBox3d& b) { return b.intersects(box); });
    if (near && Collides(*gripper.sweep_margin, c.X_BT, *part->second, detections[j].X_BO)) return true;
  }
  return false;
}

// Stage 3a, when the caller wants the queue head early: candidates in the
// order the final queue ranks them (score descending; ties as QueueByPart
// breaks them: detection index, then candidate order) are checked in blocks
// (1, 2, 4, ... up to 32 candidates, each block in parallel; every verdict
// kept in `checked` for stage 3). Filtering only removes and a score
// depends on its candidate alone, so in that order:
//   - the first candidate that passes every check and is not a last resort
//     (seal-only, or deferred on a mostly hidden part) is the head of the
//     final queue (a passing last resort ranked above it is refused by stage
//     3b, since a certain grasp exists);
//   - the first such candidate of each other part is that part's primary
//     grasp; the first primary the head's hand-out cannot make stale, even
//     through parts that may move with it (StaleAfterHead, TouchGroup), is
//     `next`: it proves that the queue still holds a grasp after the head.
// The head is published only with that proof, or when every candidate is
// checked and no other part has a certain grasp (nothing follows it: the
// remaining count 1 is exact). Other parts' grasps that may all be made
// stale (the group is a superset of what moves) leave the count unknown:
// no head early. head -1: nothing to publish early (also when there is no
// certain grasp: the head, if any, is a last resort).
struct EarlyHead {
  int head = -1;
  int next = -1;  // -1 with a head: nothing is queued after its hand-out
};
EarlyHead FindEarlyHead(const GraspPlanningModel::Impl& m, const Gripper& gripper, const CandidateFilter& filter,
                        const TaskSpec& task, const Pose& X_BW, std::span<const Detection> detections,
                        std::vector<GraspCandidate>& candidates, std::vector<uint8_t>& checked) {
  const Pose X_WB = X_BW.inverse();
  const double bin_height = m.cell.bin.inner_size.z();
  std::vector<double> score(candidates.size());
  std::vector<int> order(candidates.size());
  for (size_t i = 0; i < candidates.size(); ++i) {
    score[i] = CandidateScore(candidates[i], task, X_WB, bin_height, detections);
    order[i] = static_cast<int>(i);
  }
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
    if (score[a] != score[b]) return score[a] > score[b];
    return candidates[a].detection < candidates[b].detection;  // then candidate order (stable)
  });
  EarlyHead found;
  std::set<int> decided;  // parts whose primary was seen after the head (stale ones)
  std::vector<bool> group;  // TouchGroup of the head's part, once it is found
  size_t block = 1;
  for (size_t begin = 0; begin < order.size(); begin += block, block = std::min<size_t>(block * 2, 32)) {
    const size_t end = std::min(order.size(), begin + block);
    tbb::parallel_for(begin, end, [&](size_t k) {
      GraspCandidate& c = candidates[order[k]];
      c.rejected = filter.Verdict(c);
      checked[order[k]] = 1;
    });
    for (size_t k = begin; k < end; ++k) {
      const GraspCandidate& c = candidates[order[k]];
      if (c.rejected || c.seal_only || c.deferred) continue;
      if (found.head < 0) {
        found.head = order[k];
        decided.insert(c.detection);
        group = TouchGroup(m, detections, c.detection);
        continue;
      }
      if (!decided.insert(c.detection).second) continue;  // not its part's primary
      if (!StaleAfterHead(m, gripper, detections, c, group)) {
        found.next = order[k];
        return found;
      }
    }
  }
  // Every candidate checked without a next: publishable only when no
  // other part has a certain grasp.
  if (decided.size() > 1) found.head = -1;
  return found;
}

// Stage 3b: the last resorts. Grasps kept only because the cup seals under
// every alternative pose (seal_only) would land off their grasp point were
// an alternative true, and grasps on a mostly hidden part (deferred) pass
// near what hides it: they are refused (kAmbiguous, kHidden) while the plan
// keeps any other grasp, so that a part whose landing is certain and whose
// surroundings are seen is picked first.
void KeepLastResortsLast(std::vector<GraspCandidate>& candidates) {
  const bool certain = std::any_of(candidates.begin(), candidates.end(), [](const GraspCandidate& c) {
    return !c.rejected && !c.seal_only && !c.deferred;
  });
  if (!certain) return;
  for (GraspCandidate& c : candidates) {
    if (c.rejected) continue;
    if (c.seal_only) {
      c.rejected = RejectReason::kAmbiguous;
    } else if (c.deferred) {
      c.rejected = RejectReason::kHidden;
    }
  }
}

// Stage 4: scores of the accepted candidates (task.ranking) and the counts.
void RankCandidates(const Cell& cell, const TaskSpec& task, const Pose& X_BW, std::span<const Detection> detections,
                    std::vector<GraspCandidate>& candidates, FilterStats& stats) {
  const Pose X_WB = X_BW.inverse();
  for (GraspCandidate& c : candidates) {
    ++stats.candidates;
    if (c.rejected) {
      ++stats.rejected[static_cast<int>(*c.rejected)];
      continue;
    }
    ++stats.accepted;
    c.score = CandidateScore(c, task, X_WB, cell.bin.inner_size.z(), detections);
  }
}

// The grasp queued for a part whose best candidate is `best` (scored),
// without its related poses and stale neighbours.
Grasp PrimaryGrasp(std::span<const Detection> detections, const GraspCandidate& best) {
  Grasp g;
  g.X_BT = best.X_BT;
  g.X_BT_pre = best.X_BT_pre;
  g.X_BO = detections[best.detection].X_BO;
  g.instance_id = best.detection;
  g.class_id = best.class_id;
  g.score = best.score;
  g.name = best.name;
  g.last_resort = best.seal_only;
  return g;
}

// Stage 5: one primary grasp per part, parts ordered by their best grasp,
// the part's other accepted grasps as related_X_B.
std::vector<Grasp> QueueByPart(std::span<const Detection> detections, const std::vector<GraspCandidate>& candidates) {
  std::map<int, std::vector<const GraspCandidate*>> by_part;
  for (const GraspCandidate& c : candidates) {
    if (!c.rejected) by_part[c.detection].push_back(&c);
  }
  std::vector<std::vector<const GraspCandidate*>> parts;
  for (auto& [d, list] : by_part) {
    std::stable_sort(list.begin(), list.end(), [](auto* a, auto* b) { return a->score > b->score; });
    parts.push_back(std::move(list));
  }
  std::stable_sort(parts.begin(), parts.end(), [](const auto& a, const auto& b) { return a[0]->score > b[0]->score; });
  std::vector<Grasp> queue;
  for (const auto& list : parts) {
    Grasp g = PrimaryGrasp(detections, *list[0]);
    for (size_t k = 1; k < list.size(); ++k) g.related_X_B.push_back(list[k]->X_BT);
    queue.push_back(std::move(g));
  }
  return queue;
}

// Stage 6: each queued grasp's stale neighbours among the detected parts
// (Grasp::stale_after): parts within touch_distance of its part, and parts
// its swept gripper passes within approach_margin of (the grown geometries
// of Inflated); and the touching pairs of the detections no grasp is
// queued for (`ungrasped`: GraspPlan::ungrasped_touching), which stay in
// the bin and pass staleness on. Bounding boxes pick the pairs worth an
// FCL collision query; the queries run in parallel.
void MarkStaleNeighbours(const GraspPlanningModel::Impl& m, const Gripper& gripper,
                         std::span<const Detection> detections, std::vector<Grasp>& queue,
                         std::map<int, std::vector<int>>& ungrasped) {
  const size_t n = detections.size();
  if (queue.empty() || n < 2) return;
  const double touch = m.options.touch_distance, margin = m.options.approach_margin;
  // Per detection: its queued grasp (-1: none), geometries and bounds.
  std::vector<int> queued(n, -1);
  for (size_t i = 0; i < queue.size(); ++i) {
    const int id = queue[i].instance_id;
    if (id >= 0 && static_cast<size_t>(id) < n) queued[static_cast<size_t>(id)] = static_cast<int>(i);
  }
  // The queued grasps' X_BO are their detections' (PrimaryGrasp).
  const PartsAtPoses at = PartsAt(m, detections);
  const auto& part = at.part;
  const auto& part_touch = at.part_touch;
  const auto& box = at.box;
  struct Query {
    size_t i, j;    // detections
    bool approach;  // i's queued grasp's swept gripper against part j; else part i against part j (i < j)
  };
  std::vector<Query> queries;
  for (size_t i = 0; i < n; ++i) {
    if (part[i] == nullptr) continue;
    std::vector<Eigen::AlignedBox3d> sweep_boxes;
    if (queued[i] >= 0) {
      const Pose& X_BT = queue[static_cast<size_t>(queued[i])].X_BT;
      for (const auto& slab : gripper.slabs) sweep_boxes.push_back(Grown(WorldBox(slab, X_BT), margin));
    }
    for (size_t j = 0; j < n; ++j) {
      if (j == i || part[j] == nullptr) continue;
      if (j > i && Grown(box[i], touch).intersects(box[j])) queries.push_back({i, j, false});
      for (const auto& b : sweep_boxes) {
        if (b.intersects(box[j])) {
          queries.push_back({i, j, true});
          break;
        }
      }
    }
  }
  // Closer than the distance = colliding with the grown geometry.
  std::vector<uint8_t> close(queries.size(), 0);
  tbb::parallel_for(size_t{0}, queries.size(), [&](size_t k) {
    const Query& q = queries[k];
    const Pose& X_BO_j = detections[q.j].X_BO;
    close[k] = q.approach
                   ? Collides(*gripper.sweep_margin, queue[static_cast<size_t>(queued[q.i])].X_BT, *part[q.j], X_BO_j)
                   : Collides(*part_touch[q.i], detections[q.i].X_BO, *part[q.j], X_BO_j);
  });
  // Per detection (ids are detection indices): what its grasp is stale
  // after, and the parts it touches.
  std::vector<std::set<int>> stale(n), touching(n);
  for (size_t k = 0; k < queries.size(); ++k) {
    if (!close[k]) continue;
    const Query& q = queries[k];
    const int i = static_cast<int>(q.i), j = static_cast<int>(q.j);
    stale[q.i].insert(j);
    if (q.approach) continue;
    stale[q.j].insert(i);
    touching[q.i].insert(j);
    touching[q.j].insert(i);
  }
  for (size_t i = 0; i < n; ++i) {
    if (queued[i] >= 0) {
      Grasp& g = queue[static_cast<size_t>(queued[i])];
      g.stale_after.assign(stale[i].begin(), stale[i].end());
      g.touching.assign(touching[i].begin(), touching[i].end());
    } else if (!touching[i].empty()) {
      ungrasped[static_cast<int>(i)].assign(touching[i].begin(), touching[i].end());
    }
  }
}

}  // namespace

GraspPlan PlanGrasps(const GraspPlanningModel& model, const TaskSpec& task, const PerceptionResult& perception,
                     std::span<const TaughtGrasp> taught, const Frame* frame, const HeadReady& on_head) {
  const auto t0 = std::chrono::steady_clock::now();
  const GraspPlanningModel::Impl& m = model.impl();
  GraspPlan plan;

  const std::function<bool(int)> wanted = [&task](int class_id) {
    return task.part_classes.empty() ||
           std::find(task.part_classes.begin(), task.part_classes.end(), class_id) != task.part_classes.end();
  };
  const auto& detections = perception.detections;
  int relevant = 0;
  for (const Detection& d : detections) relevant += wanted(d.class_id) ? 1 : 0;
  if (relevant == 0) {
    plan.outcome = PlanResult::Outcome::kNoObjects;
    return plan;
  }
  auto gripper_it = m.grippers.find(task.gripper);
  if (gripper_it == m.grippers.end()) {  // cell validation makes this unreachable
    plan.outcome = PlanResult::Outcome::kNoCollisionFree;
    return plan;
  }
  const Gripper& gripper = gripper_it->second;

  plan.candidates = MakeCandidates(model, gripper, task, detections, taught, wanted);

  const auto t_obstacles = std::chrono::steady_clock::now();
  const FrameObstacles obstacles = BuildObstacles(m, perception, frame);
  // What the frame measured, for the seen-contact check: its depth image, or
  // its ROI points when it has none (built only when a grasp needs it).
  const SeenContactRule& rule = gripper.spec->seen_contact;
  std::optional<internal::SeenSurface> seen;
  if (std::any_of(detections.begin(), detections.end(),
                  [&](const Detection& d) { return wanted(d.class_id) && NeedsSeenContact(rule, d); })) {
    if (frame != nullptr && frame->organized()) {
      seen.emplace(frame->depth, frame->intrinsics, frame->X_BC, rule.max_distance);
    } else {
      seen.emplace(perception.roi_points_B, rule.max_distance);
    }
  }
  plan.stats.obstacles_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t_obstacles).count();

  // The walls stand where perception measured the bin (BinPoseOf).
  const Pose& X_BW = BinPoseOf(perception, m.cell.bin);
  const CandidateFilter filter(m, gripper, task, X_BW, detections, obstacles, seen ? &*seen : nullptr);
  std::vector<uint8_t> checked(plan.candidates.size(), 0);
  std::optional<Grasp> head;
  if (on_head) {
    const EarlyHead early = FindEarlyHead(m, gripper, filter, task, X_BW, detections, plan.candidates, checked);
    if (early.head >= 0) {
      // Scored as stage 4 will score them.
      const Pose X_WB = X_BW.inverse();
      const double bin_height = m.cell.bin.inner_size.z();
      PlanHead published;
      GraspCandidate& h = plan.candidates[early.head];
      h.score = CandidateScore(h, task, X_WB, bin_height, detections);
      published.grasp = PrimaryGrasp(detections, h);
      // One grasp per part with candidates at most, the head's included.
      std::set<int> parts;
      for (const GraspCandidate& c : plan.candidates) parts.insert(c.detection);
      published.max_queue = early.next >= 0 ? std::max(2, static_cast<int>(parts.size())) : 1;
      if (early.next >= 0) {
        GraspCandidate& n = plan.candidates[early.next];
        n.score = CandidateScore(n, task, X_WB, bin_height, detections);
        published.next = PrimaryGrasp(detections, n);
      }
      head = published.grasp;
      on_head(published);
    }
  }
  FilterCandidates(filter, plan.candidates, checked);
  if (obstacles.hidden) {
    plan.stats.hidden_spaces_built = obstacles.hidden->built();
    plan.stats.hidden_spaces = obstacles.hidden->with_bounds();
    plan.stats.hidden_tiles_built = obstacles.hidden->tiles_built();
    plan.stats.hidden_tiles = obstacles.hidden->tiles();
  }
  KeepLastResortsLast(plan.candidates);
  RankCandidates(m.cell, task, X_BW, detections, plan.candidates, plan.stats);
  plan.queue = QueueByPart(detections, plan.candidates);
  const auto t_neighbours = std::chrono::steady_clock::now();
  MarkStaleNeighbours(m, gripper, detections, plan.queue, plan.ungrasped_touching);
  plan.stats.neighbours_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t_neighbours).count();
  plan.outcome = plan.queue.empty() ? PlanResult::Outcome::kNoCollisionFree : PlanResult::Outcome::kGrasps;
  if (head && (plan.queue.empty() || plan.queue.front().instance_id != head->instance_id ||
               plan.queue.front().name != head->name)) {
    // FindHead's invariant broke: the caller withdraws the head it published.
    spdlog::error("grasp planning: the head published early ({} on part {}) is not the plan's first grasp",
                  head->name, head->instance_id);
  }
  plan.stats.filter_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return plan;
}

}  // namespace bp
