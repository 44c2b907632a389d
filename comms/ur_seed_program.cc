#include "comms/ur_seed_program.h"

#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <exception>
#include <limits>
#include <sstream>
#include <thread>

#include "comms/robot_client.h"
#include "core/conventions.h"

namespace bp {
namespace {

using Clock = std::chrono::steady_clock;

// Seed 000 "机器人发送指令常量" and "DaoAI Vision Pilot回应常量".
constexpr int RC_DAOAI_NO_COMMAND = -1;
constexpr int RC_START_MANUAL_CALIBRATION = 1;
constexpr int RC_STOP_MANUAL_CALIBRATION = 2;
constexpr int RC_MANUAL_ACCUMULATE_POSE = 6;
constexpr int RC_START_AUTO_CALIBRATION = 4;
constexpr int RC_AUTO_ACCUMULATE_POSE = 7;
constexpr int RC_GUIDANCE_CALIBRATION = 10;
constexpr int RC_START_2D_AUTO_CALIBRATION = 11;
constexpr int RC_AUTO_ACCUMULATE_2D_POSE = 12;
constexpr int RC_DAOAI_CAPTURE_AND_PROCESS_ASYNC = 19;
constexpr int RC_DAOAI_CAPTURE_AND_PROCESS = 20;
constexpr int RC_DAOAI_PICK_POSE = 21;
constexpr int RC_SEND_POSE = 30;
// daoai_check_box_empty() sends RC_CHEKC_EMPTY_BOX, which the seed never
// defines; RC_CHECK_EMPTY_BOX = 40 is what it means.
constexpr int RC_CHEKC_EMPTY_BOX = 40;
constexpr int RC_PRECISION_CHECK = 50;
constexpr int RC_SWITCH_CONFIG = 69;

constexpr int DAOAI_NO_OBJECT_FOUND = 3;
constexpr int DAOAI_NO_COLLISION_FREE_POSE = 4;
constexpr int DAOAI_CAPTURE_SUCCESS = 5;
constexpr int DAOAI_MODE_CALIBRATION = 10;
constexpr int DAOAI_MODE_AUTO_CALIBRATION = 11;
constexpr int DAOAI_MODE_2D_AUTO_CALIBRATION = 14;
constexpr int DAOAI_DONE_CALIBRATION = 33;
constexpr int DAOAI_DONE_2D_AUTO_CALIBRATION = 34;
constexpr int DAOAI_BOX_EMPTY = 41;
constexpr int DAOAI_BOX_NOT_EMPTY = 42;
constexpr int DAOAI_PRECISION_CHECK_SUCCESS = 51;
constexpr int DAOAI_PRECISION_CHECK_FAIL = 52;
constexpr int DAOAI_SWITCH_CONFIG_SUCCESS = 66;
constexpr int DAOAI_SWITCH_CONFIG_FAIL = 67;

// A controller halts the program (runtime error, lost connection); the
// exception carries that from a primitive up to Run() and never leaves it.
struct Halt {
  Status status;
};

[[noreturn]] void HaltWith(Status s) { throw Halt{std::move(s)}; }

// URScript's floor(): a real to an int.
double Floor(double v) { return std::floor(v); }

// A real written to an integer port: truncated toward zero (header comment).
int64_t ToInt(double v) {
  if (!std::isfinite(v)) HaltWith(Status::OutOfRange("a non-finite value written to a port"));
  return static_cast<int64_t>(std::trunc(v));
}

// URScript's str(): shortest form, as the popup of daoai_precision_check shows it.
std::string Str(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

}  // namespace

UrPose ToUrPose(const Pose& X) {
  const std::array<double, 4> r = EncodeOrientation(X.linear(), OrientationConvention::kAxisAngle);
  return {X.translation().x(), X.translation().y(), X.translation().z(), r[0], r[1], r[2]};
}

Pose FromUrPose(const UrPose& p) {
  const Vec3 v(p[3], p[4], p[5]);
  const double angle = v.norm();
  const Mat3 R = angle < 1e-12 ? Mat3::Identity() : Mat3(Eigen::AngleAxisd(angle, v / angle));
  return MakePose(R, Vec3(p[0], p[1], p[2]));
}

// ---- Links: the socket (seed 003) or the controller's registers (seed 000). ----

class UrSeedProgram::Link {
 public:
  virtual ~Link() = default;
};

class UrSeedProgram::SocketLink final : public Link {
 public:
  explicit SocketLink(int fd) : fd_(fd) {}
  ~SocketLink() override { ::close(fd_); }

