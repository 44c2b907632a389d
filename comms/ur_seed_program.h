// The seed robot programs, run as written (issue 38): seed 000's URScript
// interface functions (UR, Modbus TCP) and the same functions over the DaoAI
// socket (seed 003), transcribed line for line, and the example "Robot
// Program"s of seeds 000 and 003 built from them. The conformance gate of the
// DaoAI protocol: whatever binpickd answers is read exactly as a UR
// controller running the seed's script reads it.
//
// What "as written" means here:
//   - send_robot_data sends floor(mult * value) for the pose, payload_1 and
//     payload_2 as they stand (daoai_teach_pose never sets payload_1: it
//     still holds what the last reply left there), meta_1 = 7 (UR) and
//     meta_2 = DAOAI_META_VERSION = 1;
//   - over Modbus, every register is written and read one at a time at the
//     seed's addresses (request 128..139, flag 144; response 129..144, flag
//     145), with no wait for the master between two requests;
//   - over the socket, socket_send_int writes one int32 per call on a socket
//     with default options (Nagle on: socket_open has no TCP_NODELAY), and
//     recv_daoai_data loops on socket_read_binary_integer(16);
//   - every popup() is recorded; the ones a program raises because binpick's
//     answer was not the one it needs (version or robot type mismatch,
//     capture failed, no objects, no collision-free pose, config switch or
//     precision check failed) are failures, the rest notices (the operator
//     prompts of the example programs, "DaoAI Done Calibration.", "Box
//     Empty.", the precision check's result).
// Where the seed's text cannot run as printed, the transcription says so at
// the line (docs/protocols.md "Seed programs" has the table seed line ->
// binpick behaviour -> test):
//   - daoai_check_box_empty sends RC_CHEKC_EMPTY_BOX, a constant the seed
//     never defines: defined here as 40 (RC_CHECK_EMPTY_BOX);
//   - daoai_capture_and_process_async sends `task_id`, never defined: taken
//     as daoai_task_id;
//   - daoai_cam_config(id) assigns `payload_1 = id`, a local that
//     send_robot_data never reads: RC 69 goes out with the stale
//     daoai_payload_1 (kept as printed; `cam_config_sets_payload` runs the
//     one-line fix);
//   - daoai_teach_pose_2d sends RC_DAOAI_CAPTURE_AND_PROCESS (20), not
//     RC_SEND_POSE, and reads no answer: binpick captures and answers 5,
//     which the program's next recv_daoai_data_2d reads as the answer to its
//     next request (kept as printed; no test program calls it);
//   - URScript divides as real numbers and a real written to an integer
//     port is truncated toward zero (a remaining count read as 3.0 is sent
//     back as 3); registers hold int16 two's complement, as binpick's codec
//     (a controller whose read_port_register returns 0..65535 would need
//     `v - 65536` above 32767 in modbustcp_recv_daoai_data).
//
// The interface functions and globals keep the seed's names (snake_case) so
// each line can be compared with the seed's text.
//
// Threading: one program runs on one thread. Its Modbus side is the
// ModbusRobotSim's registers (the controller's Modbus server), which the
// master reads and writes concurrently.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "comms/modbus_robot_sim.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

// A UR pose p[x, y, z, rx, ry, rz]: metres, rotation vector in radians.
using UrPose = std::array<double, 6>;
UrPose ToUrPose(const Pose& X);
Pose FromUrPose(const UrPose& p);

struct UrPopup {
  std::string text;
  bool failure = false;  // raised because binpick's answer was not what the program needs
};

struct UrSeedProgramOptions {
  // Time a recv_daoai_data may wait for its answer before the program halts
  // (a UR would wait forever; a test must not).
  std::chrono::milliseconds answer_timeout{30000};
  // socket_read_binary_integer's own timeout (URScript default: 2 s).
  std::chrono::milliseconds socket_read_timeout{2000};
  // Between two reads of register 145 while waiting (the seed's loop spins).
  std::chrono::microseconds register_poll{200};
  // See the header comment: false runs daoai_cam_config as printed.
  bool cam_config_sets_payload = false;
  // daoai_plane, the plane P of the 2D functions (the robot's base frame to
  // P, UR pose); the seed's globals do not list it, its 2D programs set it.
  std::array<double, 6> daoai_plane{0, 0, 0, 0, 0, 0};
};

