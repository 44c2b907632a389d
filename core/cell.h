// The cell file: one YAML document describing a picking cell. See
// assets/cells/default.yaml (the embedded default) for every key, and
// docs/cell.md for the reference.
//
// Frames: B robot base, W bin (origin at the centre of the inner floor
// surface, z up, x along the bin's length), C camera (OpenCV: z forward,
// x right, y down), F flange, T tool centre point, O part, P fixture.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/conventions.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

// Pinhole intrinsics with OpenCV's (k1, k2, p1, p2, k3) distortion.
struct Intrinsics {
  int width = 0;
  int height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::array<double, 5> distortion{};
  bool valid() const { return width > 0 && height > 0 && fx > 0 && fy > 0; }
};

// Structured-light style depth noise. sigma_z(z) = axial_sigma_base +
// axial_sigma_quadratic * z^2 (metres, z in metres). Pixels whose surface
// normal is more than grazing_start_deg from the viewing ray start to drop out,
// all drop out past grazing_full_deg. With projector_shadow, points the
// projector (at projector_offset in the camera frame) cannot see are invalid.
struct NoiseModel {
  double axial_sigma_base = 0.0001;
  double axial_sigma_quadratic = 0.0003;
  double grazing_start_deg = 72.0;
  double grazing_full_deg = 85.0;
  double random_dropout = 0.002;  // fraction of valid pixels dropped at random
  bool projector_shadow = true;
  Vec3 projector_offset = Vec3(0.08, 0.0, 0.0);
  bool enabled = true;
  // Mixed ("flying") pixels: a pixel whose clean depth differs from a
  // 4-neighbour's by more than mixed_pixel_jump (m) takes, with this
  // probability, a depth between the two (uniform). 0 = off.
  double mixed_pixels = 0.0;
  double mixed_pixel_jump = 0.01;
  // Speckle: this fraction of the valid pixels gets an extra Gaussian offset
  // of speckle_sigma (m) along the ray. 0 = off.
  double speckle = 0.0;
  double speckle_sigma = 0.004;
};

// How a synthetic pile is dropped (docs/synthetic.md, "Pile").
enum class DropStyle {
  kDefault,  // first contact, then 2 rounds of settling tilts
  kSettled,  // settling tilts until none lowers the part (8 rounds at most)
  kJumbled,  // first contact, no settling: parts lean on each other at any angle
};

// Scene variety for synthetic sources (source.variety, `--variety`;
// docs/synthetic.md, "Variety"): each scene draws from these ranges with its
// own seed. [a, b] pairs are uniform ranges.
struct VarietySpec {
  double max_tilt_deg = 15.0;   // camera turned about where it looks on the bin floor, [0, max], any azimuth
  double max_roll_deg = 180.0;  // camera rolled about its optical axis, [-max, max]
  std::array<double, 2> focal_scale{0.92, 1.08};       // fx, fy times this
  std::array<double, 2> resolution_scale{0.8, 1.25};   // width, height (and fx, fy) times this
  double principal_offset = 0.02;  // cx, cy moved by up to this fraction of the width, height
  std::array<double, 2> axial_noise_scale{0.5, 3.0};   // axial sigma (base and quadratic) times this
  std::array<double, 2> grazing_start_deg{60.0, 78.0}; // grazing dropout from here, complete 12 deg later
  std::array<double, 2> mixed_pixels{0.0, 0.6};        // NoiseModel::mixed_pixels
  std::array<double, 2> speckle{0.0, 0.004};           // NoiseModel::speckle
  std::vector<DropStyle> drop_styles{DropStyle::kSettled, DropStyle::kJumbled};  // one per scene, uniform
};

// A named camera configuration that RC_SWITCH_CONFIG selects by id.
struct CameraConfig {
  int id = 1;
  std::string name;
  Intrinsics intrinsics;
  NoiseModel noise;
  double min_depth = 0.2;  // metres; nearer / farther measurements are invalid
  double max_depth = 3.0;
};

struct CameraSpec {
  bool eye_in_hand = false;
  Pose X_BC = Pose::Identity();   // eye-to-hand: camera in robot base
  Pose X_FC = Pose::Identity();   // eye-in-hand: camera in flange
  // Optional hand-eye calibration file, stored as a resolved absolute path.
  // When it exists at load time it must be YAML with a `pose` key (same pose
  // syntax as the cell), which overrides X_BC (eye-to-hand) or X_FC
  // (eye-in-hand); when it does not exist yet, the cell's `pose` is used.
  std::string hand_eye_file;
  // Optional 2D (plane) calibration file, resolved; written by the 2D auto
  // calibration (RC 11/12) and read at start-up by 2D tasks (twod/).
  std::string plane_calibration_file;
  std::vector<CameraConfig> configs;  // at least one
  int default_config = 1;
  const CameraConfig* FindConfig(int id) const;
};

