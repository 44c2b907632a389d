// Issue 39 over real loopback sockets: connection caps per listener and per
// peer address, allowlists as networks, who may change the cell, TCP
// keepalive on robot connections, and the accept back-off when the process
// runs out of descriptors. Clients bind to 127.0.0.x to be different peers.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cstring>
#include <filesystem>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/gri_handler.h"
#include "comms/gri_message.h"
#include "comms/gri_server.h"
#include "tests/testing/process_stats.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

using namespace std::chrono_literals;
using testing::MakeTestCell;
using testing::ScriptedPlanner;
using testing::WaitUntil;

// A robot on a raw socket bound to `from` (a 127.0.0.0/8 address).
class Peer {
 public:
  Peer(const std::string& from, int port) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in local{};
    local.sin_family = AF_INET;
    ::inet_pton(AF_INET, from.c_str(), &local.sin_addr);
    ::bind(fd_, reinterpret_cast<sockaddr*>(&local), sizeof(local));
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0;
    timeval tv{3, 0};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  }
  ~Peer() {
    if (fd_ >= 0) ::close(fd_);
  }
  Peer(const Peer&) = delete;
  Peer& operator=(const Peer&) = delete;
  bool connected() const { return connected_; }
  int local_port() const {
    sockaddr_in a{};
    socklen_t n = sizeof(a);
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &n);
    return ntohs(a.sin_port);
  }
  bool Send(const void* data, size_t n) {
    return ::send(fd_, data, n, MSG_NOSIGNAL) == static_cast<ssize_t>(n);
  }
  // The next `n` bytes, or nullopt on EOF, reset or the 3 s receive timeout.
  std::optional<std::vector<uint8_t>> Receive(size_t n) {
    std::vector<uint8_t> out(n);
    size_t got = 0;
    while (got < n) {
      const ssize_t r = ::recv(fd_, out.data() + got, n - got, 0);
      if (r <= 0) return std::nullopt;
      got += static_cast<size_t>(r);
    }
    return out;
  }
  // The answer; a default Response, without reading, for commands the robot
  // reads no answer to (`answered` false).
  std::optional<daoai::Response> Call(int32_t command, int32_t payload_1 = 0, bool answered = true) {
    daoai::Request r;
    r.position = {5000, -2500, 3000};
    r.orientation = {0, 0, 15708, 0};
    r.command = command;
    r.payload_1 = payload_1;
    r.meta_1 = 7;
    r.meta_2 = 2;
    const auto bytes = daoai::EncodeRequest(r);
    if (!Send(bytes.data(), bytes.size())) return std::nullopt;
    if (!answered) return daoai::Response{};
    std::optional<std::vector<uint8_t>> in = Receive(daoai::kResponseSize);
    if (!in) return std::nullopt;
    return daoai::DecodeResponse(std::span<const uint8_t, daoai::kResponseSize>(in->data(), in->size()));
  }
  // True once the server closed the connection.
  bool Closed() {
    uint8_t b;
    return ::recv(fd_, &b, 1, 0) == 0;
  }

 private:
  int fd_ = -1;
  bool connected_ = false;
};

struct Server {
  explicit Server(DaoaiServerOptions o = {}, Cell cell = MakeTestCell()) {
    handler = std::make_unique<RequestHandler>(cell, planner, nullptr);
    o.port = 0;
    auto started = DaoaiServer::Start(*handler, o);
    EXPECT_TRUE(started.ok()) << started.status().ToString();
    server = std::move(*started);
  }
  ~Server() {
    server->Stop();
    handler->Shutdown();
  }
  std::shared_ptr<ScriptedPlanner> planner = std::make_shared<ScriptedPlanner>();
  std::unique_ptr<RequestHandler> handler;
  std::unique_ptr<DaoaiServer> server;
};

