// Runs the built binpick binary (build/bin/binpick) as a user would.

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "pipeline/file_source.h"
#include "pipeline/frame_io.h"
#include "tests/testing/files.h"
#include "tests/testing/run_command.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

test::CommandRun RunBinpick(const std::string& args) {
  const std::string binary = std::string(BINPICK_BINARY_DIR) + "/bin/binpick";
  if (!fs::exists(binary)) return {-1, "binpick binary not built: " + binary};
  return test::RunCommand(binary + " " + args);
}

std::string FreshDir() { return bp::testing::FreshDir("cli"); }

TEST(BinpickCli, HelpListsSubcommands) {
  const test::CommandRun r = RunBinpick("--help");
  EXPECT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("render"));
  EXPECT_THAT(r.out, HasSubstr("info"));
}

TEST(BinpickCli, UnknownSubcommandPrintsUsageAndFails) {
  const test::CommandRun r = RunBinpick("frobnicate");
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_THAT(r.out, HasSubstr("render"));  // usage lists the real subcommands
}

TEST(BinpickCli, InfoOnTruncatedCloudFailsWithBadInputNamingTheFile) {
  const std::string dir = FreshDir();
  const std::string path = dir + "/broken_cloud.pcd";
  std::ofstream(path) << "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                         "WIDTH 100\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100\nDATA binary\nxyz";
  const test::CommandRun r = RunBinpick("info " + path);
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_THAT(r.out, HasSubstr("broken_cloud.pcd"));
  EXPECT_THAT(r.out, HasSubstr("truncated"));
}

TEST(BinpickCli, InfoOnMissingFileFailsWithBadInput) {
  const test::CommandRun r = RunBinpick("info /nonexistent/nothing.pcd");
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_THAT(r.out, HasSubstr("nothing.pcd"));
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

TEST(BinpickCli, RenderWritesAFrameThatLoadsBackWithItsTruth) {
  const std::string dir = FreshDir();
  const test::CommandRun r = RunBinpick("render --seed 5 --out " + dir + "/a");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("parts placed"));
  Result<Frame> depth = LoadFrameFile(dir + "/a/depth.png");
  ASSERT_TRUE(depth.ok()) << depth.status().ToString();
  ASSERT_TRUE(depth->organized());
  ASSERT_TRUE(depth->truth.has_value());
  EXPECT_EQ(depth->truth->seed, 5u);
  EXPECT_FALSE(depth->truth->parts.empty());
  EXPECT_EQ(depth->truth->labels.width, depth->depth.width);
  EXPECT_EQ(depth->intensity.width, depth->depth.width);
  Result<Frame> cloud = LoadFrameFile(dir + "/a/cloud.pcd");
  ASSERT_TRUE(cloud.ok()) << cloud.status().ToString();
  ASSERT_TRUE(cloud->organized());
  EXPECT_TRUE(cloud->X_BC.matrix() == depth->X_BC.matrix());
  ASSERT_EQ(cloud->depth.data.size(), depth->depth.data.size());
  for (size_t i = 0; i < cloud->depth.data.size(); ++i) {
    const float a = cloud->depth.data[i], b = depth->depth.data[i];
    ASSERT_EQ(std::isnan(a), std::isnan(b)) << i;
    if (!std::isnan(a)) {
      ASSERT_NEAR(a, b, 0.5 * kDepthPngScale + 1e-6) << i;
    }
  }
  // The same seed writes the same ground truth.
  ASSERT_EQ(RunBinpick("render --seed 5 --out " + dir + "/b").exit_code, 0);
  EXPECT_EQ(ReadAll(dir + "/a/truth.json"), ReadAll(dir + "/b/truth.json"));
  // The file source serves the rendered directory: cloud.pcd, depth.png, wrap.
  Cell cell;
  auto source = MakeFileSource(dir + "/a", cell);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  for (const char* expected : {"cloud.pcd", "depth.png", "cloud.pcd"}) {
    Result<Frame> f = (*source)->Capture({});
    ASSERT_TRUE(f.ok()) << f.status().ToString();
    EXPECT_EQ(fs::path(f->source).filename().string(), expected);
    EXPECT_TRUE(f->truth.has_value());
  }
}

