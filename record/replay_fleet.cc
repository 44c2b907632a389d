#include "record/replay_fleet.h"

#include <glob.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <set>

#include <nlohmann/json.hpp>

#include "grasp/bin_picking_planner.h"
#include "pipeline/perception.h"
#include "record/internal/replay_json.h"
#include "record/recorder.h"

namespace bp {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using OrderedJson = nlohmann::ordered_json;

constexpr const char* kShardFormat = "binpick.replay-shard/1";
constexpr const char* kFleetFormat = "binpick.replay-fleet/1";

std::string Trim(const std::string& s) {
  const size_t b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  return s.substr(b, s.find_last_not_of(" \t\r") - b + 1);
}

// FNV-1a, 64 bits, over the paths with a NUL after each.
std::string Fingerprint(const std::vector<std::string>& sessions) {
  uint64_t h = 1469598103934665603ull;
  for (const std::string& s : sessions) {
    for (const char c : s) h = (h ^ static_cast<unsigned char>(c)) * 1099511628211ull;
    h *= 1099511628211ull;  // the NUL separator
  }
  char buf[17];
  std::snprintf(buf, sizeof(buf), "%016llx", static_cast<unsigned long long>(h));
  return buf;
}

// The directories `pattern` names (sorted glob matches, or itself).
std::vector<std::string> ExpandEntry(const std::string& pattern) {
  std::vector<std::string> dirs;
  std::error_code ec;
  if (pattern.find_first_of("*?[") == std::string::npos) {
    if (fs::is_directory(pattern, ec)) dirs.push_back(pattern);
    return dirs;
  }
  glob_t g{};
  if (::glob(pattern.c_str(), GLOB_ONLYDIR, nullptr, &g) == 0) {
    for (size_t i = 0; i < g.gl_pathc; ++i) {
      if (fs::is_directory(g.gl_pathv[i], ec)) dirs.emplace_back(g.gl_pathv[i]);
    }
  }
  ::globfree(&g);
  std::sort(dirs.begin(), dirs.end());
  return dirs;
}

// ---- merge ----

struct LatencyStats {
  std::vector<double> replayed, recorded;
  void Add(const LatencyStats& o) {
    replayed.insert(replayed.end(), o.replayed.begin(), o.replayed.end());
    recorded.insert(recorded.end(), o.recorded.begin(), o.recorded.end());
  }
};

// Nearest-rank percentiles (the smallest value with at least p% of the
// values at or below it), ms.
OrderedJson Percentiles(std::vector<double> v) {
  OrderedJson j;
  j["count"] = v.size();
  if (v.empty()) return j;
  std::sort(v.begin(), v.end());
  const auto rank = [&v](double p) {
    const size_t k = static_cast<size_t>(std::ceil(p / 100.0 * static_cast<double>(v.size())));
    return v[std::clamp<size_t>(k, 1, v.size()) - 1];
  };
  j["p50"] = rank(50);
  j["p95"] = rank(95);
  j["p99"] = rank(99);
  j["max"] = v.back();
  return j;
}

OrderedJson LatencyJson(const LatencyStats& s) {
  return {{"replayed", Percentiles(s.replayed)}, {"recorded", Percentiles(s.recorded)}};
}

struct Totals {
  int sessions = 0, sessions_failed = 0, captures = 0, replayed = 0, compared = 0, differing = 0, skipped = 0;
  int64_t detections_recorded = 0, detections_replayed = 0;
  int detection_count_changes = 0;
  void Add(const Totals& o) {
    sessions += o.sessions;
    sessions_failed += o.sessions_failed;
    captures += o.captures;
    replayed += o.replayed;
    compared += o.compared;
    differing += o.differing;
    skipped += o.skipped;
    detections_recorded += o.detections_recorded;
    detections_replayed += o.detections_replayed;
    detection_count_changes += o.detection_count_changes;
  }
  int regressions() const { return differing + sessions_failed; }
  OrderedJson Json() const {
    return {{"sessions", sessions},
            {"sessions_failed", sessions_failed},
            {"captures", captures},
            {"replayed", replayed},
            {"compared", compared},
            {"differing", differing},
            {"skipped", skipped},
            {"detections_recorded", detections_recorded},
            {"detections_replayed", detections_replayed},
            {"detection_count_changes", detection_count_changes},
            {"regressions", regressions()}};
  }
};

struct SessionSummary {
  OrderedJson json;  // without totals and latency (added at the end)
  std::string cell;
  Totals totals;
  LatencyStats latency;
};

// One session of a shard report -> its fleet summary.
SessionSummary SummarizeSession(const json& s) {
  SessionSummary out;
  out.json["index"] = s.at("index");
  out.json["dir"] = s.at("dir");
  out.json["bytes"] = s.at("bytes");
  out.totals.sessions = 1;
  if (s.contains("error")) {
    out.cell = "<not replayed>";
    out.json["error"] = s.at("error");
    out.totals.sessions_failed = 1;
    return out;
  }
  const json& r = s.at("report");
  out.cell = r.at("cell_name").get<std::string>();
  OrderedJson regressions = OrderedJson::array();
  OrderedJson detection_changes = OrderedJson::array();
  for (const json& c : r.at("captures")) {
    ++out.totals.captures;
    const bool replayed = c.at("replayed").get<bool>();
    const bool compared = c.contains("recorded");
    out.totals.replayed += replayed ? 1 : 0;
    out.totals.compared += compared ? 1 : 0;
    if (replayed) out.latency.replayed.push_back(c.at("plan_ms").get<double>());
    if (c.contains("recorded_plan_ms")) out.latency.recorded.push_back(c.at("recorded_plan_ms").get<double>());
    const bool failed = !replayed && compared;
    const bool differs = compared && replayed && !c.at("differences").empty();
    if (failed || differs) {
      ++out.totals.differing;
      OrderedJson d{{"file", c.at("file")}, {"task_id", c.at("task_id")}};
      if (failed) d["error"] = c.value("error", "not replayed");
      if (differs) d["differences"] = c.at("differences");
      regressions.push_back(d);
    }
    if (compared && replayed) {
      const int a = c.at("recorded").at("detections").get<int>();
      const int b = c.at("result").at("detections").get<int>();
      out.totals.detections_recorded += a;
      out.totals.detections_replayed += b;
      if (a != b) {
        ++out.totals.detection_count_changes;
        detection_changes.push_back({{"file", c.at("file")}, {"recorded", a}, {"replayed", b}});
      }
    }
  }
  out.totals.skipped = static_cast<int>(r.at("skipped").size());
  out.json["regressions"] = regressions;
  out.json["detection_changes"] = detection_changes;
  if (!r.at("skipped").empty()) out.json["skipped"] = r.at("skipped");
  return out;
}

Result<json> ReadShard(const std::string& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return Status::NotFound("'" + file + "': cannot open");
  json j = json::parse(in, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) return Status::InvalidArgument("'" + file + "': not a JSON object");
  if (j.value("format", "") != kShardFormat) {
    return Status::InvalidArgument("'" + file + "': not a shard report (format is not " + kShardFormat + ")");
  }
  return j;
}

// Checks the shards against the first one and each other; fills `by_index`
// with every session, by manifest index.
Status CheckShards(const std::vector<std::string>& files, const std::vector<json>& shards,
                   std::map<int, const json*>* by_index) {
  const json& first = shards.front();
  const int count = first.at("shard").at("count").get<int>();
  const int sessions = first.at("manifest").at("sessions").get<int>();
  std::set<int> seen_shards;
  for (size_t i = 0; i < shards.size(); ++i) {
    const json& s = shards[i];
    const std::string& f = files[i];
    if (s.at("manifest") != first.at("manifest")) {
      return Status::InvalidArgument("'" + f + "': another manifest than '" + files[0] + "'s");
    }
    if (s.at("shard").at("count") != count) {
      return Status::InvalidArgument("'" + f + "': shard count " + s.at("shard").at("count").dump() + ", '" +
                                     files[0] + "' has " + std::to_string(count));
    }
    if (s.at("tolerance") != first.at("tolerance")) {
      return Status::InvalidArgument("'" + f + "': other tolerances than '" + files[0] + "'s");
    }
    const int index = s.at("shard").at("index").get<int>();
    if (!seen_shards.insert(index).second) {
      return Status::InvalidArgument("'" + f + "': shard " + std::to_string(index) + " given twice");
    }
    for (const json& session : s.at("sessions")) {
      const int k = session.at("index").get<int>();
      if (k < 0 || k >= sessions) return Status::InvalidArgument("'" + f + "': session index out of range");
      if (!by_index->emplace(k, &session).second) {
        return Status::InvalidArgument("'" + f + "': session " + session.at("dir").get<std::string>() +
                                       " was replayed by two shards (were the sessions' sizes the same for "
                                       "every shard?)");
      }
    }
  }
  for (int i = 0; i < count; ++i) {
    if (!seen_shards.count(i)) {
      return Status::InvalidArgument("shard " + std::to_string(i) + " of " + std::to_string(count) +
                                     " is missing");
    }
  }
  for (int k = 0; k < sessions; ++k) {
    if (!by_index->count(k)) {
      return Status::InvalidArgument("session " + std::to_string(k) + " of the manifest was replayed by no "
                                     "shard (were the sessions' sizes the same for every shard?)");
    }
  }
  return Status::Ok();
}

}  // namespace

