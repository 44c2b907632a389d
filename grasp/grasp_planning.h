// Grasp planning for one frame: candidates from the cell's (and taught) grasps
// expanded over part symmetries, collision filtering with FCL, ranking, and
// the queue order (issue 4 §1-3).
//
// Frames (STYLE.md): B robot base, W bin, O part, T tool centre point, F
// flange. The tool's +z points into the part; the pre-grasp pose is
// X_BT_pre = X_BT * translate(0, 0, -approach_distance).
//
// Collision model. The gripper mesh (in T) is swept along the approach: the
// union of copies at every approach_step from the grasp back to the pre-grasp,
// one OBBRSS BVH per gripper, built once. Each candidate is checked, cheapest
// first, for: approach tilt from vertical (task.max_tilt_deg), flange inside
// robot.workspace at the grasp and the pre-grasp (and, when the task names
// place_on, at the place pose and its approach), the swept gripper against
// the bin (its walls grown by bin_margin; none inside the walls or above them),
// against the other detected parts (meshes at their estimated poses grown
// by part_margin, those whose bounds meet the sweep's slab boxes; an
// ambiguous detection at each of its poses: ambiguous_poses_block), against
// its own part
// and against the scene points not explained by any detection (its
// support, the points near it, those on its model's surface at its
// pose: surface_explain_distance, and on an organized frame the mixed
// pixels on its rays: mixed_on_part_rays; an FCL OcTree built once per frame,
// behind a pre-filter: a point of the voxels within a voxel of a slab box
// of the sweep, along the tool's axes),
// with the space below them down to the floor and, on an organized frame,
// the rays of the pixels without a measurement beside them (dropout_reach),
// up to the first detected part they meet (dropout_ends_at_parts): what the
// camera did not see next to an undetected part may be that part. On an
// organized frame, the space each detected part hides from the camera
// (hidden_behind_parts; per detection, not for its own grasps) is checked
// like the points, after them.
// Its own part is checked with the gripper lifted by contact_margin along
// -z, and so are the points for a suction gripper: the cup touches the part
// at the grasp point by design, and the points are inflated by a voxel. A
// parallel jaw's points are checked without the lift: its open fingers
// straddle the part and touch nothing until they close, and their tips
// reach past the grasp point, beside the part, where an undetected
// neighbour is hit like any other.
//
// Pose ambiguity (issue 37 item 3). A detection whose view other poses
// explain as well (Detection::alternatives_X_BO: a tee turned about its run
// with its branch hidden) keeps only the candidates that land on the part
// at their grasp point under every one of those poses too (kAmbiguous,
// checked right after the workspace). A suction candidate that misses its
// grasp point under one of them but whose cup still seals on the part's
// surface under each (tool centre near the surface, approach within the
// cup's compliance of its normal; FCL's nearest triangle) is a last resort
// (GraspCandidate::seal_only): offered only when the plan keeps no other
// grasp (a tee standing on its branch, turned about its run, alone in the
// bin), else refused as kAmbiguous. A part with none is left for the next
// capture; when no part has one, the plan is kNoCollisionFree, which the
// robot hears as "no collision-free grasp" (docs/protocols.md, pick pose).
//
// Hidden parts. A grasp on a part whose camera-facing surface lies mostly
// behind measured points (Detection::visible_fraction below
// defer_below_visible) passes near what hides it, which is often no
// detection: it is deferred like a seal-only grasp, offered only when the
// plan keeps no other grasp (kHidden).
//
// Seen contact (issue 37 item 2). A grasp is kept only when this frame's
// depth shows its contact region, by the rule of the task's gripper
// (grippers[].seen_contact, SeenContactRule in core/cell.h): the model
// surface under the suction cup's footprint, or under each jaw finger pad,
// sampled once per cell grasp, must have measured points within
// max_distance at min_fraction of its samples. It runs right after the
// ambiguity check (no FCL involved). A well-fitting detection can be turned
// wrongly where the part's distinguishing feature is hidden (a tee turned
// about its run with its branch out of view): its grasps on the hidden
// feature are rejected as kUnseen, whether or not the view left the pose
// ambiguous.
//
// Stale neighbours (issue 37 item 4). Each queued grasp lists the detected
// parts whose hand-out or movement makes it stale (Grasp::stale_after):
// parts within touch_distance of its part (both at their estimated poses),
// and parts its swept gripper passes within approach_margin of; the
// touching ones also in Grasp::touching. The detections without a queued
// grasp are listed with the detections touching them
// (GraspPlan::ungrasped_touching). GraspQueue::Pop withdraws a grasp when a
// part it lists is handed out, or may move: touches, transitively, the part
// handed out, through queued parts and parts without a queued grasp alike.
//
// Thread-safety: GraspPlanningModel is immutable after Build; PlanGrasps may
// run concurrently. PlanGrasps parallelises over candidates with oneTBB in the
// calling thread's arena.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"
#include "grasp/grasp.h"
#include "grasp/planner.h"
#include "pipeline/perception.h"