TEST(BinpickCli, RenderWithUnknownConfigFailsWithBadInput) {
  const test::CommandRun r = RunBinpick("render --seed 1 --config 99 --out " + FreshDir() + "/x");
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_THAT(r.out, HasSubstr("99"));
}

TEST(BinpickCli, InfoDescribesMeshesAndCells) {
  const std::string assets = std::string(BINPICK_SOURCE_DIR) + "/assets";
  test::CommandRun r = RunBinpick("info " + assets + "/parts/pipe_tee.ply");
  EXPECT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("triangle mesh"));
  r = RunBinpick("info " + assets + "/cells/default.yaml");
  EXPECT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("pipe_tee"));
}

TEST(BinpickCli, InfoDescribesAnOrganizedDepthFrame) {
  const std::string dir = FreshDir();
  Frame f;
  f.intrinsics.width = 8;
  f.intrinsics.height = 6;
  f.intrinsics.fx = f.intrinsics.fy = 10;
  f.intrinsics.cx = 3.5;
  f.intrinsics.cy = 2.5;
  f.depth = DepthImage(8, 6, 1.25f);
  f.depth.at(0, 0) = 0.75f;
  ASSERT_TRUE(WriteDepthPng(f, dir + "/depth.png").ok());
  const test::CommandRun r = RunBinpick("info " + dir + "/depth.png");
  EXPECT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("organized 8x6"));
  EXPECT_THAT(r.out, HasSubstr("48 valid of 48"));
  EXPECT_THAT(r.out, HasSubstr("0.7500 .. 1.2500 m"));
}

// One varied scene, scored strictly: the JSON carries every detection's and
// grasp's pose and verdict, consistent with the counts; a bad tolerance is
// refused. (Varied scenes are deterministic per seed: synthetic_test.cc.)
TEST(BinpickCli, EvalWritesEveryDetectionAndGraspWithItsVerdict) {
  const std::string dir = FreshDir();
  const auto eval = [&](const std::string& out) {
    return RunBinpick("eval --scenes 1 --seed 1003 --variety --threads 2 --json " + dir + "/" + out);
  };
  const test::CommandRun r = eval("a.json");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("strict: within 5.0 mm and 5.0 deg"));
  EXPECT_THAT(r.out, HasSubstr("first grasp on its part"));
  const nlohmann::json j = nlohmann::json::parse(std::ifstream(dir + "/a.json"));
  ASSERT_EQ(j["per_frame"].size(), 1u);
  const nlohmann::json& frame = j["per_frame"][0];
  EXPECT_THAT(frame["source"].get<std::string>(), HasSubstr("variety: tilt"));
  int detections = 0, right = 0;
  for (const auto& d : frame["detections"]) {
    ++detections;
    const std::string verdict = d["verdict"];
    EXPECT_THAT((std::vector<std::string>{"true", "gross", "duplicate", "false"}), ::testing::Contains(verdict));
    EXPECT_EQ(d["X_BO"].size(), 4u);
    if (verdict == "true") {
      ++right;
      EXPECT_LE(d["translation_error_mm"].get<double>(), 5.0);
      EXPECT_LE(d["rotation_error_deg"].get<double>(), 5.0);
      EXPECT_GE(d["truth_instance"].get<int>(), 1);
    }
  }
  const nlohmann::json& all = j["classes"].back();
  EXPECT_EQ(all["name"], "all");
  EXPECT_EQ(all["detections"].get<int>(), detections);
  EXPECT_EQ(all["true_positives"].get<int>(), right);
  EXPECT_GT(right, 0);
  int grasps = 0, on_part = 0;
  for (const auto& g : frame["grasps"]) {
    ++grasps;
    on_part += g["on_part"].get<bool>() ? 1 : 0;
    EXPECT_EQ(g["X_BT"].size(), 4u);
  }
  EXPECT_EQ(j["grasps"]["grasps"].get<int>(), grasps);
  EXPECT_EQ(j["grasps"]["on_part"].get<int>(), on_part);
  EXPECT_GT(grasps, 0);
  const test::CommandRun bad = RunBinpick("eval --scenes 1 --tol-mm 0");
  EXPECT_EQ(bad.exit_code, 2) << bad.out;
  EXPECT_THAT(bad.out, HasSubstr("--tol-mm"));
}

