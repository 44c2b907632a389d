#include "core/cell.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "tests/testing/files.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::Not;

// A valid cell exercising every section; the table-driven tests below mutate
// one line of it at a time.
constexpr const char* kBaseCell = R"(name: test_cell
camera:
  mount: eye_to_hand
  pose: {xyz: [0.5, 0.0, 1.0], rpy_deg: [180, 0, 0]}
  default_config: 1
  configs:
    - id: 1
      name: vga
      resolution: [640, 480]
      intrinsics: {fx: 600.0, fy: 610.0, cx: 319.5, cy: 239.5}
      depth_range: [0.3, 2.0]
      noise: {axial_sigma_base: 0.0002, random_dropout: 0.0}
    - id: 2
      name: hd
      resolution: [1280, 720]
      intrinsics: {fx: 900.0, fy: 900.0, cx: 639.5, cy: 359.5, distortion: [0.1, -0.01, 0, 0, 0.001]}
source:
  kind: synthetic
  num_parts: 10
  seed: 7
bin:
  inner_size: [0.5, 0.4, 0.2]
  wall_thickness: 0.01
  pose: {xyz: [0.5, 0.0, 0.0]}
roi:
  wall_margin: 0.01
  floor_margin: 0.002
  height: 0.25
parts:
  - class_id: 0
    name: bushing
    mesh: meshes/bushing.ply
    symmetry: {type: revolute, axis: [0, 0, 2]}
    grasps:
      - {name: top, gripper: suction, pose: {xyz: [0, 0, 0.04], rpy_deg: [180, 0, 0]}}
  - class_id: 1
    name: tee
    mesh: meshes/tee.ply
    symmetry: {type: discrete, axis: [0, 0, 1], order: 2}
grippers:
  - name: suction
    kind: suction
    mesh: meshes/cup.ply
    tcp: {xyz: [0, 0, 0.2]}
    approach_distance: 0.08
tasks:
  - {id: 0, name: pick, kind: pick, gripper: suction}
  - {id: 1, name: bushings, kind: pick, gripper: suction, parts: [0], empty_box: {threshold_points: 100, mode: total}}
robot:
  type: ur
  protocol_version: 2
endpoints:
  daoai_port: 6969
  gri_port: 10000
)";

void Touch(const fs::path& p) {
  fs::create_directories(p.parent_path());
  std::ofstream(p) << "";
}

void WriteText(const fs::path& p, const std::string& text) {
  fs::create_directories(p.parent_path());
  std::ofstream(p) << text;
}

// Replaces the single occurrence of `from` in `text`.
std::string Mutate(std::string text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << "'" << from << "' not in the base cell";
  EXPECT_EQ(text.find(from, at + 1), std::string::npos) << "'" << from << "' is ambiguous";
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

// A temp dir holding the base cell's meshes; writes cell files into it.
class CellFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    for (const char* m : {"meshes/bushing.ply", "meshes/tee.ply", "meshes/cup.ply"}) Touch(tmp_ / m);
  }
  std::string Write(const std::string& text, const std::string& name = "cell.yaml") {
    const fs::path p = tmp_ / name;
    WriteText(p, text);
    return p.string();
  }
  Result<Cell> Load(const std::string& text) { return LoadCell(Write(text)); }

  const fs::path tmp_ = testing::FreshDir("cell");  // kept after a failure (tests/testing/files.h)
};

// Sets an environment variable for the lifetime of the object.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const std::string& value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old;
    ::setenv(name, value.c_str(), 1);
  }
  ~ScopedEnv() {
    if (old_) ::setenv(name_, old_->c_str(), 1);
    else ::unsetenv(name_);
  }

 private:
  const char* name_;
  std::optional<std::string> old_;
};

bool Near(const Pose& a, const Pose& b, double tol = 1e-9) { return a.isApprox(b, tol) || (a.matrix() - b.matrix()).cwiseAbs().maxCoeff() < tol; }

TEST_F(CellFileTest, BaseCellLoadsWithEveryValue) {
  const std::string path = Write(kBaseCell);
  Result<Cell> cell = LoadCell(path);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->name, "test_cell");
  EXPECT_EQ(cell->path, path);
  EXPECT_EQ(fs::path(cell->base_dir), fs::absolute(tmp_).lexically_normal());

  const CameraSpec& cam = cell->camera;
  EXPECT_FALSE(cam.eye_in_hand);
  EXPECT_TRUE(cam.X_BC.translation().isApprox(Vec3(0.5, 0.0, 1.0)));
  EXPECT_TRUE(cam.X_BC.linear().isApprox(Vec3(1, -1, -1).asDiagonal().toDenseMatrix(), 1e-12));
  EXPECT_TRUE(Near(cam.X_FC, Pose::Identity()));
  ASSERT_EQ(cam.configs.size(), 2u);
  EXPECT_EQ(cam.default_config, 1);
  const CameraConfig* vga = cam.FindConfig(1);
  ASSERT_NE(vga, nullptr);
  EXPECT_EQ(vga->name, "vga");
  EXPECT_EQ(vga->intrinsics.width, 640);
  EXPECT_EQ(vga->intrinsics.height, 480);
  EXPECT_DOUBLE_EQ(vga->intrinsics.fy, 610.0);
  EXPECT_DOUBLE_EQ(vga->min_depth, 0.3);
  EXPECT_DOUBLE_EQ(vga->max_depth, 2.0);
  EXPECT_DOUBLE_EQ(vga->noise.axial_sigma_base, 0.0002);
  EXPECT_DOUBLE_EQ(vga->noise.random_dropout, 0.0);
  EXPECT_DOUBLE_EQ(vga->noise.grazing_full_deg, NoiseModel().grazing_full_deg);  // default kept
  const CameraConfig* hd = cam.FindConfig(2);
  ASSERT_NE(hd, nullptr);
  EXPECT_DOUBLE_EQ(hd->intrinsics.distortion[1], -0.01);
  EXPECT_DOUBLE_EQ(hd->intrinsics.distortion[4], 0.001);
  EXPECT_EQ(cam.FindConfig(3), nullptr);

  EXPECT_EQ(cell->source.kind, SourceSpec::Kind::kSynthetic);
  EXPECT_EQ(cell->source.num_parts, 10);
  EXPECT_EQ(cell->source.seed, 7u);
  EXPECT_TRUE(cell->bin.inner_size.isApprox(Vec3(0.5, 0.4, 0.2)));
  EXPECT_TRUE(cell->bin.X_BW.translation().isApprox(Vec3(0.5, 0, 0)));
  EXPECT_DOUBLE_EQ(cell->roi.height, 0.25);

  ASSERT_EQ(cell->parts.size(), 2u);
  const PartSpec* bushing = cell->FindPart(0);
  ASSERT_NE(bushing, nullptr);
  EXPECT_EQ(bushing->symmetry.kind, Symmetry::Kind::kRevolute);
  EXPECT_TRUE(bushing->symmetry.axis.isApprox(Vec3::UnitZ())) << "axis is normalised";
  ASSERT_EQ(bushing->grasps.size(), 1u);
  EXPECT_EQ(bushing->grasps[0].gripper, "suction");
  EXPECT_TRUE(bushing->grasps[0].X_OG.translation().isApprox(Vec3(0, 0, 0.04)));
  EXPECT_EQ(cell->FindPart(1)->symmetry.order, 2);
  EXPECT_EQ(cell->FindPart(5), nullptr);

  const GripperSpec* suction = cell->FindGripper("suction");
  ASSERT_NE(suction, nullptr);
  EXPECT_DOUBLE_EQ(suction->approach_distance, 0.08);
  EXPECT_TRUE(suction->X_FT.translation().isApprox(Vec3(0, 0, 0.2)));
  EXPECT_EQ(cell->FindGripper("jaw"), nullptr);

  ASSERT_EQ(cell->tasks.size(), 2u);
  const TaskSpec* t1 = cell->FindTask(1);
  ASSERT_NE(t1, nullptr);
  EXPECT_EQ(t1->part_classes, std::vector<int>{0});
  EXPECT_EQ(t1->empty_box.mode, EmptyBoxRule::Mode::kTotal);
  EXPECT_EQ(t1->empty_box.threshold_points, 100);
  EXPECT_EQ(cell->FindTask(9), nullptr);

  EXPECT_EQ(cell->robot.model.name, "ur");
  EXPECT_EQ(cell->robot.model.type, RobotType::kUR);
  EXPECT_EQ(cell->endpoints.daoai_port, 6969);
  EXPECT_EQ(cell->endpoints.gri_official_port, 7100);  // default
}