decltype(ReplayOptions::make_planner) SharedPerceptionPlanners(const BinPickingPlannerOptions& planner_options) {
  auto cache = std::make_shared<std::map<std::string, std::shared_ptr<const Perception>>>();
  return [cache, planner_options](const Cell& cell,
                                  std::unique_ptr<CaptureSource> source) -> Result<std::unique_ptr<GraspPlanner>> {
    std::shared_ptr<const Perception>& perception = (*cache)[cell.base_dir + '\n' + cell.yaml_text];
    if (!perception) {
      Result<std::unique_ptr<Perception>> built = Perception::Build(cell);
      if (!built.ok()) return built.status();
      perception = std::move(*built);
    }
    auto planner = BinPickingPlanner::Create(cell, perception, std::move(source), planner_options);
    if (!planner.ok()) return planner.status();
    return std::unique_ptr<GraspPlanner>(std::move(*planner));
  };
}

Result<ReplayManifest> LoadReplayManifest(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound("'" + path + "': cannot open the manifest");
  ReplayManifest m;
  m.path = path;
  const fs::path base = fs::path(path).parent_path();
  std::set<std::string> seen;
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    const std::string entry = Trim(line);
    if (entry.empty() || entry[0] == '#') continue;
    const std::string pattern = fs::path(entry).is_absolute() ? entry : (base / entry).lexically_normal().string();
    const std::vector<std::string> dirs = ExpandEntry(pattern);
    if (dirs.empty()) {
      return Status::InvalidArgument(path + ":" + std::to_string(number) + ": '" + entry +
                                     "' names no directory");
    }
    for (const std::string& d : dirs) {
      if (seen.insert(d).second) m.sessions.push_back(d);
    }
  }
  if (m.sessions.empty()) return Status::InvalidArgument("'" + path + "': lists no session");
  m.fingerprint = Fingerprint(m.sessions);
  return m;
}

