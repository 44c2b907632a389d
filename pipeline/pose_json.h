// A pose as JSON: the 4x4 row-major matrix every binpick file uses (truth
// JSON, intrinsics sidecars, recordings). Doubles print with 17 significant
// digits, so a pose read back is bit-exact.
#pragma once

#include <string>

#include <nlohmann/json.hpp>

#include "core/pose.h"
#include "core/status.h"

namespace bp {

nlohmann::ordered_json PoseToJson(const Pose& X);

// @returns Corruption naming `what` unless `j` is a 4x4 array of finite
// numbers with last row [0, 0, 0, 1] and an orthonormal right-handed rotation.
Result<Pose> PoseFromJson(const nlohmann::json& j, const std::string& what);

}  // namespace bp
