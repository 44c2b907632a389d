// Fleet-wide replay: the recorded sessions of many cells, listed in a
// manifest, split into shards that run as separate processes (a Kubernetes
// Indexed Job, a Slurm job array: docs/fleet.md), and the merge of the
// shards' reports into one fleet report.
//
// Every shard computes the same assignment from the manifest and the sizes
// of the sessions on disk, so shards need no coordinator: shard i of n
// replays the sessions AssignShards gives it. The merge checks that the
// shards' reports come from one manifest and one assignment (each session
// replayed exactly once), then reports per cell and per session what
// changed, and the fleet totals. The merged report does not depend on n.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "core/status.h"
#include "grasp/bin_picking_planner.h"
#include "record/replay.h"

namespace bp {

// A manifest file: one entry per line, a session directory or a glob
// (`*`, `?`, `[...]`) of them; blank lines and lines starting with '#' are
// ignored. Relative entries resolve against the manifest's directory. A
// glob's matches are taken in sorted order; a directory listed twice counts
// once, at its first place.
struct ReplayManifest {
  std::string path;
  std::vector<std::string> sessions;  // manifest order
  std::string fingerprint;            // 16 hex digits over `sessions`: shards of one manifest agree on it
};

// @returns NotFound when the file cannot be read; InvalidArgument naming the
// line for an entry that matches no directory, or when nothing is listed.
Result<ReplayManifest> LoadReplayManifest(const std::string& path);

// "i/n": shard i of n, 0 <= i < n (n <= 100000). InvalidArgument otherwise.
struct ShardSpec {
  int index = 0;
  int count = 1;
};
Result<ShardSpec> ParseShardSpec(std::string_view text);

// The shard of each item, balanced by size: largest first (ties by position),
// each to the shard with the fewest bytes so far (ties: the lowest index).
// The largest shard then holds at most the ideal share plus one item's
// bytes. Deterministic: the same sizes give the same assignment.
std::vector<int> AssignShards(const std::vector<uint64_t>& bytes, int count);

// Bytes of the regular files under `dir`, recursively; 0 if it cannot be read.
uint64_t DirectoryBytes(const std::string& dir);

struct ShardRun {
  std::string json;         // the shard report (docs/fleet.md "Reports")
  int sessions = 0;         // sessions this shard replayed
  int failed_sessions = 0;  // sessions that could not be replayed at all
  int differing = 0;        // captures that differ or failed to replay, over its sessions
};

// A ReplayOptions::make_planner that builds one perception per distinct
// cell (its text and the directory its paths resolve against) and shares it
// between the planners it makes: building the model tables is the slow part
// of a replay, and a shard's sessions are mostly of a few cells. Not for
// concurrent calls (the replays of one process run one after another).
decltype(ReplayOptions::make_planner) SharedPerceptionPlanners(
    const BinPickingPlannerOptions& planner_options = {});

// Replays shard `shard` of `manifest`. A session that cannot be replayed
// (its directory gone, its cell unreadable) is reported as such, never
// stops the others. Sessions of the same cell share one perception model
// (options.make_planner, if set, is used as given).
ShardRun ReplayShard(const ReplayManifest& manifest, const ShardSpec& shard, const ReplayOptions& options);

struct FleetReport {
  std::string json;         // the fleet report (docs/fleet.md "Reports")
  int sessions = 0;
  int captures = 0;
  int regressions = 0;      // differing captures plus sessions that could not be replayed
};

// Merges the shard reports in `files` (any order). @returns InvalidArgument
// naming the file when a report is not a shard report, when the reports
// disagree on the manifest, the shard count or the tolerances, when a shard
// is missing or given twice, or when a session was replayed by no shard or
// by two; NotFound when a file cannot be read.
Result<FleetReport> MergeReplayShards(const std::vector<std::string>& files);

}  // namespace bp
