// Fault injection over real loopback sockets (docs/reliability.md "Faults").
// After each fault: the next valid request is answered correctly, a robot on
// another connection is unaffected, every grasp is handed out exactly once
// (counted against the planner's NotifyHandedOut), and the process's open
// descriptors and resident memory return to their baseline.
//
// Faults already covered elsewhere, not repeated here: a robot disconnecting
// while its pick pose waits for the detection (daoai_server_test
// RobotDisconnectingMidRequestLosesNoGrasp), GRI framing errors
// (gri_server_test), a Modbus robot restarting mid-request (modbus_test).
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <pcl/exceptions.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <functional>
#include <mutex>
#include <new>
#include <opencv2/core.hpp>
#include <random>
#include <set>
#include <thread>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/gri_handler.h"
#include "comms/gri_message.h"
#include "comms/gri_server.h"
#include "comms/robot_client.h"
#include "core/fault_points.h"
#include "tests/testing/process_stats.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

using namespace std::chrono_literals;
using testing::MakeTestCell;
using testing::OpenFdCount;
using testing::ResidentBytes;
using testing::ScriptedPlanner;
using testing::WaitUntil;

// Resident memory may grow by allocator caches and thread stacks touched
// once; a leak per connection of 100 connections would exceed this.
[[maybe_unused]] constexpr int64_t kRssTolerance = 16 << 20;  // unused under ASan

// A raw loopback socket: the robot that misbehaves.
class RawSocket {
 public:
  explicit RawSocket(int port, int rcvbuf = 0) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    if (rcvbuf > 0) ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf));
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0;
  }
  ~RawSocket() { Close(); }
  RawSocket(const RawSocket&) = delete;
  RawSocket& operator=(const RawSocket&) = delete;
  bool connected() const { return connected_; }
  bool Send(const void* data, size_t n, int flags = 0) {
    return ::send(fd_, data, n, MSG_NOSIGNAL | flags) == static_cast<ssize_t>(n);
  }
  // Sends with MSG_DONTWAIT: false when the socket buffers are full or closed.
  bool TrySend(const void* data, size_t n) { return Send(data, n, MSG_DONTWAIT); }
  // True once the server closed the connection (EOF or reset), within timeout.
  bool WaitClosed(std::chrono::milliseconds timeout) {
    timeval tv{static_cast<time_t>(timeout.count() / 1000),
               static_cast<suseconds_t>((timeout.count() % 1000) * 1000)};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
    std::array<uint8_t, 4096> buf{};
    for (;;) {
      const ssize_t n = ::recv(fd_, buf.data(), buf.size(), 0);
      if (n == 0) return true;
      if (n < 0) return errno != EAGAIN && errno != EWOULDBLOCK;
    }
  }
  void Close() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

 private:
  int fd_ = -1;
  bool connected_ = false;
};

daoai::Request Req(int32_t command, int32_t payload_1 = 0) {
  daoai::Request r;
  r.position = {5000, -2500, 3000};
  r.orientation = {0, 0, 15708, 0};
  r.command = command;
  r.payload_1 = payload_1;
  r.meta_1 = 7;  // UR
  r.meta_2 = 2;
  return r;
}