TEST_F(CellFileTest, RelativeMeshPathsResolveAgainstTheCellFilesDirectory) {
  Result<Cell> cell = Load(kBaseCell);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  const fs::path dir = fs::absolute(tmp_).lexically_normal();
  EXPECT_EQ(cell->FindPart(0)->mesh, (dir / "meshes/bushing.ply").string());
  EXPECT_EQ(cell->FindPart(1)->mesh, (dir / "meshes/tee.ply").string());
  EXPECT_EQ(cell->FindGripper("suction")->mesh, (dir / "meshes/cup.ply").string());
  EXPECT_TRUE(fs::path(cell->FindPart(0)->mesh).is_absolute());
}

TEST_F(CellFileTest, CellInASubdirectoryResolvesMeshesFromThatSubdirectory) {
  Touch(tmp_ / "sub/meshes/x.ply");
  std::string text = Mutate(kBaseCell, "mesh: meshes/tee.ply", "mesh: ../meshes/tee.ply");
  text = Mutate(text, "mesh: meshes/cup.ply", "mesh: ../meshes/cup.ply");
  Result<Cell> cell = LoadCell(Write(Mutate(text, "mesh: meshes/bushing.ply", "mesh: meshes/x.ply"), "sub/c.yaml"));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->FindPart(0)->mesh, (fs::absolute(tmp_).lexically_normal() / "sub/meshes/x.ply").string());
  EXPECT_EQ(cell->FindPart(1)->mesh, (fs::absolute(tmp_).lexically_normal() / "meshes/tee.ply").string());
}

TEST_F(CellFileTest, AbsoluteMeshPathIsKept) {
  const fs::path abs = fs::absolute(tmp_ / "meshes/tee.ply");
  Result<Cell> cell = Load(Mutate(kBaseCell, "mesh: meshes/tee.ply", "mesh: " + abs.string()));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->FindPart(1)->mesh, abs.lexically_normal().string());
}

struct BadCase {
  const char* label;
  std::string from, to;
  std::string key_path;  // must appear in the message
  std::string reason;    // must appear in the message
  Status::Code code = Status::Code::kInvalidArgument;
};