Result<ShardSpec> ParseShardSpec(std::string_view text) {
  const auto bad = [&] {
    return Status::InvalidArgument("--shard '" + std::string(text) + "': expected i/n with 0 <= i < n");
  };
  const size_t slash = text.find('/');
  if (slash == std::string_view::npos) return bad();
  ShardSpec s;
  const char* b = text.data();
  const auto [p1, e1] = std::from_chars(b, b + slash, s.index);
  const auto [p2, e2] = std::from_chars(b + slash + 1, b + text.size(), s.count);
  if (e1 != std::errc() || p1 != b + slash || e2 != std::errc() || p2 != b + text.size()) return bad();
  if (s.count < 1 || s.count > 100000 || s.index < 0 || s.index >= s.count) return bad();
  return s;
}

std::vector<int> AssignShards(const std::vector<uint64_t>& bytes, int count) {
  std::vector<size_t> order(bytes.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return bytes[a] > bytes[b]; });
  std::vector<uint64_t> load(static_cast<size_t>(std::max(count, 1)), 0);
  std::vector<int> shard(bytes.size(), 0);
  for (const size_t i : order) {
    const size_t s = static_cast<size_t>(std::min_element(load.begin(), load.end()) - load.begin());
    shard[i] = static_cast<int>(s);
    load[s] += bytes[i];
  }
  return shard;
}

uint64_t DirectoryBytes(const std::string& dir) {
  uint64_t total = 0;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code e;
    if (it->is_regular_file(e)) {
      const uintmax_t n = it->file_size(e);
      if (!e) total += n;
    }
  }
  return total;
}

