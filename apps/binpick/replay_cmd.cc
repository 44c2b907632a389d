// binpick replay DIR [--json OUT] [--cell FILE] [--tol-mm X] [--tol-deg Y]
// binpick replay --manifest FILE [--shard i/n] --json OUT [...]
// Reruns the pipeline over a recorded session (or any directory of PCD / PLY
// / depth PNG files) and prints, per capture, the per-stage latency, the
// detections and the differences from what was recorded (record/replay.h).
// With --manifest, replays shard i of n of the manifest's sessions and
// writes a shard report for `binpick replay-merge` (record/replay_fleet.h,
// docs/fleet.md).
// Exit codes: 0 same within tolerances (with --manifest: the shard report was
// written, whatever it holds), 1 some capture differs or failed to replay (a
// regression), 2 bad input (no such directory, bad cell, bad manifest or
// --shard).
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "apps/binpick/command.h"
#include "core/atomic_file.h"
#include "grasp/bin_picking_planner.h"
#include "record/replay.h"
#include "record/replay_fleet.h"

namespace bp::cli {
namespace {

void PrintCapture(const CaptureReplay& c) {
  const std::string name = c.file.substr(c.file.find_last_of('/') + 1);
  if (!c.replayed) {
    std::printf("%s task %d: not replayed: %s\n", name.c_str(), c.task_id, c.error.c_str());
    return;
  }
  std::printf("%s task %d: %s, %d detections, %zu grasps; %.1f ms (", name.c_str(), c.task_id,
              std::string(ToString(c.result.outcome)).c_str(), c.result.detections, c.result.grasps.size(),
              c.plan_ms);
  for (size_t i = 0; i < c.result.stages.size(); ++i) {
    std::printf("%s%s %.1f", i ? ", " : "", c.result.stages[i].stage.c_str(), c.result.stages[i].ms);
  }
  std::printf(")");
  if (!c.compared) {
    std::printf("; nothing recorded to compare\n");
  } else if (c.differences.empty()) {
    std::printf("; same as recorded (max %.3g mm, %.3g deg)\n", c.max_position_diff_mm, c.max_angle_diff_deg);
  } else {
    std::printf("; DIFFERS from the recording:\n");
    for (const std::string& d : c.differences) std::printf("    %s\n", d.c_str());
  }
}

int ReplayOne(const std::string& dir, const std::string& json_out, const ReplayOptions& options) {
  Result<ReplayReport> report = ReplayDirectory(dir, options);
  if (!report.ok()) return Fail("replay", report.status());
  std::printf("replay %s (%s) with cell %s\n", dir.c_str(), report->session ? "recorded session" : "frame files",
              report->cell.c_str());
  for (const std::string& s : report->skipped) std::printf("skipped: %s\n", s.c_str());
  for (const CaptureReplay& c : report->captures) PrintCapture(c);
  std::printf("%zu captures, %d differing, %zu skipped\n", report->captures.size(), report->differing,
              report->skipped.size());
  if (!json_out.empty()) {
    std::ofstream out(json_out);
    out << ReplayReportJson(*report, options) << "\n";
    if (!out) return Fail("replay", Status::Internal("'" + json_out + "': cannot write"));
  }
  return report->differing == 0 ? kExitOk : kExitFailure;
}

int ReplayManifestShard(const std::string& manifest_path, const std::string& shard_text,
                        const std::string& json_out, const ReplayOptions& options) {
  Result<ShardSpec> shard = ParseShardSpec(shard_text);
  if (!shard.ok()) return Fail("replay", shard.status());
  Result<ReplayManifest> manifest = LoadReplayManifest(manifest_path);
  if (!manifest.ok()) return Fail("replay", manifest.status());
  // The run's report directory may be new (a Job's pods share one volume).
  std::error_code ec;
  if (const auto parent = std::filesystem::path(json_out).parent_path(); !parent.empty()) {
    std::filesystem::create_directories(parent, ec);
  }
  const ShardRun run = ReplayShard(*manifest, *shard, options);
  // Atomic: a merge never reads half a report of a shard that died writing it.
  if (Status s = WriteFileAtomic(json_out, run.json + "\n"); !s.ok()) return Fail("replay", s);
  std::printf("shard %d/%d of %s: %d of %zu sessions, %d not replayed, %d captures differing; report %s\n",
              shard->index, shard->count, manifest_path.c_str(), run.sessions, manifest->sessions.size(),
              run.failed_sessions, run.differing, json_out.c_str());
  // The shard did its job; whether the fleet regressed is replay-merge's
  // verdict (a failing shard would make a Job retry it and a Slurm merge
  // with afterok never run).
  return kExitOk;
}

}  // namespace

Command ReplayCommand() {
  return {"replay", "rerun the pipeline over a recorded session or a directory of frames; compare with the recording",
          [](CLI::App& sub) -> std::function<int()> {
            auto dir = std::make_shared<std::string>();
            auto json_out = std::make_shared<std::string>();
            auto manifest = std::make_shared<std::string>();
            auto shard = std::make_shared<std::string>("0/1");
            auto options = std::make_shared<ReplayOptions>();
            CLI::Option* dir_option =
                sub.add_option("dir", *dir, "session directory (or a directory of PCD / PLY / depth PNG files)");
            CLI::Option* manifest_option = sub.add_option(
                "--manifest", *manifest,
                "file listing session directories or globs, one a line: replay a shard of them (docs/fleet.md)");
            manifest_option->excludes(dir_option);
            sub.add_option("--shard", *shard, "with --manifest: i/n, replay shard i of n (0-based)")
                ->capture_default_str()
                ->needs(manifest_option);
            sub.add_option("--json", *json_out,
                           "write the full report as JSON to this file (with --manifest: the shard report)");
            sub.add_option("--cell", options->cell_path,
                           "cell file (default: the session's cell.yaml, else the embedded default)");
            sub.add_option("--tol-mm", options->tolerance_mm, "position tolerance for parts and grasps (mm)");
            sub.add_option("--tol-deg", options->tolerance_deg, "rotation tolerance for parts and grasps (deg)");
            auto retry_ms = std::make_shared<double>(BinPickingPlannerOptions{}.thorough_retry_ms);
            sub.add_option("--thorough-retry-ms", *retry_ms,
                           "time cap of the planner's thorough perception retry, ms "
                           "(BinPickingPlannerOptions::thorough_retry_ms)")
                ->capture_default_str()
                ->check(CLI::PositiveNumber);
            auto retry_estimates = std::make_shared<int>(BinPickingPlannerOptions{}.thorough_retry_estimates);
            sub.add_option("--thorough-retry-estimates", *retry_estimates,
                           "budget of the planner's thorough perception retry in pose estimates, 0: no count "
                           "(BinPickingPlannerOptions::thorough_retry_estimates)")
                ->capture_default_str()
                ->check(CLI::NonNegativeNumber);
            return [dir, json_out, manifest, shard, options, retry_ms, retry_estimates]() -> int {
              BinPickingPlannerOptions planner_options;
              planner_options.thorough_retry_ms = *retry_ms;
              planner_options.thorough_retry_estimates = *retry_estimates;
              options->make_planner = SharedPerceptionPlanners(planner_options);
              if (manifest->empty()) {
                if (dir->empty()) return Fail("replay", Status::InvalidArgument("give a DIR or --manifest FILE"));
                return ReplayOne(*dir, *json_out, *options);
              }
              if (json_out->empty()) {
                return Fail("replay", Status::InvalidArgument("--manifest needs --json OUT (the shard report)"));
              }
              return ReplayManifestShard(*manifest, *shard, *json_out, *options);
            };
          }};
}

}  // namespace bp::cli