std::vector<BadCase> BadCases() {
  using C = Status::Code;
  return {
      {"unknown_top_level_key", "name: test_cell", "nmae: test_cell", "nmae", "unknown key 'nmae' (did you mean 'name'?)"},
      {"unknown_section_key", "    approach_distance: 0.08", "    aproach_distance: 0.08",
       "grippers[0].aproach_distance", "unknown key"},
      {"unknown_pose_key", "pose: {xyz: [0, 0, 0.04], rpy_deg: [180, 0, 0]}", "pose: {xyz: [0, 0, 0.04], rpy: [180, 0, 0]}",
       "parts[0].grasps[0].pose.rpy", "unknown key"},
      {"unknown_noise_key", "random_dropout: 0.0}", "random_droput: 0.0}", "camera.configs[0].noise.random_droput",
       "unknown key"},
      {"duplicate_key", "  seed: 7", "  seed: 7\n  seed: 8", "source.seed", "duplicate key"},
      {"missing_required_key", "  type: ur\n", "", "robot.type", "missing required key"},
      {"missing_section", "robot:\n  type: ur\n  protocol_version: 2\n", "", "robot", "missing required key"},
      {"wrong_type_number", "  num_parts: 10", "  num_parts: ten", "source.num_parts", "expected an integer"},
      {"wrong_type_fraction", "  num_parts: 10", "  num_parts: 1.5", "source.num_parts", "expected an integer"},
      {"wrong_type_map", "tcp: {xyz: [0, 0, 0.2]}", "tcp: [0, 0, 0.2]", "grippers[0].tcp", "expected a map"},
      {"wrong_type_list", "inner_size: [0.5, 0.4, 0.2]", "inner_size: 0.5", "bin.inner_size", "expected a list of 3"},
      {"wrong_type_bool", "  seed: 7", "  seed: 7\n  simulate_picks: maybe", "source.simulate_picks", "expected true or false"},
      {"xyz_wrong_length", "pose: {xyz: [0.5, 0.0, 0.0]}", "pose: {xyz: [0.5, 0.0]}", "bin.pose.xyz", "list of 3"},
      {"non_finite", "wall_thickness: 0.01", "wall_thickness: .nan", "bin.wall_thickness", "finite"},
      {"resolution_zero", "[640, 480]", "[0, 480]", "camera.configs[0].resolution[0]", "must be > 0"},
      {"resolution_negative", "[1280, 720]", "[1280, -720]", "camera.configs[1].resolution[1]", "must be > 0"},
      {"fx_non_positive", "fx: 600.0", "fx: -600.0", "camera.configs[0].intrinsics.fx", "must be > 0"},
      {"fy_zero", "fy: 610.0", "fy: 0", "camera.configs[0].intrinsics.fy", "must be > 0"},
      {"principal_point_outside", "cx: 319.5", "cx: 700", "camera.configs[0].intrinsics.cx", "principal point"},
      {"duplicate_config_id", "    - id: 2", "    - id: 1", "camera.configs[1].id", "duplicate camera config id 1"},
      {"default_config_unknown", "default_config: 1", "default_config: 5", "camera.default_config", "not among"},
      {"unknown_mount", "mount: eye_to_hand", "mount: eye_on_hand", "camera.mount", "unknown mount 'eye_on_hand'"},
      {"depth_range_inverted", "[0.3, 2.0]", "[2.0, 0.3]", "camera.configs[0].depth_range", "0 < min < max"},
      {"depth_range_zero", "[0.3, 2.0]", "[0.0, 2.0]", "camera.configs[0].depth_range", "0 < min < max"},
      {"unknown_source_kind", "kind: synthetic", "kind: synthetc", "source.kind", "unknown source kind 'synthetc'"},
      {"files_without_dir", "kind: synthetic", "kind: files", "source.dir", "missing required key"},
      {"replay_without_dir", "kind: synthetic", "kind: replay", "source.dir", "missing required key"},
      {"num_parts_negative", "num_parts: 10", "num_parts: -1", "source.num_parts", "must be in 0..500"},
      {"num_parts_absurd", "num_parts: 10", "num_parts: 501", "source.num_parts", "must be in 0..500"},
      {"source_unknown_part_class", "  seed: 7", "  seed: 7\n  part_classes: [0, 4]", "source.part_classes[1]",
       "unknown part class 4"},
      {"bin_size_zero", "inner_size: [0.5, 0.4, 0.2]", "inner_size: [0.5, 0.0, 0.2]", "bin.inner_size[1]", "must be > 0"},
      {"bin_wall_zero", "wall_thickness: 0.01", "wall_thickness: 0", "bin.wall_thickness", "must be > 0"},
      {"roi_wall_margin_empty", "wall_margin: 0.01", "wall_margin: 0.2", "roi.wall_margin", "empty region of interest"},
      {"roi_floor_margin_empty", "floor_margin: 0.002", "floor_margin: 0.3", "roi.floor_margin", "empty region of interest"},
      {"duplicate_part_class", "  - class_id: 1", "  - class_id: 0", "parts[1].class_id", "duplicate part class id 0"},
      {"mesh_missing", "meshes/tee.ply", "meshes/missing.ply", "parts[1].mesh", "missing.ply' does not exist", C::kNotFound},
      {"gripper_mesh_missing", "meshes/cup.ply", "meshes/nocup.ply", "grippers[0].mesh", "nocup.ply' does not exist",
       C::kNotFound},
      {"symmetry_type_unknown", "{type: revolute,", "{type: spherical,", "parts[0].symmetry.type",
       "unknown symmetry type 'spherical'"},
      {"symmetry_order_too_small", "order: 2}", "order: 1}", "parts[1].symmetry.order", "order >= 2"},
      {"symmetry_axis_zero", "axis: [0, 0, 2]", "axis: [0, 0, 0]", "parts[0].symmetry.axis", "non-zero"},
      {"grasp_unknown_gripper", "{name: top, gripper: suction", "{name: top, gripper: vacuum",
       "parts[0].grasps[0].gripper", "unknown gripper 'vacuum'"},
      {"gripper_kind_unknown", "    kind: suction", "    kind: magnet", "grippers[0].kind", "unknown gripper kind 'magnet'"},
      {"approach_distance_zero", "approach_distance: 0.08", "approach_distance: 0", "grippers[0].approach_distance",
       "must be > 0"},
      {"parallel_jaw_without_opening", "    kind: suction", "    kind: parallel_jaw", "grippers[0].opening",
       "opening > 0"},
      {"seen_contact_rule_unknown", "    approach_distance: 0.08", "    approach_distance: 0.08\n    seen_contact: {rule: sometimes}",
       "grippers[0].seen_contact.rule", "unknown seen_contact rule 'sometimes'"},
      {"seen_contact_unknown_key", "    approach_distance: 0.08", "    approach_distance: 0.08\n    seen_contact: {max_dist: 0.002}",
       "grippers[0].seen_contact.max_dist", "unknown key"},
      {"seen_contact_distance_zero", "    approach_distance: 0.08",
       "    approach_distance: 0.08\n    seen_contact: {max_distance: 0}", "grippers[0].seen_contact.max_distance",
       "must be in (0, 0.05]"},
      {"seen_contact_fraction_above_one", "    approach_distance: 0.08",
       "    approach_distance: 0.08\n    seen_contact: {min_fraction: 1.5}", "grippers[0].seen_contact.min_fraction",
       "must be in (0, 1]"},
      {"seen_contact_radius_negative", "    approach_distance: 0.08",
       "    approach_distance: 0.08\n    seen_contact: {radius: -0.01}", "grippers[0].seen_contact.radius", "must be >= 0"},
      {"seen_contact_pad_zero", "    approach_distance: 0.08",
       "    approach_distance: 0.08\n    seen_contact: {pad_width: 0}", "grippers[0].seen_contact.pad_width", "must be > 0"},
      {"duplicate_task_id", "{id: 1, name: bushings", "{id: 0, name: bushings", "tasks[1].id", "duplicate task id 0"},
      {"task_unknown_part", "parts: [0]", "parts: [7]", "tasks[1].parts[0]", "unknown part class 7"},
      {"task_unknown_gripper", "name: pick, kind: pick, gripper: suction}", "name: pick, kind: pick, gripper: jaw}",
       "tasks[0].gripper", "unknown gripper 'jaw'"},
      {"task_kind_unknown", "name: pick, kind: pick,", "name: pick, kind: throw,", "tasks[0].kind",
       "unknown task kind 'throw'"},
      {"empty_box_mode_unknown", "mode: total", "mode: most", "tasks[1].empty_box.mode", "unknown empty_box mode 'most'"},
      {"empty_box_threshold_negative", "threshold_points: 100", "threshold_points: -1",
       "tasks[1].empty_box.threshold_points", "must be >= 0"},
      {"robot_type_unknown", "type: ur", "type: hal9000", "robot.type", "unknown robot type 'hal9000'"},
      {"protocol_version_3", "protocol_version: 2", "protocol_version: 3", "robot.protocol_version", "must be 1 or 2"},
      {"port_too_large", "daoai_port: 6969", "daoai_port: 70000", "endpoints.daoai_port", "outside 0..65535"},
      {"port_negative", "gri_port: 10000", "gri_port: -5", "endpoints.gri_port", "outside 0..65535"},
      {"port_reused", "gri_port: 10000", "gri_port: 6969", "endpoints.gri_port", "already used by endpoints.daoai_port"},
      {"modbus_port_invalid", "  protocol_version: 2", "  protocol_version: 2\n  modbus: {host: plc, port: 0}",
       "robot.modbus.port", "outside 1..65535"},
      {"modbus_flag_in_request", "  protocol_version: 2",
       "  protocol_version: 2\n  modbus: {host: plc, request_flag: 130}", "robot.modbus",
       "request_flag lies inside the request registers"},
      {"modbus_poll_negative", "  protocol_version: 2", "  protocol_version: 2\n  modbus: {host: plc, poll_ms: -1}",
       "robot.modbus.poll_ms", "must be in 0..1000"},
      {"quat_not_unit", "pose: {xyz: [0.5, 0.0, 1.0], rpy_deg: [180, 0, 0]}",
       "pose: {xyz: [0.5, 0.0, 1.0], quat_wxyz: [0, 2, 0, 0]}", "camera.pose.quat_wxyz", "norm 2 is not 1"},
      {"two_rotation_keys", "pose: {xyz: [0.5, 0.0, 1.0], rpy_deg: [180, 0, 0]}",
       "pose: {xyz: [0.5, 0.0, 1.0], rpy_deg: [180, 0, 0], quat_wxyz: [0, 1, 0, 0]}", "camera.pose",
       "at most one of rpy_deg, quat_wxyz, matrix"},
      {"matrix_not_orthonormal", "pose: {xyz: [0.5, 0.0, 0.0]}",
       "pose: {matrix: [[1, 0, 0, 0.5], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}", "bin.pose.matrix", "orthonormal"},
      {"matrix_reflection", "pose: {xyz: [0.5, 0.0, 0.0]}",
       "pose: {matrix: [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]}", "bin.pose.matrix", "determinant"},
      {"matrix_bad_last_row", "pose: {xyz: [0.5, 0.0, 0.0]}",
       "pose: {matrix: [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}", "bin.pose.matrix[3]",
       "last row"},
      {"workspace_inverted", "  protocol_version: 2",
       "  protocol_version: 2\n  workspace: {min: [0, 0, 0], max: [1, -1, 1]}", "robot.workspace.max",
       "must be > min on every axis"},
      {"workspace_without_max", "  protocol_version: 2", "  protocol_version: 2\n  workspace: {min: [0, 0, 0]}",
       "robot.workspace.max", "missing required key"},
      {"ranking_negative", "name: pick, kind: pick, gripper: suction}",
       "name: pick, kind: pick, gripper: suction, ranking: {tilt: -1}}", "tasks[0].ranking.tilt", "must be >= 0"},
      {"ranking_unknown_key", "name: pick, kind: pick, gripper: suction}",
       "name: pick, kind: pick, gripper: suction, ranking: {hieght: 1}}", "tasks[0].ranking.hieght", "unknown key"},
      {"variety_tilt_too_large", "  seed: 7", "  seed: 7\n  variety: {max_tilt_deg: 60}", "source.variety.max_tilt_deg",
       "must be in [0, 45]"},
      {"variety_range_inverted", "  seed: 7", "  seed: 7\n  variety: {focal_scale: [1.1, 0.9]}",
       "source.variety.focal_scale", "a <= b"},
      {"variety_drop_style_unknown", "  seed: 7", "  seed: 7\n  variety: {drop_styles: [settled, tossed]}",
       "source.variety.drop_styles[1]", "unknown drop style 'tossed'"},
      {"noise_mixed_pixels_above_one", "random_dropout: 0.0}", "random_dropout: 0.0, mixed_pixels: 2}",
       "camera.configs[0].noise.mixed_pixels", "must be in [0, 1]"},
      {"part_perception_unknown_key", "    mesh: meshes/tee.ply", "    mesh: meshes/tee.ply\n    perception: {suport_distance: 0.002}",
       "parts[1].perception.suport_distance", "unknown key"},
      {"part_perception_in_millimetres", "    mesh: meshes/tee.ply", "    mesh: meshes/tee.ply\n    perception: {support_distance: 2}",
       "parts[1].perception.support_distance", "not millimetres"},
      {"part_perception_free_space_below_support", "    mesh: meshes/tee.ply",
       "    mesh: meshes/tee.ply\n    perception: {support_distance: 0.004, free_space_distance: 0.003}",
       "parts[1].perception.free_space_distance", "larger than support_distance"},
      {"part_perception_min_view_points_small", "    mesh: meshes/tee.ply",
       "    mesh: meshes/tee.ply\n    perception: {min_view_points: 3}", "parts[1].perception.min_view_points",
       "must be >= 10"},
      {"part_optional_not_bool", "    mesh: meshes/tee.ply", "    mesh: meshes/tee.ply\n    optional: maybe",
       "parts[1].optional", "expected true or false"},
      {"yaml_syntax_error", "  kind: synthetic", "  kind: [synthetic", "cell.yaml:", "YAML syntax error", C::kCorruption},
  };
}

class CellValidationTest : public CellFileTest, public ::testing::WithParamInterface<BadCase> {};

TEST_P(CellValidationTest, RejectsWithFileKeyPathAndReason) {
  const BadCase& c = GetParam();
  const std::string path = Write(Mutate(kBaseCell, c.from, c.to));
  Result<Cell> cell = LoadCell(path);
  ASSERT_FALSE(cell.ok()) << c.label << " was accepted";
  EXPECT_EQ(cell.status().code(), c.code) << cell.status().ToString();
  EXPECT_THAT(cell.status().message(), HasSubstr(path));
  EXPECT_THAT(cell.status().message(), HasSubstr(c.key_path));
  EXPECT_THAT(cell.status().message(), HasSubstr(c.reason));
}

INSTANTIATE_TEST_SUITE_P(Mutations, CellValidationTest, ::testing::ValuesIn(BadCases()),
                         [](const ::testing::TestParamInfo<BadCase>& info) { return std::string(info.param.label); });

