// Robot orientation conventions (seed 000, "重要声明" table), the meta_1 robot
// type ids, GRI pose formats (seed 002) and MULT fixed-point encoding.
//
// All functions are pure and thread-safe. Angles in radians unless a name says
// otherwise; positions in metres unless a name says otherwise.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "core/pose.h"
#include "core/status.h"

namespace bp {

// meta_1 robot type ids (seed 000, "Meta消息说明").
enum class RobotType : int32_t {
  kABB = 0, kFanuc = 1, kHanwha = 2, kKuka = 3, kOmronTM = 4, kSiemensPLC = 5,
  kStaubli = 6, kUR = 7, kYaskawa = 8, kEfort = 9, kAubo = 10, kDobot = 11,
  kMitsubishi = 12, kOther = 99,
};

// How the 4 orientation fields of a DaoAI message encode a rotation.
enum class OrientationConvention {
  kAxisAngle,           // UR: rx, ry, rz (rotation vector), 0
  kQuaternionXYZW,      // ABB: x, y, z, w  (q2, q3, q4, q1)
  kEulerZYXIntrinsic,   // KUKA, Mitsubishi, Aubo, Dobot, Hanwha: ZY'X'' -> fields (a=z, b=y, c=x)?, see .cc
  kEulerXYZExtrinsic,   // Yaskawa, Fanuc, Syntec: fixed-axis X then Y then Z
  kEulerXYZIntrinsic,   // Staubli, Turin: XY'Z''
  kEulerZYZIntrinsic,   // Adept, Kawasaki, Comau, Efort: ZY'Z''
};

std::string_view ToString(OrientationConvention c);
std::optional<OrientationConvention> ParseOrientationConvention(std::string_view name);

// Robot names accepted in the cell file ("ur", "abb", "kuka", "kawasaki", ...),
// case-insensitive. Robots without a meta_1 id (Adept, Kawasaki, Comau, Syntec,
// Turin) map to RobotType::kOther plus their own convention.
struct RobotModel {
  std::string name;                  // canonical lower-case name
  RobotType type;                    // meta_1 id
  OrientationConvention convention;  // orientation fields on the wire
};
std::optional<RobotModel> FindRobotModel(std::string_view name);
std::optional<RobotModel> FindRobotModel(RobotType type);
std::string_view ToString(RobotType type);

// The 4 orientation fields for rotation R (unscaled: radians or unit quaternion).
std::array<double, 4> EncodeOrientation(const Mat3& R, OrientationConvention c);
// Inverse of EncodeOrientation. @returns InvalidArgument for non-finite values
// or a quaternion far from unit norm.
Result<Mat3> DecodeOrientation(const std::array<double, 4>& fields, OrientationConvention c);

// GRI pose formats (seed 002, "Base Pose Formats").
enum class GriPoseFormat : uint8_t {
  kUnknown = 0, kMQuaternion = 1, kMMQuaternion = 2, kMEulerDegree = 3, kMEulerRadians = 4,
  kMMEulerDegree = 5, kMMEulerRadians = 6, kMMAbcKuka = 7, kMAxisAngle = 8, kMMAxisAngle = 9,
  kMMWprFanuc = 10,
};
// Quaternion field order differs between GRI wire formats (see docs/protocols.md).
enum class QuaternionOrder { kXYZW, kWXYZ };
// 7 pose values in the given format (position then rotation fields; unused
// trailing fields are 0). @returns InvalidArgument for kUnknown or out-of-table.
Result<std::array<double, 7>> EncodeGriPose(const Pose& X, GriPoseFormat f,
                                            QuaternionOrder q = QuaternionOrder::kXYZW);
Result<Pose> DecodeGriPose(const std::array<double, 7>& v, GriPoseFormat f,
                           QuaternionOrder q = QuaternionOrder::kXYZW);

// MULT fixed point (seed 000): value * 10000, rounded to nearest.
inline constexpr double kMult = 10000.0;
// @returns OutOfRange when value * mult does not fit in int32, InvalidArgument for NaN/inf.
Result<int32_t> ToFixed(double value, double mult = kMult);
inline double FromFixed(int32_t fixed, double mult = kMult) { return fixed / mult; }
// As ToFixed but for int16 registers (Modbus).
Result<int16_t> ToFixed16(double value, double mult = kMult);

}  // namespace bp