  // socket_send_int: one int32, big-endian, one send() call.
  Status SendInt(int32_t v) {
    const uint32_t u = static_cast<uint32_t>(v);
    const uint8_t bytes[4] = {static_cast<uint8_t>(u >> 24), static_cast<uint8_t>(u >> 16),
                              static_cast<uint8_t>(u >> 8), static_cast<uint8_t>(u)};
    size_t sent = 0;
    while (sent < 4) {
      const ssize_t n = ::send(fd_, bytes + sent, 4 - sent, MSG_NOSIGNAL);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return Status::Unavailable(std::string("socket_send_int failed: ") + std::strerror(errno));
      sent += static_cast<size_t>(n);
    }
    return Status::Ok();
  }

  // socket_read_binary_integer(number): `number` int32 within `timeout`, or
  // none ([0]); bytes of an incomplete read stay for the next call.
  Result<std::vector<int32_t>> ReadInts(int number, std::chrono::milliseconds timeout) {
    const size_t want = static_cast<size_t>(number) * 4;
    const auto deadline = Clock::now() + timeout;
    while (buffer_.size() < want) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
      if (left.count() <= 0) return std::vector<int32_t>{};
      pollfd p{fd_, POLLIN, 0};
      const int rc = ::poll(&p, 1, static_cast<int>(left.count()));
      if (rc < 0 && errno == EINTR) continue;
      if (rc <= 0) return std::vector<int32_t>{};
      uint8_t chunk[256];
      const ssize_t n = ::recv(fd_, chunk, std::min(sizeof(chunk), want - buffer_.size()), 0);
      if (n == 0) return Status::Unavailable("the server closed the connection");
      if (n < 0) {
        if (errno == EINTR) continue;
        return Status::Unavailable(std::string("socket read failed: ") + std::strerror(errno));
      }
      buffer_.insert(buffer_.end(), chunk, chunk + n);
    }
    std::vector<int32_t> out(static_cast<size_t>(number));
    for (size_t i = 0; i < out.size(); ++i) {
      const uint8_t* b = buffer_.data() + 4 * i;
      out[i] = static_cast<int32_t>((uint32_t{b[0]} << 24) | (uint32_t{b[1]} << 16) |
                                    (uint32_t{b[2]} << 8) | uint32_t{b[3]});
    }
    buffer_.erase(buffer_.begin(), buffer_.begin() + static_cast<std::ptrdiff_t>(want));
    return out;
  }

 private:
  int fd_;
  std::vector<uint8_t> buffer_;
};

class UrSeedProgram::ModbusLink final : public Link {
 public:
  explicit ModbusLink(ModbusRobotSim& robot) : robot_(robot) {}
  ModbusRobotSim& robot() { return robot_; }