class UrSeedProgram {
 public:
  // seed 003: socket_open(ip, port) (default socket options).
  static Result<std::unique_ptr<UrSeedProgram>> OverSocket(const std::string& host, int port,
                                                           const UrPose& start,
                                                           UrSeedProgramOptions options = {});
  // seed 000: the controller's Modbus server is `robot` (must outlive the program).
  static std::unique_ptr<UrSeedProgram> OverModbus(ModbusRobotSim& robot, const UrPose& start,
                                                   UrSeedProgramOptions options = {});
  ~UrSeedProgram();
  UrSeedProgram(const UrSeedProgram&) = delete;
  UrSeedProgram& operator=(const UrSeedProgram&) = delete;

  // Runs `body` (calls of the functions below) until it returns or the
  // program halts: a socket or register failure, or no answer within
  // answer_timeout, halts it as a controller would, and is returned here.
  Status Run(const std::function<void()>& body);

  // ---- The example "Robot Program"s (seed 000 "通信流程示例", seed 003). ----
  // Manual calibration: MoveJ each waypoint, daoai_manual_accumulate_calibration(),
  // then daoai_stop_manual_calibration().
  void ManualCalibrationProgram(const std::vector<UrPose>& waypoints);
  // Auto calibration: MoveJ center_pose; if daoai_start_auto_calibration():
  // Loop daoai_auto_accumulate(): calibra_pose = daoai_tcp_pose; MoveL calibra_pose.
  // `max_loops` bounds the loop (the seed's has no bound); @returns the loops run.
  int AutoCalibrationProgram(const UrPose& center_pose, int max_loops);
  // One pass of seed 000's "抓取通信示例" outer Loop exactly as printed: if
  // daoai_capture_and_process(): Loop daoai_get_picking_pose(): MoveL
  // detection_pose, MoveL pick_pose, MoveL detection_pose. The inner Loop
  // ends only when daoai_get_picking_pose() returns False, and each of its
  // False paths pops up (after the last pose of a capture: binpick answers 3,
  // payload_1 0, "NO OBJECTS FOUND."). @returns the picks made.
  int PickLoopAsPrinted(const UrPose& detection_pose);
  // 2D auto calibration, the 3D program with the 2D functions (seed 000
  // prints no 2D example program): MoveJ center_pose; if
  // daoai_start_auto_calibration_2d(): Loop daoai_auto_accumulate_2d():
  // calibra_pose = daoai_tcp_pose; MoveL calibra_pose. @returns the loops run.
  int AutoCalibration2DProgram(const UrPose& center_pose, int max_loops);
  // 2D pick: PickProgram with daoai_capture_and_process_2d() and
  // daoai_get_picking_pose_2d() (the empty-box check is the 3D function, the
  // only one the seed has). @returns the picks made.
  int Pick2DProgram(const UrPose& detection_pose, int max_cycles);
  // Pick (seed 000 "抓取通信示例" with its step 7: a pose with payload_1 = 1 is
  // the last of its capture, the robot captures again instead of asking once
  // more), starting each cycle with daoai_check_box_empty() (seed 000:
  // RC_CHECK_EMPTY_BOX): stops on an empty box, or when a capture or a pick
  // pose fails, or after max_cycles captures. @returns the picks made.
  int PickProgram(const UrPose& detection_pose, int max_cycles);
  // Seed 003 "抓取 - 物体姿态修正 - 放置", `iterations` passes of its Loop,
  // as printed: stage 0 (task 0) picks, stage 1 (task 1) records the part's
  // pose in the gripper (obj_in_tool) without moving, stage 2 (task 3) the
  // place area's offset from where it was taught (place_in_base), stage 3
  // moves to tool_in_base = place_in_base * obj_in_Place * obj_in_tool^-1
  // between two MoveJ pre_drop_pose. A stage that gets no answer leaves the
  // pass (the next starts at stage 0). @returns the picks made.
  int PickCorrectPlaceProgram(const UrPose& detection_pose, const UrPose& adjust_det_pose,
                              const UrPose& place_det_pose, const UrPose& pre_drop_pose,
                              const UrPose& obj_in_place, int iterations);