namespace bp {

// Why a candidate was rejected, in the order the checks run.
enum class RejectReason : int {
  kTilt = 0,   // approach further from vertical than task.max_tilt_deg
  kWorkspace,  // flange outside robot.workspace at the grasp or pre-grasp
  // task.place_on: held this way, the part placed on that fixture (taught
  // pose, part_pose) puts the flange outside robot.workspace at the place or
  // its approach (e.g. the tool under a part picked on the face that goes down)
  kUnplaceable,
  kAmbiguous,  // would miss its grasp point under another pose the view allows (Detection::alternatives_X_BO)
  kUnseen,     // the frame's depth does not show the contact region (SeenContactRule)
  kBin,        // swept gripper hits the bin
  kPart,       // swept gripper hits another detected part
  kSelf,       // lifted gripper cuts into its own part (its mesh, or the points only its surface explains)
  kPoints,     // lifted swept gripper hits scene points no detection explains
  kHiddenSpace,  // lifted swept gripper enters the space another detected part hides from the camera (hidden_behind_parts)
  // Passed every check, but its part is mostly hidden (Detection::
  // visible_fraction below GraspPlanningOptions::defer_below_visible) while
  // the plan keeps a grasp on a better-seen part (stage 3b, as the seal-only
  // last resorts).
  kHidden,
};
inline constexpr int kNumRejectReasons = 11;
std::string_view ToString(RejectReason reason);

struct GraspPlanningOptions {
  double revolute_step_deg = 15.0;  // samples about a revolute symmetry axis
  double approach_step = 0.005;     // m between swept copies of the gripper
  double contact_margin = 0.005;    // m the gripper is lifted for self checks (and point checks of a suction cup)
  // m, voxel edge of the scene-point OcTree: the points no detection
  // explains are that obstacle inflated by up to one voxel. Derived from
  // the clearance of the point check and the depth noise: the gripper is
  // lifted by contact_margin (5 mm) for it, and a measured point of the
  // surface it lands on lies up to 2 sigma_z (~1 mm at the bin floor, the
  // default camera) above that surface; one voxel more must stay within the
  // lift: 5 - 1 = 4 mm.
  double octree_resolution = 0.004;
  // Unexplained points are voxelised in the OcTree's grid, and the occluded
  // columns found on a dense grid of the bin's columns, before any
  // structure is built: the obstacle costs in proportion to the occupied
  // voxels of the bin, not to the image's pixels. The OcTree is the one
  // built point by point (same voxels), so every verdict is the same.
  // false: point by point (the reference tests compare with).
  bool voxelised_obstacles = true;
  // The space below each scene point no detection explains, down to the bin
  // floor, is an obstacle too (voxels of octree_resolution): the camera sees
  // the top edge of an undetected plate standing on end, not the plate below
  // it, and a tilted tool passing beside that edge hits the hidden part.
  bool occluded_columns = true;
  // Perception's grid spacing (PerceptionOptions::grid_spacing, m; the
  // BinPickingPlanner copies its perception's): the ROI points within twice
  // this of a detection's support point are explained too, no obstacle. 0:
  // the support points alone.
  // Why: perception fits one sample per grid cell, the cell's top-left pixel
  // (stride = grid_spacing / the pixel footprint on the floor, rounded), and
  // a detection's support is those samples: at 1920 x 1200 (stride 3) the
  // other eight pixels of every supported cell were obstacles, and a part's
  // own surface refused its own grasps (kPoints). A sample stands for the
  // points of its own cell; they lie within sqrt(2) * (stride - 1) pixels of
  // it across the view, under sqrt(2) * grid_spacing at any stride (1.1 mm
  // at 1920 x 1200), so twice the spacing holds the cell on a surface tilted
  // up to 45 deg from the view (60 deg at 1920 x 1200; steeper cells keep
  // some points as obstacles, the safe side). The plan has no pixel
  // coordinates, hence a distance in B rather than the cell itself.
  // No other part loses a verdict: a point explained lies within 2 * spacing
  // (2.4 mm) in 3D of a support sample, which lies on the detected part's
  // fitted surface within the fit's residual limit; another part's point is
  // dropped only where that part touches the detected one (a neighbour below
  // an edge differs in depth by more), and its points farther away stay, in
  // octree_resolution voxels (4 mm) that move each point by up to 2 mm.
  double support_grid_spacing = 0.0012;
  // m: a ROI point within this of a detection's model surface at its
  // estimated pose, on a side facing the camera (the surface's outward
  // normal at most 10 deg past grazing, toward the frame's camera or, without
  // a frame, the cell's), is explained too: that part's own point, no
  // obstacle. GraspPlanningModel::Build raises it to perception's support
  // distance for the cell's camera (3.4 sigma_z at the bin floor, the
  // noisiest config, pipeline/internal/part_settings.h). 0: off.
  // Why: a detection's support is the view it was matched in (a segment of
  // the frame), so its part's points in another segment (the other plate of
  // an L-bracket, a tee's far arm) and its grazing and edge points were
  // obstacles, inflated to octree_resolution voxels with the occluded
  // columns below them, and refused the part's own grasps (kPoints; traced
  // in docs/tuning.md, "Own points"). The part's surface is checked as a
  // mesh already (kSelf, kPart); another part's points are explained only
  // within this of the detected surface (where the two touch), and a
  // neighbour 5 mm off still blocks. The points explained so are still the
  // part as measured: each detection's are checked against its own grasps'
  // sweep lifted by contact_margin, like its mesh (kSelf; in 0.5 mm voxels,
  // no columns), since the estimated mesh may be a fraction of a degree off
  // where the view it was matched in did not reach (traced in
  // docs/tuning.md, "Own points", a tee's run_top into its own part).
  double surface_explain_distance = 0.0015;
  // m across the view (on the bin floor): a pixel of an organized frame
  // without a measurement this near a measured point no detection explains
  // makes obstacle points of its ray, from that point's depth to the
  // farthest depth measured this near (every octree_resolution / 2, inside
  // the ROI; the occluded columns below them). 0: off.
  // Why: a steep face (an undetected L-bracket leaning on a bushing, seen
  // nearly edge-on) drops out of the depth image but for a few points along
  // its top; the camera did not see the space between them, and a cup
  // beside the detected part passed through the face there (clear seed
  // 14730, docs/tuning.md "Unseen space"). A dropout ray is unseen from the
  // camera down; its nearest neighbour's depth bounds how high an unbroken
  // surface through it can rise, its farthest how low. 3 mm: two pixels at
  // 640 x 480 (the gap in 14730's face), five at 1920 x 1200.
  double dropout_reach = 0.003;
  // A dropout ray ends where it meets a detected part's surface (the
  // detections' meshes at their poses, the nearest surface along the ray),
  // before the farthest depth measured near it; a ray that starts behind
  // one is dropped. Why: the space behind a detected part, seen from the
  // camera, is that part, an obstacle already (another part's mesh, or its
  // own for the self check); ray points there, inflated to their voxels,
  // refused cups on and beside the part for nothing (docs/tuning.md
  // "Unseen space"). false: to the farthest depth (the first rule).
  bool dropout_ends_at_parts = true;
  // m (along the camera's z): a measured point no detection explains, on an
  // organized frame, is explained when its pixel's ray meets a detected
  // part's surface (its mesh at its estimated pose) more than this nearer
  // or farther than the point, and its depth is on no surface its
  // neighbours see: more than this from each measured 8-neighbour's depth
  // and from the mean of each opposite pair of them. GraspPlanningModel::
  // Build raises it to perception's support distance for the cell's
  // camera, as surface_explain_distance (the depth noise of a point on
  // a surface). 0: off.
  // Why: a pixel on a depth edge measures, at times, a depth between its
  // own surface and its neighbour's across the edge (a mixed pixel), and a
  // speckled one a depth off both: its point floats in the air in front of
  // or behind a detected part, on no surface, and its occluded column and
  // the dropout rays beside it filled the empty space below it: they
  // refused grasps on the part beside it that hit nothing on the true pile
  // (traced in docs/tuning.md, "The parts left as no_grasp:points and
  // no_grasp:bin traced"). Behind the
  // part, seen from the camera, no surface can have been seen at all (the
  // ray met the part first); in front, a real occluder is a surface, whose
  // points lie within this of a neighbour or of the mean of two opposite
  // ones (a face seen steeply): those stay.
  double mixed_on_part_rays = 0.0015;
  // On an organized frame, the space each detected part hides from the
  // camera is an obstacle for the grasps on the other parts (kHiddenSpace):
  // along the rays through the part, from where they leave its mesh at its
  // estimated pose to the bin floor or the first other detected part they
  // meet, where that stretch is long enough to hold a part (the smallest
  // side of the cell's smallest part box: 40 mm in the default cell, the
  // bushing's height and the tee's width), on rays every octree_resolution
  // / 2 across the view, inside the ROI, in octree_resolution voxels,
  // checked like the points (the sweep lifted by the cup's contact
  // margin). A ray whose pixel measured a depth more than the depth noise
  // (mixed_on_part_rays) beyond the part's far side saw through it there:
  // none. false: off.
  // Why: the camera never saw that space, and a part perception missed, or
  // the true side of a part detected in a wrong turn, may lie there. A
  // shorter stretch (a part lying on the floor or on another detected part,
  // the thin wedges beside it) cannot hold a part whose rest the camera does
  // not see; grown obstacles of that kind refused too many grasps
  // (docs/tuning.md, "Rejected: the occluded rays", "Hidden space behind
  // detected parts").
  bool hidden_behind_parts = true;
  // A detection's hidden space (hidden_behind_parts) is built only where a
  // grasp on another part that passed every other check comes near it: its
  // rays are cast when a slab box of the swept gripper meets a box holding
  // the space and its view (pixels and depths), and of its tiles of 16 x 16
  // rays only those whose rays' view meets a slab box's are voxelised (each
  // ray's points kept only where they enter another voxel); false: the
  // first form, every detection's space built whole before any candidate is
  // checked, from every ray point. The voxels a sweep can meet and so the
  // verdicts are the same either way
  // (HiddenSpace.BuiltOnDemandEachCandidateHasTheVerdictOfEverySpaceBuiltFirst).
  // Why: building every space doubled the plan (docs/tuning.md "Hidden
  // spaces built on demand").
  bool hidden_space_on_demand = true;
  // A detection whose view other poses explain as well
  // (Detection::alternatives_X_BO: a tee turned about its run, its branch
  // out of view) is an obstacle for the other parts' grasps at each of
  // those poses too (kPart), as its own grasps must land under each
  // (kAmbiguous). false: at its estimated pose alone.
  // Why: the view does not tell which pose is true, and the part is at one
  // of them; a cup beside one pose may meet the part at another where the
  // camera measured nothing (docs/tuning.md "Hidden space behind detected
  // parts").
  bool ambiguous_poses_block = true;
  // Suction cups comply with a surface up to some angle: each suction
  // candidate also gets a variant turned about its contact point toward a
  // vertical approach by min(tilt, suction_compliance_deg -
  // suction_compliance_margin_deg) (name + "~v"). The margin is left for the
  // pose error: a turn by the whole compliance is tipped past it by any
  // error of the detected pose. 5 deg is the strict pose tolerance (a
  // detection counted right may be that far off). Compliance 0, or a margin
  // at least the compliance, disables the variants.
  double suction_compliance_deg = 20.0;
  double suction_compliance_margin_deg = 5.0;
  // A candidate too steep for its "~v" turn to reach vertical (tilt above
  // the turn) also gets variants turned by the same angle about the same
  // point in other directions: the "~v" turn's axis turned about the
  // approach by each of these azimuths, deg (name + "~v+45", "~v-90" ..).
  // Vertical is not always the clear side: a part leaning by a wall gives a
  // "~v" tool whose shaft still crosses the rim, which a turn away from the
  // wall clears (measured in docs/tuning.md, "The parts left, split by
  // cause"). The judge holds each to the compliance like "~v"
  // (grasp/grasp_judge.h). Empty: "~v" alone.
  std::vector<double> suction_turn_azimuths_deg = {-90.0, -45.0, 45.0, 90.0};
  // Pose ambiguity (issue 37 item 3): on a detection with alternative poses
  // (Detection::alternatives_X_BO) a grasp is kept only when it lands on the
  // part at each of them as well: tool centre within ambiguity_max_position
  // (m) of the grasp's point on the part there, modulo symmetry, and approach
  // within the gripper's compliance (suction_compliance_deg; parallel jaws
  // ambiguity_jaw_approach_deg). The figures are the strict grasp judge's
  // (grasp/grasp_judge.h): a grasp offered must land whichever pose is true.
  // Last resort (suction only, GraspCandidate::seal_only): the cup seals
  // where it meets the part placed at each alternative, wherever on the part
  // that is: tool centre within ambiguity_max_position of the part's
  // surface, approach within suction_compliance_deg less
  // suction_compliance_margin_deg (the alternative is itself an estimate, up
  // to the strict 5 deg off) of the surface's inward normal there.
  double ambiguity_max_position = 0.002;
  double ambiguity_jaw_approach_deg = 5.0;
  // Stale neighbours (Grasp::stale_after): parts closer than touch_distance
  // (m) at their estimated poses touch; a grasp whose swept gripper passes
  // closer than approach_margin (m) to another part is stale once that part
  // is picked. 3 mm covers the detections' pose error (about 1 mm) on parts
  // resting on each other; 10 mm is the space a picked neighbour's
  // resettling parts can move into.
  double touch_distance = 0.003;
  double approach_margin = 0.010;
  // m the swept gripper keeps from the bin in the plan (the walls grown by
  // it, as Inflated grows a mesh): the walls stand where the cell or the bin
  // detection says, a measured bin is off by a few tenths of a mm
  // (docs/tuning.md, "bin_margin"), and a grasp planned to graze the
  // measured wall would hit the true one. The judge's check
  // (CheckAgainstParts) takes the exact bin.
  double bin_margin = 0.0005;
  // m the swept gripper keeps from the other detected parts in the plan
  // (their meshes grown by it, as bin_margin grows the walls): a detection
  // stands a few tenths of a mm off its part (median 0.2 mm / 0.2 deg at
  // 640 x 480, docs/perception.md), and a grasp planned to graze its
  // neighbour's estimated surface hits the true one (docs/tuning.md,
  // "part_margin"). The judge's check (CheckAgainstParts) takes the exact
  // parts.
  double part_margin = 0.0005;
  // A part whose camera-facing surface lies mostly behind measured points
  // (Detection::visible_fraction, in [0, 1], below this) is grasped only
  // when no better-seen part has a grasp (GraspCandidate::deferred): what
  // hides it is near its grasp and often no detection (an undetected
  // neighbour, or a bushing fitted into a tee's arm whose other points the
  // false fit explains away), and picking the rest first uncovers it
  // (docs/tuning.md, "defer_below_visible"). 0 disables.
  double defer_below_visible = 0.75;
};

namespace internal {
struct ContactRegion;  // grasp/internal/contact_region.h
}  // namespace internal

// A grasp of a part class in the part frame, before symmetry expansion.
struct TaughtGrasp {
  int class_id = 0;
  std::string name;
  std::string gripper;
  Pose X_OG = Pose::Identity();
  // The part surface the gripper touches (in the grasp's frame; shared by
  // the symmetric copies). Null: sampled by PlanGrasps when its rule needs it.
  std::shared_ptr<const internal::ContactRegion> contact;
};

struct GraspCandidate {
  int detection = -1;       // index into the detections
  int class_id = 0;
  std::string name;         // grasp name (+ "@<symmetry index>" when expanded)
  Pose X_OG = Pose::Identity();
  Pose X_BT = Pose::Identity();
  Pose X_BT_pre = Pose::Identity();
  double tilt_rad = 0.0;    // approach direction from straight down
  // The contact region's frame: X_BT before the suction compliance turn
  // (a turned cup still seals on the same surface), and its samples.
  Pose X_BG = Pose::Identity();
  std::shared_ptr<const internal::ContactRegion> contact;
  // The least seen share over the grasp's contacts; -1 when not checked.
  double seen_fraction = -1.0;
  std::optional<RejectReason> rejected;
  // Suction on an ambiguous detection: misses its grasp point under an
  // alternative pose, but the cup seals on the part under each. Kept only
  // when no other candidate of the plan is (else rejected as kAmbiguous).
  bool seal_only = false;
  // Its detection is mostly hidden (defer_below_visible): kept only when no
  // candidate of the plan is neither this nor seal_only (else kHidden).
  bool deferred = false;
  double score = 0.0;       // ranking score (accepted candidates)
};

struct FilterStats {
  int candidates = 0;
  int accepted = 0;
  std::array<int, kNumRejectReasons> rejected{};
  double obstacles_ms = 0.0;  // building this frame's obstacles (part scene, point OcTree)
  double neighbours_ms = 0.0; // the queued grasps' stale neighbours
  double filter_ms = 0.0;     // the whole PlanGrasps call
  // Detections whose hidden space's rays were cast (hidden_behind_parts)
  // and those that may hide one; on demand (hidden_space_on_demand), the
  // tiles of those rays whose voxels were built and those with rays.
  int hidden_spaces_built = 0;
  int hidden_spaces = 0;
  int hidden_tiles_built = 0;
  int hidden_tiles = 0;
  std::string Describe() const;  // "560 candidates, 120 accepted; tilt 200, bin 12, ..."
};

struct GraspPlan {
  PlanResult::Outcome outcome = PlanResult::Outcome::kNoObjects;
  std::vector<Grasp> queue;                 // one primary grasp per part, best first
  // The detections without a queued grasp and the detections touching each
  // (PlanResult::ungrasped_touching).
  std::map<int, std::vector<int>> ungrasped_touching;
  std::vector<GraspCandidate> candidates;   // every candidate with its verdict
  FilterStats stats;
};

// Immutable per-cell data: part, bin and swept gripper geometries, and every
// part class's cell grasps expanded over its symmetry.
class GraspPlanningModel {
 public:
  // Loads meshes (parts, grippers, bin) of `cell`. @returns the loader's
  // NotFound / Corruption naming the file, InvalidArgument for empty meshes.
  static Result<std::shared_ptr<const GraspPlanningModel>> Build(const Cell& cell,
                                                                  const GraspPlanningOptions& options = {});
  ~GraspPlanningModel();

