// Sharded replay end to end: sessions of two cells recorded by the Recorder
// (real perception, a robot's capture + pick pose cycles through the request
// handler), listed in a manifest; `binpick replay --manifest --shard i/n`
// runs as n separate processes for n = 1 (unsharded), 2 and 3, and
// `binpick replay-merge` of each run gives the same fleet report: the same
// sessions, per cell, the same regression (a recorded result changed on
// purpose), the same totals; only the measured latencies differ. n = 2 and
// 3 run the Kubernetes Job's and the Slurm scripts' own commands.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "comms/request_handler.h"
#include "grasp/bin_picking_planner.h"
#include "pipeline/capture_source.h"
#include "pipeline/perception.h"
#include "record/recorder.h"
#include "record/replay_fleet.h"
#include "tests/record/record_test_util.h"
#include "tests/testing/files.h"
#include "tests/testing/run_command.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

const std::string kBin = std::string(BINPICK_BINARY_DIR) + "/bin/";

daoai::Request Req(int32_t command) {
  daoai::Request r;
  r.position = {5000, 0, 6000};
  r.orientation = {0, 0, 0, 10000};
  r.command = command;
  r.payload_1 = 0;
  r.meta_1 = 7;
  r.meta_2 = 2;
  return r;
}

// Records `cycles` capture + pick pose cycles of `cell` into a new session
// under `root`; @returns the session directory.
std::string RecordSession(const Cell& cell, std::shared_ptr<const Perception> perception, const std::string& root,
                          int cycles) {
  auto source = MakeCaptureSource(cell);
  EXPECT_TRUE(source.ok()) << source.status().ToString();
  BinPickingPlannerOptions options;
  options.teach_file = "-";
  auto planner = BinPickingPlanner::Create(cell, std::move(perception), std::move(*source), options);
  EXPECT_TRUE(planner.ok()) << planner.status().ToString();
  RecorderOptions ro;
  ro.directory = root;
  auto recorder = Recorder::Start(cell, ro);
  EXPECT_TRUE(recorder.ok()) << recorder.status().ToString();
  {
    RequestHandler handler(cell, std::shared_ptr<GraspPlanner>(std::move(*planner)), nullptr);
    handler.AddObserver(*recorder);
    ClientContext client;
    for (int i = 0; i < cycles; ++i) {
      EXPECT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess), client)->status, daoai::kDetection);
      EXPECT_TRUE(handler.Handle(Req(daoai::kPickPose), client).has_value());
    }
    handler.Shutdown();
  }
  (*recorder)->Stop();
  return (*recorder)->session_dir();
}

json ReadJson(const std::string& path) {
  std::ifstream in(path);
  json j = json::parse(in, nullptr, /*allow_exceptions=*/false);
  EXPECT_FALSE(j.is_discarded()) << path << " is not JSON";
  return j;
}

// The fleet report without what is measured (latency values) or depends on
// n (the shard count): keeps the latency sample counts.
json Comparable(json j) {
  if (j.is_object()) {
    j.erase("shards");
    for (auto& [key, value] : j.items()) {
      if (key == "latency_ms") {
        for (auto& [kind, stats] : value.items()) stats = {{"count", stats["count"]}};
      } else {
        value = Comparable(value);
      }
    }
  } else if (j.is_array()) {
    for (json& v : j) v = Comparable(v);
  }
  return j;
}

