// Fleet replay (record/replay_fleet.h): the manifest, the size-balanced
// shard assignment, and the merge of shard reports (regressions, latency
// percentiles, detection-count changes, consistency checks) on shard
// reports written here with known contents. The end-to-end sharded replay
// over recorded sessions is in replay_shards_test.cc.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <numeric>
#include <random>

#include <nlohmann/json.hpp>

#include "record/replay_fleet.h"
#include "tests/testing/files.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

TEST(ReplayManifest, ExpandsGlobsInSortedOrderRelativeToTheManifestAndKeepsTheFirstPlaceOfADuplicate) {
  const std::string dir = testing::FreshDir("m");
  for (const char* d : {"site/cellA/s2", "site/cellA/s1", "site/cellB/s1", "other"}) {
    fs::create_directories(dir + "/" + d);
  }
  testing::WriteText(dir + "/site/cellA/not_a_dir", "x");
  testing::WriteText(dir + "/fleet.txt",
                     "# sessions of the site\n\n  other  \nsite/cellA/*\n" + dir + "/site/cellB/s1\nsite/cellA/s1\n");
  Result<ReplayManifest> m = LoadReplayManifest(dir + "/fleet.txt");
  ASSERT_TRUE(m.ok()) << m.status().ToString();
  EXPECT_EQ(m->sessions, (std::vector<std::string>{dir + "/other", dir + "/site/cellA/s1", dir + "/site/cellA/s2",
                                                   dir + "/site/cellB/s1"}));
  EXPECT_EQ(m->fingerprint.size(), 16u);
  testing::WriteText(dir + "/fleet2.txt", "other\nsite/cellA/s1\n");
  Result<ReplayManifest> m2 = LoadReplayManifest(dir + "/fleet2.txt");
  ASSERT_TRUE(m2.ok());
  EXPECT_NE(m2->fingerprint, m->fingerprint);
}

TEST(ReplayManifest, AnEntryNamingNothingIsAnErrorNamingItsLine) {
  const std::string dir = testing::FreshDir("m");
  fs::create_directories(dir + "/s1");
  testing::WriteText(dir + "/fleet.txt", "s1\n# comment\ns9*\n");
  Result<ReplayManifest> m = LoadReplayManifest(dir + "/fleet.txt");
  ASSERT_FALSE(m.ok());
  EXPECT_EQ(m.status().code(), Status::Code::kInvalidArgument);
  EXPECT_NE(m.status().message().find("fleet.txt:3: 's9*' names no directory"), std::string::npos)
      << m.status().ToString();
  testing::WriteText(dir + "/empty.txt", "# nothing\n");
  EXPECT_FALSE(LoadReplayManifest(dir + "/empty.txt").ok());
  EXPECT_EQ(LoadReplayManifest(dir + "/none.txt").status().code(), Status::Code::kNotFound);
}

TEST(ShardSpec, ParsesIOfNAndRefusesAnythingElse) {
  Result<ShardSpec> s = ParseShardSpec("2/3");
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->index, 2);
  EXPECT_EQ(s->count, 3);
  for (const char* bad : {"3/3", "-1/3", "0/0", "1", "1/", "/2", "a/2", "1/2x", " 1/2", "0/100001"}) {
    EXPECT_FALSE(ParseShardSpec(bad).ok()) << bad;
  }
}

