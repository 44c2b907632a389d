// The seed robot programs, run as written (issue 38): seed 000's and seed
// 003's UR programs (comms/ur_seed_program.h) against binpickd on the default
// cell (synthetic pile, real perception, the real hand-eye calibration), over
// the DaoAI socket and over Modbus TCP (binpickd the master of the test's
// robot, a libmodbus slave whose registers the program reads and writes one
// at a time). The conformance gate of the DaoAI protocol: no popup a program
// raises because of binpick's answer, no move to a pose binpick did not mean.
//
// BINPICK_SEED_PARTS (default 6) sets the parts in the bin and
// BINPICK_SEED_SCENE (default 3) the pile's seed; 20 parts, seed 1 is the
// default cell's bin as shipped (docs/protocols.md "Seed programs" has that run).
// BINPICK_SEED_RECORD=DIR makes binpickd record every capture and answer
// under DIR (one session directory per Rig; `binpick eval --source files:`
// scores a session's frames against their truth.json).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "calib/calibration_camera.h"
#include "comms/modbus_robot_sim.h"
#include "comms/ur_seed_program.h"
#include "core/cell.h"
#include "grasp/robot_targets.h"
#include "tests/testing/binpickd.h"
#include "tests/testing/files.h"

namespace bp {
namespace {

using namespace std::chrono_literals;

enum class Link { kSocket, kModbus };

// The default cell with `parts` parts from scene `seed`, relative paths made
// absolute; calibration, precision references and taught grasps land next to it.
// place_picks: a seed-003 cell, whose task 0 (the program's pick,
// daoai_switch_task(0)) offers only grasps the part can be placed on the nest
// with (`place_on: place_nest`, as the default cell's task 7).
std::string WriteCell(const std::string& dir, int parts, uint64_t seed, bool place_picks = false) {
  std::ifstream in(std::string(BINPICK_SOURCE_DIR) + "/assets/cells/default.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), {});
  const std::string from = "num_parts: 20\n  seed: 1";
  const size_t at = text.find(from);
  if (at == std::string::npos) return "";
  text.replace(at, from.size(), "num_parts: " + std::to_string(parts) + "\n  seed: " + std::to_string(seed));
  if (place_picks) {
    const std::string task0 = "{id: 0, name: pick_mixed, kind: pick, gripper: suction,";
    const size_t t = text.find(task0);
    if (t == std::string::npos) return "";
    text.insert(t + task0.size(), " place_on: place_nest,");
  }
  const std::string assets = std::string(BINPICK_SOURCE_DIR) + "/assets/";
  for (size_t p = text.find("../"); p != std::string::npos; p = text.find("../", p)) text.replace(p, 3, assets);
  const std::string path = dir + "/seed_cell.yaml";
  testing::WriteText(path, text);
  return path;
}

// The 2D cell (assets/cells/twod.yaml: flat parts on a table under a fixed
// camera, task 0 pick_2d), relative paths made absolute but the 2D
// calibration file, which lands next to it.
std::string WriteTwodCell(const std::string& dir) {
  std::ifstream in(std::string(BINPICK_SOURCE_DIR) + "/assets/cells/twod.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), {});
  const std::string assets = std::string(BINPICK_SOURCE_DIR) + "/assets/";
  for (size_t p = text.find("../"); p != std::string::npos; p = text.find("../", p)) text.replace(p, 3, assets);
  const std::string path = dir + "/twod_cell.yaml";
  testing::WriteText(path, text);
  return path;
}

int SeedParts() {
  const char* env = std::getenv("BINPICK_SEED_PARTS");
  return env ? std::atoi(env) : 6;
}

// The synthetic pile's seed (BINPICK_SEED_SCENE, default 3).
uint64_t SeedScene() {
  const char* env = std::getenv("BINPICK_SEED_SCENE");
  return env ? std::strtoull(env, nullptr, 10) : 3;
}

// Where the robot waits while the camera captures (seed: detection_pose):
// above the bin, tool pointing down.
UrPose DetectionPose() {
  return ToUrPose(MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.4, -0.3, 0.6)));
}

bool IsZero(const UrPose& p) {
  return std::abs(p[0]) + std::abs(p[1]) + std::abs(p[2]) < 1e-9;
}

// binpickd on the test cell, and the robot's side of the link.
class Rig {
 public:
  Rig(Link link, int parts, uint64_t seed, const std::string& name)
      : Rig(link, name, [&](const std::string& dir) { return WriteCell(dir, parts, seed); }) {}
  // binpickd on the cell `write_cell` writes into the test's directory.
  Rig(Link link, const std::string& name, const std::function<std::string(const std::string&)>& write_cell)
      : link_(link) {
    dir_ = testing::FreshDir(name);
    cell_path_ = write_cell(dir_);
    const std::string bin = std::string(BINPICK_BINARY_DIR) + "/bin/";
    std::vector<std::string> args = {bin + "binpickd", "--cell", cell_path_, "--gri-port", "0",
                                     "--gri-official-port", "0"};
    if (const char* record = std::getenv("BINPICK_SEED_RECORD"); record != nullptr && *record != '\0') {
      args.insert(args.end(), {"--record-dir", std::string(record) + "/" + name});
    } else {
      args.push_back("--no-record");
    }
    if (link == Link::kModbus) {
      robot_ = std::move(ModbusRobotSim::Start(ModbusRobotSimOptions{}).value());
      args.insert(args.end(), {"--daoai-port", "0", "--modbus-robot",
                               "127.0.0.1:" + std::to_string(robot_->port())});
    } else {
      port_ = testing::FreeLoopbackTcpPort();
      args.insert(args.end(), {"--daoai-port", std::to_string(port_)});
    }
    const auto t0 = std::chrono::steady_clock::now();
    daemon_ = std::make_unique<testing::BinpickdProcess>(args, dir_ + "/binpickd.log");
    // About a second normally; the model tables take far longer under ASan
    // with other test binaries on the two cores.
    ready_ = daemon_->ReadyLine(300000).find("binpickd ready") != std::string::npos;
    if (ready_ && robot_) ready_ = robot_->WaitForMaster(30s);
    ready_s_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  ~Rig() {
    if (daemon_) daemon_->Stop();
    if (robot_) robot_->Stop();
  }

  bool ready() const { return ready_; }
  double ready_seconds() const { return ready_s_; }  // from starting binpickd to its ready line
  std::string log() const { return testing::ReadBytes(dir_ + "/binpickd.log"); }
  const std::string& cell_path() const { return cell_path_; }
  std::string Sibling(const std::string& extension) const {
    return std::filesystem::path(cell_path_).replace_extension(extension).string();
  }

  std::unique_ptr<UrSeedProgram> Program(const UrPose& start, UrSeedProgramOptions o = {}) {
    if (link_ == Link::kModbus) return UrSeedProgram::OverModbus(*robot_, start, o);
    Result<std::unique_ptr<UrSeedProgram>> p = UrSeedProgram::OverSocket("127.0.0.1", port_, start, o);
    EXPECT_TRUE(p.ok()) << p.status().ToString();
    return p.ok() ? std::move(*p) : nullptr;
  }

  // A request without an answer (teach, stop-manual) has been taken: over
  // Modbus the master clears the request flag; over the socket TCP keeps the
  // order. The seed's programs do not wait, their next move takes seconds.
  void WaitTaken() {
    if (!robot_) return;
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    while (robot_->ReadRegister(144) == 1 && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(1ms);
    }
  }

  // Waits up to 20 s for `path` to exist.
  static bool WaitForFile(const std::string& path) {
    const auto deadline = std::chrono::steady_clock::now() + 20s;
    while (!std::filesystem::exists(path) && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(20ms);
    }
    return std::filesystem::exists(path);
  }

 private:
  Link link_;
  std::string dir_, cell_path_;
  int port_ = 0;
  std::unique_ptr<ModbusRobotSim> robot_;
  std::unique_ptr<testing::BinpickdProcess> daemon_;
  bool ready_ = false;
  double ready_s_ = 0;
};

class SeedPrograms : public ::testing::TestWithParam<Link> {};

const char* LinkName(Link link) { return link == Link::kSocket ? "socket" : "Modbus"; }

// Where a program's time went: its wall time, the robot's waits for
// binpick's answers (sum, count) and the slowest three with their commands.
// A slow run shows whether binpick was slow to answer, and to which request,
// or the time was elsewhere (binpickd's start-up, the test's own work).
std::string Timing(const UrSeedProgram& p, double wall_s) {
  std::vector<UrSeedProgram::AnswerTime> t = p.answer_times();
  double waited = 0;
  for (const auto& a : t) waited += a.ms;
  std::sort(t.begin(), t.end(), [](const auto& a, const auto& b) { return a.ms > b.ms; });
  char buf[160];
  std::snprintf(buf, sizeof buf, "%.1f s, %zu answers waited %.1f s, slowest", wall_s, t.size(), waited / 1000);
  std::string s = buf;
  for (size_t i = 0; i < std::min<size_t>(3, t.size()); ++i) {
    std::snprintf(buf, sizeof buf, " %d:%.0f ms", t[i].command, t[i].ms);
    s += buf;
  }
  return s;
}

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

std::string Popups(const UrSeedProgram& p) {
  std::string s;
  for (const UrPopup& u : p.popups()) s += std::string(u.failure ? "  FAILURE: " : "  notice: ") + u.text + "\n";
  return s;
}

// Seed 000's calibration programs, teach, precision check and config switch,
// then its pick program until the box is empty.
TEST_P(SeedPrograms, Seed000ProgramsCalibratePickAndClearTheBinWithoutAFailurePopup) {
  const int parts = SeedParts();
  Rig rig(GetParam(), parts, SeedScene(), "seed000");
  ASSERT_TRUE(rig.ready()) << rig.log();
  const Cell cell = LoadCell(rig.cell_path()).value();
  const UrPose facing = ToUrPose(BoardFacingStartPose(cell));

  {  // Auto calibration started where the camera cannot see the board: every
     // answer keeps the robot where it is, and three failed views end it (33).
    Pose away_pose = BoardFacingStartPose(cell);
    away_pose.translation() += Vec3(0.6, 0, 0);
    const UrPose away = ToUrPose(away_pose);
    auto p = rig.Program(away);
    ASSERT_TRUE(p);
    int loops = 0;
    ASSERT_TRUE(p->Run([&] { loops = p->AutoCalibrationProgram(away, 20); }).ok()) << rig.log();
    EXPECT_EQ(loops, 2);  // 11, 11, then 33
    EXPECT_EQ(p->status(), 33);
    for (const UrPose& m : p->moves()) {
      EXPECT_LT(std::abs(m[0] - away[0]) + std::abs(m[1] - away[1]) + std::abs(m[2] - away[2]), 2e-4);
    }
    EXPECT_TRUE(p->failure_popups().empty()) << Popups(*p);
  }
  {  // Auto calibration from where the board faces the camera: binpickd plans
     // the views, the robot moves to each, 33 ends it and the result is written.
    auto p = rig.Program(facing);
    int loops = 0;
    ASSERT_TRUE(p->Run([&] { loops = p->AutoCalibrationProgram(facing, 30); }).ok()) << rig.log();
    EXPECT_EQ(p->status(), 33);
    EXPECT_GE(loops, cell.calibration->min_poses - 1);
    for (const UrPose& m : p->moves()) EXPECT_FALSE(IsZero(m));
    EXPECT_TRUE(p->failure_popups().empty()) << Popups(*p);
    EXPECT_TRUE(Rig::WaitForFile(rig.cell_path() + ".calibration.yaml")) << rig.log();
  }
  {  // Manual calibration over 9 waypoints: 10 for each, no answer to 2.
    std::vector<UrPose> waypoints;
    const Pose start = BoardFacingStartPose(cell);
    const Vec3 axes[] = {Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), Vec3(1, 1, 0), Vec3(1, -1, 0),
                         Vec3(0, 1, 1), Vec3(1, 0, -1), Vec3(1, 1, 1), Vec3(-1, 1, 1)};
    for (int i = 0; i < 9; ++i) {
      const double angle = (i % 2 == 0 ? 1.0 : -1.0) * (i == 0 ? 0.0 : 10.0 + 2.0 * (i % 3)) * M_PI / 180.0;
      waypoints.push_back(ToUrPose(start * MakePose(Mat3(Eigen::AngleAxisd(angle, axes[i].normalized())),
                                                    Vec3(0.01 * (i % 3 - 1), 0.01 * (i / 3 % 3 - 1), 0.0))));
    }
    auto p = rig.Program(waypoints[0]);
    ASSERT_TRUE(p->Run([&] { p->ManualCalibrationProgram(waypoints); }).ok()) << rig.log();
    EXPECT_EQ(p->status(), 10);
    EXPECT_TRUE(p->failure_popups().empty()) << Popups(*p);
    ASSERT_FALSE(p->popups().empty());
    EXPECT_EQ(p->popups().back().text, "DaoAI Done Calibration.");
    rig.WaitTaken();
  }
  {  // Precision check on task 0 (the first defines the reference: 0 mm), and
     // the camera config switch, as printed (RC 69 carries the stale
     // daoai_payload_1: the seed's `payload_1 = id` sets a local) and with the
     // one-line fix.
    auto p = rig.Program(DetectionPose());
    bool precise = false, literal = true, started = false;
    ASSERT_TRUE(p->Run([&] {
      p->daoai_switch_job(0);
      started = p->daoai_capture_and_process_async();  // 19: 5 at once
      precise = p->daoai_precision_check();
      literal = p->daoai_cam_config(2);
    }).ok()) << rig.log();
    EXPECT_TRUE(started);
    EXPECT_TRUE(precise) << Popups(*p);
    EXPECT_EQ(p->popups().at(0).text, "3D error is : 0mm");
    EXPECT_FALSE(literal);  // daoai_payload_1 is 0 (the precision answer's payload_1 / mult): no config 0
    EXPECT_EQ(p->failure_popups(), std::vector<std::string>{
                                       "DaoAI switch camera config failed, please check your configs."});
    UrSeedProgramOptions fixed;
    fixed.cam_config_sets_payload = true;
    auto q = rig.Program(DetectionPose(), fixed);
    bool switched = false;
    ASSERT_TRUE(q->Run([&] { switched = q->daoai_cam_config(1); }).ok());
    EXPECT_TRUE(switched);
    EXPECT_TRUE(q->failure_popups().empty()) << Popups(*q);
  }
  int picked = 0;
  {  // Teach: after the last pose of a capture (payload_1 = 1, which names task
     // 1) the robot stands at the pick pose and sends it; daoai_teach_pose never
     // sets payload_1, so binpickd files it on the task last picked from (0),
     // whose part it was: the taught grasp is stored.
    auto p = rig.Program(DetectionPose());
    bool taught = false;
    ASSERT_TRUE(p->Run([&] {
      p->daoai_switch_job(0);
      if (!p->daoai_capture_and_process()) return;
      while (p->daoai_get_picking_pose()) {
        p->MoveL(p->pick_pose());
        ++picked;
        if (p->daoai_remaining_objects() <= 1) {
          p->daoai_teach_pose();
          taught = true;
          break;
        }
      }
    }).ok()) << rig.log();
    ASSERT_TRUE(taught) << Popups(*p);
    EXPECT_EQ(p->payload_1(), 1.0);
    rig.WaitTaken();
    EXPECT_TRUE(Rig::WaitForFile(rig.Sibling(".taught.yaml"))) << rig.log();
    EXPECT_TRUE(p->failure_popups().empty()) << Popups(*p);
  }
  {  // One capture with the pick Loop exactly as printed: it asks once more
     // after the last pose (payload_1 = 1) and gets what step 7 says, 3 with
     // payload_1 0 and the robot's own pose, so it stops on the seed's own
     // "NO OBJECTS FOUND." popup, the only way that Loop ends, and moves
     // nowhere after it.
    auto p = rig.Program(DetectionPose());
    int literal = 0;
    ASSERT_TRUE(p->Run([&] { literal = p->PickLoopAsPrinted(DetectionPose()); }).ok()) << rig.log();
    picked += literal;
    EXPECT_EQ(p->failure_popups(), std::vector<std::string>{"NO OBJECTS FOUND."}) << Popups(*p);
    EXPECT_EQ(p->status(), 3);
    EXPECT_EQ(p->payload_1(), 0.0);
    EXPECT_EQ(p->moves().size(), 3u * static_cast<size_t>(literal));
    for (const UrPose& m : p->moves()) EXPECT_FALSE(IsZero(m));
  }
  const int picked_before = picked;  // by the teach stage and the literal Loop
  {  // The pick program until the box is empty.
    auto p = rig.Program(DetectionPose());
    ASSERT_TRUE(p->Run([&] { picked += p->PickProgram(DetectionPose(), 3 * parts); }).ok()) << rig.log();
    EXPECT_EQ(picked, parts) << Popups(*p);
    std::printf("seed 000 over %s: %d parts, %d picked (teach stage and printed Loop %d, pick program %d), %zu "
                "failure popups\n",
                LinkName(GetParam()), parts, picked, picked_before, picked - picked_before,
                p->failure_popups().size());
    EXPECT_TRUE(p->failure_popups().empty()) << Popups(*p);
    ASSERT_FALSE(p->popups().empty());
    EXPECT_EQ(p->popups().back().text, "Box Empty.");
    for (const UrPose& m : p->moves()) EXPECT_FALSE(IsZero(m));
  }
  EXPECT_EQ(rig.log().find("interface version"), std::string::npos);
}

// Seed 003's auto calibration program (the same as seed 000's), then its
// "抓取 - 物体姿态修正 - 放置" program as printed, one part per pass of its
// Loop: stage 0 picks (task 0), stage 1 looks at the part in the gripper
// (task 1, in_hand: obj_in_tool), stage 2 at the place area (task 3,
// place_area: place_in_base, the nest's offset from where it was taught),
// stage 3 moves the tool to place_in_base * obj_in_Place * obj_in_tool^-1.
// On a seed-003 cell (docs/protocols.md "Seed programs"): task 0 offers only
// grasps the part can be placed on the nest with, so every part picked is
// placed, and a bin whose parts left have no such grasp ends with the
// program's "NO Collision-free PICK pose." (the operator turns them over).
// BINPICK_SEED003_DEFAULT_CELL=1 runs it on the default cell as shipped
// (task 0 without place_on: a pass whose place binpick refuses stops on
// "NO OBJECTS FOUND." with the part in the gripper), for the Runs table.
TEST_P(SeedPrograms, Seed003CalibratesThenRunsItsPickCorrectPlaceProgramAsPrinted) {
  const int parts = SeedParts();
  const uint64_t scene = SeedScene();
  const bool place_picks = std::getenv("BINPICK_SEED003_DEFAULT_CELL") == nullptr;
  Rig rig(GetParam(), "seed003", [&](const std::string& dir) { return WriteCell(dir, parts, scene, place_picks); });
  ASSERT_TRUE(rig.ready()) << rig.log();
  const Cell cell = LoadCell(rig.cell_path()).value();
  std::string timing;
  {  // The default cell's camera is not where the cell file says until the
     // cell is calibrated (calibration.true_pose): uncalibrated, the emptied
     // bin still showed ~19,000 points and detections without a grasp.
    const UrPose facing = ToUrPose(BoardFacingStartPose(cell));
    auto c = rig.Program(facing);
    const auto t0 = std::chrono::steady_clock::now();
    ASSERT_TRUE(c->Run([&] { c->AutoCalibrationProgram(facing, 30); }).ok()) << rig.log();
    timing = "calibration " + Timing(*c, SecondsSince(t0));
    EXPECT_EQ(c->status(), 33);
    EXPECT_TRUE(c->failure_popups().empty()) << Popups(*c);
    ASSERT_TRUE(Rig::WaitForFile(rig.cell_path() + ".calibration.yaml")) << rig.log();
  }
  // The program's taught waypoints for the default cell: adjust_det_pose
  // 0.5 m under the camera, the tool tilted 35 deg off the line of sight
  // (as `binpick place`'s, grasp/place_cycles.h); the place area
  // seen from detection_pose; pre_drop_pose 0.2 m above the nest, tool down;
  // obj_in_Place where the part stood on the nest when the place was taught.
  const FixtureSpec& nest = *cell.FindFixture(cell.FindTask(3)->fixture);
  const UrPose detection = DetectionPose();
  const UrPose adjust = ToUrPose(MakePose(
      Mat3(Eigen::AngleAxisd(0.4, Vec3::UnitZ()) * Eigen::AngleAxisd(35.0 * M_PI / 180, Vec3::UnitX())),
      Vec3(0.7, 0.0, 0.55)));
  const Pose obj_in_place = nest.X_BP_taught * nest.X_PO;
  const UrPose pre_drop = ToUrPose(
      MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), nest.X_BP_taught.translation() + Vec3(0, 0, 0.2)));
  auto p = rig.Program(detection);
  int picks = 0, passes = 0;
  bool empty = false, unplaceable_left = false;
  const std::string kNoPlaceableGrasp = "NO Collision-free PICK pose.";
  const auto program_t0 = std::chrono::steady_clock::now();
  // The operator stops the Loop (it has no end): after one pass per part,
  // then (a part perception missed in a pass is still there) a pass at a
  // time until daoai_check_box_empty() says empty, or until a pick is
  // answered 4 with the box not empty (the pile does not move: every pass
  // would repeat it).
  ASSERT_TRUE(p->Run([&] {
    auto run = [&](int n) {
      picks += p->PickCorrectPlaceProgram(detection, adjust, detection, pre_drop, ToUrPose(obj_in_place), n);
      passes += n;
    };
    // The empty-box check on the pick task (seed 003: "需要先运行daoai_switch_task()来选择检查的task").
    auto check_empty = [&] {
      p->daoai_switch_job(0);
      return p->daoai_check_box_empty();
    };
    auto answered_4 = [&] { return !p->popups().empty() && p->popups().back().text == kNoPlaceableGrasp; };
    run(parts);
    unplaceable_left = answered_4();
    empty = check_empty();
    while (!empty && !unplaceable_left && passes < 2 * parts) {
      run(1);
      unplaceable_left = answered_4();
      empty = check_empty();
    }
  }).ok()) << rig.log();
  std::printf("seed 003 timing over %s: binpickd ready in %.1f s; %s; program %s\n", LinkName(GetParam()),
              rig.ready_seconds(), timing.c_str(), Timing(*p, SecondsSince(program_t0)).c_str());
  std::printf("seed 003 program on the %s cell over %s: %d parts, %d picked in %d passes, %zu failure popups (%s)",
              place_picks ? "seed-003" : "default", LinkName(GetParam()), parts, picks, passes,
              p->failure_popups().size(), empty ? "box empty" : "parts left");
  // Seed-003 cell: the only popup is the pick's 4 once no part left has a
  // placeable grasp (at most one per pass of the run(parts) phase: a pass
  // that gets it picks nothing, so the pile and the answer stay). Default
  // cell: a pass whose stage 1 or 2 gets no answer stops there with "NO
  // OBJECTS FOUND." (binpick's 3: the place would leave the workspace, or
  // perception missed the part in the gripper or the nest).
  // Default cell: a part no grasp of task 0 can take at all (an L-bracket on
  // its side, scenes 2 and 4: seed 000's pick program leaves it too) ends the
  // run on the pick's 4 with the box not empty, as a seed-003 cell's
  // unplaceable parts do.
  const std::vector<std::string> failures = p->failure_popups();
  EXPECT_TRUE(empty || unplaceable_left) << Popups(*p);
  if (empty) {
    EXPECT_EQ(picks, parts) << Popups(*p);
  }
  // Scene 3's 6 parts, the test's default bin, all have a (placeable) grasp.
  if (std::getenv("BINPICK_SEED_PARTS") == nullptr && std::getenv("BINPICK_SEED_SCENE") == nullptr) {
    EXPECT_TRUE(empty) << Popups(*p);
  }
  int not_placed = 0;  // passes stopped at stage 1 or 2 with the part in the gripper
  for (const std::string& f : failures) {
    if (place_picks || f != "NO OBJECTS FOUND.") {
      EXPECT_EQ(f, kNoPlaceableGrasp) << Popups(*p);
    } else {
      ++not_placed;
    }
  }
  // Each place is MoveJ pre_drop_pose, MoveJ tool_in_base, MoveJ pre_drop_pose.
  const std::vector<UrPose>& moves = p->moves();
  int places = 0;
  for (size_t i = 0; i + 2 < moves.size(); ++i) {
    if (moves[i] != pre_drop || moves[i + 2] != pre_drop) continue;
    ++places;
    // The tool holds the part within its grasp's reach (hub_top: 4 cm) of
    // where the part belongs on the nest, and inside the workspace.
    const Pose tool_in_base = FromUrPose(moves[i + 1]);
    EXPECT_LT((tool_in_base.translation() - obj_in_place.translation()).norm(), 0.1) << "place " << places;
    EXPECT_TRUE(CheckToolPose(cell, cell.FindTask(3)->gripper, tool_in_base).ok()) << "place " << places;
  }
  if (place_picks) {
    EXPECT_EQ(places, picks) << Popups(*p);  // every part picked is placed
  } else {
    EXPECT_EQ(places + not_placed, picks) << Popups(*p);  // each pass that picked placed or stopped
  }
  EXPECT_GE(places, 1) << Popups(*p);
  std::printf(", %d placed\n", places);
  for (const UrPose& m : moves) EXPECT_FALSE(IsZero(m));
}

