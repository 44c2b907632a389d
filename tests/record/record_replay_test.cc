// Record then replay on the same build: the real BinPickingPlanner (real
// perception) on a small synthetic pile, driven through the request handler
// as a robot would, recorded by the Recorder; the replay must reproduce every
// detection and grasp exactly, and report a recorded result that was changed.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "comms/request_handler.h"
#include "grasp/bin_picking_planner.h"
#include "pipeline/capture_source.h"
#include "pipeline/perception.h"
#include "pipeline/recording.h"
#include "record/recorder.h"
#include "core/atomic_file.h"
#include "pipeline/frame_io.h"
#include "record/replay.h"
#include "tests/record/record_test_util.h"
#include "tests/testing/files.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

daoai::Request Req(int32_t command, int32_t task) {
  daoai::Request r;
  r.position = {5000, 0, 6000};
  r.orientation = {0, 0, 0, 10000};
  r.command = command;
  r.payload_1 = task;
  r.meta_1 = 7;
  r.meta_2 = 2;
  return r;
}

json ReadJson(const std::string& path) {
  std::ifstream in(path);
  return json::parse(in);
}

// One perception for the whole suite: building its model tables is the slow part.
std::shared_ptr<const Perception> SharedPerception(const Cell& cell) {
  static std::shared_ptr<const Perception> perception = [&] {
    auto p = Perception::Build(cell);
    EXPECT_TRUE(p.ok()) << p.status().ToString();
    return std::shared_ptr<const Perception>(p.ok() ? std::move(*p) : nullptr);
  }();
  return perception;
}

ReplayOptions ReplayWith(std::shared_ptr<const Perception> perception) {
  ReplayOptions o;
  o.tolerance_mm = 0.0;  // same build: exactly the same numbers
  o.tolerance_deg = 0.0;
  o.make_planner = [perception](const Cell& cell,
                                std::unique_ptr<CaptureSource> source) -> Result<std::unique_ptr<GraspPlanner>> {
    BinPickingPlannerOptions options;
    options.teach_file = "-";
    auto planner = BinPickingPlanner::Create(cell, perception, std::move(source), options);
    if (!planner.ok()) return planner.status();
    return std::unique_ptr<GraspPlanner>(std::move(*planner));
  };
  return o;
}

class RecordReplay : public ::testing::Test {
 protected:
  // Records `cycles` capture + pick-pose cycles into a fresh session.
  void Record(int cycles) {
    dir_ = testing::FreshDir("rec");
    Result<Cell> cell = LoadCell(testing::WriteSmallCell(dir_, 4, 7));
    ASSERT_TRUE(cell.ok()) << cell.status().ToString();
    cell_ = *cell;
    perception_ = SharedPerception(cell_);
    ASSERT_NE(perception_, nullptr);
    auto source = MakeCaptureSource(cell_);
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    BinPickingPlannerOptions options;
    options.teach_file = "-";
    auto planner = BinPickingPlanner::Create(cell_, perception_, std::move(*source), options);
    ASSERT_TRUE(planner.ok()) << planner.status().ToString();
    RecorderOptions ro;
    ro.directory = dir_ + "/recordings";
    auto recorder = Recorder::Start(cell_, ro);
    ASSERT_TRUE(recorder.ok()) << recorder.status().ToString();
    {
      RequestHandler handler(cell_, std::shared_ptr<GraspPlanner>(std::move(*planner)), nullptr);
      handler.AddObserver(*recorder);
      ClientContext client;
      for (int i = 0; i < cycles; ++i) {
        ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
        const auto pick = handler.Handle(Req(daoai::kPickPose, 0), client);
        ASSERT_TRUE(pick);
        statuses_.push_back(pick->status);
      }
      handler.Shutdown();
    }
    (*recorder)->Stop();
    session_ = (*recorder)->session_dir();
    stats_ = (*recorder)->stats();
  }

  std::string dir_;
  Cell cell_;
  std::shared_ptr<const Perception> perception_;
  std::string session_;
  RecorderStats stats_;
  std::vector<int32_t> statuses_;
};