 private:
  ModbusRobotSim& robot_;
};

Result<std::unique_ptr<UrSeedProgram>> UrSeedProgram::OverSocket(const std::string& host, int port,
                                                                 const UrPose& start,
                                                                 UrSeedProgramOptions options) {
  Result<int> fd = ConnectTcp(host, port);
  if (!fd.ok()) return Status::Unavailable("socket_open: " + fd.status().message());
  // No TCP_NODELAY: URScript's socket_open has no such option.
  return std::unique_ptr<UrSeedProgram>(
      new UrSeedProgram(std::make_unique<SocketLink>(*fd), start, std::move(options)));
}

std::unique_ptr<UrSeedProgram> UrSeedProgram::OverModbus(ModbusRobotSim& robot, const UrPose& start,
                                                         UrSeedProgramOptions options) {
  return std::unique_ptr<UrSeedProgram>(
      new UrSeedProgram(std::make_unique<ModbusLink>(robot), start, std::move(options)));
}

UrSeedProgram::UrSeedProgram(std::unique_ptr<Link> link, const UrPose& start, UrSeedProgramOptions options)
    : link_(std::move(link)),
      options_(std::move(options)),
      modbus_(dynamic_cast<ModbusLink*>(link_.get()) != nullptr),
      actual_tcp_pose_(start),
      daoai_plane_(options_.daoai_plane) {}

UrSeedProgram::~UrSeedProgram() = default;

Status UrSeedProgram::Run(const std::function<void()>& body) {
  try {
    body();
  } catch (const Halt& h) {
    return h.status;
  }
  return Status::Ok();
}

// ---- URScript primitives. ----

void UrSeedProgram::socket_send_int(double value) {
  const int64_t v = ToInt(value);
  if (v < std::numeric_limits<int32_t>::min() || v > std::numeric_limits<int32_t>::max()) {
    HaltWith(Status::OutOfRange("socket_send_int(" + std::to_string(v) + "): not an int32"));
  }
  if (Status s = static_cast<SocketLink&>(*link_).SendInt(static_cast<int32_t>(v)); !s.ok()) HaltWith(s);
}

std::vector<double> UrSeedProgram::socket_read_binary_integer(int number) {
  if (Clock::now() > answer_deadline_) {
    HaltWith(Status::Unavailable("no answer within " + std::to_string(options_.answer_timeout.count()) + " ms"));
  }
  Result<std::vector<int32_t>> ints =
      static_cast<SocketLink&>(*link_).ReadInts(number, options_.socket_read_timeout);
  if (!ints.ok()) HaltWith(ints.status());
  std::vector<double> out = {static_cast<double>(ints->size())};  // list[0]: how many were read
  for (int32_t v : *ints) out.push_back(v);
  return out;
}

void UrSeedProgram::write_port_register(int address, double value) {
  const int64_t v = ToInt(value);
  if (v < std::numeric_limits<int16_t>::min() || v > std::numeric_limits<int16_t>::max()) {
    HaltWith(Status::OutOfRange("write_port_register(" + std::to_string(address) + ", " + std::to_string(v) +
                                "): does not fit a 16-bit register"));
  }
  static_cast<ModbusLink&>(*link_).robot().WriteRegister(address, static_cast<uint16_t>(static_cast<int16_t>(v)));
}

double UrSeedProgram::read_port_register(int address) {
  return static_cast<int16_t>(static_cast<ModbusLink&>(*link_).robot().ReadRegister(address));
}

// ---- Networking (seed 000 "Networking/收发和通讯"; seed 003 for the socket). ----

void UrSeedProgram::modbustcp_send_robot_data(const std::array<double, 12>& robot_data) {
  int i = 0;
  while (i < 12) {
    write_port_register(128 + i, robot_data[static_cast<size_t>(i)]);
    i = i + 1;
  }
  write_port_register(144, 1);
}

void UrSeedProgram::send_robot_data() {
  std::array<double, 12> robot_data{};
  const UrPose p_actual_pose = get_actual_tcp_pose();
  robot_data[0] = Floor(mult * p_actual_pose[0]);
  robot_data[1] = Floor(mult * p_actual_pose[1]);
  robot_data[2] = Floor(mult * p_actual_pose[2]);
  robot_data[3] = Floor(mult * p_actual_pose[3]);
  robot_data[4] = Floor(mult * p_actual_pose[4]);
  robot_data[5] = Floor(mult * p_actual_pose[5]);
  robot_data[6] = Floor(mult * 0.0);
  robot_data[7] = daoai_r_command_;
  robot_data[8] = daoai_payload_1_;
  robot_data[9] = daoai_payload_2_;
  robot_data[10] = DAOAI_ROBOT_TYPE;
  robot_data[11] = DAOAI_META_VERSION;
  SendFields(robot_data);
  daoai_r_command_ = RC_DAOAI_NO_COMMAND;
}

void UrSeedProgram::SendFields(const std::array<double, 12>& robot_data) {
  sent_at_ = Clock::now();
  sent_command_ = static_cast<int>(robot_data[7]);
  if (modbus_) {
    modbustcp_send_robot_data(robot_data);
  } else {
    // seed 003 (send_robot_data_2d's socket form): one socket_send_int per field.
    for (double v : robot_data) socket_send_int(v);
  }
  ++requests_sent_;
}

std::array<double, 17> UrSeedProgram::modbustcp_recv_daoai_data() {
  int i = 1;
  std::array<double, 17> daoai_data{16, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
  while (read_port_register(145) == 0) {
    if (Clock::now() > answer_deadline_) {
      HaltWith(Status::Unavailable("register 145 still 0 after " +
                                   std::to_string(options_.answer_timeout.count()) + " ms"));
    }
    std::this_thread::sleep_for(options_.register_poll);
  }
  while (i < 17) {
    daoai_data[static_cast<size_t>(i)] = read_port_register(128 + i);
    i = i + 1;
  }
  write_port_register(145, 0);
  return daoai_data;
}

std::vector<double> UrSeedProgram::ReceiveFields() {
  answer_deadline_ = Clock::now() + options_.answer_timeout;
  std::vector<double> daoai_data;
  bool wait_for_data = true;
  while (wait_for_data == true) {
    if (modbus_) {
      const std::array<double, 17> d = modbustcp_recv_daoai_data();
      daoai_data.assign(d.begin(), d.end());
    } else {
      daoai_data = socket_read_binary_integer(16);
    }
    if (daoai_data[0] == 16) wait_for_data = false;
  }
  answer_times_.push_back({sent_command_, std::chrono::duration<double, std::milli>(Clock::now() - sent_at_).count()});
  if (daoai_data[15] != DAOAI_ROBOT_TYPE) {
    popup("Pick-it is not configured to communicate with a UR robot.", /*failure=*/true);
  }
  if (daoai_data[16] != DAOAI_META_VERSION) {
    popup("The DaoAI interface version does not match the version of this program.", /*failure=*/true);
  }
  return daoai_data;
}

void UrSeedProgram::recv_daoai_data() {
  const std::vector<double> daoai_data = ReceiveFields();
  daoai_tcp_pose_ = {daoai_data[1] / mult, daoai_data[2] / mult, daoai_data[3] / mult,
                     daoai_data[4] / mult, daoai_data[5] / mult, daoai_data[6] / mult};
  daoai_payload_1_ = daoai_data[8] / mult;
  daoai_payload_2_ = daoai_data[9] / mult;
  daoai_payload_3_ = daoai_data[10] / mult;
  daoai_payload_4_ = daoai_data[11] / mult;
  daoai_payload_5_ = daoai_data[12] / mult;
  daoai_payload_6_ = daoai_data[13] / mult;
  daoai_status_ = static_cast<int>(daoai_data[14]);
}

// seed 000 send_robot_data_2d (seed 003: the same fields, one socket_send_int each).
void UrSeedProgram::send_robot_data_2d(const UrPose& plane, bool optional_z, double z_value) {
  std::array<double, 12> robot_data{};
  const Pose base_in_plane = FromUrPose(plane).inverse();                          // pose_inv(plane)
  const UrPose tool_in_plane = ToUrPose(base_in_plane * FromUrPose(get_actual_tcp_pose()));  // pose_trans
  const UrPose p_actual_pose = tool_in_plane;
  if (optional_z) {
    robot_data[2] = Floor(mult * z_value);
  } else {
    robot_data[2] = Floor(mult * p_actual_pose[2]);
  }
  robot_data[0] = Floor(mult * p_actual_pose[0]);
  robot_data[1] = Floor(mult * p_actual_pose[1]);
  robot_data[3] = Floor(mult * p_actual_pose[3]);
  robot_data[4] = Floor(mult * p_actual_pose[4]);
  robot_data[5] = Floor(mult * p_actual_pose[5]);
  robot_data[6] = Floor(mult * 0.0);
  robot_data[7] = daoai_r_command_;
  robot_data[8] = daoai_payload_1_;
  robot_data[9] = daoai_payload_2_;
  robot_data[10] = DAOAI_ROBOT_TYPE;
  robot_data[11] = DAOAI_META_VERSION;
  SendFields(robot_data);
  daoai_r_command_ = RC_DAOAI_NO_COMMAND;
}

// seed 000 recv_daoai_data_2d: the answer's pose is the tool in the plane;
// the robot keeps its own z.
void UrSeedProgram::recv_daoai_data_2d(const UrPose& plane) {
  const std::vector<double> daoai_data = ReceiveFields();
  const UrPose tool_in_plane = {daoai_data[1] / mult, daoai_data[2] / mult, daoai_data[3] / mult,
                                daoai_data[4] / mult, daoai_data[5] / mult, daoai_data[6] / mult};
  const UrPose bp = ToUrPose(FromUrPose(plane) * FromUrPose(tool_in_plane));  // pose_trans(plane, tool_in_plane)
  const UrPose cur_pose = get_actual_tcp_pose();
  daoai_tcp_pose_ = bp;
  daoai_payload_1_ = daoai_data[8] / mult;
  daoai_payload_2_ = daoai_data[9] / mult;
  daoai_payload_3_ = daoai_data[10] / mult;
  daoai_payload_4_ = daoai_data[11] / mult;
  daoai_payload_5_ = daoai_data[12] / mult;
  daoai_payload_6_ = daoai_data[13] / mult;
  daoai_status_ = static_cast<int>(daoai_data[14]);
  daoai_tcp_pose_[2] = cur_pose[2];
}

// ---- Calibration (seed 000 "Calibration/校准函数"). ----

bool UrSeedProgram::daoai_start_manual_calibration() {
  daoai_r_command_ = RC_START_MANUAL_CALIBRATION;
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ != DAOAI_MODE_CALIBRATION) return false;
  return true;
}

bool UrSeedProgram::daoai_manual_accumulate_calibration() {
  daoai_r_command_ = RC_MANUAL_ACCUMULATE_POSE;
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ != DAOAI_MODE_CALIBRATION) return false;
  if (daoai_status_ == DAOAI_DONE_CALIBRATION) return false;  // unreachable as printed
  return true;
}