  // ---- seed 000 / 003 interface functions, as printed. ----
  void send_robot_data();
  void recv_daoai_data();
  void modbustcp_send_robot_data(const std::array<double, 12>& robot_data);
  std::array<double, 17> modbustcp_recv_daoai_data();
  bool daoai_start_manual_calibration();
  bool daoai_manual_accumulate_calibration();
  bool daoai_stop_manual_calibration();
  bool daoai_guidance_accumulate_calibration();
  bool daoai_start_auto_calibration();
  bool daoai_auto_accumulate();
  void daoai_teach_pose();
  bool daoai_capture_and_process_async();
  bool daoai_capture_and_process();
  bool daoai_get_picking_pose();
  bool daoai_cam_config(int id);
  bool daoai_check_box_empty();
  int daoai_remaining_objects() const;
  void daoai_switch_job(int id);  // printed as daoai_switch_task in the text, daoai_switch_job in the code
  int daoai_object_type() const;
  bool daoai_precision_check();
  // The 2D functions (seed 000 "2D ..." sections, seed 003 for the socket).
  void send_robot_data_2d(const UrPose& plane, bool optional_z = false, double z_value = 0);
  void recv_daoai_data_2d(const UrPose& plane);
  bool daoai_start_auto_calibration_2d();
  bool daoai_auto_accumulate_2d();
  void daoai_teach_pose_2d();
  bool daoai_capture_and_process_2d_async();
  bool daoai_capture_and_process_2d();
  bool daoai_get_picking_pose_2d();

  // ---- The controller. ----
  UrPose get_actual_tcp_pose() const { return actual_tcp_pose_; }
  void MoveL(const UrPose& pose);
  void MoveJ(const UrPose& pose);
  void popup(const std::string& text, bool failure);

  // ---- What a test reads afterwards. ----
  const std::vector<UrPopup>& popups() const { return popups_; }
  std::vector<std::string> failure_popups() const;
  const std::vector<UrPose>& moves() const { return moves_; }  // every MoveL / MoveJ target
  // Globals of the seed's script (read-only for tests).
  double payload_1() const { return daoai_payload_1_; }
  double payload_2() const { return daoai_payload_2_; }
  int status() const { return daoai_status_; }
  const UrPose& tcp_pose() const { return daoai_tcp_pose_; }
  const UrPose& pick_pose() const { return pick_pose_; }
  int requests_sent() const { return requests_sent_; }
  // Each answered request: its command and the time from sending its first
  // field to reading its last (the robot's wait for binpick's answer), in
  // order. Where a slow run's time went (docs/protocols.md "Seed programs").
  struct AnswerTime {
    int command = 0;
    double ms = 0;
  };
  const std::vector<AnswerTime>& answer_times() const { return answer_times_; }

  // Seed 000 "全局常量" (the ones the functions use).
  static constexpr int mult = 10000;
  static constexpr int DAOAI_ROBOT_TYPE = 7;
  static constexpr int DAOAI_META_VERSION = 1;

 private:
  class Link;
  class SocketLink;
  class ModbusLink;
  UrSeedProgram(std::unique_ptr<Link> link, const UrPose& start, UrSeedProgramOptions options);

  // The wire half of send_robot_data / send_robot_data_2d (seed 000:
  // modbustcp_send_robot_data; seed 003: one socket_send_int per field), and
  // of recv_daoai_data / recv_daoai_data_2d up to their popups: the 17-entry
  // daoai_data list.
  void SendFields(const std::array<double, 12>& robot_data);
  std::vector<double> ReceiveFields();

  // URScript primitives on the link (halt the program on failure).
  void socket_send_int(double value);
  std::vector<double> socket_read_binary_integer(int number);
  void write_port_register(int address, double value);
  double read_port_register(int address);

  std::unique_ptr<Link> link_;
  const UrSeedProgramOptions options_;
  const bool modbus_;
  UrPose actual_tcp_pose_{};
  std::vector<UrPopup> popups_;
  std::vector<UrPose> moves_;
  int requests_sent_ = 0;
  std::chrono::steady_clock::time_point answer_deadline_{};
  std::chrono::steady_clock::time_point sent_at_{};  // the last request's first field
  int sent_command_ = 0;                             // the last request's command
  std::vector<AnswerTime> answer_times_;

  // Seed 000 "Global Variables".
  UrPose daoai_tcp_pose_{};
  double daoai_payload_1_ = 0, daoai_payload_2_ = 0, daoai_payload_3_ = 0;
  double daoai_payload_4_ = 0, daoai_payload_5_ = 0, daoai_payload_6_ = 0;
  int daoai_status_ = 0;
  int daoai_r_command_ = 0;
  int daoai_task_id_ = 0;
  double daoai_num_remaining_objects_ = 0;
  double daoai_object_type_id_ = 0;
  UrPose pick_pose_{};
  UrPose daoai_plane_{};
};

}  // namespace bp