// CI runs `binpick eval` over the clouds other tools wrote
// (tests/pipeline/data/clouds): every file loads, organized, and perception
// finds the parts (the comparison with their depth images is
// CloudPerception.CloudsFromOtherToolsFindWhatTheirDepthImagesFind).
TEST(BinpickCli, EvalScoresCloudsFromOtherTools) {
  const std::string data = std::string(BINPICK_SOURCE_DIR) + "/tests/pipeline/data/clouds";
  const std::string json_path = FreshDir() + "/eval.json";
  const test::CommandRun r = RunBinpick("eval --source files:" + data + " --json " + json_path);
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, ::testing::Not(HasSubstr("assumed")));
  const nlohmann::json j = nlohmann::json::parse(ReadAll(json_path));
  EXPECT_EQ(j.at("frames").get<int>(), 5);
  const nlohmann::json& all = j.at("classes").back();
  ASSERT_EQ(all.at("name").get<std::string>(), "all");
  // Strict: 0.824 / 0.967 (their depth images 0.853 / 1.000; the merged cloud
  // turns one tee about its run).
  EXPECT_GE(all.at("targets").get<int>(), 30);
  EXPECT_GE(all.at("recall").get<double>(), 0.75);
  EXPECT_GE(all.at("precision").get<double>(), 0.9);
}

// `eval --bin-only` runs the bin detection stage alone on bins moved off
// their taught pose (--bin-offset) and scores it against the true bin; with
// more parts (--parts) the measured fill level rises.
TEST(BinpickCli, EvalBinOnlyScoresTheMeasuredBinAgainstTheTrueOne) {
  const std::string dir = FreshDir();
  const auto eval = [&](const std::string& args, const std::string& out) {
    const test::CommandRun r =
        RunBinpick("eval --scenes 2 --seed 9001 --bin-offset --bin-only " + args + " --json " + dir + "/" + out);
    EXPECT_EQ(r.exit_code, 0) << r.out;
    EXPECT_THAT(r.out, HasSubstr("bin detection: 2 frames, 2 found"));
    return nlohmann::json::parse(std::ifstream(dir + "/" + out));
  };
  const nlohmann::json few = eval("", "few.json");
  EXPECT_EQ(few.at("bin_detection").at("found").get<int>(), 2);
  EXPECT_LT(few.at("bin_detection").at("error_mm").at("max").get<double>(), 1.0);
  EXPECT_LT(few.at("bin_detection").at("error_deg").at("max").get<double>(), 0.2);
  ASSERT_EQ(few.at("frames").size(), 2u);
  for (const nlohmann::json& f : few.at("frames")) {
    EXPECT_TRUE(f.at("found").get<bool>());
    // The bin really was moved, by more than the error the stage is allowed.
    EXPECT_GT(f.at("offset_mm").get<double>(), 5.0);
    EXPECT_EQ(f.at("parts").get<int>(), 20);
  }
  const nlohmann::json many = eval("--parts 60", "many.json");
  ASSERT_EQ(many.at("frames").size(), 2u);
  for (size_t i = 0; i < 2; ++i) {
    // The truth lists the parts that came to rest inside the bin.
    EXPECT_GT(many["frames"][i].at("parts").get<int>(), 50);
    EXPECT_GT(many["frames"][i].at("fill_mean_mm").get<double>(), few["frames"][i].at("fill_mean_mm").get<double>());
  }
}