struct SourceSpec {
  enum class Kind { kSynthetic, kFiles, kReplay };
  Kind kind = Kind::kSynthetic;
  std::string dir;              // files / replay
  int num_parts = 20;           // synthetic
  uint64_t seed = 1;            // synthetic; a seed reproduces a scene exactly
  bool simulate_picks = false;  // synthetic: a handed-out grasp removes its part
  std::vector<int> part_classes;  // synthetic: classes to draw from (empty = all)
  std::optional<VarietySpec> variety;  // synthetic: scene variety (none = the cell's camera and noise)
  // Synthetic, with simulate_picks: a picked part sits in the gripper where
  // the grasp really met it (X_TO = X_BT^-1 * X_BO, true X_BO) and then
  // slips by up to these (source.in_hand_slip; docs/synthetic.md "In hand"):
  // a translation across the tool's z, a turn about a random axis through
  // the tool centre point. 0 = no slip.
  double slip_translation = 0.0;   // m
  double slip_rotation_deg = 0.0;  // deg
  // Synthetic: every fixture stands at its taught pose moved by up to these,
  // drawn anew for each part placed (source.fixture_offset): a translation
  // in the xy plane of P and a turn about P's z.
  double fixture_offset_translation = 0.01;  // m
  double fixture_offset_rotation_deg = 5.0;  // deg
  // Synthetic: the bin stands off its nominal pose (bin.pose) by up to these,
  // drawn from the seed once per scene (source.bin_offset; docs/synthetic.md
  // "Bin offset"): a translation in the floor's xy plane (uniform in the
  // square +-bin_offset_translation), a turn about the bin's z (uniform in
  // +-bin_offset_yaw_deg) and a tilt about a random horizontal axis (uniform
  // in [0, bin_offset_tilt_deg]). All 0 = the bin where the cell says.
  double bin_offset_translation = 0.0;  // m, [0, 0.1]
  double bin_offset_yaw_deg = 0.0;      // deg, [0, 45]
  double bin_offset_tilt_deg = 0.0;     // deg, [0, 5]
};

// Bin detection (issue 41, pipeline/bin_detection.h): each capture looking
// into the bin first measures the bin's pose from the depth (its rim and
// floor matched to the bin model), and that pose drives the ROI crop, the
// floor and empty-box rules and the collision walls.
struct BinDetectSpec {
  enum class Mode {
    kOff,       // the nominal pose, always (no stage runs)
    kOn,        // the measured pose when the bin is found, else the nominal pose (logged)
    kRequired,  // a capture whose bin is not found fails (DaoAI: 9 CAPTURE_FAIL) with the reason
  };
  // Default on: a bin that sits where the cell says costs the stage's time
  // (docs/tuning.md "Bin detection") and nothing else; one that does not is
  // found.
  Mode mode = Mode::kOn;
  // Search window about the nominal pose: translation in the floor plane
  // (m) and yaw (deg). The rim fit converges from anywhere inside it.
  double search_translation = 0.05;
  double search_yaw_deg = 10.0;
  // A bin found farther than this from nominal (translation, m) or turned
  // more than warn_offset_deg is warned about (log, status page, metric).
  double warn_offset = 0.01;
  double warn_offset_deg = 2.0;
};

struct BinSpec {
  Vec3 inner_size = Vec3(0.6, 0.4, 0.25);  // x length, y width, z height (m)
  double wall_thickness = 0.01;
  Pose X_BW = Pose::Identity();            // bin frame in robot base (nominal)
  std::string mesh;  // optional; generated from the sizes when empty
  BinDetectSpec detect;
};

// Region of interest, in the bin frame: the inner box shrunk by wall_margin,
// from floor_margin above the floor up to height.
struct RoiSpec {
  double wall_margin = 0.01;
  double floor_margin = 0.002;
  double height = 0.3;
};

struct Symmetry {
  enum class Kind { kNone, kRevolute, kDiscrete };
  Kind kind = Kind::kNone;
  Vec3 axis = Vec3::UnitZ();  // in the part frame, through the part origin
  int order = 1;              // kDiscrete: rotations by 2*pi/order about axis
  // Extra discrete flips (e.g. a 180 deg turn about x for a part symmetric
  // top-to-bottom), combined with the axis symmetry.
  std::vector<Pose> extra;
};