  const Cell& cell() const;
  const GraspPlanningOptions& options() const;

  // `grasp` expanded over the part class's symmetry: X_OG' = E * R_k * X_OG
  // for E in {I} + symmetry.extra and R_k the k-th axis rotation (revolute:
  // every revolute_step_deg; discrete: order rotations; none: identity).
  std::vector<TaughtGrasp> Expand(const TaughtGrasp& grasp) const;
  // The cell's grasps of `class_id` for `gripper`, expanded.
  const std::vector<TaughtGrasp>& CellGrasps(int class_id, const std::string& gripper) const;

  // Checks one tool pose against the bin standing at X_BW and `parts`
  // (meshes at their poses; parts[target] is the part being grasped),
  // without points or task limits. Used to judge a grasp against ground
  // truth (the true bin pose). nullopt = collision-free. `with_bin` false:
  // the parts alone (which parts a grasp that also hits the bin hits).
  std::optional<RejectReason> CheckAgainstParts(const std::string& gripper, const Pose& X_BT,
                                                std::span<const Detection> parts, int target,
                                                const Pose& X_BW, bool with_bin = true) const;
  // Distance (m) from p_B to the surface of a part of `class_id` placed at
  // X_BO (0 on it; a point inside is measured to the surface too), nullopt
  // for a class the cell does not have.
  std::optional<double> SurfaceDistance(int class_id, const Pose& X_BO, const Vec3& p_B) const;