TEST(AssignShards, EveryItemOnceBalancedByBytesWithinOneItemAndTheSameForTheSameSizes) {
  std::mt19937 rng{42};
  for (int trial = 0; trial < 200; ++trial) {
    const int count = 1 + static_cast<int>(rng() % 7);
    std::vector<uint64_t> bytes(rng() % 40);
    for (uint64_t& b : bytes) b = rng() % 1000 == 0 ? 0 : 1 + rng() % 5'000'000;
    const std::vector<int> shard = AssignShards(bytes, count);
    ASSERT_EQ(shard.size(), bytes.size());
    std::vector<uint64_t> load(count, 0);
    for (size_t i = 0; i < bytes.size(); ++i) {
      ASSERT_GE(shard[i], 0);
      ASSERT_LT(shard[i], count);
      load[shard[i]] += bytes[i];
    }
    // Greedy largest-first: the fullest shard exceeds the emptiest by at most
    // the largest item.
    const uint64_t largest = bytes.empty() ? 0 : *std::max_element(bytes.begin(), bytes.end());
    EXPECT_LE(*std::max_element(load.begin(), load.end()) - *std::min_element(load.begin(), load.end()), largest);
    EXPECT_EQ(AssignShards(bytes, count), shard);
  }
  // By size, not by count: one big session is a shard of its own.
  EXPECT_EQ(AssignShards({100, 10, 10, 10, 10, 10}, 2), (std::vector<int>{0, 1, 1, 1, 1, 1}));
}

// A capture of a session report as ReplayReportJson writes it.
json Capture(const std::string& file, double plan_ms, int recorded_detections, int replayed_detections,
             std::vector<std::string> differences = {}) {
  return {{"file", file},
          {"task_id", 0},
          {"replayed", true},
          {"recorded_plan_ms", plan_ms + 1.0},
          {"plan_ms", plan_ms},
          {"result", {{"detections", replayed_detections}}},
          {"recorded", {{"detections", recorded_detections}}},
          {"differences", differences}};
}

json Session(int index, const std::string& cell, std::vector<json> captures) {
  return {{"index", index},
          {"dir", "/s/" + std::to_string(index)},
          {"bytes", 1000},
          {"report",
           {{"cell_name", cell}, {"captures", captures}, {"skipped", json::array()}}}};
}

std::string WriteShard(const std::string& dir, int index, int count, std::vector<json> sessions, int total = 4) {
  json j{{"format", "binpick.replay-shard/1"},
         {"manifest", {{"path", "/m.txt"}, {"sessions", total}, {"fingerprint", "0123456789abcdef"}}},
         {"shard", {{"index", index}, {"count", count}}},
         {"tolerance", {{"mm", 1.0}, {"deg", 1.0}}},
         {"sessions", sessions}};
  const std::string path = dir + "/shard" + std::to_string(index) + ".json";
  testing::WriteText(path, j.dump());
  return path;
}

TEST(MergeReplayShards, ReportsPerCellAndSessionTheRegressionsPercentilesAndDetectionChanges) {
  const std::string dir = testing::FreshDir("merge");
  std::vector<json> cell_a;
  for (int i = 1; i <= 20; ++i) cell_a.push_back(Capture("/s/0/cap_" + std::to_string(i), i, 3, 3));
  const std::string s0 = WriteShard(
      dir, 0, 2,
      {Session(0, "cellA", cell_a),
       Session(3, "cellB", {Capture("/s/3/cap_1", 100, 2, 1, {"detections: recorded 2, replayed 1"})})});
  json failed{{"index", 2}, {"dir", "/s/2"}, {"bytes", 0}, {"error", "NotFound: '/s/2': no such directory"}};
  const std::string s1 =
      WriteShard(dir, 1, 2, {Session(1, "cellB", {Capture("/s/1/cap_1", 50, 4, 4)}), failed});

  Result<FleetReport> fleet = MergeReplayShards({s1, s0});
  ASSERT_TRUE(fleet.ok()) << fleet.status().ToString();
  EXPECT_EQ(fleet->sessions, 4);
  EXPECT_EQ(fleet->captures, 22);
  EXPECT_EQ(fleet->regressions, 2);  // the differing capture and the session that was not replayed
  const json j = json::parse(fleet->json);
  EXPECT_EQ(j["format"], "binpick.replay-fleet/1");
  EXPECT_TRUE(j["regression"].get<bool>());
  ASSERT_EQ(j["cells"].size(), 3u);  // sorted by name
  EXPECT_EQ(j["cells"][0]["cell"], "<not replayed>");
  EXPECT_EQ(j["cells"][0]["sessions"][0]["error"], "NotFound: '/s/2': no such directory");
  const json& a = j["cells"][1];
  EXPECT_EQ(a["cell"], "cellA");
  // Nearest rank over 1..20 ms: p50 the 10th, p95 the 19th, p99 the 20th.
  EXPECT_EQ(a["latency_ms"]["replayed"], json({{"count", 20}, {"p50", 10.0}, {"p95", 19.0}, {"p99", 20.0},
                                               {"max", 20.0}}));
  EXPECT_EQ(a["latency_ms"]["recorded"]["p50"], 11.0);
  EXPECT_EQ(a["totals"]["regressions"], 0);
  const json& b = j["cells"][2];
  EXPECT_EQ(b["cell"], "cellB");
  ASSERT_EQ(b["sessions"].size(), 2u);
  EXPECT_EQ(b["sessions"][0]["index"], 1);  // manifest order within a cell
  EXPECT_EQ(b["sessions"][1]["regressions"][0]["differences"][0], "detections: recorded 2, replayed 1");
  EXPECT_EQ(b["sessions"][1]["detection_changes"][0], json({{"file", "/s/3/cap_1"}, {"recorded", 2}, {"replayed", 1}}));
  EXPECT_EQ(b["totals"]["detections_recorded"], 6);
  EXPECT_EQ(b["totals"]["detections_replayed"], 5);
  EXPECT_EQ(b["latency_ms"]["replayed"]["max"], 100.0);
  EXPECT_EQ(j["totals"]["sessions_failed"], 1);
  EXPECT_EQ(j["totals"]["differing"], 1);
  EXPECT_EQ(j["totals"]["detection_count_changes"], 1);
  EXPECT_EQ(j["latency_ms"]["replayed"]["count"], 22);
}