class FaultTest : public ::testing::Test {
 protected:
  void Start(DaoaiServerOptions options = {}) {
    planner_ = std::make_shared<ScriptedPlanner>();
    ScriptedPlanner::Script many;
    many.grasps = 6;
    planner_->SetScript(0, many);
    planner_->SetScript(1, many);
    handler_ = std::make_unique<RequestHandler>(MakeTestCell(), planner_, std::move(calibration_));
    if (observer_) handler_->AddObserver(observer_);
    options.port = 0;
    // Robots that idle through a fault (the bystander between its calls, a
    // robot waiting on another's fault) must never be closed as idle, however
    // slowly a loaded machine schedules the test: a 300 ms timeout closed them
    // at load 17 on 2 cores. Only the test of the read timeout sets a short
    // one, and keeps its bystander talking.
    if (options.read_timeout == DaoaiServerOptions{}.read_timeout) options.read_timeout = 10s;
    auto server = DaoaiServer::Start(*handler_, options);
    ASSERT_TRUE(server.ok()) << server.status().ToString();
    server_ = std::move(*server);
    // Warm up (threads, allocator arenas, spdlog) before the baseline.
    for (int i = 0; i < 3; ++i) {
      auto c = Connect();
      ASSERT_TRUE(c);
      ASSERT_EQ(c->Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
    }
    ASSERT_TRUE(WaitUntil([&] { return server_->connection_count() == 0; }));
    // The bystander: a robot on task 1 connected through every fault, last,
    // so that its idle time starts when the test does.
    bystander_ = Connect();
    ASSERT_TRUE(bystander_);
    ASSERT_EQ(bystander_->Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
    ASSERT_TRUE(WaitUntil([&] { return server_->connection_count() == 1; }));
    fds_ = OpenFdCount();
    rss_ = ResidentBytes();
  }

  void TearDown() override {
    fault::DisarmAll();  // a failed fault test leaves nothing armed for the next
    bystander_.reset();
    if (server_) server_->Stop();
    if (handler_) handler_->Shutdown();
  }

  std::unique_ptr<RobotClient> Connect() {
    RobotClientOptions o;
    o.port = server_->port();
    o.version = 2;
    o.timeout = 5000ms;
    auto c = RobotClient::Connect(o);
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return c.ok() ? std::move(*c) : nullptr;
  }

  // The bystander captures on task 1 and takes one grasp: unaffected.
  void ExpectBystanderServed() {
    Result<RobotReply> cap = bystander_->Call(daoai::kCaptureAndProcess, 1);
    ASSERT_TRUE(cap.ok()) << cap.status().ToString();
    EXPECT_EQ(cap->status, daoai::kDetection);
    Result<RobotReply> pick = bystander_->Call(daoai::kPickPose, 1);
    ASSERT_TRUE(pick.ok()) << pick.status().ToString();
    EXPECT_EQ(pick->status, daoai::kObjectsFound);
    EXPECT_NEAR(pick->X_BT->translation().y(), -0.08, 1e-4);  // task 1's grasp
  }

  // Every grasp handed out once: no (task, instance) twice within a detection.
  // Returns the task-0 instances in order.
  std::vector<int> Task0HandedOut() const {
    std::vector<int> out;
    for (const auto& [task, instance] : planner_->handed_out()) {
      if (task == 0) out.push_back(instance);
    }
    return out;
  }

  // The bystander keeps talking (so its own read timeout never fires) while
  // waiting for `done`; each of its requests must be answered.
  bool WaitWhileBystanderTalks(const std::function<bool()>& done,
                               std::chrono::milliseconds timeout = 5000ms) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (!done()) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      Result<RobotReply> r = bystander_->Call(daoai::kSwitchConfig, 1);
      EXPECT_TRUE(r.ok() && r->status == daoai::kSwitchConfigSuccess) << r.status().ToString();
      std::this_thread::sleep_for(20ms);
    }
    return true;
  }

  void ExpectBaseline() {
    EXPECT_TRUE(WaitUntil([&] { return server_->connection_count() == 1; }))
        << server_->connection_count() << " connections open";
    EXPECT_TRUE(WaitUntil([&] { return OpenFdCount() <= fds_; }))
        << "fds " << OpenFdCount() << " vs baseline " << fds_;
#if !BP_UNDER_ASAN
    // Not under ASan: its quarantine keeps freed memory resident on purpose
    // (LSan checks leaks there instead, at exit).
    EXPECT_LE(ResidentBytes(), rss_ + kRssTolerance)
        << "RSS grew by " << (ResidentBytes() - rss_) / 1024 << " KiB";
#endif
  }

  std::shared_ptr<ScriptedPlanner> planner_;
  // Set before Start(): the handler's calibration service (null: counting)
  // and an observer.
  std::unique_ptr<CalibrationService> calibration_;
  std::shared_ptr<ServerObserver> observer_;
  std::unique_ptr<RequestHandler> handler_;
  std::unique_ptr<DaoaiServer> server_;
  std::unique_ptr<RobotClient> bystander_;
  int fds_ = 0;
  int64_t rss_ = 0;
};

