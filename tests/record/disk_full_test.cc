// "The disk fills while recording" (docs/reliability.md "Faults"), on a real
// full file system: the test process enters a mount namespace of its own and
// mounts a 2 MiB tmpfs, the recorder records into it through the real stack
// (DaoaiServer over loopback -> RequestHandler -> planner with real frames ->
// Recorder) until writes fail with ENOSPC. Needs CAP_SYS_ADMIN (root, as on
// CI); skipped with the reason otherwise. ctest runs each test case in its own
// process, so the namespace and the mount end with it.
#include <errno.h>
#include <sched.h>
#include <sys/mount.h>

#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <thread>

#include <nlohmann/json.hpp>

#include "comms/daoai_server.h"
#include "comms/request_handler.h"
#include "comms/robot_client.h"
#include "pipeline/recording.h"
#include "record/recorder.h"
#include "record/recorder_metrics.h"
#include "tests/testing/files.h"
#include "tests/testing/scripted_planner.h"
#include "tests/web/web_test_util.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using testing::ScriptedPlanner;

constexpr int kGraspsPerDetection = 6;

// Mounts a tmpfs of `size` ("2m") on `dir` in a private mount namespace of
// this thread (and of the threads it starts afterwards). @returns the reason
// when it cannot (no privilege): the caller skips.
std::string MountTinyDisk(const std::string& dir, const char* size) {
  if (::unshare(CLONE_NEWNS) != 0) return std::string("unshare(CLONE_NEWNS): ") + std::strerror(errno);
  if (::mount(nullptr, "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0) {
    return std::string("making / private: ") + std::strerror(errno);
  }
  const std::string options = std::string("size=") + size;
  if (::mount("tmpfs", dir.c_str(), "tmpfs", 0, options.c_str()) != 0) {
    return std::string("mount tmpfs: ") + std::strerror(errno);
  }
  return "";
}

// Every record directory of `session`: no partial one, and each verifies.
void ExpectOnlyCompleteRecords(const std::string& session, size_t expected) {
  std::vector<std::string> leftovers;
  size_t records = 0;
  for (const auto& entry : fs::directory_iterator(session)) {
    const std::string name = entry.path().filename().string();
    if (IsRecordDirName(name)) {
      ++records;
      const Status s = VerifyRecord(entry.path().string());
      EXPECT_TRUE(s.ok()) << name << ": " << s.ToString();
    } else if (name != kSessionManifestName && name != kSessionCellName &&
               !(name.rfind("answers_", 0) == 0 && entry.path().extension() == ".json")) {
      leftovers.push_back(name);  // a .partial directory, a temporary file
    }
  }
  EXPECT_EQ(leftovers, std::vector<std::string>{});
  EXPECT_EQ(records, expected);
  Result<RecordListing> listing = ListRecords(session);
  ASSERT_TRUE(listing.ok());
  EXPECT_EQ(listing->records.size(), expected);
  EXPECT_EQ(listing->skipped, std::vector<std::string>{});
}

TEST(DiskFull, RecordingPausesOnENOSPCTheServerLosesNoGraspAndRecordingResumesWhenSpaceIsFreed) {
  const std::string disk = testing::FreshDir("disk_full");
  if (const std::string why = MountTinyDisk(disk, "2m"); !why.empty()) {
    GTEST_SKIP() << "needs a private mount namespace (root): " << why;
  }
  // Ballast the operator will delete to free space.
  {
    std::ofstream ballast(disk + "/ballast", std::ios::binary);
    const std::string mib(1 << 20, 'x');
    ballast << mib;
    ASSERT_TRUE(ballast.good());
  }

  std::ostringstream log;
  auto sink = std::make_shared<spdlog::sinks::ostream_sink_mt>(log);
  spdlog::default_logger()->sinks().push_back(sink);

  const Cell cell = testing::MakeTestCell();
  RecorderOptions ro;
  ro.directory = disk + "/rec";
  ro.max_disk_bytes = int64_t{1} << 30;  // the cap is not what stops it: the disk is
  ro.retry_after = 300ms;
  auto started = Recorder::Start(cell, ro);
  ASSERT_TRUE(started.ok()) << started.status().ToString();
  std::shared_ptr<Recorder> recorder = *started;
  const std::string session = recorder->session_dir();
  MetricsRegistry metrics;
  AddRecorderMetrics(metrics, *recorder);
  auto scrape = [&metrics] {
    std::map<std::string, double> samples;
    EXPECT_EQ(webtest::CheckPrometheusText(metrics.Render(), &samples), std::vector<std::string>{});
    return samples;
  };

  auto script = std::make_shared<ScriptedPlanner>();
  ScriptedPlanner::Script many;
  many.grasps = kGraspsPerDetection;
  script->SetScript(0, many);
  RequestHandler handler(cell, std::make_shared<webtest::FramePlanner>(script), nullptr);
  handler.AddObserver(recorder);
  DaoaiServerOptions so;
  so.port = 0;
  auto server = DaoaiServer::Start(handler, so);
  ASSERT_TRUE(server.ok()) << server.status().ToString();
  RobotClientOptions co;
  co.port = (*server)->port();
  co.version = 2;
  co.timeout = 5000ms;
  auto robot = RobotClient::Connect(co);
  ASSERT_TRUE(robot.ok()) << robot.status().ToString();

  // One cycle: a capture, then every grasp of the detection, each checked
  // against the planner's grasp i. Returns false on any wrong answer.
  int cycles = 0;
  auto cycle = [&] {
    ++cycles;
    Result<RobotReply> cap = (*robot)->Call(daoai::kCaptureAndProcess, 0);
    EXPECT_TRUE(cap.ok() && cap->status == daoai::kDetection) << cap.status().ToString();
    if (!cap.ok() || cap->status != daoai::kDetection) return false;
    for (int i = 0; i < kGraspsPerDetection; ++i) {
      Result<RobotReply> pick = (*robot)->Call(daoai::kPickPose, 0);
      EXPECT_TRUE(pick.ok() && pick->status == daoai::kObjectsFound && pick->X_BT) << "cycle " << cycles
                                                                                    << " pick " << i;
      if (!pick.ok() || pick->status != daoai::kObjectsFound || !pick->X_BT) return false;
      const Vec3 expected = ScriptedPlanner::GraspPose(0, i).translation();
      EXPECT_LT((pick->X_BT->translation() - expected).norm(), 1e-4) << "cycle " << cycles << " pick " << i;
    }
    recorder->Flush();
    return true;
  };

  // Record until the disk is full: ~240 KB per record on 1 MiB left.
  while (recorder->stats().captures_failed == 0 && cycles < 30) ASSERT_TRUE(cycle());
  RecorderStats s = recorder->stats();
  ASSERT_TRUE(s.paused) << "the disk never filled in " << cycles << " cycles";
  EXPECT_GE(s.captures_recorded, 2u);
  EXPECT_GE(s.captures_failed, 1u);
  EXPECT_NE(s.last_error.find("No space left on device"), std::string::npos) << s.last_error;
  EXPECT_NE(s.last_error.find("disk full"), std::string::npos) << s.last_error;
  EXPECT_NE(log.str().find("recording paused"), std::string::npos) << log.str();
  EXPECT_NE(log.str().find("No space left on device"), std::string::npos) << log.str();
  std::map<std::string, double> m = scrape();
  EXPECT_EQ(m["binpick_recording_paused"], 1);
  EXPECT_EQ(m["binpick_recording_captures_total{result=\"failed\"}"], static_cast<double>(s.captures_failed));
  EXPECT_EQ(m["binpick_recording_captures_total{result=\"recorded\"}"], static_cast<double>(s.captures_recorded));
  // What is on disk is complete records only: the failed one left nothing.
  ExpectOnlyCompleteRecords(session, s.captures_recorded);

  // Then not a byte left (another writer took the rest): the answers files
  // cannot be written either.
  {
    std::ofstream filler(disk + "/filler", std::ios::binary);
    const std::string block(4096, 'f');
    while (filler.write(block.data(), block.size())) filler.flush();
  }
  ASSERT_EQ(fs::space(disk).available, 0u);
  // The server keeps serving while the disk stays full, paused or retrying.
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(cycle());
    std::this_thread::sleep_for(150ms);
  }
  s = recorder->stats();
  EXPECT_EQ(s.captures_recorded + s.captures_failed + s.captures_dropped, static_cast<uint64_t>(cycles));
  ExpectOnlyCompleteRecords(session, s.captures_recorded);
  const uint64_t recorded_while_full = s.captures_recorded;

  // Space is freed: after the pause the next capture is recorded again.
  fs::remove(disk + "/ballast");
  fs::remove(disk + "/filler");
  std::this_thread::sleep_for(ro.retry_after + 100ms);
  ASSERT_TRUE(cycle());
  s = recorder->stats();
  EXPECT_FALSE(s.paused) << s.last_error;
  EXPECT_EQ(s.captures_recorded, recorded_while_full + 1);
  EXPECT_NE(log.str().find("recording: resuming"), std::string::npos);
  m = scrape();
  EXPECT_EQ(m["binpick_recording_paused"], 0);
  EXPECT_EQ(m["binpick_recording_captures_total{result=\"recorded\"}"], static_cast<double>(s.captures_recorded));

  // Every grasp handed out exactly once: 6 per cycle, in order, none twice.
  // Handed out once written: the last write's completion may lag the read.
  EXPECT_TRUE(script->WaitForHandedOut(static_cast<size_t>(cycles * kGraspsPerDetection)));
  const std::vector<std::pair<int, int>> handed_out = script->handed_out();
  ASSERT_EQ(handed_out.size(), static_cast<size_t>(cycles * kGraspsPerDetection));
  for (size_t k = 0; k < handed_out.size(); ++k) {
    EXPECT_EQ(handed_out[k], std::make_pair(0, static_cast<int>(k % kGraspsPerDetection))) << k;
  }

  (*robot).reset();
  (*server)->Stop();
  handler.Shutdown();
  recorder->Stop();
  s = recorder->stats();
  ExpectOnlyCompleteRecords(session, s.captures_recorded);
  // Every answer sent (a capture and 6 picks a cycle) is either in an answers
  // file or counted as dropped, never both, never neither.
  size_t on_disk = 0;
  for (const auto& entry : fs::directory_iterator(session)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("answers_", 0) != 0) continue;
    std::ifstream in(entry.path());
    on_disk += nlohmann::json::parse(in).at("answers").size();
  }
  EXPECT_EQ(on_disk, s.answers_recorded);
  EXPECT_EQ(s.answers_recorded + s.answers_dropped, static_cast<uint64_t>(cycles * (1 + kGraspsPerDetection)));
  spdlog::default_logger()->sinks().pop_back();
  ::umount2(disk.c_str(), MNT_DETACH);
}

}  // namespace
}  // namespace bp
