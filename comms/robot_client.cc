#include "comms/robot_client.h"

#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>

namespace bp {
namespace {

// The robot scripts send floor(MULT * value) (seed 000, send_robot_data),
// clamped so a silly pose cannot overflow.
int32_t FloorFixed(double value) {
  const double v = std::floor(value * kMult);
  if (!std::isfinite(v)) return 0;
  if (v > INT32_MAX) return INT32_MAX;
  if (v < INT32_MIN) return INT32_MIN;
  return static_cast<int32_t>(v);
}

}  // namespace

Result<int> ConnectTcp(const std::string& host, int port) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  const std::string service = std::to_string(port);
  if (const int rc = getaddrinfo(host.c_str(), service.c_str(), &hints, &found); rc != 0) {
    return Status::Unavailable("cannot resolve " + host + ": " + gai_strerror(rc));
  }
  int fd = -1;
  std::string error = "no address";
  for (addrinfo* a = found; a; a = a->ai_next) {
    fd = ::socket(a->ai_family, a->ai_socktype, a->ai_protocol);
    if (fd < 0) continue;
    if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) break;
    error = std::strerror(errno);
    ::close(fd);
    fd = -1;
  }
  freeaddrinfo(found);
  if (fd < 0) return Status::Unavailable("cannot connect to " + host + ":" + service + ": " + error);
  return fd;
}

Result<std::unique_ptr<RobotClient>> RobotClient::Connect(const RobotClientOptions& options) {
  Result<int> connected = ConnectTcp(options.host, options.port);
  if (!connected.ok()) return connected.status();
  const int fd = *connected;
  if (options.tcp_nodelay) {
    const int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  }
  return std::unique_ptr<RobotClient>(new RobotClient(fd, options));
}

std::unique_ptr<RobotClient> RobotClient::Over(std::unique_ptr<RobotTransport> transport,
                                               const RobotClientOptions& options) {
  std::unique_ptr<RobotClient> client(new RobotClient(-1, options));
  client->transport_ = std::move(transport);
  return client;
}

RobotClient::~RobotClient() { Close(); }

void RobotClient::Close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  transport_.reset();
}

daoai::Request RobotClient::MakeRequest(int32_t command, int32_t payload_1,
                                        int32_t payload_2) const {
  daoai::Request r;
  for (int i = 0; i < 3; ++i) r.position[i] = FloorFixed(X_BF_.translation()[i] / options_.position_scale);
  const std::array<double, 4> fields = EncodeOrientation(X_BF_.linear(), options_.convention);
  for (int i = 0; i < 4; ++i) r.orientation[i] = FloorFixed(fields[i]);
  r.command = command;
  r.payload_1 = payload_1;
  r.payload_2 = payload_2;
  r.meta_1 = static_cast<int32_t>(options_.robot_type);
  r.meta_2 = options_.version;
  return r;
}

Status RobotClient::SendBytes(const uint8_t* data, size_t size) {
  while (size > 0) {
    const ssize_t n = ::send(fd_, data, size, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      return Status::Unavailable(std::string("send failed: ") + std::strerror(errno));
    }
    data += n;
    size -= static_cast<size_t>(n);
  }
  return Status::Ok();
}

Status RobotClient::ReceiveBytes(uint8_t* data, size_t size) {
  const auto deadline = std::chrono::steady_clock::now() + options_.timeout;
  while (size > 0) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) return Status::Unavailable("no response within the timeout");
    pollfd p{fd_, POLLIN, 0};
    const int rc = ::poll(&p, 1, static_cast<int>(left.count()));
    if (rc < 0 && errno == EINTR) continue;
    if (rc <= 0) return Status::Unavailable("no response within the timeout");
    const ssize_t n = ::recv(fd_, data, size, 0);
    if (n == 0) return Status::Unavailable("server closed the connection");
    if (n < 0) {
      if (errno == EINTR) continue;
      return Status::Unavailable(std::string("receive failed: ") + std::strerror(errno));
    }
    data += n;
    size -= static_cast<size_t>(n);
  }
  return Status::Ok();
}