TEST_F(FaultTest, RobotDisconnectingMidMessageLosesNothing) {
  Start();
  auto a = Connect();
  ASSERT_TRUE(a);
  ASSERT_EQ(a->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  ASSERT_EQ(a->Call(daoai::kPickPose, 0)->payload[0], 6);
  {
    RawSocket raw(server_->port());
    ASSERT_TRUE(raw.connected());
    const auto pick = daoai::EncodeRequest(Req(daoai::kPickPose, 0));
    ASSERT_TRUE(raw.Send(pick.data(), 20));  // 20 of 48 bytes, then gone
  }
  ASSERT_TRUE(WaitUntil([&] { return server_->connection_count() == 2; }));
  // The half request popped nothing: the next grasp is the second one.
  Result<RobotReply> next = a->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(next.ok());
  EXPECT_EQ(next->status, daoai::kObjectsFound);
  EXPECT_EQ(next->payload[0], 5);
  EXPECT_TRUE(planner_->WaitForHandedOut(2));

  EXPECT_EQ(Task0HandedOut(), (std::vector<int>{0, 1}));
  ExpectBystanderServed();
  a.reset();
  ExpectBaseline();
}

TEST_F(FaultTest, RobotDisconnectingMidDetectionLosesNothing) {
  Start();
  planner_->HoldPlans(true);
  {
    RawSocket raw(server_->port());
    ASSERT_TRUE(raw.connected());
    const auto cap = daoai::EncodeRequest(Req(daoai::kCaptureAndProcess, 0));
    const auto pick = daoai::EncodeRequest(Req(daoai::kPickPose, 0));
    ASSERT_TRUE(raw.Send(cap.data(), cap.size()));
    ASSERT_TRUE(raw.Send(pick.data(), pick.size()));  // waits for the held detection
    ASSERT_TRUE(WaitUntil([&] { return planner_->captures() == 1; }));
  }
  ASSERT_TRUE(WaitUntil([&] { return server_->connection_count() == 1; }));
  planner_->HoldPlans(false);
  ASSERT_TRUE(WaitUntil([&] { return planner_->plans() == 1; }));
  std::this_thread::sleep_for(50ms);
  EXPECT_TRUE(Task0HandedOut().empty()) << "a grasp was popped for a robot that had left";
  auto b = Connect();
  ASSERT_TRUE(b);
  Result<RobotReply> first = b->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(first->payload[0], 6);  // the detection's first grasp, still queued
  EXPECT_TRUE(planner_->WaitForHandedOut(1));

  EXPECT_EQ(Task0HandedOut(), (std::vector<int>{0}));
  ExpectBystanderServed();
  b.reset();
  ExpectBaseline();
}

TEST_F(FaultTest, RobotDisconnectingRightAfterAPopCountsThatGraspAsHandedOut) {
  Start();
  auto a = Connect();
  ASSERT_TRUE(a);
  ASSERT_EQ(a->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  {
    RawSocket raw(server_->port());
    ASSERT_TRUE(raw.connected());
    const auto pick = daoai::EncodeRequest(Req(daoai::kPickPose, 0));
    ASSERT_TRUE(raw.Send(pick.data(), pick.size()));
    // Popped and written; the robot leaves without reading the answer.
    ASSERT_TRUE(WaitUntil([&] { return Task0HandedOut().size() == 1; }));
  }
  // docs/protocols.md "The pop rule": that grasp is gone; nothing is handed
  // out twice and the queue continues with the next one.
  Result<RobotReply> next = a->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(next.ok());
  EXPECT_EQ(next->payload[0], 5);
  EXPECT_NEAR(next->X_BT->translation().x(), 0.51, 1e-4);  // grasp 1
  EXPECT_TRUE(planner_->WaitForHandedOut(2));

  EXPECT_EQ(Task0HandedOut(), (std::vector<int>{0, 1}));
  ExpectBystanderServed();
  a.reset();
  ExpectBaseline();
}

TEST_F(FaultTest, HalfAMessageThenSilenceIsClosedAndReleased) {
  DaoaiServerOptions o;
  o.read_timeout = 1s;  // the bystander talks every ~20 ms throughout
  Start(o);
  RawSocket raw(server_->port());
  ASSERT_TRUE(raw.connected());
  const auto req = daoai::EncodeRequest(Req(daoai::kSwitchConfig, 1));
  ASSERT_TRUE(raw.Send(req.data(), 30));
  ASSERT_TRUE(WaitWhileBystanderTalks([&] { return server_->connection_count() == 2; }));
  EXPECT_TRUE(WaitWhileBystanderTalks([&] { return server_->connection_count() == 1; }))
      << "read timeout did not close the connection";
  EXPECT_TRUE(raw.WaitClosed(1000ms));
  raw.Close();
  ExpectBystanderServed();
  ExpectBaseline();
}

TEST_F(FaultTest, GarbageThenAValidMessageOnTheSameConnection) {
  Start();
  auto c = Connect();
  ASSERT_TRUE(c);
  // 48 random bytes frame as one request with an unknown command: answered
  // UNKNOWN_COMMAND (-1), and the connection stays in step.
  std::mt19937 rng(11);
  std::array<uint8_t, daoai::kRequestSize> garbage{};
  for (auto& b : garbage) b = static_cast<uint8_t>(rng());
  garbage[28] = 0x5A;  // command = 0x5A...: never a known command
  ASSERT_TRUE(c->SendBytes(garbage.data(), garbage.size()).ok());
  Result<RobotReply> r = c->Receive();
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->status, daoai::kUnknownCommand);
  ASSERT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  Result<RobotReply> pick = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  EXPECT_EQ(pick->payload[0], 6);
  EXPECT_TRUE(planner_->WaitForHandedOut(1));

  EXPECT_EQ(Task0HandedOut(), (std::vector<int>{0}));
  ExpectBystanderServed();
  c.reset();
  ExpectBaseline();
}

TEST_F(FaultTest, HundredConnectionsOpenedAndDroppedLeaveNothingBehind) {
  Start();
  const auto full = daoai::EncodeRequest(Req(daoai::kSwitchConfig, 1));
  const auto pick = daoai::EncodeRequest(Req(daoai::kPickPose, 0));
  ASSERT_EQ(bystander_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  for (int i = 0; i < 100; ++i) {
    RawSocket raw(server_->port());
    ASSERT_TRUE(raw.connected()) << i;
    switch (i % 4) {
      case 0: break;                                               // connect, close
      case 1: raw.Send(full.data(), 17); break;                    // part of a request
      case 2: raw.Send(full.data(), full.size()); break;           // a request, unread
      case 3: raw.Send(pick.data(), pick.size() - 1); break;       // a pick, one byte short
    }
  }
  EXPECT_TRUE(Task0HandedOut().empty());
  Result<RobotReply> first = bystander_->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(first->payload[0], 6);
  ExpectBystanderServed();
  ExpectBaseline();
}

TEST_F(FaultTest, RobotThatNeverReadsIsClosedWithoutBlockingOthers) {
  Start();
  RawSocket hog(server_->port(), /*rcvbuf=*/4096);
  ASSERT_TRUE(hog.connected());
  std::atomic<bool> stop{false};
  std::atomic<int> sent{0};
  // The hog pipelines requests and never reads an answer.
  std::thread writer([&] {
    const auto req = daoai::EncodeRequest(Req(daoai::kSwitchConfig, 1));
    while (!stop && hog.TrySend(req.data(), req.size())) ++sent;
    while (!stop) std::this_thread::sleep_for(5ms);
  });
  // Meanwhile the bystander is answered as usual.
  for (int i = 0; i < 5; ++i) ExpectBystanderServed();
  // Closed: by the request queue bound, or by the write timeout once the
  // hog's buffers are full and it stops sending. Filling the server's send
  // buffer (autotuned up to tcp_wmem's maximum, megabytes of 64-byte
  // answers) took more than 5 s under TSan on a busy 2-core machine (84k
  // requests; closed 6 ms after a 5 s deadline), hence the long deadline.
  EXPECT_TRUE(WaitWhileBystanderTalks([&] { return server_->connection_count() == 1; }, 30000ms))
      << "the non-reading robot is still connected after " << sent << " requests";
  stop = true;
  writer.join();
  hog.Close();
  ExpectBystanderServed();
  ExpectBaseline();
}

// Issue 39, the pop rule completed: a robot pipelines picks and never reads.
// Its answers fill the (small) socket buffers, a write blocks, and the
// connection is closed with that answer unwritten (queue overflow or write
// timeout). The grasp in that answer goes back to the front of the queue:
// the next robot gets it, and no grasp is handed out that was not written.
TEST_F(FaultTest, AnAnswerCutShortByTheConnectionClosingPutsItsGraspBack) {
  DaoaiServerOptions o;
  o.send_buffer_bytes = 4096;  // the write blocks after a few hundred answers
  // The hog is closed by the queue bound; robot `a` and the bystander stay
  // idle meanwhile and must not be closed as idle on a loaded machine (the
  // fixture's 300 ms closed them when scheduling stalled the test).
  o.read_timeout = 10s;
  Start(o);
  constexpr int kGrasps = 5000;
  ScriptedPlanner::Script many;
  many.grasps = kGrasps;
  planner_->SetScript(0, many);
  auto a = Connect();
  ASSERT_TRUE(a);
  ASSERT_EQ(a->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  ASSERT_TRUE(WaitUntil([&] { return handler_->Snapshot(0)->in_flight == 0; }));
  RawSocket hog(server_->port(), /*rcvbuf=*/4096);
  ASSERT_TRUE(hog.connected());
  ASSERT_TRUE(WaitUntil([&] { return server_->connection_count() == 3; }));
  std::atomic<bool> stop{false};
  // Picks in batches of 8, every 5 ms: answered as they come while the
  // buffers have room (fewer than 16 queued at once), then, once a write
  // blocks, queued until the 17th closes the connection with that write
  // pending (or the write timeout does).
  std::thread writer([&] {
    const auto pick = daoai::EncodeRequest(Req(daoai::kPickPose, 0));
    while (!stop) {
      for (int i = 0; i < 8 && !stop; ++i) {
        if (!hog.TrySend(pick.data(), pick.size())) stop = true;
      }
      std::this_thread::sleep_for(5ms);
    }
  });
  EXPECT_TRUE(WaitWhileBystanderTalks([&] { return server_->connection_count() == 2; }, 30000ms))
      << "the hog is still connected";
  stop = true;
  writer.join();
  hog.Close();
  const std::vector<int> handed = Task0HandedOut();
  ASSERT_GT(handed.size(), 10u);
  ASSERT_LT(handed.size(), static_cast<size_t>(kGrasps)) << "the test needs grasps left";
  EXPECT_EQ(handler_->stats().grasps_requeued, 1u);
  EXPECT_EQ(static_cast<int>(handed.size()) + handler_->QueueSize(0), kGrasps);
  for (size_t i = 0; i < handed.size(); ++i) ASSERT_EQ(handed[i], static_cast<int>(i));
  // The grasp of the unwritten answer is the next one handed out.
  Result<RobotReply> next = a->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(next.ok());
  EXPECT_EQ(next->status, daoai::kObjectsFound);
  EXPECT_EQ(next->payload[0], kGrasps - static_cast<int>(handed.size()));
  ASSERT_TRUE(planner_->WaitForHandedOut(handed.size() + 1));
  EXPECT_EQ(Task0HandedOut().back(), static_cast<int>(handed.size()));
  ExpectBystanderServed();
  a.reset();
  ExpectBaseline();
}

TEST_F(FaultTest, FailingCaptureAndThrowingDetectionAreAnsweredAndRecovered) {
  Start();
  auto c = Connect();
  ASSERT_TRUE(c);
  ScriptedPlanner::Script s;
  s.grasps = 6;
  s.capture_fails = true;
  planner_->SetScript(0, s);
  EXPECT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kCaptureFail);
  s.capture_fails = false;
  s.capture_throws = true;
  planner_->SetScript(0, s);
  EXPECT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kCaptureFail);
  s.capture_throws = false;
  s.plan_throws = true;
  planner_->SetScript(0, s);
  // The capture succeeded, so it is answered CAPTURE_SUCCESS; the pick then
  // must not wait forever for a detection that threw.
  EXPECT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  // Answered as an error, not NO_OBJECT_FOUND (issue 39: the robot must not
  // take a failed detection for an empty bin).
  Result<RobotReply> pick = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok()) << pick.status().ToString();
  EXPECT_EQ(pick->status, daoai::kUnknownCommand);
  EXPECT_EQ(pick->payload[0], 0);
  // The empty-box check with a throwing detection: not empty (no evidence).
  Result<RobotReply> empty = c->Call(daoai::kCheckEmptyBox, 0);
  ASSERT_TRUE(empty.ok()) << empty.status().ToString();
  EXPECT_EQ(empty->status, daoai::kBoxNotEmpty);
  s.plan_throws = false;
  planner_->SetScript(0, s);
  EXPECT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  Result<RobotReply> ok = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(ok.ok());
  EXPECT_EQ(ok->status, daoai::kObjectsFound);
  EXPECT_EQ(ok->payload[0], 6);
  EXPECT_TRUE(planner_->WaitForHandedOut(1));

  EXPECT_EQ(Task0HandedOut(), (std::vector<int>{0}));
  ExpectBystanderServed();
  c.reset();
  ExpectBaseline();
}