TEST(BinpickCli, InfoSaysHowACloudIsReadAndHowPerceptionTakesIt) {
  const std::string data = std::string(BINPICK_SOURCE_DIR) + "/tests/pipeline/data/clouds";
  test::CommandRun r = RunBinpick("info " + data + "/s4601_open3d_cloud.ply");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("PLY point cloud (binary_little_endian, float64 coordinates)"));
  EXPECT_THAT(r.out, HasSubstr("unorganized (point list)"));
  EXPECT_THAT(r.out, HasSubstr("units:       m (no \"unit\" declared)"));
  EXPECT_THAT(r.out, HasSubstr("a pinhole lattice recovered from the points"));
  r = RunBinpick("info " + data + "/s4603_hand_cloud.pcd");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("not used: intensity"));
  EXPECT_THAT(r.out, HasSubstr("units:       mm"));
  r = RunBinpick("info " + data + "/s4604_grid_cloud.pcd");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("stored as a 320x240 grid"));
  EXPECT_THAT(r.out, HasSubstr("VIEWPOINT"));
  r = RunBinpick("info " + data + "/s4605_merged_cloud.pcd");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("no pixel lattice"));
  // Without its sidecar: the assumed view, said.
  const std::string dir = FreshDir();
  fs::copy_file(data + "/s4602_pcl_cloud.pcd", dir + "/scan.pcd");
  r = RunBinpick("info " + dir + "/scan.pcd");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("no X_BC: the cell camera's (assumed)"));
  EXPECT_THAT(r.out, HasSubstr("[warning: assumed view]"));
  EXPECT_THAT(r.out, HasSubstr("not used: rgba normal_x normal_y normal_z curvature"));
}

// `binpick bench-cell` (issue 40 item 5) at config 1 for 2 cycles: binpickd
// started and stopped by it, a report with every step, percentiles in order,
// and binpickd's own capture and plan times inside the robot's capture ->
// first pose. Timing values are not checked (bench figures, not tests).
TEST(BinpickCli, BenchCellReportsEveryStepConsistently) {
  const std::string dir = FreshDir();
  const std::string path = dir + "/bench.json";
  const test::CommandRun r = RunBinpick("bench-cell --config 1 --cycles 2 --json " + path);
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_THAT(r.out, HasSubstr("config 1: 2 cycles"));
  EXPECT_THAT(r.out, HasSubstr("capture -> first pose (21)"));
  EXPECT_THAT(r.out, HasSubstr("synthetic capture (render)"));
  EXPECT_THAT(r.out, HasSubstr("load average (1 min)"));
  std::ifstream in(path);
  const nlohmann::json report = nlohmann::json::parse(in, nullptr, false);
  ASSERT_FALSE(report.is_discarded()) << r.out;
  EXPECT_GE(report["load_average_1min_before"].get<double>(), 0.0);
  ASSERT_EQ(report["configs"].size(), 1u);
  const nlohmann::json& c = report["configs"][0];
  EXPECT_EQ(c["config"], 1);
  EXPECT_EQ(c["cycles"], 2);
  ASSERT_EQ(c["per_cycle"].size(), 2u);
  for (const char* step : {"capture_ack", "first_pose", "further_pose", "synthetic_capture", "product", "plan",
                           "serving", "stage:pose", "stage:grasps"}) {
    SCOPED_TRACE(step);
    ASSERT_TRUE(c["steps"].contains(step));
  }
  for (const auto& [name, s] : c["steps"].items()) {
    SCOPED_TRACE(name);
    if (name != "further_pose") {
      EXPECT_EQ(s["n"], 2);
    }
    EXPECT_LE(s["p50"].get<double>(), s["p90"].get<double>());
    EXPECT_LE(s["p90"].get<double>(), s["p99"].get<double>());
  }
  for (const nlohmann::json& cycle : c["per_cycle"]) {
    const double ack = cycle["capture_ack"], first = cycle["first_pose"];
    const double capture = cycle["synthetic_capture"], plan = cycle["plan"];
    EXPECT_GT(capture, 0.0);
    EXPECT_GT(plan, 0.0);
    EXPECT_LE(ack, first);
    // binpickd's times lie inside the robot's round trips: 20 is answered
    // once the capture is done, the first 21 once the plan's head is known,
    // which is before the whole plan is when it is published early
    // (docs/protocols.md "The first pose early": `serving` is then < 0).
    EXPECT_LE(capture, ack);
    EXPECT_NEAR(capture + cycle["product"].get<double>(), first, 1e-6);
    EXPECT_NEAR(capture + plan + cycle["serving"].get<double>(), first, 1e-6);
  }
}

}  // namespace
}  // namespace bp