struct GraspSpec {
  std::string name;
  std::string gripper;
  Pose X_OG = Pose::Identity();  // grasp (tool centre point) in the part frame; tool z approaches
};

// A 2D grasp (parts[].flat_2d.grasps[j]): the tool centre point at `xy` in the
// part's 2D frame, the tool turned by `angle` about the plane normal.
struct Grasp2DSpec {
  std::string name;
  std::string gripper;
  Eigen::Vector2d xy = Eigen::Vector2d::Zero();  // m
  double angle = 0.0;                            // rad
};

// How a part lies flat in a 2D task, seen from above: its outline in the part
// frame (origin on the plane, z the plane normal; counter-clockwise, m), its
// thickness above the plane, and its 2D grasps.
struct Flat2DSpec {
  std::vector<Eigen::Vector2d> outline;
  double thickness = 0.0;
  std::vector<Grasp2DSpec> grasps;
};

// parts[].perception: overrides of the values perception derives for the
// part from its mesh and the camera (docs/perception_pipeline.md, "Settings
// that scale"). Unset = derived. Metres unless named otherwise.
struct PartPerception {
  std::optional<double> ppf_step;             // PPF sampling distance, (0, 0.1]
  std::optional<double> icp_spacing;          // dense model samples, (0, 0.02]
  std::optional<double> verify_spacing;       // verification samples, (0, 0.05]
  std::optional<double> support_distance;     // (0, 0.05]
  std::optional<double> free_space_distance;  // (0, 0.1]
  std::optional<double> min_score;            // estimator's bar, [0, 1]
  std::optional<double> flat_height;          // lowest upward face lying flat (floor band), (0, 1]
  std::optional<int> min_view_points;         // grid points a view of it needs, >= 10
};

struct PartSpec {
  int class_id = 0;
  std::string name;
  std::string mesh;  // resolved to an absolute path by the loader
  Symmetry symmetry;
  std::vector<GraspSpec> grasps;
  std::optional<Flat2DSpec> flat_2d;  // parts[].flat_2d: the part in 2D tasks
  // parts[].optional: binpickd starts without this class when its model
  // cannot be built (logged); without it, it refuses to start.
  bool optional = false;
  PartPerception perception;
};

// When a grasp needs its contact region shown by the frame's depth
// (grippers[].seen_contact, docs/cell.md): the model surface under the
// suction cup's footprint disk, or under each parallel-jaw finger pad, is
// sampled; a sample is seen when a measured point of the frame's ROI lies
// within max_distance of it; the grasp passes when at least min_fraction of
// the samples are seen (per finger for a jaw). A grasp on a surface the
// camera never saw (a hidden face of a well-fitting but wrongly turned
// pose) would put the tool in air or on another part.
struct SeenContactRule {
  enum class When {
    kOff,          // never checked
    kAlways,       // every grasp
    kIfAmbiguous,  // only grasps on detections whose pose is ambiguous (Detection::pose_ambiguous())
  };
  When when = When::kAlways;
  double max_distance = 0.003;  // m, measured point to contact sample
  double min_fraction = 0.6;    // share of the samples seen, in (0, 1]
  // Suction: radius of the footprint disk (m) in the tool's xy plane at the
  // tool centre point; 0 = the gripper mesh's largest radius at z = 0.
  double radius = 0.0;
  // Parallel jaw: each finger pad is pad_width (m, along the tool's y) by
  // pad_depth (m, along z up from the finger tips, the mesh's largest z).
  double pad_width = 0.02;
  double pad_depth = 0.015;
};

// A fixture parts are placed on (fixtures[i]): found by place and
// place_area tasks with the same pose estimation as the parts. Frame P: the
// mesh's frame, z = 0 on the surface it stands on, z up.
struct FixtureSpec {
  int class_id = 0;  // perception class, distinct from every part's
  std::string name;
  std::string mesh;  // resolved to an absolute path by the loader
  Pose X_BP_taught = Pose::Identity();  // where it stood when the place was taught (taught_pose)
  Pose X_PO = Pose::Identity();         // a placed part in P (part_pose)
};

