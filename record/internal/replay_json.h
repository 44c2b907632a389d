// JSON of a replay report (`binpick replay --json`, one session of a shard
// report). Schema: docs/fleet.md "Reports".
#pragma once

#include <nlohmann/json.hpp>

#include "record/replay.h"

namespace bp::record_internal {

nlohmann::ordered_json ReplayReportToJson(const ReplayReport& report, const ReplayOptions& options);

}  // namespace bp::record_internal
