// binpick replay-merge SHARD.json... --json FLEET.json
// Merges the shard reports of `binpick replay --manifest ... --shard i/n`
// into one fleet report (record/replay_fleet.h, docs/fleet.md): per cell and
// per session the captures that differ beyond tolerance, latency
// percentiles and detection-count changes, and the fleet totals.
// Exit codes: 0 no regression, 1 a capture differs or failed to replay, or a
// session could not be replayed, 2 bad input (unreadable or inconsistent
// shard reports: another manifest, a shard missing or given twice).
#include <cstdio>

#include "apps/binpick/command.h"
#include "core/atomic_file.h"
#include "record/replay_fleet.h"

namespace bp::cli {

Command ReplayMergeCommand() {
  return {"replay-merge", "merge the shard reports of `binpick replay --manifest` into one fleet report",
          [](CLI::App& sub) -> std::function<int()> {
            auto files = std::make_shared<std::vector<std::string>>();
            auto json_out = std::make_shared<std::string>();
            sub.add_option("reports", *files, "shard reports (every shard of one run, any order)")->required();
            sub.add_option("--json", *json_out, "write the fleet report to this file")->required();
            return [files, json_out]() -> int {
              Result<FleetReport> fleet = MergeReplayShards(*files);
              if (!fleet.ok()) return Fail("replay-merge", fleet.status());
              if (Status s = WriteFileAtomic(*json_out, fleet->json + "\n"); !s.ok()) return Fail("replay-merge", s);
              std::printf("%zu shard reports: %d sessions, %d captures, %d regressions; fleet report %s\n",
                          files->size(), fleet->sessions, fleet->captures, fleet->regressions, json_out->c_str());
              return fleet->regressions == 0 ? kExitOk : kExitFailure;
            };
          }};
}

}  // namespace bp::cli