struct GripperSpec {
  enum class Kind { kSuction, kParallelJaw };
  std::string name;
  Kind kind = Kind::kSuction;
  std::string mesh;                // collision / render mesh in the tool frame T
  Pose X_FT = Pose::Identity();    // tool centre point in flange
  double approach_distance = 0.1;  // pre-grasp offset along -z of the tool (m)
  double opening = 0.0;            // parallel jaw: max opening (m)
  // Top view of the gripper in the tool frame (x, y in m) for 2D collision
  // checks (grippers[].footprint); empty = no 2D footprint.
  std::vector<Eigen::Vector2d> footprint;
  // Default: kAlways for suction, kIfAmbiguous for parallel jaws (their
  // fingers close on faces parallel to the approach, which a camera looking
  // along it rarely sees).
  SeenContactRule seen_contact;
};

// The empty-box rule of a task (RC_CHECK_EMPTY_BOX, grasp/empty_box.h).
// threshold_points is stated at a reference resolution and scaled by the
// pixel count of the image it is applied to (EffectiveThreshold): the same
// field of view at a quarter of the pixels shows a quarter of the points.
// The defaults are the seed's: "ROI区域<2000个点" for the vendor's 1920 x 1200
// camera (docs/protocols.md "Empty box").
struct EmptyBoxRule {
  enum class Mode { kLargestRegion, kTotal };
  int threshold_points = 2000;
  Mode mode = Mode::kLargestRegion;
  int reference_width = 1920;   // pixels
  int reference_height = 1200;  // pixels
};
// threshold_points scaled to an image of `image_pixels` pixels (rounded to
// the nearest point); `image_pixels` 0 (unknown): threshold_points as stated.
int64_t EffectiveThreshold(const EmptyBoxRule& rule, int64_t image_pixels);

// Weights of the grasp ranking score (docs/cell.md, tasks[].ranking): score =
// height * (z of the grasp above the bin floor, m / bin height)
// + detection * (detection score, 0..1) - tilt * (approach tilt / max_tilt).
struct GraspRanking {
  double height = 1.0;
  double detection = 0.5;
  double tilt = 0.2;
};

// Task kinds (docs/protocols.md "Task kinds"):
//   pick       the bin's grasps (seed 000 "抓取通信示例");
//   place      seed 000 "抓取并请求放置": the drop-off tool pose binpick
//              computes from the fixture it finds (answered DROP_OFF_POSE, 6);
//   in_hand    seed 003 stage 2: the part held by the gripper, in the tool frame;
//   place_area seed 003 stage 3: the fixture's offset from its taught pose;
//   precision  the precision check's target; pick_2d  2D picks.
// What binpick does after a robot reports a failed pick (docs/protocols.md
// "Failed-pick feedback", command 60). A failed spot is the part's position
// in the bin frame W and its class; it is remembered for `captures` captures
// of the task after its last failure, across re-captures.
struct FailedPickRule {
  // m: grasps on parts whose origin lies within this of a failed spot (the
  // part itself and its near neighbours) are withdrawn while anything else
  // can be picked. 30 mm: about half the smallest part of the default cell,
  // wider than a detection's position error (5 mm) plus a slip.
  double radius = 0.03;
  // N >= 1: captures of the task a spot is remembered for after its last failure.
  int captures = 3;
  // K >= 1: failures on one spot (same class within `radius`) after which
  // binpick no longer sends the robot there: its grasps are refused even when
  // nothing else is left (the pick is answered NO_COLLISION_FREE_POSE).
  int max_failures = 3;
};

struct TaskSpec {
  enum class Kind { kPick, kPlace, kInHand, kPlaceArea, kPrecision, kPick2D };
  int id = 0;
  Kind kind = Kind::kPick;
  std::string name;
  std::vector<int> part_classes;  // empty = all parts
  std::string gripper;
  EmptyBoxRule empty_box;
  double max_tilt_deg = 45.0;
  GraspRanking ranking;
  // place, place_area: the fixture looked for (fixtures[].name).
  std::string fixture;
  // pick: the fixture (fixtures[].name) every part this task picks is placed
  // on at its part_pose, seed 003's pick -> correct in hand -> place. Its
  // grasps are then only those whose place pose, with the fixture at its
  // taught pose, keeps the flange inside robot.workspace at the place and at
  // its approach (grasp_planning.h, RejectReason::kUnplaceable). Empty: any.
  std::string place_on;
  // in_hand, place, place_area: where perception looks instead of the bin,
  // a box in the task's frame: in_hand the tool frame T at the robot's pose,
  // place and place_area the fixture's taught frame P. Its z = 0 plane is
  // the surface the object rests on (the suction cup's lip, the table).
  // Empty for the other kinds (they look into the bin's roi).
  Eigen::AlignedBox3d roi;
  // pick tasks: failed-pick feedback (tasks[].failed_picks).
  FailedPickRule failed_picks;
};
// True for the kinds that look at a fixture / at the gripper.
inline bool LooksAtFixture(const TaskSpec& t) {
  return t.kind == TaskSpec::Kind::kPlace || t.kind == TaskSpec::Kind::kPlaceArea;
}