bool UrSeedProgram::daoai_stop_manual_calibration() {
  daoai_r_command_ = RC_STOP_MANUAL_CALIBRATION;
  send_robot_data();
  popup("DaoAI Done Calibration.", /*failure=*/false);
  return true;
}

bool UrSeedProgram::daoai_guidance_accumulate_calibration() {
  daoai_r_command_ = RC_GUIDANCE_CALIBRATION;
  send_robot_data();
  return true;
}

bool UrSeedProgram::daoai_start_auto_calibration() {
  daoai_r_command_ = RC_START_AUTO_CALIBRATION;
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ != DAOAI_MODE_AUTO_CALIBRATION) return false;
  return true;
}

bool UrSeedProgram::daoai_auto_accumulate() {
  daoai_r_command_ = RC_AUTO_ACCUMULATE_POSE;
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ == DAOAI_DONE_CALIBRATION) return false;
  return true;
}

// ---- 2D auto calibration (seed 000 "2D Auto Calibration"). ----

bool UrSeedProgram::daoai_start_auto_calibration_2d() {
  daoai_r_command_ = RC_START_2D_AUTO_CALIBRATION;
  send_robot_data_2d(daoai_plane_);
  recv_daoai_data_2d(daoai_plane_);
  if (daoai_status_ != DAOAI_MODE_2D_AUTO_CALIBRATION) {
    popup("DaoAI Cannot Start Auto 2d Calibration.", /*failure=*/true);
    return false;
  }
  return true;
}