TEST_F(CellFileTest, WorkspaceAndRankingAreParsedAndDefaultToUnboundedAndDefaults) {
  Result<Cell> plain = LoadCell(Write(kBaseCell));
  ASSERT_TRUE(plain.ok()) << plain.status().ToString();
  EXPECT_TRUE(plain->robot.workspace.contains(Vec3(100, -100, 100)));
  EXPECT_DOUBLE_EQ(plain->tasks[0].ranking.height, 1.0);
  const std::string text = Mutate(Mutate(kBaseCell, "  protocol_version: 2",
                                         "  protocol_version: 2\n  workspace: {min: [-1, -1, 0], max: [1, 1, 1.5]}"),
                                  "name: pick, kind: pick, gripper: suction}",
                                  "name: pick, kind: pick, gripper: suction, ranking: {height: 2, detection: 0}}");
  Result<Cell> cell = LoadCell(Write(text));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_TRUE(cell->robot.workspace.contains(Vec3(0.5, 0, 1.0)));
  EXPECT_FALSE(cell->robot.workspace.contains(Vec3(0.5, 0, 1.6)));
  EXPECT_DOUBLE_EQ(cell->tasks[0].ranking.height, 2.0);
  EXPECT_DOUBLE_EQ(cell->tasks[0].ranking.detection, 0.0);
  EXPECT_DOUBLE_EQ(cell->tasks[0].ranking.tilt, 0.2);
}

// kBaseCell with a fixture and the three tasks that look elsewhere than the bin.
std::string FixtureCell() {
  std::string text = Mutate(kBaseCell, "tasks:\n", R"(fixtures:
  - {class_id: 5, name: nest, mesh: meshes/nest.ply, taught_pose: {xyz: [0.3, 0.1, 0.0], rpy_deg: [0, 0, 90]},
     part_pose: {xyz: [0, 0, 0.035]}}
tasks:
  - {id: 2, name: held, kind: in_hand, gripper: suction, roi: {min: [-0.1, -0.1, 0.002], max: [0.1, 0.1, 0.15]}}
  - {id: 3, name: area, kind: place_area, gripper: suction, fixture: nest, roi: {min: [-0.07, -0.06, 0.002], max: [0.07, 0.06, 0.05]}}
  - {id: 4, name: drop, kind: place, gripper: suction, fixture: nest, roi: {min: [-0.07, -0.06, 0.002], max: [0.07, 0.06, 0.05]}}
)");
  return Mutate(text, "  seed: 7", "  seed: 7\n  in_hand_slip: {translation: 0.01, rotation_deg: 10}");
}

TEST_F(CellFileTest, FixturesAndTheirTasksAreParsed) {
  Touch(tmp_ / "meshes/nest.ply");
  Result<Cell> cell = LoadCell(Write(FixtureCell()));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  ASSERT_EQ(cell->fixtures.size(), 1u);
  const FixtureSpec* nest = cell->FindFixture("nest");
  ASSERT_NE(nest, nullptr);
  EXPECT_EQ(cell->FindFixture(5), nest);
  EXPECT_EQ(cell->FindFixture(0), nullptr);  // a part's class
  EXPECT_EQ(nest->mesh, (tmp_ / "meshes/nest.ply").string());
  EXPECT_TRUE(nest->X_BP_taught.translation().isApprox(Vec3(0.3, 0.1, 0.0)));
  EXPECT_TRUE(nest->X_PO.translation().isApprox(Vec3(0, 0, 0.035)));
  EXPECT_EQ(cell->FindTask(2)->kind, TaskSpec::Kind::kInHand);
  EXPECT_TRUE(cell->FindTask(2)->roi.contains(Vec3(0.05, -0.05, 0.1)));
  EXPECT_FALSE(cell->FindTask(2)->roi.contains(Vec3(0, 0, 0.001)));
  EXPECT_EQ(cell->FindTask(3)->kind, TaskSpec::Kind::kPlaceArea);
  EXPECT_EQ(cell->FindTask(3)->fixture, "nest");
  EXPECT_EQ(cell->FindTask(4)->kind, TaskSpec::Kind::kPlace);
  EXPECT_TRUE(cell->FindTask(0)->roi.isEmpty());  // picks look into the bin's roi
  EXPECT_TRUE(cell->FindTask(0)->place_on.empty());
  Result<Cell> placing = LoadCell(Write(Mutate(FixtureCell(), "{id: 0, name: pick, kind: pick, gripper: suction}",
                                               "{id: 0, name: pick, kind: pick, gripper: suction, place_on: nest}")));
  ASSERT_TRUE(placing.ok()) << placing.status().ToString();
  EXPECT_EQ(placing->FindTask(0)->place_on, "nest");
  EXPECT_THAT(Describe(*placing), HasSubstr("task 0 places on nest (placeable grasps only)"));
  EXPECT_THAT(Describe(*cell), Not(HasSubstr("places on")));
  EXPECT_DOUBLE_EQ(cell->source.slip_translation, 0.01);
  EXPECT_DOUBLE_EQ(cell->source.slip_rotation_deg, 10.0);
  EXPECT_DOUBLE_EQ(cell->source.fixture_offset_translation, SourceSpec{}.fixture_offset_translation);
  EXPECT_THAT(Describe(*cell), HasSubstr("fixtures: 5=nest taught at [0.300, 0.100, 0.000]"));
}

TEST_F(CellFileTest, FixtureMistakesAreRejectedWithTheirKeyPath) {
  Touch(tmp_ / "meshes/nest.ply");
  const std::string base = FixtureCell();
  struct Case {
    const char* from;
    const char* to;
    const char* key;
    const char* reason;
  };
  const Case cases[] = {
      {"class_id: 5, name: nest", "class_id: 1, name: nest", "fixtures[0].class_id", "already a part's"},
      {"mesh: meshes/nest.ply", "mesh: meshes/none.ply", "fixtures[0].mesh", "does not exist"},
      {"kind: place_area, gripper: suction, fixture: nest", "kind: place_area, gripper: suction, fixture: tray",
       "tasks[1].fixture", "unknown fixture 'tray'"},
      {"kind: place_area, gripper: suction, fixture: nest,", "kind: place_area, gripper: suction,", "tasks[1].fixture",
       "missing required key"},
      {"kind: in_hand, gripper: suction, roi: {min: [-0.1, -0.1, 0.002], max: [0.1, 0.1, 0.15]}",
       "kind: in_hand, gripper: suction", "tasks[0].roi", "missing required key"},
      {"kind: in_hand, gripper: suction, roi: {min: [-0.1, -0.1, 0.002], max: [0.1, 0.1, 0.15]}",
       "kind: in_hand, gripper: suction, roi: {min: [-0.1, -0.1, 0.2], max: [0.1, 0.1, 0.15]}", "tasks[0].roi.max",
       "must be > min"},
      {"{id: 0, name: pick, kind: pick, gripper: suction}",
       "{id: 0, name: pick, kind: pick, gripper: suction, fixture: nest}", "tasks[3].fixture",
       "only place and place_area tasks"},
      {"{id: 0, name: pick, kind: pick, gripper: suction}",
       "{id: 0, name: pick, kind: pick, gripper: suction, roi: {min: [0, 0, 0], max: [1, 1, 1]}}", "tasks[3].roi",
       "only in_hand, place and place_area tasks"},
      {"  mount: eye_to_hand", "  mount: eye_in_hand", "tasks[0].kind", "needs an eye_to_hand camera"},
      {"{id: 0, name: pick, kind: pick, gripper: suction}",
       "{id: 0, name: pick, kind: pick, gripper: suction, place_on: tray}", "tasks[3].place_on",
       "unknown fixture 'tray'"},
      {"kind: place_area, gripper: suction, fixture: nest,", "kind: place_area, gripper: suction, fixture: nest, place_on: nest,",
       "tasks[1].place_on", "only pick tasks"},
      {"in_hand_slip: {translation: 0.01", "in_hand_slip: {translation: -0.01", "source.in_hand_slip.translation",
       "must be in [0, 0.1] m"},
  };
  for (const Case& c : cases) {
    Result<Cell> cell = LoadCell(Write(Mutate(base, c.from, c.to)));
    ASSERT_FALSE(cell.ok()) << c.key << " was accepted";
    EXPECT_THAT(cell.status().message(), HasSubstr(c.key));
    EXPECT_THAT(cell.status().message(), HasSubstr(c.reason));
  }
}