// The exceptions a planner's libraries throw (issue 39 "no hangs"): the
// standard ones, OpenCV's and PCL's (both std::exceptions), and one that is
// not a std::exception at all.
struct Injected {
  const char* name;
  std::function<void()> raise;
};
std::vector<Injected> InjectedExceptions() {
  return {
      {"std::runtime_error", [] { throw std::runtime_error("injected"); }},
      {"std::bad_alloc", [] { throw std::bad_alloc(); }},
      {"cv::Exception", [] { throw cv::Exception(cv::Error::StsNoMem, "injected", "Capture", __FILE__, __LINE__); }},
      {"pcl::PCLException", [] { throw pcl::PCLException("injected"); }},
      {"an int", [] { throw 42; }},
  };
}

class DetectionLog final : public ServerObserver {
 public:
  void OnDetection(const DetectionEvent& e) override {
    std::lock_guard lock(mutex_);
    events_.push_back(e);
  }
  std::optional<DetectionEvent> last() const {
    std::lock_guard lock(mutex_);
    if (events_.empty()) return std::nullopt;
    return events_.back();
  }

 private:
  mutable std::mutex mutex_;
  std::vector<DetectionEvent> events_;
};

// A failed detection's pick: an error the seed programs stop on, never "no
// objects" (a robot would take the bin for empty).
void ExpectPickError(RobotClient& c) {
  Result<RobotReply> pick = c.Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok()) << pick.status().ToString();
  EXPECT_EQ(pick->status, daoai::kUnknownCommand);
  EXPECT_EQ(pick->payload[0], 0);
}

