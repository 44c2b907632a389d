// The robot side of the DaoAI socket protocol, played exactly as the seeds'
// UR scripts do (seed 000 / 003): send_robot_data() writes 12 int32 with
// floor(MULT * value), recv_daoai_data() reads 16 int32 and checks meta_1 /
// meta_2 against its own robot type and version. Blocking; one request at a
// time, as a robot controller does. For the simulator, tests and benches.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "comms/daoai_message.h"
#include "core/cell.h"
#include "core/conventions.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

struct RobotClientOptions {
  std::string host = "127.0.0.1";
  int port = 6969;
  RobotType robot_type = RobotType::kUR;            // meta_1
  OrientationConvention convention = OrientationConvention::kAxisAngle;
  int version = 2;                                  // meta_2
  // Which seed's script the robot plays (docs/protocols.md "Dialects"):
  // whether stop-manual (2) and guidance (10) read an answer, what status 4 means.
  DaoaiDialect dialect = DaoaiDialect::kVisionPilot;
  double position_scale = 1.0;                      // metres per wire unit
  std::chrono::milliseconds timeout{10000};         // per receive
  // TCP_NODELAY on the robot's socket. Robot controllers rarely let a program
  // set it (URScript's socket_open cannot): false plays such a robot, whose
  // small writes wait for the server's ACK of the previous one (Nagle).
  bool tcp_nodelay = true;
};

// What carries the robot's requests and the server's responses when not the
// DaoAI socket: e.g. Modbus registers (comms/modbus_robot_sim.h). The flows
// run unchanged over any transport.
class RobotTransport {
 public:
  virtual ~RobotTransport() = default;
  // send_robot_data(); `expects_response`: the robot script reads an answer.
  virtual Status Write(const daoai::Request& request, bool expects_response) = 0;
  // recv_daoai_data(): the next response, or Unavailable after `timeout`.
  virtual Result<daoai::Response> Read(std::chrono::milliseconds timeout) = 0;
};

// A decoded response with the checks recv_daoai_data() makes.
struct RobotReply {
  daoai::Response raw;
  std::optional<Pose> X_BT;   // decoded pose (absent when the fields do not decode)
  double payload[6] = {};     // payload_i / MULT, as the script divides them
  int32_t status = 0;
  std::vector<std::string> warnings;  // the script's popups for meta mismatches
};

// A TCP connection to host:port over the first address getaddrinfo gives
// that connects, with the socket's default options. @returns the connected
// descriptor (the caller closes it), or Unavailable naming host, port and why.
Result<int> ConnectTcp(const std::string& host, int port);

class RobotClient {
 public:
  // @returns Unavailable when the server cannot be reached.
  static Result<std::unique_ptr<RobotClient>> Connect(const RobotClientOptions& options);
  // A client over another transport (options.host / port are not used).
  static std::unique_ptr<RobotClient> Over(std::unique_ptr<RobotTransport> transport,
                                           const RobotClientOptions& options);
  ~RobotClient();
  RobotClient(const RobotClient&) = delete;
  RobotClient& operator=(const RobotClient&) = delete;

  // The robot's current pose, sent with every request (send_robot_data).
  void SetPose(const Pose& X_BF) { X_BF_ = X_BF; }
  const Pose& pose() const { return X_BF_; }
  const RobotClientOptions& options() const { return options_; }
  void set_timeout(std::chrono::milliseconds timeout) { options_.timeout = timeout; }
  // Closes the connection (further calls fail with Unavailable).
  void Close();

  // The 48-byte request send_robot_data() builds for `command`.
  daoai::Request MakeRequest(int32_t command, int32_t payload_1 = 0, int32_t payload_2 = 0) const;
  // Sends a request for a command whose script reads no answer.
  Status Send(int32_t command, int32_t payload_1 = 0, int32_t payload_2 = 0);
  // Sends, then reads exactly one 64-byte response.
  Result<RobotReply> Call(int32_t command, int32_t payload_1 = 0, int32_t payload_2 = 0);

  // Raw access for tests over the socket: bytes out, bytes in (exact counts,
  // with timeout).
  Status SendBytes(const uint8_t* data, size_t size);
  Status ReceiveBytes(uint8_t* data, size_t size);
  Result<RobotReply> Receive();

 private:
  RobotClient(int fd, RobotClientOptions options) : fd_(fd), options_(std::move(options)) {}
  RobotReply Decode(const daoai::Response& raw) const;
  int fd_ = -1;
  std::unique_ptr<RobotTransport> transport_;  // null: the socket fd_
  RobotClientOptions options_;
  Pose X_BF_ = Pose::Identity();
};

// Status names of seed 000 (vision_pilot) / 004 (socket_v1), e.g. "OBJECTS_FOUND".
std::string DaoaiStatusName(int32_t status, DaoaiDialect dialect);

}  // namespace bp