TEST(MergeReplayShards, InconsistentShardReportsAreRefusedWithTheReason) {
  const std::string dir = testing::FreshDir("bad");
  const auto one = [](int i) { return Session(i, "c", {Capture("/s/" + std::to_string(i) + "/cap_1", 5, 1, 1)}); };
  const std::string a = WriteShard(dir, 0, 2, {one(0), one(1)});
  const std::string b = WriteShard(dir, 1, 2, {one(2), one(3)});
  ASSERT_TRUE(MergeReplayShards({a, b}).ok());
  EXPECT_EQ(MergeReplayShards({a, b})->regressions, 0);

  const auto refused = [](const std::vector<std::string>& files, const std::string& why) {
    Result<FleetReport> r = MergeReplayShards(files);
    ASSERT_FALSE(r.ok()) << why;
    EXPECT_NE(r.status().message().find(why), std::string::npos) << r.status().ToString();
  };
  refused({a}, "shard 1 of 2 is missing");
  refused({a, a}, "shard 0 given twice");
  const std::string twice = dir + "/twice";
  fs::create_directories(twice);
  refused({a, WriteShard(twice, 1, 2, {one(1), one(2), one(3)})}, "replayed by two shards");
  const std::string gap = dir + "/gap";
  fs::create_directories(gap);
  refused({a, WriteShard(gap, 1, 2, {one(3)})}, "session 2 of the manifest was replayed by no shard");
  const std::string three = dir + "/three";
  fs::create_directories(three);
  refused({a, WriteShard(three, 1, 3, {one(2), one(3)})}, "shard count 3");
  const std::string other = dir + "/other";
  fs::create_directories(other);
  refused({a, WriteShard(other, 1, 2, {one(2), one(3)}, 5)}, "another manifest");
  testing::WriteText(dir + "/fleet.json", R"({"format": "binpick.replay-fleet/1"})");
  refused({a, dir + "/fleet.json"}, "not a shard report");
  testing::WriteText(dir + "/cut.json", testing::ReadBytes(b).substr(0, 40));
  refused({a, dir + "/cut.json"}, "not a JSON object");
  EXPECT_EQ(MergeReplayShards({a, dir + "/none.json"}).status().code(), Status::Code::kNotFound);
}

}  // namespace
}  // namespace bp