TEST_F(FaultTest, AnExceptionOfAnyKindInTheCaptureOrThePlanIsAnsweredAsAnError) {
  auto log = std::make_shared<DetectionLog>();
  observer_ = log;
  Start();
  auto c = Connect();
  ASSERT_TRUE(c);
  uint64_t failures = 0;
  size_t handed = 0;
  for (const Injected& e : InjectedExceptions()) {
    SCOPED_TRACE(e.name);
    ScriptedPlanner::Script s;
    s.grasps = 6;
    // The capture throws: RC 20 is answered CAPTURE_FAIL, and so is the
    // pick that waits for an RC 19's detection: as an error.
    s.in_capture = e.raise;
    planner_->SetScript(0, s);
    EXPECT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kCaptureFail);
    ExpectPickError(*c);
    EXPECT_EQ(c->Call(daoai::kCaptureAndProcessAsync, 0)->status, daoai::kDetection);
    ExpectPickError(*c);
    failures += 2;
    // The plan throws after the capture: the waiting pick gets an error and
    // the observers (the recorder) the frame with the error, for replay.
    s.in_capture = nullptr;
    s.in_plan = e.raise;
    planner_->SetScript(0, s);
    EXPECT_EQ(c->Call(daoai::kCaptureAndProcessAsync, 0)->status, daoai::kDetection);
    ExpectPickError(*c);
    failures += 1;
    const std::optional<DetectionEvent> failed = log->last();
    ASSERT_TRUE(failed);
    EXPECT_TRUE(failed->scene);
    EXPECT_FALSE(failed->plan);
    EXPECT_FALSE(failed->plan_status.ok());
    EXPECT_EQ(handler_->stats().planner_failures, failures);
    EXPECT_EQ(handler_->Snapshot(0)->in_flight, 0);
    // Served again once the planner stops throwing.
    s.in_plan = nullptr;
    planner_->SetScript(0, s);
    EXPECT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
    Result<RobotReply> ok = c->Call(daoai::kPickPose, 0);
    ASSERT_TRUE(ok.ok()) << ok.status().ToString();
    EXPECT_EQ(ok->status, daoai::kObjectsFound);
    ASSERT_TRUE(planner_->WaitForHandedOut(++handed));
  }
  // One grasp per good detection, each the first: none lost, none twice.
  EXPECT_EQ(Task0HandedOut(), std::vector<int>(handed, 0));
  ExpectBystanderServed();
  c.reset();
  ExpectBaseline();
}