bool UrSeedProgram::daoai_auto_accumulate_2d() {
  daoai_r_command_ = RC_AUTO_ACCUMULATE_2D_POSE;
  send_robot_data_2d(daoai_plane_);
  recv_daoai_data_2d(daoai_plane_);
  if (daoai_status_ == DAOAI_DONE_2D_AUTO_CALIBRATION) {
    popup("DaoAI Done Calibration.", /*failure=*/false);
    return false;
  }
  return true;
}

// ---- Teach, capture, pick (seed 000). ----

void UrSeedProgram::daoai_teach_pose() {
  daoai_r_command_ = RC_SEND_POSE;
  send_robot_data();
}

bool UrSeedProgram::daoai_capture_and_process_async() {
  daoai_r_command_ = RC_DAOAI_CAPTURE_AND_PROCESS_ASYNC;
  daoai_payload_1_ = daoai_task_id_;  // printed `task_id`, which the seed never defines
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ == DAOAI_CAPTURE_SUCCESS) return true;
  popup("DaoAI Image Capture Failed.", /*failure=*/true);
  return false;
}

bool UrSeedProgram::daoai_capture_and_process() {
  daoai_r_command_ = RC_DAOAI_CAPTURE_AND_PROCESS;
  daoai_payload_1_ = daoai_task_id_;
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ == DAOAI_CAPTURE_SUCCESS) return true;
  popup("DaoAI Image Capture Failed.", /*failure=*/true);
  return false;
}