TEST(Workspace, NamesTheFlangePositionAndTheFirstLimitItBreaks) {
  RobotSpec robot;
  robot.workspace = Eigen::AlignedBox3d(Vec3(-1.3, -1.3, -0.2), Vec3(1.3, 1.3, 1.5));
  EXPECT_TRUE(CheckWorkspace(robot, MakePose(Mat3::Identity(), Vec3(0.5, -0.2, 0.3))).ok());
  EXPECT_TRUE(CheckWorkspace(robot, MakePose(Mat3::Identity(), Vec3(1.3, -1.3, -0.2))).ok());  // on the faces
  const Status below = CheckWorkspace(robot, MakePose(Mat3::Identity(), Vec3(0.12, -0.06, -0.3)));
  EXPECT_EQ(below.code(), Status::Code::kOutOfRange);
  EXPECT_EQ(below.message(), "flange at (0.120, -0.060, -0.300) m is outside robot.workspace: z -0.300 < min -0.200");
  const Status far = CheckWorkspace(robot, MakePose(Mat3::Identity(), Vec3(1.4, 0, 2)));
  EXPECT_THAT(far.message(), HasSubstr("x 1.400 > max 1.300"));
  const Status nan = CheckWorkspace(robot, MakePose(Mat3::Identity(), Vec3(NAN, 0, 0)));
  EXPECT_FALSE(nan.ok());
  EXPECT_TRUE(CheckWorkspace(RobotSpec{}, MakePose(Mat3::Identity(), Vec3(100, -100, 100))).ok());  // unbounded
}

TEST_F(CellFileTest, SourceVarietyIsParsedAndAbsentByDefault) {
  Result<Cell> plain = LoadCell(Write(kBaseCell));
  ASSERT_TRUE(plain.ok()) << plain.status().ToString();
  EXPECT_FALSE(plain->source.variety.has_value());
  Result<Cell> cell = LoadCell(Write(Mutate(
      kBaseCell, "  seed: 7", "  seed: 7\n  variety: {max_tilt_deg: 10, speckle: [0, 0.001], drop_styles: [jumbled]}")));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  ASSERT_TRUE(cell->source.variety.has_value());
  EXPECT_DOUBLE_EQ(cell->source.variety->max_tilt_deg, 10.0);
  EXPECT_DOUBLE_EQ(cell->source.variety->speckle[1], 0.001);
  EXPECT_DOUBLE_EQ(cell->source.variety->max_roll_deg, VarietySpec{}.max_roll_deg);
  ASSERT_EQ(cell->source.variety->drop_styles.size(), 1u);
  EXPECT_EQ(cell->source.variety->drop_styles[0], DropStyle::kJumbled);
}

TEST_F(CellFileTest, SeenContactDefaultsByGripperKindAndIsParsed) {
  Result<Cell> plain = LoadCell(Write(kBaseCell));
  ASSERT_TRUE(plain.ok()) << plain.status().ToString();
  const SeenContactRule& rule = plain->grippers[0].seen_contact;
  EXPECT_EQ(rule.when, SeenContactRule::When::kAlways);  // suction
  EXPECT_DOUBLE_EQ(rule.max_distance, 0.003);
  EXPECT_DOUBLE_EQ(rule.min_fraction, 0.6);
  EXPECT_DOUBLE_EQ(rule.radius, 0.0);
  const std::string jaw = Mutate(Mutate(kBaseCell, "    kind: suction", "    kind: parallel_jaw"),
                                 "    approach_distance: 0.08", "    approach_distance: 0.08\n    opening: 0.06");
  Result<Cell> jaw_cell = LoadCell(Write(jaw));
  ASSERT_TRUE(jaw_cell.ok()) << jaw_cell.status().ToString();
  EXPECT_EQ(jaw_cell->grippers[0].seen_contact.when, SeenContactRule::When::kIfAmbiguous);
  const std::string text =
      Mutate(kBaseCell, "    approach_distance: 0.08",
             "    approach_distance: 0.08\n    seen_contact: {rule: off, max_distance: 0.002, min_fraction: 0.75, "
             "radius: 0.01, pad_width: 0.03, pad_depth: 0.02}");
  Result<Cell> cell = LoadCell(Write(text));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  const SeenContactRule& r = cell->grippers[0].seen_contact;
  EXPECT_EQ(r.when, SeenContactRule::When::kOff);
  EXPECT_DOUBLE_EQ(r.max_distance, 0.002);
  EXPECT_DOUBLE_EQ(r.min_fraction, 0.75);
  EXPECT_DOUBLE_EQ(r.radius, 0.01);
  EXPECT_DOUBLE_EQ(r.pad_width, 0.03);
  EXPECT_DOUBLE_EQ(r.pad_depth, 0.02);
}

TEST_F(CellFileTest, PartPerceptionOverridesAndOptionalAreParsedAndUnsetByDefault) {
  Result<Cell> plain = LoadCell(Write(kBaseCell));
  ASSERT_TRUE(plain.ok()) << plain.status().ToString();
  EXPECT_FALSE(plain->FindPart(1)->optional);
  EXPECT_FALSE(plain->FindPart(1)->perception.support_distance.has_value());
  EXPECT_FALSE(plain->FindPart(1)->perception.min_view_points.has_value());
  Result<Cell> cell = LoadCell(Write(Mutate(kBaseCell, "    mesh: meshes/tee.ply",
                                            "    mesh: meshes/tee.ply\n    optional: true\n"
                                            "    perception: {support_distance: 0.002, min_view_points: 40, "
                                            "flat_height: 0.003, min_score: 0.5}")));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  const PartSpec& tee = *cell->FindPart(1);
  EXPECT_TRUE(tee.optional);
  EXPECT_DOUBLE_EQ(tee.perception.support_distance.value_or(0), 0.002);
  EXPECT_EQ(tee.perception.min_view_points.value_or(0), 40);
  EXPECT_DOUBLE_EQ(tee.perception.flat_height.value_or(0), 0.003);
  EXPECT_DOUBLE_EQ(tee.perception.min_score.value_or(0), 0.5);
  EXPECT_FALSE(tee.perception.ppf_step.has_value());
  EXPECT_FALSE(cell->FindPart(0)->optional);
}

TEST_F(CellFileTest, ErrorMessageStartsWithFileAndLineOfTheOffendingValue) {
  // Line 18 of the base cell is "  kind: synthetic".
  const std::string path = Write(Mutate(kBaseCell, "kind: synthetic", "kind: synthetc"));
  Result<Cell> cell = LoadCell(path);
  ASSERT_FALSE(cell.ok());
  EXPECT_EQ(cell.status().message().rfind(path + ":18: source.kind: unknown source kind", 0), 0u)
      << cell.status().message();
}

TEST_F(CellFileTest, SyntaxErrorNamesTheLine) {
  const std::string path = Write(Mutate(kBaseCell, "  seed: 7", "  seed: [7"));
  Result<Cell> cell = LoadCell(path);
  ASSERT_FALSE(cell.ok());
  EXPECT_EQ(cell.status().code(), Status::Code::kCorruption);
  EXPECT_THAT(cell.status().message(), ::testing::MatchesRegex(".*cell\\.yaml:2[0-9]:[0-9]+: YAML syntax error.*"));
}

TEST_F(CellFileTest, MissingFileIsNotFound) {
  const std::string path = (tmp_ / "nope.yaml").string();
  Result<Cell> cell = LoadCell(path);
  ASSERT_FALSE(cell.ok());
  EXPECT_EQ(cell.status().code(), Status::Code::kNotFound);
  EXPECT_THAT(cell.status().message(), HasSubstr(path));
}

TEST_F(CellFileTest, EmptyFileIsRejected) {
  Result<Cell> cell = Load("# nothing\n");
  ASSERT_FALSE(cell.ok());
  EXPECT_THAT(cell.status().message(), HasSubstr("empty"));
}

TEST_F(CellFileTest, RobotTypeAcceptsMeta1Id) {
  Result<Cell> cell = Load(Mutate(kBaseCell, "type: ur", "type: 0"));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->robot.model.type, RobotType::kABB);
  EXPECT_EQ(cell->robot.model.name, "abb");
}

TEST_F(CellFileTest, RobotTypeNameIsCaseInsensitiveAndUnknownIdsAreRejected) {
  Result<Cell> kuka = Load(Mutate(kBaseCell, "type: ur", "type: KUKA"));
  ASSERT_TRUE(kuka.ok()) << kuka.status().ToString();
  EXPECT_EQ(kuka->robot.model.type, RobotType::kKuka);
  Result<Cell> bad = Load(Mutate(kBaseCell, "type: ur", "type: 42"));
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.status().message(), HasSubstr("robot.type: unknown robot type '42'"));
}