// The planner throwing when told of a hand-out (on the network thread, as
// the answer's write completes) once ended that thread and the process. The
// robot has the grasp: it counts as handed out, once.
TEST_F(FaultTest, ThePlannerThrowingWhenToldOfAHandOutLosesNoGraspAndRepeatsNone) {
  Start();
  auto c = Connect();
  ASSERT_TRUE(c);
  ScriptedPlanner::Script s;
  s.grasps = 6;
  planner_->SetScript(0, s);
  EXPECT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  const std::vector<Injected> kinds = InjectedExceptions();
  for (size_t i = 0; i < kinds.size(); ++i) {
    SCOPED_TRACE(kinds[i].name);
    s.in_handed_out = kinds[i].raise;
    planner_->SetScript(0, s);
    Result<RobotReply> pick = c->Call(daoai::kPickPose, 0);
    ASSERT_TRUE(pick.ok()) << pick.status().ToString();
    EXPECT_EQ(pick->status, daoai::kObjectsFound);
    ASSERT_TRUE(pick->X_BT);
    EXPECT_NEAR(pick->X_BT->translation().x(), ScriptedPlanner::GraspPose(0, static_cast<int>(i)).translation().x(),
                1e-4);
    ASSERT_TRUE(planner_->WaitForHandedOut(i + 1));
  }
  EXPECT_TRUE(WaitUntil([&] { return handler_->stats().planner_failures == kinds.size(); }));
  EXPECT_EQ(Task0HandedOut(), (std::vector<int>{0, 1, 2, 3, 4}));
  EXPECT_EQ(handler_->QueueSize(0), 1);
  ExpectBystanderServed();
  c.reset();
  ExpectBaseline();
}