TEST(ReplayShards, OneTwoAndThreeShardProcessesMergeToTheSameFleetReport) {
  const std::string dir = testing::FreshDir("fleet");
  // Two cells: the small default cell under two names and two piles.
  std::vector<Cell> cells;
  for (const auto& [name, seed] : std::vector<std::pair<std::string, int>>{{"cell_a", 7}, {"cell_b", 9}}) {
    fs::create_directories(dir + "/" + name);
    std::string path = testing::WriteSmallCell(dir + "/" + name, 3, seed);
    std::string text = testing::ReadBytes(path);
    testing::ReplaceOnce(text, "name: default", "name: " + name);
    testing::WriteText(path, text);
    Result<Cell> cell = LoadCell(path);
    ASSERT_TRUE(cell.ok()) << cell.status().ToString();
    cells.push_back(*cell);
  }
  auto built = Perception::Build(cells[0]);  // the same parts and camera in both cells
  ASSERT_TRUE(built.ok()) << built.status().ToString();
  const std::shared_ptr<const Perception> perception(std::move(*built));
  // Sessions of different sizes: 1, 3 and 2 cycles of cell_a, 2 of cell_b.
  std::vector<std::string> sessions;
  int n = 0;
  for (const auto& [c, cycles] : std::vector<std::pair<int, int>>{{0, 1}, {0, 3}, {1, 2}, {0, 2}}) {
    sessions.push_back(RecordSession(cells[c], perception, dir + "/site/" + cells[c].name + "_" + std::to_string(++n),
                                     cycles));
  }
  // A regression: one recorded result changed (one more detection than the replay finds).
  const std::string changed = sessions[1] + "/cap_000002/record.json";
  json r = ReadJson(changed);
  r["plan"]["result"]["detections"] = r["plan"]["result"]["detections"].get<int>() + 1;
  std::ofstream(changed) << r.dump(1);
  testing::WriteText(dir + "/fleet.txt", "# every session of the site\nsite/*/session_*\n");
  Result<ReplayManifest> manifest = LoadReplayManifest(dir + "/fleet.txt");
  ASSERT_TRUE(manifest.ok()) << manifest.status().ToString();
  ASSERT_EQ(manifest->sessions.size(), 4u);

  // n = 1: the CLI by hand; n = 2: as the Kubernetes Indexed Job runs it;
  // n = 3: as the Slurm array and its merge job run it
  // (tests/deploy/run_fleet_manifests.py: the manifests' own commands).
  const std::string runner = "/usr/bin/python3 " + std::string(BINPICK_SOURCE_DIR) +
                             "/tests/deploy/run_fleet_manifests.py ";
  const std::vector<std::string> runs = {"direct", "k8s", "slurm"};
  std::vector<json> fleets;
  for (int count = 1; count <= 3; ++count) {
    const std::string run = runs[count - 1];
    const std::string reports = dir + "/reports/" + run;
    test::CommandRun merge;
    if (count == 1) {
      const test::CommandRun shard = test::RunCommand(kBin + "binpick --log-level info replay --manifest " + dir +
                                                      "/fleet.txt --json " + reports + "/shard-0.json");
      ASSERT_EQ(shard.exit_code, 0) << shard.out;
      // The sessions of a cell share its perception model: each part's model
      // is built (and logged) once per cell, not once per session.
      size_t builds = 0;
      for (size_t at = shard.out.find("perception: part '"); at != std::string::npos;
           at = shard.out.find("perception: part '", at + 1)) {
        ++builds;
      }
      EXPECT_EQ(builds, cells.size() * cells[0].parts.size()) << shard.out;
      merge = test::RunCommand(kBin + "binpick replay-merge " + reports + "/shard-0.json --json " + reports +
                               "/fleet.json");
    } else {
      merge = test::RunCommand(runner + run + " --data " + dir + " --binpick " + kBin + "binpick --shards " +
                               std::to_string(count) + " --run " + run);
    }
    EXPECT_EQ(merge.exit_code, 1) << "the changed record is a regression: " << merge.out;
    EXPECT_NE(merge.out.find("4 sessions, 8 captures, 1 regressions"), std::string::npos) << merge.out;
    fleets.push_back(ReadJson(reports + "/fleet.json"));
    // Each shard took what the size-balanced assignment gives it.
    std::vector<uint64_t> bytes;
    for (const std::string& s : manifest->sessions) bytes.push_back(DirectoryBytes(s));
    const std::vector<int> assignment = AssignShards(bytes, count);
    for (int i = 0; i < count; ++i) {
      const json shard = ReadJson(reports + "/shard-" + std::to_string(i) + ".json");
      std::vector<int> expected;
      for (size_t k = 0; k < assignment.size(); ++k) {
        if (assignment[k] == i) expected.push_back(static_cast<int>(k));
      }
      EXPECT_EQ(shard["shard"]["assigned"].get<std::vector<int>>(), expected) << run << " shard " << i;
    }
  }
  const json& unsharded = fleets[0];
  ASSERT_EQ(unsharded["cells"].size(), 2u);
  EXPECT_EQ(unsharded["cells"][0]["cell"], "cell_a");
  EXPECT_EQ(unsharded["cells"][0]["sessions"].size(), 3u);
  EXPECT_EQ(unsharded["cells"][1]["cell"], "cell_b");
  EXPECT_EQ(unsharded["totals"]["captures"], 8);
  EXPECT_EQ(unsharded["totals"]["differing"], 1);
  EXPECT_EQ(unsharded["totals"]["detection_count_changes"], 1);
  EXPECT_EQ(unsharded["latency_ms"]["replayed"]["count"], 8);
  const json& regressions = unsharded["cells"][0]["sessions"][1]["regressions"];
  ASSERT_EQ(regressions.size(), 1u) << unsharded.dump(1);
  EXPECT_EQ(regressions[0]["file"], sessions[1] + "/cap_000002");
  EXPECT_NE(regressions[0]["differences"][0].get<std::string>().find("detections: recorded"), std::string::npos);
  for (size_t i = 1; i < fleets.size(); ++i) {
    EXPECT_EQ(fleets[i]["shards"], static_cast<int>(i + 1));
    EXPECT_EQ(Comparable(fleets[i]), Comparable(unsharded)) << "n=" << i + 1 << " differs from n=1";
  }

  // Bad input is exit 2 and names what is wrong: a shard out of range, a
  // manifest entry naming nothing, a merge missing a shard.
  const test::CommandRun bad_shard =
      test::RunCommand(kBin + "binpick replay --manifest " + dir + "/fleet.txt --shard 3/3 --json " + dir + "/x.json");
  EXPECT_EQ(bad_shard.exit_code, 2) << bad_shard.out;
  EXPECT_NE(bad_shard.out.find("--shard '3/3'"), std::string::npos) << bad_shard.out;
  testing::WriteText(dir + "/bad.txt", "site/*/session_*\nno_such_cell/*\n");
  const test::CommandRun bad_manifest =
      test::RunCommand(kBin + "binpick replay --manifest " + dir + "/bad.txt --json " + dir + "/x.json");
  EXPECT_EQ(bad_manifest.exit_code, 2) << bad_manifest.out;
  EXPECT_NE(bad_manifest.out.find("bad.txt:2: 'no_such_cell/*' names no directory"), std::string::npos)
      << bad_manifest.out;
  const test::CommandRun partial = test::RunCommand(kBin + "binpick replay-merge " + dir +
                                                    "/reports/slurm/shard-0.json --json " + dir + "/x.json");
  EXPECT_EQ(partial.exit_code, 2) << partial.out;
  EXPECT_NE(partial.out.find("shard 1 of 3 is missing"), std::string::npos) << partial.out;
  EXPECT_FALSE(fs::exists(dir + "/x.json"));
}

}  // namespace
}  // namespace bp