// Where the DaoAI fields live in a robot's Modbus holding registers
// (docs/protocols.md "Modbus TCP"). Default: seed 000's UR map.
struct ModbusRegisterMap {
  int request_base = 128;   // 12 request fields, one int16 register each
  int request_flag = 144;   // robot sets 1 when a request is complete
  int response_base = 129;  // 16 response fields
  int response_flag = 145;  // binpick sets 1 when a response is complete
};
// @returns InvalidArgument naming the problem: registers outside 0..65535,
// a flag inside the block it signals (or the two flags equal), a response
// flag inside the request block, a request flag inside the response block
// while request_base + 11 is on a response field other than payload_3..6
// (no register for the handshake's marker), or a map not within 125
// consecutive registers (one read must see it all).
Status ValidateModbusRegisterMap(const ModbusRegisterMap& map);

// Which seed's rules a DaoAI robot program follows (robot.dialect,
// docs/protocols.md "Dialects"): which commands are answered and what status
// 4 means. Chosen by the cell, never by a request's meta_2 (the seeds' own
// programs send meta_2 = 1 whichever rules they follow).
enum class DaoaiDialect {
  kVisionPilot,  // seed 000 / 003 (UR socket and Modbus scripts): 2 and 10 unanswered, 4 = NO_COLLISION_FREE_POSE
  kSocketV1,     // seed 004 (socket v1): 2 answered -1, 10 answered 12/13/32, 4 = NO_IMAGE_CAPTURED
};
std::string_view ToString(DaoaiDialect dialect);  // "vision_pilot", "socket_v1"
std::optional<DaoaiDialect> ParseDaoaiDialect(std::string_view name);

struct RobotSpec {
  RobotModel model;                 // from robot.type
  DaoaiDialect dialect = DaoaiDialect::kVisionPilot;
  // meta_2 of an answer to a request whose own meta_2 is not 1 or 2 (every
  // other answer echoes the request's meta_2).
  int protocol_version = 2;
  double position_scale = 1.0;      // wire position unit in metres (1.0 = metres, 0.001 = mm)
  std::string modbus_host;          // empty: no Modbus master
  int modbus_port = 502;
  int modbus_unit_id = 1;
  ModbusRegisterMap modbus_map;
  int modbus_poll_ms = 2;           // request flag poll interval
  // Box in base the flange must stay inside at every pose binpick sends the
  // robot to (robot.workspace; default: unbounded).
  Eigen::AlignedBox3d workspace{Vec3::Constant(-1e9), Vec3::Constant(1e9)};
};

// OK when the flange at X_BF lies inside robot.workspace; else
// OutOfRange naming the flange position and the first limit it breaks, e.g.
// "flange at (0.120, -0.060, -0.300) m is outside robot.workspace: z -0.300 < min -0.200".
Status CheckWorkspace(const RobotSpec& robot, const Pose& X_BF);

struct Endpoints {
  std::string bind = "127.0.0.1";
  int daoai_port = 6969;
  int gri_port = 10000;
  int gri_official_port = 7100;
  int http_port = 0;
  // Limits and allowlist of the robot listeners (DaoAI, GRI), docs/cell.md
  // "endpoints" and docs/reliability.md. 0: unlimited; empty: any peer.
  int max_connections = 64;
  // Connections one peer address may hold at once per listener, so one host
  // cannot take every slot (issue 39). 0: unlimited.
  int max_connections_per_peer = 16;
  // Requests per second per connection (one second of burst); above it the
  // connection is read no faster (TCP back-pressure, nothing dropped). On by
  // default: no robot sends 1000 requests/s, a flooding one costs the
  // network thread and the cores the detections need (docs/reliability.md
  // "Capture flood and soak"). 0: unlimited.
  double max_message_rate = 1000;
  // Addresses or ADDR/PREFIX networks (core/address_list.h).
  std::vector<std::string> allowlist;  // robots that may connect
  // Robots that may change the cell: calibration (DaoAI 1-12, GRI HEC),
  // teach (30), camera config (69). Empty: every robot that may connect.
  std::vector<std::string> config_allowlist;
  // The status page / metrics HTTP listener (web/status_server.h): its own
  // allowlist (operator PCs, the metrics scraper; not the robots') and
  // connection limit. Empty: any peer; 0: unlimited.
  std::vector<std::string> http_allowlist;
  int http_max_connections = 16;
};

