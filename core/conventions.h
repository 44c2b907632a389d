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

// How the 4 orientation fields of a DaoAI message encode a rotation
// (docs/conventions.md). Euler fields are the three angles in the order the
// rotations are applied (the order the convention's name lists the axes); the
// 4th field is written 0 and ignored on decode.
enum class OrientationConvention {
  kAxisAngle,           // UR: rx, ry, rz (rotation vector, |v| = angle), 0
  kQuaternionXYZW,      // ABB: x, y, z, w  (q2, q3, q4, q1)
  kEulerZYXIntrinsic,   // KUKA, Mitsubishi, Aubo, Dobot, Hanwha: ZY'X'': a, b, c, 0 (KUKA A, B, C)
                        //   R = Rz(a) Ry(b) Rx(c)
  kEulerXYZExtrinsic,   // Yaskawa, Fanuc, Syntec: fixed X, then Y, then Z: rx, ry, rz, 0 (Fanuc W, P, R)
                        //   R = Rz(rz) Ry(ry) Rx(rx)  (same matrix as ZY'X'', fields reversed)
  kEulerXYZIntrinsic,   // Staubli, Turin: XY'Z'': a, b, c, 0;  R = Rx(a) Ry(b) Rz(c)
  kEulerZYZIntrinsic,   // Adept, Kawasaki, Comau, Efort: ZY'Z'': a, b, c, 0;  R = Rz(a) Ry(b) Rz(c)
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
// The canonical model for a meta_1 id (kOther -> "other"); nullopt for a value
// outside the enum.
std::optional<RobotModel> FindRobotModel(RobotType type);
// meta_1 value from the wire or a cell file -> RobotType; nullopt if not an id.
std::optional<RobotType> RobotTypeFromId(int32_t id);
std::string_view ToString(RobotType type);  // canonical name, "unknown" if none

// The 4 orientation fields for rotation R (unscaled: radians or unit quaternion).
// REQUIRES: R is a rotation matrix. Ranges: Tait-Bryan middle angle in
// [-pi/2, pi/2], ZYZ middle angle in [0, pi], other angles in [-pi, pi];
// at gimbal lock the first angle is 0. Axis-angle |v| in [0, pi]; quaternion
// with w >= 0.
std::array<double, 4> EncodeOrientation(const Mat3& R, OrientationConvention c);
// Inverse of EncodeOrientation (any angle values are accepted). The 4th field
// is ignored except for quaternions. @returns InvalidArgument for non-finite
// values or a quaternion whose norm is not within 1e-3 of 1 (it is normalised
// otherwise, absorbing fixed-point rounding).
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
// Rotation fields (docs/conventions.md): 1-2 quaternion in order q; 3-6 roll,
// pitch, yaw (fixed X, Y, Z: R = Rz(yaw) Ry(pitch) Rx(roll)); 7 KUKA A, B, C
// degrees; 8-9 rotation vector rx, ry, rz in radians, 0; 10 Fanuc W, P, R
// degrees. The quaternion order only matters for formats 1-2.
Result<std::array<double, 7>> EncodeGriPose(const Pose& X, GriPoseFormat f,
                                            QuaternionOrder q = QuaternionOrder::kXYZW);
Result<Pose> DecodeGriPose(const std::array<double, 7>& v, GriPoseFormat f,
                           QuaternionOrder q = QuaternionOrder::kXYZW);

// MULT fixed point (seed 000): value * 10000, rounded to nearest, ties away
// from zero (std::round of the double product value * mult).
inline constexpr double kMult = 10000.0;
// @returns OutOfRange when the rounded value * mult does not fit in int32 (never
// wraps), InvalidArgument for NaN/inf value or a mult that is not finite and > 0.
Result<int32_t> ToFixed(double value, double mult = kMult);
inline double FromFixed(int32_t fixed, double mult = kMult) { return fixed / mult; }
// As ToFixed but for int16 registers (Modbus).
Result<int16_t> ToFixed16(double value, double mult = kMult);

}  // namespace bp