// Issue 39: an exception thrown inside the request handler's HandleAsync
// (no memory, a bug) on the network thread once reached Asio and ended the
// process. Now the robot gets -1 with payload_1 0 and, as 21's answer is
// moved to, its own pose; logged and counted. Nothing is popped, the
// connection stays in step (the next answer is the next request's own) and
// the bystander is served. Injected (core/fault_points.h) where no answer
// was given yet, and after the pick started waiting for a detection: then
// the Reply the detection gives later is dropped.
TEST_F(FaultTest, AnExceptionInsideHandleAsyncIsAnsweredAnErrorAndPopsNothing) {
  Start();
  auto c = Connect();
  ASSERT_TRUE(c);
  ASSERT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  fault::Arm("daoai.handle");
  Result<RobotReply> failed = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(failed.ok()) << failed.status().ToString();
  EXPECT_EQ(failed->status, daoai::kUnknownCommand);
  EXPECT_EQ(failed->payload[0], 0);
  ASSERT_TRUE(failed->X_BT);
  EXPECT_LT((failed->X_BT->translation() - c->pose().translation()).norm(), 1e-3);
  EXPECT_EQ(handler_->stats().answer_failures, 1u);
  Result<RobotReply> pick = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok()) << pick.status().ToString();
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  EXPECT_EQ(pick->payload[0], 6);  // the first grasp: nothing was popped

  planner_->HoldPlans(true);
  ASSERT_EQ(c->Call(daoai::kCaptureAndProcessAsync, 0)->status, daoai::kDetection);
  fault::Arm("daoai.handled");
  failed = c->Call(daoai::kPickPose, 0);  // waits for the held detection, then throws
  ASSERT_TRUE(failed.ok()) << failed.status().ToString();
  EXPECT_EQ(failed->status, daoai::kUnknownCommand);
  EXPECT_EQ(handler_->stats().answer_failures, 2u);
  planner_->HoldPlans(false);
  ASSERT_TRUE(WaitUntil([&] { return handler_->Snapshot(0)->in_flight == 0; }));
  EXPECT_EQ(c->Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);  // in step
  pick = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok()) << pick.status().ToString();
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  EXPECT_EQ(pick->payload[0], 6);  // the new detection's first grasp: the dropped Reply popped nothing
  ASSERT_TRUE(planner_->WaitForHandedOut(2));
  EXPECT_EQ(Task0HandedOut(), (std::vector<int>{0, 0}));  // one grasp of each detection
  EXPECT_EQ(fault::Armed("daoai.handle") + fault::Armed("daoai.handled"), 0);
  ExpectBystanderServed();
  c.reset();
  ExpectBaseline();
}

// A calibration service that throws (it must not) once stopped the
// calibration sequence for good: the step was never answered, every later
// calibration step and teach pose waited forever.
class ThrowingCalibration final : public CalibrationService {
 public:
  explicit ThrowingCalibration(std::shared_ptr<std::atomic<bool>> throws) : throws_(std::move(throws)) {}
  Status Start(CalibrationKind, const Pose&) override {
    MaybeThrow();
    return Status::Ok();
  }
  Result<CalibrationStep> Accumulate(CalibrationKind, const Pose&) override {
    MaybeThrow();
    return CalibrationStep{};
  }
  Status Finish(CalibrationKind) override {
    MaybeThrow();
    return Status::Ok();
  }

 private:
  void MaybeThrow() const {
    if (*throws_) throw std::bad_alloc();
  }
  std::shared_ptr<std::atomic<bool>> throws_;
};

TEST_F(FaultTest, ACalibrationServiceThatThrowsIsAnsweredAndTheNextStepIsServed) {
  auto throws = std::make_shared<std::atomic<bool>>(true);
  calibration_ = std::make_unique<ThrowingCalibration>(throws);
  Start();
  auto c = Connect();
  ASSERT_TRUE(c);
  Result<RobotReply> refused = c->Call(daoai::kStartManualCalibration, 0);
  ASSERT_TRUE(refused.ok()) << refused.status().ToString();
  EXPECT_EQ(refused->status, daoai::kUnknownCommand);
  EXPECT_EQ(handler_->stats().answer_failures, 1u);
  *throws = false;
  EXPECT_EQ(c->Call(daoai::kStartManualCalibration, 0)->status, daoai::kModeCalibration);
  EXPECT_EQ(c->Call(daoai::kManualAccumulatePose, 0)->status, daoai::kModeCalibration);
  ExpectBystanderServed();
  c.reset();
  ExpectBaseline();
}

// ------------------------------------------------------------------ limits