// The hand-eye calibration target and its simulator (docs/cell.md,
// `calibration`). The solver sees only images and robot poses: true_pose and
// target_pose are read by the simulated camera alone.
struct CalibrationSpec {
  // Checkerboard: inner corners per row (cols) and per column (rows), square
  // edge in metres. Board frame T: origin at the first inner corner, x along
  // a row, y down the columns, z into the board (OpenCV).
  int cols = 9;
  int rows = 6;
  double square_size = 0.02;
  // Simulator: the true hand-eye transform (X_BC eye-to-hand, X_FC
  // eye-in-hand; default: the cell's nominal camera.pose) and the board
  // (X_FT on the flange eye-to-hand, X_BT fixed in the base eye-in-hand).
  Pose true_pose = Pose::Identity();
  Pose target_pose = Pose::Identity();
  double image_noise = 2.0;  // grey-level sigma of the gaussian image noise
  double blur_sigma = 0.8;   // pixels
  uint64_t seed = 1;         // image noise seed (each view draws the next numbers)
  // Solver: poses a solve needs (>= 3) and poses an auto calibration plans (<= 15).
  int min_poses = 6;
  int auto_poses = 12;
  // Precision check (RC 50): a board of the same kind fixed in the base at
  // X_BP, in view of the camera at the check's robot pose.
  Pose precision_target = Pose::Identity();
};

// Recording of captures and answers (record/recorder.h, docs/file_formats.md
// "Recordings"). On by default.
struct RecordingSpec {
  bool enabled = true;
  // Root of the session directories. Empty: "binpick_recordings" in the
  // server's working directory. A relative path resolves against the cell file.
  std::string directory;
  int64_t max_disk_mb = 1024;  // cap on everything under `directory`
  int queue_captures = 8;      // captures waiting for the writer before new ones are dropped
};

struct Cell {
  std::string path;       // file it was loaded from ("<embedded default>" if none)
  std::string base_dir;   // relative paths in the file resolve against this
  std::string name;
  CameraSpec camera;
  SourceSpec source;
  BinSpec bin;
  RoiSpec roi;
  std::vector<PartSpec> parts;
  std::vector<GripperSpec> grippers;
  std::vector<TaskSpec> tasks;
  std::vector<FixtureSpec> fixtures;
  RobotSpec robot;
  Endpoints endpoints;
  // Present with a `calibration` section; then camera.hand_eye_file defaults
  // to "<cell file>.calibration.yaml" (none for the embedded default cell).
  std::optional<CalibrationSpec> calibration;
  RecordingSpec recording;
  // The YAML text the cell was parsed from (recordings hash and keep it).
  std::string yaml_text;

  const PartSpec* FindPart(int class_id) const;
  const GripperSpec* FindGripper(const std::string& name) const;
  const TaskSpec* FindTask(int id) const;
  const FixtureSpec* FindFixture(const std::string& name) const;
  const FixtureSpec* FindFixture(int class_id) const;
};

// Loads and validates a cell file. Every error names the file, the line, the
// key path (e.g. "parts[1].symmetry.order") and the reason, as
// "<file>:<line>: <key path>: <reason>"; nothing is half-loaded.
// @returns NotFound for a missing cell, mesh or hand-eye file, Corruption for
// a YAML syntax error, InvalidArgument for everything else. Mesh files are
// only checked to exist (LoadMesh parses them); their paths are made absolute.
Result<Cell> LoadCell(const std::string& path);
// Parses YAML text; `path` is used for messages and to resolve relative paths.
Result<Cell> ParseCell(const std::string& yaml_text, const std::string& path);
// The embedded default cell (assets/cells/default.yaml, compiled in; its
// relative paths resolve against AssetsDir()/cells, as they would for the file on disk).
Result<Cell> LoadDefaultCell();
// LoadCell(path) if path is non-empty, else LoadDefaultCell().
Result<Cell> LoadCellOrDefault(const std::string& path);

// A short multi-line human summary (camera, source, bin, parts, grippers,
// tasks, robot, endpoints), for the CLI and logs.
std::string Describe(const Cell& cell);

// Directory holding the shipped assets (compile-time default, overridable by
// the BINPICK_ASSETS environment variable).
std::string AssetsDir();

}  // namespace bp