Status RobotClient::Send(int32_t command, int32_t payload_1, int32_t payload_2) {
  if (transport_) return transport_->Write(MakeRequest(command, payload_1, payload_2), false);
  const auto bytes = daoai::EncodeRequest(MakeRequest(command, payload_1, payload_2));
  return SendBytes(bytes.data(), bytes.size());
}

Result<RobotReply> RobotClient::Receive() {
  if (transport_) {
    Result<daoai::Response> raw = transport_->Read(options_.timeout);
    if (!raw.ok()) return raw.status();
    return Decode(*raw);
  }
  std::array<uint8_t, daoai::kResponseSize> bytes{};
  if (Status s = ReceiveBytes(bytes.data(), bytes.size()); !s.ok()) return s;
  return Decode(daoai::DecodeResponse(bytes));
}

RobotReply RobotClient::Decode(const daoai::Response& raw) const {
  RobotReply reply;
  reply.raw = raw;
  reply.status = reply.raw.status;
  for (int i = 0; i < 6; ++i) reply.payload[i] = FromFixed(reply.raw.payload[i]);
  // recv_daoai_data(): daoai_data[15] is meta_1, daoai_data[16] meta_2.
  if (reply.raw.meta_1 != static_cast<int32_t>(options_.robot_type)) {
    reply.warnings.push_back("vision is not configured to communicate with a " +
                             std::string(ToString(options_.robot_type)) + " robot (meta_1 " +
                             std::to_string(reply.raw.meta_1) + ")");
  }
  if (reply.raw.meta_2 != options_.version) {
    reply.warnings.push_back("the DaoAI interface version (" + std::to_string(reply.raw.meta_2) +
                             ") does not match the version of this program (" +
                             std::to_string(options_.version) + ")");
  }
  Vec3 t;
  for (int i = 0; i < 3; ++i) t[i] = FromFixed(reply.raw.position[i]) * options_.position_scale;
  std::array<double, 4> fields{};
  for (int i = 0; i < 4; ++i) fields[i] = FromFixed(reply.raw.orientation[i]);
  if (Result<Mat3> R = DecodeOrientation(fields, options_.convention); R.ok()) {
    reply.X_BT = MakePose(*R, t);
  }
  return reply;
}

Result<RobotReply> RobotClient::Call(int32_t command, int32_t payload_1, int32_t payload_2) {
  if (transport_) {
    const Status s = transport_->Write(MakeRequest(command, payload_1, payload_2), true);
    if (!s.ok()) return s;
    return Receive();
  }
  if (Status s = Send(command, payload_1, payload_2); !s.ok()) return s;
  return Receive();
}

std::string DaoaiStatusName(int32_t status, DaoaiDialect dialect) {
  const bool v1 = dialect == DaoaiDialect::kSocketV1;
  switch (status) {
    case -1: return "UNKNOWN_COMMAND";
    case 2: return "OBJECTS_FOUND";
    case 3: return "NO_OBJECT_FOUND";
    case 4: return v1 ? "NO_IMAGE_CAPTURED" : "NO_COLLISION_FREE_POSE";
    case 5: return v1 ? "DETECTION" : "CAPTURE_SUCCESS";
    case 6: return "DROP_OFF_POSE";
    case 9: return "CAPTURE_FAIL";
    case 10: return "MODE_CALIBRATION";
    case 11: return "MODE_AUTO_CALIBRATION";
    case 12: return "GUIDANCE_CALIBRATION_GOOD";
    case 13: return "GUIDANCE_CALIBRATION_BAD";
    case 14: return "MODE_2D_AUTO_CALIBRATION";
    case 32: return "DONE_GUIDANCE_CALIBRATION";
    case 33: return "DONE_CALIBRATION";
    case 34: return "DONE_2D_AUTO_CALIBRATION";
    case 41: return "BOX_EMPTY";
    case 42: return "BOX_NOT_EMPTY";
    case 51: return "PRECISION_CHECK_SUCCESS";
    case 52: return "PRECISION_CHECK_FAIL";
    case 66: return "SWITCH_CONFIG_SUCCESS";
    case 67: return "SWITCH_CONFIG_FAIL";
    default: return "STATUS_" + std::to_string(status);
  }
}

}  // namespace bp