TEST_F(RecordReplay, ReplayReproducesTheRecordedDetectionsAndGraspsExactly) {
  ASSERT_NO_FATAL_FAILURE(Record(3));
  EXPECT_EQ(stats_.captures_recorded, 3u);
  EXPECT_EQ(stats_.captures_dropped + stats_.captures_failed, 0u);
  EXPECT_EQ(stats_.answers_recorded, 6u);  // 3 x (DETECTION + the pick pose answer)

  // What a record holds.
  const json session = ReadJson(session_ + "/session.json");
  EXPECT_EQ(session["binpick_version"], BinpickVersion());
  const std::string rec = session_ + "/cap_000001";
  for (const char* f : {"cloud.pcd", "cloud.intrinsics.json", "depth.png", "depth.intrinsics.json",
                        "intensity.png", "truth.json", "labels.png", "record.json"}) {
    EXPECT_TRUE(fs::exists(rec + "/" + f)) << f;
  }
  const json r = ReadJson(rec + "/record.json");
  EXPECT_EQ(r["config_hash"], ConfigHash(cell_, 0));
  EXPECT_EQ(r["binpick_version"], BinpickVersion());
  EXPECT_EQ(r["task_id"], 0);
  EXPECT_FALSE(r["X_BF"].is_null());  // the robot pose sent with the request
  EXPECT_DOUBLE_EQ(r["X_BF"][0][3].get<double>(), 0.5);
  int detections = 0;
  for (int i = 1; i <= 3; ++i) {
    const json ri = ReadJson(session_ + "/cap_00000" + std::to_string(i) + "/record.json");
    detections += ri["plan"]["result"]["detections"].get<int>();
    EXPECT_FALSE(ri["plan"]["result"]["stages"].empty());
  }
  EXPECT_GT(detections, 0) << "the pile must give the comparison something to compare";
  // Every status sent, in order.
  const json answers = ReadJson(session_ + "/answers_000001.json")["answers"];
  ASSERT_EQ(answers.size(), 6u);
  for (size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(answers[2 * i]["response"]["status"], daoai::kDetection);
    EXPECT_EQ(answers[2 * i + 1]["response"]["status"], statuses_[i]);
    EXPECT_EQ(answers[2 * i + 1]["request"]["command"], daoai::kPickPose);
  }

  Result<ReplayReport> report = ReplayDirectory(session_, ReplayWith(perception_));
  ASSERT_TRUE(report.ok()) << report.status().ToString();
  EXPECT_TRUE(report->session);
  EXPECT_TRUE(report->skipped.empty());
  ASSERT_EQ(report->captures.size(), 3u);
  EXPECT_EQ(report->differing, 0);
  for (const CaptureReplay& c : report->captures) {
    EXPECT_TRUE(c.replayed) << c.error;
    EXPECT_TRUE(c.compared);
    EXPECT_TRUE(c.differences.empty()) << c.file << ": " << ::testing::PrintToString(c.differences);
    EXPECT_EQ(c.max_position_diff_mm, 0.0);
    EXPECT_EQ(c.max_angle_diff_deg, 0.0);
    EXPECT_EQ(c.result.detections, c.recorded.detections);
    EXPECT_EQ(c.result.grasps.size(), c.recorded.grasps.size());
    EXPECT_EQ(c.result.roi_points, c.recorded.roi_points);
    EXPECT_FALSE(c.result.stages.empty());
  }
}

TEST_F(RecordReplay, AResultThatMovedBeyondToleranceIsADifference) {
  ASSERT_NO_FATAL_FAILURE(Record(1));
  const std::string manifest = session_ + "/cap_000001/record.json";
  json r = ReadJson(manifest);
  json& grasps = r["plan"]["result"]["grasps"];
  ASSERT_FALSE(grasps.empty());
  grasps[0]["X_BT"][0][3] = grasps[0]["X_BT"][0][3].get<double>() + 0.005;  // 5 mm along x
  std::ofstream(manifest) << r.dump(1);

  ReplayOptions o = ReplayWith(perception_);
  o.tolerance_mm = 1.0;
  o.tolerance_deg = 1.0;
  Result<ReplayReport> report = ReplayDirectory(session_, o);
  ASSERT_TRUE(report.ok()) << report.status().ToString();
  ASSERT_EQ(report->captures.size(), 1u);
  EXPECT_EQ(report->differing, 1);
  ASSERT_EQ(report->captures[0].differences.size(), 1u);
  EXPECT_NE(report->captures[0].differences[0].find("grasps[0] moved 5.000 mm"), std::string::npos)
      << report->captures[0].differences[0];
  o.tolerance_mm = 6.0;  // within a looser tolerance
  report = ReplayDirectory(session_, o);
  ASSERT_TRUE(report.ok());
  EXPECT_EQ(report->differing, 0);
  EXPECT_NEAR(report->captures[0].max_position_diff_mm, 5.0, 1e-9);
}

