// JSON of what a record holds (poses, plan results, robot messages), shared
// by the recorder and the replay. Schema: docs/file_formats.md "Recordings".
#pragma once

#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "comms/daoai_message.h"
#include "core/pose.h"
#include "core/status.h"
#include "grasp/planner.h"
#include "pipeline/pose_json.h"

namespace bp::record_internal {

using OrderedJson = nlohmann::ordered_json;

// Poses: PoseToJson / PoseFromJson (pipeline/pose_json.h).

OrderedJson PlanResultJson(const PlanResult& result);
// The fields PlanResultJson writes (stages included). Corruption on a bad shape.
Result<PlanResult> PlanResultFromJson(const nlohmann::json& j, const std::string& what);

OrderedJson RequestJson(const daoai::Request& request);
OrderedJson ResponseJson(const daoai::Response& response);

}  // namespace bp::record_internal