TEST_F(CellFileTest, FilesSourceDirResolvesAgainstCellDirectory) {
  Result<Cell> cell = Load(Mutate(kBaseCell, "kind: synthetic", "kind: files\n  dir: recordings"));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->source.kind, SourceSpec::Kind::kFiles);
  EXPECT_EQ(cell->source.dir, (fs::absolute(tmp_).lexically_normal() / "recordings").string());
}

class PoseParsingTest : public CellFileTest {
 protected:
  // Parses `pose` as the bin pose of the base cell.
  Pose ParseBinPose(const std::string& pose) {
    Result<Cell> cell = Load(Mutate(kBaseCell, "pose: {xyz: [0.5, 0.0, 0.0]}", "pose: " + pose));
    EXPECT_TRUE(cell.ok()) << cell.status().ToString();
    return cell.ok() ? cell->bin.X_BW : Pose(Eigen::Matrix4d::Zero());
  }
};

TEST_F(PoseParsingTest, Roll180EqualsQuaternionAboutX) {
  const Pose a = ParseBinPose("{xyz: [1, 2, 3], rpy_deg: [180, 0, 0]}");
  const Pose b = ParseBinPose("{xyz: [1, 2, 3], quat_wxyz: [0, 1, 0, 0]}");
  EXPECT_TRUE(Near(a, b, 1e-12)) << a.matrix() << "\n" << b.matrix();
  EXPECT_TRUE(a.translation().isApprox(Vec3(1, 2, 3)));
  EXPECT_NEAR(a.linear()(1, 1), -1.0, 1e-12);
  EXPECT_NEAR(a.linear()(2, 2), -1.0, 1e-12);
}

TEST_F(PoseParsingTest, YawIsAboutZ) {
  const Pose a = ParseBinPose("{rpy_deg: [0, 0, 90]}");
  EXPECT_TRUE(a.linear().isApprox((Mat3() << 0, -1, 0, 1, 0, 0, 0, 0, 1).finished(), 1e-12)) << a.linear();
  const Pose b = ParseBinPose("{quat_wxyz: [0.70710678, 0, 0, 0.70710678]}");
  EXPECT_TRUE(Near(a, b, 1e-8));
}

TEST_F(PoseParsingTest, RpyIsFixedAxisXThenYThenZ) {
  const double r = 30 * std::numbers::pi / 180, p = 45 * std::numbers::pi / 180, y = 60 * std::numbers::pi / 180;
  const Mat3 expected = (Eigen::AngleAxisd(y, Vec3::UnitZ()) * Eigen::AngleAxisd(p, Vec3::UnitY()) *
                         Eigen::AngleAxisd(r, Vec3::UnitX()))
                            .toRotationMatrix();
  const Pose a = ParseBinPose("{rpy_deg: [30, 45, 60]}");
  EXPECT_TRUE(a.linear().isApprox(expected, 1e-12));
  const Quat q(expected);
  std::ostringstream quat;
  quat.precision(17);
  quat << "{quat_wxyz: [" << q.w() << ", " << q.x() << ", " << q.y() << ", " << q.z() << "]}";
  EXPECT_TRUE(Near(a, ParseBinPose(quat.str()), 1e-12));
  std::ostringstream m;
  m.precision(17);
  m << "{matrix: [";
  for (int i = 0; i < 3; ++i) {
    m << "[" << expected(i, 0) << ", " << expected(i, 1) << ", " << expected(i, 2) << ", " << i + 1 << "], ";
  }
  m << "[0, 0, 0, 1]]}";
  const Pose c = ParseBinPose(m.str());
  EXPECT_TRUE(c.linear().isApprox(expected, 1e-12));
  EXPECT_TRUE(c.translation().isApprox(Vec3(1, 2, 3)));
}

TEST_F(PoseParsingTest, SlightlyUnnormalisedQuaternionIsNormalised) {
  const Pose a = ParseBinPose("{quat_wxyz: [0.999, 0, 0, 0]}");
  EXPECT_TRUE(a.linear().isApprox(Mat3::Identity(), 1e-12));
}

TEST_F(PoseParsingTest, NoRotationKeyIsIdentity) {
  const Pose a = ParseBinPose("{xyz: [0.1, 0.2, 0.3]}");
  EXPECT_TRUE(a.linear().isApprox(Mat3::Identity()));
}

TEST_F(CellFileTest, HandEyeFileOverridesThePoseWhenItExists) {
  WriteText(tmp_ / "calib/hand_eye.yaml", "pose: {xyz: [0.1, 0.2, 0.9], rpy_deg: [180, 0, 90]}\nresidual_mm: 0.4\n");
  const std::string text = Mutate(kBaseCell, "  default_config: 1", "  default_config: 1\n  hand_eye_file: calib/hand_eye.yaml");
  Result<Cell> cell = Load(text);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->camera.hand_eye_file, (fs::absolute(tmp_).lexically_normal() / "calib/hand_eye.yaml").string());
  EXPECT_TRUE(cell->camera.X_BC.translation().isApprox(Vec3(0.1, 0.2, 0.9)));

  // Eye in hand: the same file gives X_FC.
  Result<Cell> in_hand = Load(Mutate(text, "mount: eye_to_hand", "mount: eye_in_hand"));
  ASSERT_TRUE(in_hand.ok()) << in_hand.status().ToString();
  EXPECT_TRUE(in_hand->camera.eye_in_hand);
  EXPECT_TRUE(in_hand->camera.X_FC.translation().isApprox(Vec3(0.1, 0.2, 0.9)));
  EXPECT_TRUE(Near(in_hand->camera.X_BC, Pose::Identity()));
}

TEST_F(CellFileTest, AbsentHandEyeFileKeepsThePoseAndStoresTheResolvedPath) {
  Result<Cell> cell = Load(Mutate(kBaseCell, "  default_config: 1", "  default_config: 1\n  hand_eye_file: calib/later.yaml"));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->camera.hand_eye_file, (fs::absolute(tmp_).lexically_normal() / "calib/later.yaml").string());
  EXPECT_TRUE(cell->camera.X_BC.translation().isApprox(Vec3(0.5, 0.0, 1.0)));
}

TEST_F(CellFileTest, MalformedHandEyeFileIsRejectedNamingIt) {
  WriteText(tmp_ / "calib/hand_eye.yaml", "pose: {xyz: [0.1, 0.2], rpy_deg: [180, 0, 90]}\n");
  Result<Cell> cell = Load(Mutate(kBaseCell, "  default_config: 1", "  default_config: 1\n  hand_eye_file: calib/hand_eye.yaml"));
  ASSERT_FALSE(cell.ok());
  EXPECT_THAT(cell.status().message(), HasSubstr("hand_eye.yaml:1: pose.xyz: expected a list of 3 numbers"));
}

// Issue 39: a corrupt hand-eye result at start-up names the backup the last
// calibration kept, so the user knows what to restore.
TEST_F(CellFileTest, CorruptHandEyeFileNamesTheBackupToRestore) {
  const std::string cell = Mutate(kBaseCell, "  default_config: 1", "  default_config: 1\n  hand_eye_file: calib/hand_eye.yaml");
  WriteText(tmp_ / "calib/hand_eye.yaml", "pose: {xyz: [0.1, 0.2, 0.9], rpy_deg: [180, 0\n");  // cut off mid-write
  Result<Cell> no_backup = Load(cell);
  ASSERT_FALSE(no_backup.ok());
  EXPECT_THAT(no_backup.status().message(), HasSubstr("YAML syntax error"));
  EXPECT_THAT(no_backup.status().message(), HasSubstr("there is no backup ('"));
  WriteText(tmp_ / "calib/hand_eye.yaml.bak", "pose: {xyz: [0.1, 0.2, 0.9], rpy_deg: [180, 0, 90]}\n");
  Result<Cell> with_backup = Load(cell);
  ASSERT_FALSE(with_backup.ok());
  const std::string bak = (fs::absolute(tmp_).lexically_normal() / "calib/hand_eye.yaml.bak").string();
  EXPECT_THAT(with_backup.status().message(), HasSubstr("the previous calibration is kept in '" + bak + "'"));
  EXPECT_THAT(with_backup.status().message(), HasSubstr("cp '" + bak + "'"));
  // A well-formed file with a bad value names it too.
  WriteText(tmp_ / "calib/hand_eye.yaml", "pose: {xyz: [0.1, 0.2], rpy_deg: [180, 0, 90]}\n");
  Result<Cell> bad_value = Load(cell);
  ASSERT_FALSE(bad_value.ok());
  EXPECT_THAT(bad_value.status().message(), HasSubstr("restore it with"));
}