bool UrSeedProgram::daoai_get_picking_pose() {
  daoai_r_command_ = RC_DAOAI_PICK_POSE;
  daoai_payload_1_ = daoai_task_id_;
  send_robot_data();
  recv_daoai_data();
  daoai_num_remaining_objects_ = daoai_payload_1_;
  if (daoai_status_ == DAOAI_NO_OBJECT_FOUND) {
    popup("NO OBJECTS FOUND.", /*failure=*/true);
    return false;
  }
  if (daoai_status_ == DAOAI_NO_COLLISION_FREE_POSE) {
    popup("NO Collision-free PICK pose.", /*failure=*/true);
    return false;
  }
  if (daoai_payload_1_ <= 0) {
    popup("NO OBJECTS FOUND.", /*failure=*/true);
    return false;
  }
  pick_pose_ = daoai_tcp_pose_;
  return true;
}

// ---- 2D teach, capture, pick (seed 000 "Teach Pose", "2D Camera Capture", "2D Pick"). ----

void UrSeedProgram::daoai_teach_pose_2d() {
  daoai_r_command_ = RC_DAOAI_CAPTURE_AND_PROCESS;  // as printed (header comment): not RC_SEND_POSE
  send_robot_data_2d(daoai_plane_);
}

bool UrSeedProgram::daoai_capture_and_process_2d_async() {
  daoai_r_command_ = RC_DAOAI_CAPTURE_AND_PROCESS_ASYNC;
  daoai_payload_1_ = daoai_task_id_;
  send_robot_data_2d(daoai_plane_);
  recv_daoai_data_2d(daoai_plane_);
  if (daoai_status_ == DAOAI_CAPTURE_SUCCESS) return true;
  popup("DaoAI Image Capture Failed.", /*failure=*/true);
  return false;
}

bool UrSeedProgram::daoai_capture_and_process_2d() {
  daoai_r_command_ = RC_DAOAI_CAPTURE_AND_PROCESS;
  daoai_payload_1_ = daoai_task_id_;
  send_robot_data_2d(daoai_plane_);
  recv_daoai_data_2d(daoai_plane_);
  if (daoai_status_ == DAOAI_CAPTURE_SUCCESS) return true;
  popup("DaoAI Image Capture Failed.", /*failure=*/true);
  return false;
}

bool UrSeedProgram::daoai_get_picking_pose_2d() {
  daoai_r_command_ = RC_DAOAI_PICK_POSE;
  daoai_payload_1_ = daoai_task_id_;
  send_robot_data_2d(daoai_plane_);
  recv_daoai_data_2d(daoai_plane_);
  daoai_num_remaining_objects_ = daoai_payload_1_;
  daoai_object_type_id_ = daoai_payload_2_;
  if (daoai_status_ == DAOAI_NO_OBJECT_FOUND) {
    popup("No object found or detected.", /*failure=*/true);
    return false;
  }
  if (daoai_status_ == DAOAI_NO_COLLISION_FREE_POSE) {
    popup("NO Collision-free PICK pose.", /*failure=*/true);
    return false;
  }
  if (daoai_payload_1_ <= 0) return false;  // no popup, as printed
  pick_pose_ = daoai_tcp_pose_;
  return true;
}