TEST_F(FaultTest, ConnectionsBeyondMaxConnectionsAreClosedAtAccept) {
  DaoaiServerOptions o;
  o.max_connections = 3;  // the bystander + 2
  Start(o);
  auto a = Connect();
  auto b = Connect();
  ASSERT_TRUE(a && b);
  ASSERT_TRUE(WaitUntil([&] { return server_->connection_count() == 3; }));
  RawSocket extra(server_->port());
  ASSERT_TRUE(extra.connected());  // the kernel accepts; binpick closes it
  EXPECT_TRUE(extra.WaitClosed(3000ms));
  EXPECT_EQ(server_->refused_count(), 1u);
  EXPECT_EQ(a->Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
  b.reset();
  ASSERT_TRUE(WaitUntil([&] { return server_->connection_count() == 2; }));
  auto again = Connect();  // a freed slot is usable
  ASSERT_TRUE(again);
  EXPECT_EQ(again->Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
  ExpectBystanderServed();
}

TEST_F(FaultTest, AboveMaxMessageRateRequestsAreDelayedNotDropped) {
  DaoaiServerOptions o;
  o.max_message_rate = 20;  // burst 20, then one per 50 ms
  Start(o);
  auto c = Connect();
  ASSERT_TRUE(c);
  std::vector<uint8_t> burst;
  const auto req = daoai::EncodeRequest(Req(daoai::kSwitchConfig, 1));
  for (int i = 0; i < 30; ++i) burst.insert(burst.end(), req.begin(), req.end());
  // 30 pipelined: more than max_queued_requests (16) would close an
  // unthrottled robot only if it outran the handler; throttled, all 30 are
  // read in turn and answered in order.
  const auto t0 = std::chrono::steady_clock::now();
  ASSERT_TRUE(c->SendBytes(burst.data(), burst.size()).ok());
  std::atomic<int> answered = 0;
  std::thread reader([&] {
    for (int i = 0; i < 30; ++i) {
      Result<RobotReply> r = c->Receive();
      if (!r.ok()) break;
      answered += r->status == daoai::kSwitchConfigSuccess;
    }
  });
  EXPECT_TRUE(WaitWhileBystanderTalks([&] { return answered == 30; }));
  reader.join();
  EXPECT_EQ(answered, 30);
  // A lower bound, the limit itself: the 10 requests past the burst of 20
  // are read at 20/s.
  EXPECT_GE(std::chrono::steady_clock::now() - t0, 450ms);
  ExpectBystanderServed();
}

TEST(ServerAllowlist, PeersNotListedAreClosedAtAcceptOnBothServers) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  GriHandler gri_handler(handler);
  // Only 127.0.0.2 may connect; the test connects from 127.0.0.1.
  DaoaiServerOptions d;
  d.port = 0;
  d.allowlist = {"127.0.0.2"};
  auto daoai = DaoaiServer::Start(handler, d);
  ASSERT_TRUE(daoai.ok()) << daoai.status().ToString();
  GriServerOptions g;
  g.v2_port = -1;
  g.official_port = 0;
  g.allowlist = {"127.0.0.2"};
  auto gri = GriServer::Start(gri_handler, g);
  ASSERT_TRUE(gri.ok()) << gri.status().ToString();
  for (int port : {(*daoai)->port(), (*gri)->v2_port()}) {
    RawSocket s(port);
    ASSERT_TRUE(s.connected());
    EXPECT_TRUE(s.WaitClosed(3000ms)) << "port " << port;
  }
  EXPECT_EQ((*daoai)->refused_count(), 1u);
  EXPECT_EQ((*gri)->refused_count(), 1u);
  EXPECT_EQ((*daoai)->connection_count(), 0u);
  // Listed: served.
  DaoaiServerOptions listed = d;
  listed.allowlist = {"10.0.0.9", "127.0.0.1"};
  auto open = DaoaiServer::Start(handler, listed);
  ASSERT_TRUE(open.ok());
  RobotClientOptions ro;
  ro.port = (*open)->port();
  auto c = RobotClient::Connect(ro);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ((*c)->Call(daoai::kSwitchConfig, 1)->status, daoai::kSwitchConfigSuccess);
  EXPECT_EQ((*open)->refused_count(), 0u);
  // A malformed entry is refused at start.
  DaoaiServerOptions bad = d;
  bad.allowlist = {"robot-1"};
  auto refused = DaoaiServer::Start(handler, bad);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), Status::Code::kInvalidArgument);
  (*c).reset();
  (*open)->Stop();
  (*gri)->Stop();
  (*daoai)->Stop();
  handler.Shutdown();
}

}  // namespace
}  // namespace bp