TEST_F(CellFileTest, ModbusSectionReadsTheRegisterMapAndPollInterval) {
  const std::string path = Write(Mutate(kBaseCell, "  protocol_version: 2",
                                        "  protocol_version: 2\n  modbus: {host: 10.0.0.5, port: 1502, "
                                        "unit_id: 3, request_base: 1000, request_flag: 1020, "
                                        "response_base: 1030, response_flag: 1050, poll_ms: 5}"));
  Result<Cell> cell = LoadCell(path);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  const RobotSpec& r = cell->robot;
  EXPECT_EQ(r.modbus_host, "10.0.0.5");
  EXPECT_EQ(r.modbus_port, 1502);
  EXPECT_EQ(r.modbus_unit_id, 3);
  EXPECT_EQ(r.modbus_map.request_base, 1000);
  EXPECT_EQ(r.modbus_map.request_flag, 1020);
  EXPECT_EQ(r.modbus_map.response_base, 1030);
  EXPECT_EQ(r.modbus_map.response_flag, 1050);
  EXPECT_EQ(r.modbus_poll_ms, 5);
  // Absent keys: seed 000's map.
  Result<Cell> seed = LoadCell(Write(Mutate(kBaseCell, "  protocol_version: 2",
                                            "  protocol_version: 2\n  modbus: {host: plc}")));
  ASSERT_TRUE(seed.ok()) << seed.status().ToString();
  EXPECT_EQ(seed->robot.modbus_map.request_base, 128);
  EXPECT_EQ(seed->robot.modbus_map.request_flag, 144);
  EXPECT_EQ(seed->robot.modbus_map.response_base, 129);
  EXPECT_EQ(seed->robot.modbus_map.response_flag, 145);
  EXPECT_EQ(seed->robot.modbus_poll_ms, 2);
}

// Found by fuzz/modbus_registers_fuzz: request_base + 12 overflowed int for a
// base near INT_MAX (undefined behaviour; the wrapped sum passed the check).
TEST_F(CellFileTest, ModbusRegisterNearIntMaxIsRejectedWithoutOverflow) {
  for (const char* key : {"request_base", "response_base"}) {
    Result<Cell> cell = LoadCell(Write(Mutate(
        kBaseCell, "  protocol_version: 2",
        std::string("  protocol_version: 2\n  modbus: {host: plc, ") + key + ": 2147483647}")));
    ASSERT_FALSE(cell.ok()) << key;
    EXPECT_THAT(cell.status().message(), HasSubstr(std::string(key) + " out of 0..")) << key;
  }
}

TEST_F(CellFileTest, EndpointLimitsAndAllowlistAreReadAndValidated) {
  auto with = [](const std::string& lines) {
    return Mutate(kBaseCell, "  gri_port: 10000", "  gri_port: 10000\n" + lines);
  };
  Result<Cell> cell = ParseCell(with("  max_connections: 4\n  max_message_rate: 50\n"
                                     "  allowlist: [192.168.10.21, \"fd00::7\", 10.1.0.0/16]\n"
                                     "  config_allowlist: [192.168.10.21]\n  max_connections_per_peer: 2\n"
                                     "  http_allowlist: [10.1.2.3]\n  http_max_connections: 3"),
                                (tmp_ / "c.yaml").string());
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->endpoints.max_connections, 4);
  EXPECT_EQ(cell->endpoints.max_message_rate, 50);
  EXPECT_EQ(cell->endpoints.allowlist,
            (std::vector<std::string>{"192.168.10.21", "fd00::7", "10.1.0.0/16"}));
  EXPECT_EQ(cell->endpoints.config_allowlist, (std::vector<std::string>{"192.168.10.21"}));
  EXPECT_EQ(cell->endpoints.max_connections_per_peer, 2);
  EXPECT_EQ(cell->endpoints.http_allowlist, (std::vector<std::string>{"10.1.2.3"}));
  EXPECT_EQ(cell->endpoints.http_max_connections, 3);
  Result<Cell> defaults = ParseCell(kBaseCell, (tmp_ / "d.yaml").string());
  ASSERT_TRUE(defaults.ok());
  EXPECT_EQ(defaults->endpoints.max_connections, 64);
  EXPECT_EQ(defaults->endpoints.max_message_rate, 1000);
  EXPECT_TRUE(defaults->endpoints.allowlist.empty());
  EXPECT_TRUE(defaults->endpoints.config_allowlist.empty());
  EXPECT_EQ(defaults->endpoints.max_connections_per_peer, 16);
  EXPECT_TRUE(defaults->endpoints.http_allowlist.empty());
  EXPECT_EQ(defaults->endpoints.http_max_connections, 16);
  for (const auto& [yaml, error] : std::vector<std::pair<std::string, std::string>>{
           {"  allowlist: [robot-1]", "endpoints.allowlist[0]: 'robot-1' is not an IP address"},
           {"  allowlist: [10.0.0.0/40]", "endpoints.allowlist[0]: '10.0.0.0/40': the prefix length must be 0..32"},
           {"  config_allowlist: [x]", "endpoints.config_allowlist[0]: 'x' is not an IP address"},
           {"  max_connections_per_peer: -2", "endpoints.max_connections_per_peer: must be >= 0"},
           {"  allowlist: 10.0.0.1", "endpoints.allowlist: expected a list"},
           {"  max_connections: -1", "endpoints.max_connections: must be >= 0"},
           {"  max_message_rate: -5", "endpoints.max_message_rate: must be >= 0"},
           {"  http_allowlist: [10.0.0.1, 10.0.0.300]", "endpoints.http_allowlist[1]: '10.0.0.300' is not an IP address"},
           {"  http_allowlist: {a: 1}", "endpoints.http_allowlist: expected a list"},
           {"  http_allowlist: [[10.0.0.1]]", "endpoints.http_allowlist[0]"},
           {"  http_max_connections: -1", "endpoints.http_max_connections: must be >= 0"},
           {"  http_max_connections: many", "endpoints.http_max_connections"}}) {
    Result<Cell> bad = ParseCell(with(yaml), (tmp_ / "b.yaml").string());
    ASSERT_FALSE(bad.ok()) << yaml;
    EXPECT_THAT(bad.status().message(), HasSubstr(error)) << yaml;
  }
}

TEST_F(CellFileTest, ParseCellResolvesAgainstTheGivenPath) {
  Result<Cell> cell = ParseCell(kBaseCell, (tmp_ / "virtual.yaml").string());
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->FindPart(0)->mesh, (fs::absolute(tmp_).lexically_normal() / "meshes/bushing.ply").string());
}

TEST_F(CellFileTest, DescribeSummarisesTheCell) {
  Result<Cell> cell = Load(kBaseCell);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  const std::string text = Describe(*cell);
  EXPECT_THAT(text, HasSubstr("test_cell"));
  EXPECT_THAT(text, HasSubstr("1=vga 640x480 (default)"));
  EXPECT_THAT(text, HasSubstr("0=bushing (revolute, 1 grasps)"));
  EXPECT_THAT(text, HasSubstr("suction (suction)"));
  EXPECT_THAT(text, HasSubstr("robot: ur (meta_1 id 7, "));
  EXPECT_THAT(text, HasSubstr("dialect vision_pilot"));
  // Task 1: 100 points at the default reference 1920 x 1200, scaled to VGA.
  EXPECT_THAT(text, HasSubstr("task 1 empty box: < 100 points at 1920x1200, effective: 1=vga 13"));
}

// The seed's 2000 points are a 1920 x 1200 figure: the same field of view at
// another resolution shows the part with proportionally fewer points.
TEST(EmptyBoxRule, ThresholdScalesWithThePixelCountOfTheImage) {
  EmptyBoxRule r;  // 2000 at 1920 x 1200
  EXPECT_EQ(EffectiveThreshold(r, 1920 * 1200), 2000);
  EXPECT_EQ(EffectiveThreshold(r, 640 * 480), 267);  // 2000 x 307200 / 2304000 = 266.7
  EXPECT_EQ(EffectiveThreshold(r, 320 * 240), 67);
  EXPECT_EQ(EffectiveThreshold(r, 0), 2000);  // unknown image: as stated
  r.reference_width = 640;
  r.reference_height = 480;
  EXPECT_EQ(EffectiveThreshold(r, 640 * 480), 2000);
  EXPECT_EQ(EffectiveThreshold(r, 1920 * 1200), 15000);
}