ShardRun ReplayShard(const ReplayManifest& manifest, const ShardSpec& shard, const ReplayOptions& options) {
  std::vector<uint64_t> bytes;
  for (const std::string& s : manifest.sessions) bytes.push_back(DirectoryBytes(s));
  const std::vector<int> assignment = AssignShards(bytes, shard.count);
  ReplayOptions replay = options;
  if (!replay.make_planner) replay.make_planner = SharedPerceptionPlanners();

  ShardRun run;
  OrderedJson sessions = OrderedJson::array();
  OrderedJson assigned = OrderedJson::array();
  uint64_t shard_bytes = 0;
  for (size_t k = 0; k < manifest.sessions.size(); ++k) {
    if (assignment[k] != shard.index) continue;
    assigned.push_back(k);
    shard_bytes += bytes[k];
    ++run.sessions;
    OrderedJson s{{"index", k}, {"dir", manifest.sessions[k]}, {"bytes", bytes[k]}};
    Result<ReplayReport> report = ReplayDirectory(manifest.sessions[k], replay);
    if (report.ok()) {
      s["report"] = record_internal::ReplayReportToJson(*report, options);
      run.differing += report->differing;
    } else {
      s["error"] = report.status().ToString();
      ++run.failed_sessions;
    }
    sessions.push_back(std::move(s));
  }
  OrderedJson j;
  j["format"] = kShardFormat;
  j["binpick_version"] = BinpickVersion();
  j["manifest"] = {{"path", manifest.path}, {"sessions", manifest.sessions.size()},
                   {"fingerprint", manifest.fingerprint}};
  j["shard"] = {{"index", shard.index}, {"count", shard.count}, {"bytes", shard_bytes}, {"assigned", assigned}};
  j["tolerance"] = {{"mm", options.tolerance_mm}, {"deg", options.tolerance_deg}};
  j["sessions"] = std::move(sessions);
  run.json = j.dump(1);
  return run;
}

Result<FleetReport> MergeReplayShards(const std::vector<std::string>& files) {
  if (files.empty()) return Status::InvalidArgument("no shard report given");
  std::vector<json> shards;
  for (const std::string& f : files) {
    Result<json> s = ReadShard(f);
    if (!s.ok()) return s.status();
    shards.push_back(std::move(*s));
  }
  std::map<int, const json*> by_index;
  std::map<std::string, std::vector<SessionSummary>> cells;  // by name: sorted output
  try {
    if (Status s = CheckShards(files, shards, &by_index); !s.ok()) return s;
    for (const auto& [k, session] : by_index) {
      SessionSummary summary = SummarizeSession(*session);
      cells[summary.cell].push_back(std::move(summary));
    }
  } catch (const json::exception& e) {
    return Status::InvalidArgument("a shard report has a bad shape: " + std::string(e.what()));
  }
  Totals fleet;
  LatencyStats fleet_latency;
  OrderedJson cells_json = OrderedJson::array();
  for (auto& [name, sessions] : cells) {
    Totals totals;
    LatencyStats latency;
    OrderedJson sessions_json = OrderedJson::array();
    for (SessionSummary& s : sessions) {
      totals.Add(s.totals);
      latency.Add(s.latency);
      s.json["totals"] = s.totals.Json();
      s.json["latency_ms"] = LatencyJson(s.latency);
      sessions_json.push_back(std::move(s.json));
    }
    fleet.Add(totals);
    fleet_latency.Add(latency);
    cells_json.push_back(
        {{"cell", name}, {"totals", totals.Json()}, {"latency_ms", LatencyJson(latency)}, {"sessions", sessions_json}});
  }
  const json& first = shards.front();
  OrderedJson j;
  j["format"] = kFleetFormat;
  j["manifest"] = first.at("manifest");
  j["shards"] = first.at("shard").at("count");
  j["tolerance"] = first.at("tolerance");
  j["regression"] = fleet.regressions() > 0;
  j["totals"] = fleet.Json();
  j["latency_ms"] = LatencyJson(fleet_latency);
  j["cells"] = std::move(cells_json);

  FleetReport report;
  report.json = j.dump(1);
  report.sessions = fleet.sessions;
  report.captures = fleet.captures;
  report.regressions = fleet.regressions();
  return report;
}

}  // namespace bp