TEST_F(RecordReplay, RecordsCutOffMidWriteAreSkippedWithAWarningAndReplayGoesOn) {
  ASSERT_NO_FATAL_FAILURE(Record(4));
  // cap 2: a data file cut short (a crash or a bad disk after the record was complete).
  const std::string pcd = session_ + "/cap_000002/cloud.pcd";
  fs::resize_file(pcd, fs::file_size(pcd) / 2);
  // cap 3: the manifest never made it, only its temporary file did.
  const std::string manifest = session_ + "/cap_000003/record.json";
  const std::string text = testing::ReadBytes(manifest);
  fs::remove(manifest);
  testing::WriteText(AtomicTempPath(manifest) + ".00001a2b000000070badc0de", text.substr(0, text.size() / 3));
  // cap 5: the staging directory of a record being written when the server died.
  fs::create_directories(session_ + "/cap_000005.partial");
  testing::WriteText(session_ + "/cap_000005.partial/cloud.pcd", "# .PCD v0.7");

  Result<ReplayReport> report = ReplayDirectory(session_, ReplayWith(perception_));
  ASSERT_TRUE(report.ok()) << report.status().ToString();
  ASSERT_EQ(report->skipped.size(), 3u) << ::testing::PrintToString(report->skipped);
  EXPECT_NE(report->skipped[0].find("cap_000002/cloud.pcd"), std::string::npos) << report->skipped[0];
  EXPECT_NE(report->skipped[0].find("truncated"), std::string::npos) << report->skipped[0];
  EXPECT_NE(report->skipped[1].find("cap_000003': no record.json"), std::string::npos) << report->skipped[1];
  EXPECT_NE(report->skipped[2].find("cap_000005.partial"), std::string::npos) << report->skipped[2];
  ASSERT_EQ(report->captures.size(), 2u);
  EXPECT_EQ(report->captures[0].file, session_ + "/cap_000001");
  EXPECT_EQ(report->captures[1].file, session_ + "/cap_000004");
  EXPECT_EQ(report->differing, 0);
  for (const CaptureReplay& c : report->captures) EXPECT_TRUE(c.replayed && c.compared) << c.error;

  // The replay source serves the complete records only, in order, wrapping around.
  auto source = MakeReplaySource(session_, cell_);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  std::vector<std::string> served;
  for (int i = 0; i < 3; ++i) {
    Result<Frame> frame = (*source)->Capture({});
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    served.push_back(frame->source);
  }
  EXPECT_EQ(served, (std::vector<std::string>{"replay " + session_ + "/cap_000001",
                                              "replay " + session_ + "/cap_000004",
                                              "replay " + session_ + "/cap_000001"}));
}

TEST(Replay, APlainDirectoryOfPcdAndDepthFilesReplays) {
  const std::string dir = testing::FreshDir("plain");
  const std::string cell_path = testing::WriteSmallCell(dir, 4, 7);
  Result<Cell> cell = LoadCell(cell_path);
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  auto source = MakeCaptureSource(*cell);
  ASSERT_TRUE(source.ok());
  Result<Frame> frame = (*source)->Capture({});
  ASSERT_TRUE(frame.ok()) << frame.status().ToString();
  const std::string frames = dir + "/frames";
  fs::create_directories(frames);
  ASSERT_TRUE(WriteCloudPcd(*frame, frames + "/f000_cloud.pcd").ok());
  ASSERT_TRUE(WriteDepthPng(*frame, frames + "/f001_depth.png").ok());

  ReplayOptions o = ReplayWith(SharedPerception(*cell));
  o.cell_path = cell_path;
  Result<ReplayReport> report = ReplayDirectory(frames, o);
  ASSERT_TRUE(report.ok()) << report.status().ToString();
  EXPECT_FALSE(report->session);
  ASSERT_EQ(report->captures.size(), 2u);
  for (const CaptureReplay& c : report->captures) {
    EXPECT_TRUE(c.replayed) << c.error;
    EXPECT_FALSE(c.compared);  // nothing recorded
    EXPECT_GT(c.result.detections, 0) << c.file;
    EXPECT_FALSE(c.result.stages.empty());
  }
  EXPECT_EQ(report->differing, 0);
}

}  // namespace
}  // namespace bp