TEST_F(CellFileTest, EmptyBoxReferenceResolutionIsReadAndChecked) {
  Result<Cell> cell = Load(Mutate(kBaseCell, "threshold_points: 100, mode: total",
                                  "threshold_points: 100, reference_resolution: [640, 480], mode: total"));
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->FindTask(1)->empty_box.reference_width, 640);
  EXPECT_EQ(cell->FindTask(1)->empty_box.reference_height, 480);
  Result<Cell> bad = Load(Mutate(kBaseCell, "threshold_points: 100, mode: total",
                                 "threshold_points: 100, reference_resolution: [640], mode: total"));
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.status().message(), HasSubstr("tasks[1].empty_box.reference_resolution"));
  Result<Cell> dialect = Load(Mutate(kBaseCell, "  protocol_version: 2", "  protocol_version: 2\n  dialect: socket_v1"));
  ASSERT_TRUE(dialect.ok()) << dialect.status().ToString();
  EXPECT_EQ(dialect->robot.dialect, DaoaiDialect::kSocketV1);
  Result<Cell> unknown = Load(Mutate(kBaseCell, "  protocol_version: 2", "  protocol_version: 2\n  dialect: v3"));
  ASSERT_FALSE(unknown.ok());
  EXPECT_THAT(unknown.status().message(), HasSubstr("robot.dialect"));
}

// The default cell's meshes, as empty files in a temp assets dir: the loader
// only checks that they exist.
const char* const kDefaultMeshes[] = {"parts/flanged_bushing.ply", "parts/l_bracket.ply", "parts/pipe_tee.ply",
                                      "grippers/suction_cup.ply", "grippers/parallel_jaw.ply",
                                      "fixtures/place_nest.ply"};

TEST(DefaultCell, LoadsWithItsPartsGrippersTasksAndConfigs) {
  const fs::path assets = testing::FreshDir("assets");
  for (const char* m : kDefaultMeshes) Touch(assets / m);
  ScopedEnv env("BINPICK_ASSETS", assets.string());
  EXPECT_EQ(AssetsDir(), assets.string());

  Result<Cell> cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->name, "default");
  EXPECT_EQ(cell->path, "<embedded default>");
  ASSERT_EQ(cell->parts.size(), 3u);
  EXPECT_EQ(cell->FindPart(0)->name, "flanged_bushing");
  EXPECT_EQ(cell->FindPart(1)->name, "l_bracket");
  EXPECT_EQ(cell->FindPart(2)->name, "pipe_tee");
  EXPECT_EQ(cell->FindPart(2)->symmetry.kind, Symmetry::Kind::kDiscrete);
  EXPECT_EQ(cell->FindPart(0)->mesh, (assets / "parts/flanged_bushing.ply").lexically_normal().string());
  for (const PartSpec& p : cell->parts) EXPECT_FALSE(p.grasps.empty()) << p.name;
  ASSERT_NE(cell->FindGripper("suction"), nullptr);
  ASSERT_NE(cell->FindGripper("parallel"), nullptr);
  EXPECT_EQ(cell->FindGripper("parallel")->kind, GripperSpec::Kind::kParallelJaw);
  EXPECT_NE(cell->FindTask(0), nullptr);
  EXPECT_NE(cell->FindTask(1), nullptr);
  // Seed 003's program switches to tasks 0 (pick), 1 (in hand) and 3 (place area).
  EXPECT_EQ(cell->FindTask(0)->kind, TaskSpec::Kind::kPick);
  EXPECT_EQ(cell->FindTask(1)->kind, TaskSpec::Kind::kInHand);
  EXPECT_EQ(cell->FindTask(2)->kind, TaskSpec::Kind::kPlace);
  EXPECT_EQ(cell->FindTask(3)->kind, TaskSpec::Kind::kPlaceArea);
  ASSERT_NE(cell->FindFixture(cell->FindTask(3)->fixture), nullptr);
  EXPECT_EQ(cell->FindFixture(cell->FindTask(3)->fixture)->mesh,
            (assets / "fixtures/place_nest.ply").lexically_normal().string());
  EXPECT_EQ(cell->camera.default_config, 1);
  ASSERT_NE(cell->camera.FindConfig(1), nullptr);
  ASSERT_NE(cell->camera.FindConfig(2), nullptr);
  EXPECT_EQ(cell->camera.FindConfig(2)->intrinsics.width, 1920);
  // The YAML anchor shares the noise model between configs.
  EXPECT_DOUBLE_EQ(cell->camera.FindConfig(2)->noise.grazing_full_deg, 85.0);
  EXPECT_EQ(cell->robot.model.type, RobotType::kUR);

  Result<Cell> same = LoadCellOrDefault("");
  ASSERT_TRUE(same.ok());
  EXPECT_EQ(same->parts.size(), 3u);
}

// The shipped assets/cells/default.yaml is the embedded cell, and loads from
// disk as it is, against the real shipped meshes.
TEST(DefaultCell, ShippedFileLoadsFromDiskLikeTheEmbeddedCopy) {
  const fs::path assets = fs::path(BINPICK_SOURCE_DIR) / "assets";
  ScopedEnv env("BINPICK_ASSETS", assets.string());
  Result<Cell> embedded = LoadDefaultCell();
  ASSERT_TRUE(embedded.ok()) << embedded.status().ToString();
  Result<Cell> on_disk = LoadCell((assets / "cells/default.yaml").string());
  ASSERT_TRUE(on_disk.ok()) << on_disk.status().ToString();
  ASSERT_EQ(on_disk->parts.size(), embedded->parts.size());
  for (size_t i = 0; i < embedded->parts.size(); ++i) {
    EXPECT_EQ(on_disk->parts[i].mesh, embedded->parts[i].mesh);
    EXPECT_TRUE(fs::exists(embedded->parts[i].mesh)) << embedded->parts[i].mesh;
  }
  EXPECT_EQ(on_disk->grippers[0].mesh, embedded->grippers[0].mesh);
  EXPECT_EQ(on_disk->tasks.size(), embedded->tasks.size());
  EXPECT_EQ(on_disk->camera.configs.size(), embedded->camera.configs.size());
}

// A cell given by a path relative to the working directory (`binpickd
// --cell assets/cells/default.yaml`) keeps its calibration result next to
// it: the default "<cell file>.calibration.yaml" was resolved against the
// cell's directory a second time (assets/cells/assets/cells/...).
TEST(DefaultCell, TheCalibrationFileOfACellGivenByARelativePathIsNextToIt) {
  const fs::path source = fs::path(BINPICK_SOURCE_DIR);
  const fs::path cwd = fs::current_path();
  fs::current_path(source);
  Result<Cell> cell = LoadCell("assets/cells/default.yaml");
  fs::current_path(cwd);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  EXPECT_EQ(cell->camera.hand_eye_file,
            (fs::absolute(source) / "assets/cells/default.yaml.calibration.yaml").lexically_normal().string());
}

TEST(DefaultCell, MissingAssetsAreReportedAsNotFound) {
  const fs::path assets = testing::FreshDir("assets");  // empty
  ScopedEnv env("BINPICK_ASSETS", assets.string());
  Result<Cell> cell = LoadDefaultCell();
  ASSERT_FALSE(cell.ok());
  EXPECT_EQ(cell.status().code(), Status::Code::kNotFound);
  EXPECT_THAT(cell.status().message(), HasSubstr("<embedded default>"));
  EXPECT_THAT(cell.status().message(), HasSubstr("grippers/suction_cup.ply' does not exist"));
}

TEST_F(CellFileTest, BinDetectSearchTakesAnyYaw) {
  auto with = [](const std::string& search) {
    return Mutate(kBaseCell, "  wall_thickness: 0.01", "  wall_thickness: 0.01\n  detect_search: " + search);
  };
  Result<Cell> any = ParseCell(with("{translation: 0.03, rotation_deg: any}"), (tmp_ / "a.yaml").string());
  ASSERT_TRUE(any.ok()) << any.status().ToString();
  EXPECT_DOUBLE_EQ(any->bin.detect.search_yaw_deg, 180.0);
  EXPECT_DOUBLE_EQ(any->bin.detect.search_translation, 0.03);
  Result<Cell> wide = ParseCell(with("{rotation_deg: 120}"), (tmp_ / "w.yaml").string());
  ASSERT_TRUE(wide.ok()) << wide.status().ToString();
  EXPECT_DOUBLE_EQ(wide->bin.detect.search_yaw_deg, 120.0);
  EXPECT_DOUBLE_EQ(wide->bin.detect.search_translation, BinDetectSpec{}.search_translation);
  for (const char* bad : {"{rotation_deg: 181}", "{rotation_deg: some}", "{translation: 0.2}", "{yaw: 3}"}) {
    EXPECT_FALSE(ParseCell(with(bad), (tmp_ / "b.yaml").string()).ok()) << bad;
  }
}

}  // namespace

}  // namespace bp