bool UrSeedProgram::daoai_cam_config(int id) {
  // Printed `payload_1 = id`: a local of this function that send_robot_data
  // never reads, so RC 69 carries the stale daoai_payload_1.
  if (options_.cam_config_sets_payload) daoai_payload_1_ = id;
  daoai_r_command_ = RC_SWITCH_CONFIG;
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ == DAOAI_SWITCH_CONFIG_SUCCESS) return true;
  if (daoai_status_ == DAOAI_SWITCH_CONFIG_FAIL) {
    popup("DaoAI switch camera config failed, please check your configs.", /*failure=*/true);
  }
  return false;
}

// ---- Helpers (seed 000 "Helper"). ----

bool UrSeedProgram::daoai_check_box_empty() {
  daoai_r_command_ = RC_CHEKC_EMPTY_BOX;
  daoai_payload_1_ = daoai_task_id_;
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ == DAOAI_BOX_NOT_EMPTY) return false;
  if (daoai_status_ == DAOAI_BOX_EMPTY) {
    popup("Box Empty.", /*failure=*/false);
    return true;
  }
  return false;
}

int UrSeedProgram::daoai_remaining_objects() const { return static_cast<int>(daoai_num_remaining_objects_); }

void UrSeedProgram::daoai_switch_job(int id) { daoai_task_id_ = id; }

int UrSeedProgram::daoai_object_type() const { return static_cast<int>(daoai_object_type_id_); }

bool UrSeedProgram::daoai_precision_check() {
  daoai_r_command_ = RC_PRECISION_CHECK;
  daoai_payload_1_ = daoai_task_id_;
  send_robot_data();
  recv_daoai_data();
  if (daoai_status_ == DAOAI_PRECISION_CHECK_FAIL) {
    popup("DaoAI drift check failed, please make sure the sticker is visible and has not moved since "
          "initial define.", /*failure=*/true);
    return false;
  }
  if (daoai_status_ == DAOAI_PRECISION_CHECK_SUCCESS) {
    std::string msg = "3D error is : " + Str(daoai_payload_1_);
    msg = msg + "mm";
    popup(msg, /*failure=*/false);
    return true;
  }
  return false;
}

// ---- The controller. ----

void UrSeedProgram::MoveL(const UrPose& pose) {
  moves_.push_back(pose);
  actual_tcp_pose_ = pose;
}

void UrSeedProgram::MoveJ(const UrPose& pose) { MoveL(pose); }

void UrSeedProgram::popup(const std::string& text, bool failure) { popups_.push_back({text, failure}); }

std::vector<std::string> UrSeedProgram::failure_popups() const {
  std::vector<std::string> out;
  for (const UrPopup& p : popups_) {
    if (p.failure) out.push_back(p.text);
  }
  return out;
}

// ---- Robot Programs. The seed's Wait lines are left out (no arm to settle). ----

void UrSeedProgram::ManualCalibrationProgram(const std::vector<UrPose>& waypoints) {
  popup("Start Manual Calibration", /*failure=*/false);
  if (waypoints.empty()) return;
  if (daoai_start_manual_calibration()) {
    MoveJ(waypoints[0]);
  }
  daoai_manual_accumulate_calibration();
  for (size_t i = 1; i < waypoints.size(); ++i) {  // "#Repeats ..." up to Waypoint_9
    MoveJ(waypoints[i]);
    daoai_manual_accumulate_calibration();
  }
  daoai_stop_manual_calibration();
}

int UrSeedProgram::AutoCalibrationProgram(const UrPose& center_pose, int max_loops) {
  popup("Start Auto Calibration", /*failure=*/false);
  MoveJ(center_pose);
  int loops = 0;
  if (daoai_start_auto_calibration()) {
    while (loops < max_loops && daoai_auto_accumulate()) {  // printed daoai_auto_accumulate_calibration()
      ++loops;
      const UrPose calibra_pose = daoai_tcp_pose_;
      MoveL(calibra_pose);
    }
  }
  return loops;
}