// Seed 000's 2D auto calibration loop and 2D pick (send_robot_data_2d /
// recv_daoai_data_2d: poses in the robot's plane, the robot keeps its z) on
// the 2D cell: started where the camera cannot see the marker, every answer
// keeps the robot where it is and three failed views end it (34, the status
// daoai_auto_accumulate_2d stops on); from the plane's centre binpickd walks
// its 5 x 4 grid, fits and writes the calibration; then the pick program
// clears the table (8 flat parts, twod.yaml's scene) until "Box Empty.".
TEST_P(SeedPrograms, Seed000TwoDProgramsCalibrateAndClearThePlaneWithoutAFailurePopup) {
  Rig rig(GetParam(), "seed000_2d", WriteTwodCell);
  ASSERT_TRUE(rig.ready()) << rig.log();
  const Cell cell = LoadCell(rig.cell_path()).value();
  const std::string plane_file = cell.camera.plane_calibration_file;  // resolved next to the cell
  ASSERT_FALSE(plane_file.empty());
  // daoai_plane: the table, the synthetic scene's bin frame.
  const UrPose plane = ToUrPose(cell.bin.X_BW);
  UrSeedProgramOptions o;
  o.daoai_plane = plane;
  // The tool-mounted marker on the plane, tool pointing down.
  auto on_plane = [&](double x, double y, double z) {
    return ToUrPose(FromUrPose(plane) * MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(x, y, z)));
  };
  {
    const UrPose away = on_plane(0.6, 0.0, 0.0);  // 0.6 m off the camera's axis: out of view
    auto p = rig.Program(away, o);
    ASSERT_TRUE(p);
    int loops = 0;
    ASSERT_TRUE(p->Run([&] { loops = p->AutoCalibration2DProgram(away, 20); }).ok()) << rig.log();
    EXPECT_EQ(loops, 2);  // 14, 14, then 34
    EXPECT_EQ(p->status(), 34);
    ASSERT_EQ(p->moves().size(), 3u);  // MoveJ center_pose, then the two loops' MoveL
    for (const UrPose& m : p->moves()) {
      EXPECT_LT(std::abs(m[0] - away[0]) + std::abs(m[1] - away[1]) + std::abs(m[2] - away[2]), 3e-4);
    }
    EXPECT_TRUE(p->failure_popups().empty()) << Popups(*p);
    EXPECT_EQ(p->popups().back().text, "DaoAI Done Calibration.");
    EXPECT_FALSE(std::filesystem::exists(plane_file));
  }
  {
    const UrPose centre = on_plane(0.0, 0.0, 0.0);
    auto p = rig.Program(centre, o);
    int loops = 0;
    ASSERT_TRUE(p->Run([&] { loops = p->AutoCalibration2DProgram(centre, 40); }).ok()) << rig.log();
    EXPECT_EQ(p->status(), 34);
    EXPECT_EQ(loops, 20);  // the centre, then 20 grid points; the 21st view is answered 34
    for (const UrPose& m : p->moves()) {
      // On the grid (0.36 m x 0.24 m about the centre), on the plane: the robot keeps its z.
      const Vec3 in_plane = FromUrPose(plane).inverse() * Vec3(m[0], m[1], m[2]);
      EXPECT_LE(std::abs(in_plane.x()), 0.18 + 1e-3);
      EXPECT_LE(std::abs(in_plane.y()), 0.12 + 1e-3);
      EXPECT_NEAR(m[2], centre[2], 1e-9);
    }
    EXPECT_TRUE(p->failure_popups().empty()) << Popups(*p);
    EXPECT_TRUE(Rig::WaitForFile(plane_file)) << rig.log();
  }
  {
    const int parts = cell.source.num_parts;
    const UrPose detection = on_plane(0.0, 0.0, 0.3);
    auto p = rig.Program(detection, o);
    int picked = 0;
    ASSERT_TRUE(p->Run([&] { picked = p->Pick2DProgram(detection, 3 * parts); }).ok()) << rig.log();
    EXPECT_EQ(picked, parts) << Popups(*p);
    std::printf("seed 000 2D pick program over %s: %d parts, %d picked, %zu failure popups, %d requests\n",
                LinkName(GetParam()), parts, picked, p->failure_popups().size(), p->requests_sent());
    EXPECT_TRUE(p->failure_popups().empty()) << Popups(*p);
    ASSERT_FALSE(p->popups().empty());
    EXPECT_EQ(p->popups().back().text, "Box Empty.");
    for (const UrPose& m : p->moves()) {
      // Over the table, at the robot's own height (recv_daoai_data_2d keeps z).
      const Vec3 in_plane = FromUrPose(plane).inverse() * Vec3(m[0], m[1], m[2]);
      EXPECT_LE(std::abs(in_plane.x()), cell.bin.inner_size.x() / 2) << in_plane.transpose();
      EXPECT_LE(std::abs(in_plane.y()), cell.bin.inner_size.y() / 2) << in_plane.transpose();
      EXPECT_NEAR(m[2], detection[2], 1e-9);
    }
  }
  EXPECT_EQ(rig.log().find("interface version"), std::string::npos);
}

INSTANTIATE_TEST_SUITE_P(Links, SeedPrograms, ::testing::Values(Link::kSocket, Link::kModbus),
                         [](const auto& info) { return info.param == Link::kSocket ? "Socket" : "Modbus"; });

}  // namespace
}  // namespace bp