TEST(ServerLimits, OnePeerAddressCannotHoldMoreThanMaxConnectionsPerPeer) {
  DaoaiServerOptions o;
  o.max_connections = 10;
  o.max_connections_per_peer = 3;
  Server s(o);
  std::vector<std::unique_ptr<Peer>> mine;
  for (int i = 0; i < 3; ++i) {
    mine.push_back(std::make_unique<Peer>("127.0.0.1", s.server->port()));
    ASSERT_EQ(mine.back()->Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
  }
  Peer fourth("127.0.0.1", s.server->port());
  ASSERT_TRUE(fourth.connected());  // the kernel accepts; binpick closes it
  EXPECT_TRUE(fourth.Closed());
  // Another address is served, and so is this one once it frees a slot.
  Peer other("127.0.0.2", s.server->port());
  EXPECT_EQ(other.Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
  mine.pop_back();
  ASSERT_TRUE(WaitUntil([&] { return s.server->connection_count() == 3; }));
  Peer again("127.0.0.1", s.server->port());
  EXPECT_EQ(again.Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
  const TransportStats stats = s.server->stats();
  EXPECT_EQ(stats.refused_per_peer, 1u);
  EXPECT_EQ(stats.refused_max_connections, 0u);
  EXPECT_EQ(s.server->refused_count(), 1u);
}

TEST(ServerLimits, AllowlistEntriesMayBeNetworks) {
  DaoaiServerOptions o;
  o.allowlist = {"10.0.0.0/8", "127.0.0.0/31"};  // 127.0.0.0 and 127.0.0.1
  Server s(o);
  Peer listed("127.0.0.1", s.server->port());
  EXPECT_EQ(listed.Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
  Peer outside("127.0.0.2", s.server->port());
  EXPECT_TRUE(outside.Closed());
  EXPECT_EQ(s.server->stats().refused_allowlist, 1u);
  DaoaiServerOptions bad;
  bad.allowlist = {"127.0.0.0/33"};
  RequestHandler handler(MakeTestCell(), std::make_shared<ScriptedPlanner>(), nullptr);
  bad.port = 0;
  const auto refused = DaoaiServer::Start(handler, bad);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("'127.0.0.0/33'"), std::string::npos)
      << refused.status().ToString();
  handler.Shutdown();
}

// Issue 39 item 5: only peers in the config allowlist may calibrate, teach or
// switch the camera config; the others get the command's refusal (and no
// answer where the robot reads none, so the stream stays in step), and may
// still pick.
TEST(ServerLimits, StateChangingRequestsFromPeersNotInTheConfigAllowlistAreRefused) {
  DaoaiServerOptions o;
  o.config_allowlist = {"127.0.0.2"};
  Server s(o);
  Peer robot("127.0.0.1", s.server->port());
  EXPECT_EQ(robot.Call(daoai::kSwitchConfig, 2)->status, daoai::kSwitchConfigFail);
  EXPECT_EQ(s.handler->camera_config_id(), 1);
  EXPECT_EQ(robot.Call(daoai::kStartManualCalibration)->status, daoai::kUnknownCommand);
  EXPECT_EQ(robot.Call(daoai::kStartAutoCalibration)->status, daoai::kUnknownCommand);
  ASSERT_TRUE(robot.Call(daoai::kSendPose, 0, /*answered=*/false));  // teach: not stored
  ASSERT_TRUE(robot.Call(daoai::kGuidanceCalibration, 0, /*answered=*/false));  // version 2
  // Still in step, and still picking.
  EXPECT_EQ(robot.Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  EXPECT_EQ(robot.Call(daoai::kPickPose, 0)->status, daoai::kObjectsFound);
  EXPECT_EQ(s.handler->stats().changes_refused, 5u);
  Peer engineer("127.0.0.2", s.server->port());
  EXPECT_EQ(engineer.Call(daoai::kSwitchConfig, 2)->status, daoai::kSwitchConfigSuccess);
  EXPECT_EQ(s.handler->camera_config_id(), 2);
  EXPECT_EQ(engineer.Call(daoai::kStartManualCalibration)->status, daoai::kModeCalibration);
  s.handler->Shutdown();
  EXPECT_TRUE(s.planner->taught().empty());
}

TEST(ServerLimits, GriHandEyeActionsFromPeersNotInTheConfigAllowlistAreRefused) {
  Cell cell = MakeTestCell();
  cell.calibration = CalibrationSpec{};
  RequestHandler handler(cell, std::make_shared<ScriptedPlanner>(), nullptr);
  GriHandler gri_handler(handler);
  GriServerOptions g;
  g.v2_port = -1;
  g.official_port = 0;
  g.config_allowlist = {"127.0.0.2"};
  auto server = GriServer::Start(gri_handler, g);
  ASSERT_TRUE(server.ok()) << server.status().ToString();
  auto hec_init = [&](const std::string& from) -> std::optional<gri::Response> {
    Peer p(from, (*server)->v2_port());
    gri::Request r;
    r.format = gri::Format::kV2;
    r.pose_format = 1;
    r.action = gri::kHecInit;
    r.pose = {0.1, 0.2, 0.3, 0, 0, 0, 1};
    Result<std::vector<uint8_t>> bytes = gri::EncodeRequest(r);
    if (!bytes.ok() || !p.Send(bytes->data(), bytes->size())) return std::nullopt;
    std::optional<std::vector<uint8_t>> in = p.Receive(gri::kV2ResponseSize);
    if (!in) return std::nullopt;
    Result<gri::Response> resp = gri::DecodeResponse(*in);
    return resp.ok() ? std::optional<gri::Response>(*resp) : std::nullopt;
  };
  const auto refused = hec_init("127.0.0.1");
  ASSERT_TRUE(refused);
  EXPECT_EQ(refused->error_code, gri::WireErrorCode(gri::Format::kV2, gri::Code::kHecConfigError));
  const auto allowed = hec_init("127.0.0.2");
  ASSERT_TRUE(allowed);
  EXPECT_EQ(allowed->error_code, gri::WireErrorCode(gri::Format::kV2, gri::Code::kOk));
  (*server)->Stop();
  handler.Shutdown();
}

// The server's end of a loopback connection whose client port is
// `client_port`: a descriptor of this process (the server runs in it).
std::optional<int> ServerSideSocket(int client_port) {
  for (const auto& entry : std::filesystem::directory_iterator("/proc/self/fd")) {
    const int fd = std::stoi(entry.path().filename().string());
    sockaddr_in peer{};
    socklen_t n = sizeof(peer);
    if (::getpeername(fd, reinterpret_cast<sockaddr*>(&peer), &n) != 0) continue;
    if (peer.sin_family != AF_INET || ntohs(peer.sin_port) != client_port) continue;
    return fd;
  }
  return std::nullopt;
}

int IntOption(int fd, int level, int name) {
  int v = -1;
  socklen_t n = sizeof(v);
  ::getsockopt(fd, level, name, &v, &n);
  return v;
}

// Issue 39 item 2: a robot that vanishes without FIN must not have its
// grasp written into a dead connection: every robot connection has TCP
// keepalive (10 s idle, 3 probes 2 s apart) and the same 16 s bound on
// unacknowledged data.
TEST(ServerLimits, RobotConnectionsHaveTcpKeepaliveAndAUserTimeout) {
  Server s;
  Peer robot("127.0.0.1", s.server->port());
  ASSERT_EQ(robot.Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
  const std::optional<int> fd = ServerSideSocket(robot.local_port());
  ASSERT_TRUE(fd) << "no server-side socket for client port " << robot.local_port();
  EXPECT_EQ(IntOption(*fd, SOL_SOCKET, SO_KEEPALIVE), 1);
  EXPECT_EQ(IntOption(*fd, IPPROTO_TCP, TCP_KEEPIDLE), 10);
  EXPECT_EQ(IntOption(*fd, IPPROTO_TCP, TCP_KEEPINTVL), 2);
  EXPECT_EQ(IntOption(*fd, IPPROTO_TCP, TCP_KEEPCNT), 3);
  EXPECT_EQ(IntOption(*fd, IPPROTO_TCP, TCP_USER_TIMEOUT), 16000);
  // The GRI listener shares the connection base.
  RequestHandler handler(MakeTestCell(), std::make_shared<ScriptedPlanner>(), nullptr);
  GriHandler gri_handler(handler);
  GriServerOptions g;
  g.v2_port = -1;
  g.official_port = 0;
  g.keepalive_idle = 5s;
  auto gri = GriServer::Start(gri_handler, g);
  ASSERT_TRUE(gri.ok());
  Peer gri_robot("127.0.0.1", (*gri)->v2_port());
  ASSERT_TRUE(WaitUntil([&] { return (*gri)->connection_count() == 1; }));
  const std::optional<int> gri_fd = ServerSideSocket(gri_robot.local_port());
  ASSERT_TRUE(gri_fd);
  EXPECT_EQ(IntOption(*gri_fd, SOL_SOCKET, SO_KEEPALIVE), 1);
  EXPECT_EQ(IntOption(*gri_fd, IPPROTO_TCP, TCP_KEEPIDLE), 5);
  EXPECT_EQ(IntOption(*gri_fd, IPPROTO_TCP, TCP_USER_TIMEOUT), 11000);
  (*gri)->Stop();
  handler.Shutdown();
}

// Issue 39 item 3: out of descriptors, accept() fails for every pending
// connection; the listener pauses (10 ms doubling to 1 s) instead of
// retrying at once, and serves the connections when descriptors are back.
TEST(ServerLimits, AcceptBacksOffWhileOutOfDescriptorsThenServes) {
  Server s;
  // The clients' sockets exist before the limit drops (connect() needs no
  // new descriptor; the server's accept() does).
  std::vector<int> clients;
  for (int i = 0; i < 3; ++i) clients.push_back(::socket(AF_INET, SOCK_STREAM, 0));
  rlimit old{};
  ASSERT_EQ(::getrlimit(RLIMIT_NOFILE, &old), 0);
  rlimit low = old;
  low.rlim_cur = static_cast<rlim_t>(testing::OpenFdCount() - 1);  // nothing more can open
  ASSERT_EQ(::setrlimit(RLIMIT_NOFILE, &low), 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<uint16_t>(s.server->port()));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  for (int fd : clients) ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)), 0);
  std::this_thread::sleep_for(500ms);
  const uint64_t errors = s.server->stats().accept_errors;
  ASSERT_EQ(::setrlimit(RLIMIT_NOFILE, &old), 0);
  // With the back-off, at most ~7 attempts fit in 0.5 s (10+20+...+320 ms);
  // retrying at once made hundreds of thousands (one core at 100%).
  EXPECT_GE(errors, 1u);
  EXPECT_LE(errors, 10u);
  EXPECT_TRUE(WaitUntil([&] { return s.server->connection_count() == clients.size(); }, 5000ms))
      << s.server->connection_count() << " of " << clients.size() << " accepted";
  for (int fd : clients) ::close(fd);
}

}  // namespace
}  // namespace bp