int UrSeedProgram::AutoCalibration2DProgram(const UrPose& center_pose, int max_loops) {
  popup("Start Auto Calibration", /*failure=*/false);
  MoveJ(center_pose);
  int loops = 0;
  if (daoai_start_auto_calibration_2d()) {
    while (loops < max_loops && daoai_auto_accumulate_2d()) {
      ++loops;
      const UrPose calibra_pose = daoai_tcp_pose_;
      MoveL(calibra_pose);
    }
  }
  return loops;
}

int UrSeedProgram::Pick2DProgram(const UrPose& detection_pose, int max_cycles) {
  int picks = 0;
  for (int cycle = 0; cycle < max_cycles; ++cycle) {
    MoveJ(detection_pose);
    if (daoai_check_box_empty()) break;
    if (!daoai_capture_and_process_2d()) break;
    bool picked_last = false;
    while (!picked_last && daoai_get_picking_pose_2d()) {
      MoveL(detection_pose);
      MoveL(pick_pose_);
      MoveL(detection_pose);
      ++picks;
      picked_last = daoai_remaining_objects() <= 1;  // seed 000 step 7, as in PickProgram
    }
    if (!picked_last) break;
  }
  return picks;
}

int UrSeedProgram::PickLoopAsPrinted(const UrPose& detection_pose) {
  int picks = 0;
  if (daoai_capture_and_process()) {
    while (daoai_get_picking_pose()) {
      MoveL(detection_pose);
      MoveL(pick_pose_);
      MoveL(detection_pose);
      ++picks;
    }
  }
  return picks;
}

int UrSeedProgram::PickProgram(const UrPose& detection_pose, int max_cycles) {
  int picks = 0;
  for (int cycle = 0; cycle < max_cycles; ++cycle) {
    MoveJ(detection_pose);
    if (daoai_check_box_empty()) break;
    if (!daoai_capture_and_process()) break;
    bool picked_last = false;
    while (!picked_last && daoai_get_picking_pose()) {
      MoveL(detection_pose);
      MoveL(pick_pose_);
      MoveL(detection_pose);
      ++picks;
      // Seed 000 step 7: payload_1 = 1 marks the last pose of this capture.
      picked_last = daoai_remaining_objects() <= 1;
    }
    if (!picked_last) break;  // a pick pose failed (its popup says why)
  }
  return picks;
}

int UrSeedProgram::PickCorrectPlaceProgram(const UrPose& detection_pose, const UrPose& adjust_det_pose,
                                           const UrPose& place_det_pose, const UrPose& pre_drop_pose,
                                           const UrPose& obj_in_Place, int iterations) {
  int picks = 0;
  UrPose obj_in_tool{}, place_in_base{};
  for (int i = 0; i < iterations; ++i) {  // Loop
    int stage = 0;
    if (stage == 0) {
      daoai_switch_job(0);
      MoveJ(detection_pose);
      if (daoai_capture_and_process()) {
        if (daoai_get_picking_pose()) {
          stage = 1;
          MoveJ(pick_pose_);
          ++picks;
        }
      }
    }
    if (stage == 1) {
      daoai_switch_job(1);
      MoveJ(adjust_det_pose);
      if (daoai_capture_and_process()) {
        if (daoai_get_picking_pose()) {
          stage = 2;
          obj_in_tool = pick_pose_;
        }
      }
    }
    if (stage == 2) {
      daoai_switch_job(3);
      MoveJ(place_det_pose);
      if (daoai_capture_and_process()) {
        if (daoai_get_picking_pose()) {
          stage = 3;
          place_in_base = pick_pose_;
        }
      }
    }
    if (stage == 3) {
      const Pose obj_in_base = FromUrPose(place_in_base) * FromUrPose(obj_in_Place);  // pose_trans
      const Pose t_in_obj = FromUrPose(obj_in_tool).inverse();                        // pose_inv
      const UrPose tool_in_base = ToUrPose(obj_in_base * t_in_obj);
      MoveJ(pre_drop_pose);
      MoveJ(tool_in_base);
      MoveJ(pre_drop_pose);
      stage = 0;
    }
  }
  return picks;
}

}  // namespace bp