  class Impl;
  const Impl& impl() const { return *impl_; }

 private:
  explicit GraspPlanningModel(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Plans grasps for `task` from a perception result: candidates for every
// detection of the task's part classes (cell grasps plus `taught`, for the
// task's gripper), filtered, ranked by task.ranking; one primary grasp per
// part, its other collision-free grasps as related_X_B (best first), its
// stale neighbours in stale_after (any detection), the detections no grasp
// is queued for with their touching ones in ungrasped_touching.
// Outcome: kNoObjects without detections of the task's classes,
// kNoCollisionFree when there are some but no grasp survives (also when every
// grasp of an ambiguous detection is kAmbiguous), else kGrasps.
// Grasp::instance_id is the detection index.
// `frame`: the frame perception ran on. The seen-contact check reads its
// depth image when it is organized, else perception.roi_points_B (also
// without a frame): with neither, no contact region is seen.
//
// `on_head` (optional): called once, on the calling thread, with the
// queue's first grasp as soon as it has passed every check and the
// candidates ranked above the next part's primary grasp that the head's
// hand-out leaves queued have been checked (PlanHead: that grasp, or
// max_queue 1 when there is none). The other candidates are checked after
// it returns. The head is the grasp the returned queue starts with, without
// its related poses and stale neighbours; never a seal-only last resort
// (not called then, nor when nothing passes, nor when every candidate is
// checked and other parts' grasps might all be withdrawn by the head's
// hand-out: the remaining count is then unknown until the plan is done).
GraspPlan PlanGrasps(const GraspPlanningModel& model, const TaskSpec& task, const PerceptionResult& perception,
                     std::span<const TaughtGrasp> taught = {}, const Frame* frame = nullptr,
                     const HeadReady& on_head = {});

}  // namespace bp
