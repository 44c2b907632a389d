#include "core/conventions.h"

#include <cassert>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

namespace bp {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDegPerRad = 180.0 / kPi;

// Below this |cos(pitch)| (Tait-Bryan) or |sin(b)| (ZYZ) the first and third
// axes coincide; the first angle is then fixed to 0 and the third carries the
// whole rotation about the shared axis.
constexpr double kGimbalEps = 1e-12;

// A decoded quaternion may deviate this much from unit norm (MULT fixed point
// rounds each component by up to 0.5e-4); beyond that the message is wrong.
constexpr double kQuaternionNormTolerance = 1e-3;

enum class Axis { kX, kY, kZ };

Mat3 Rot(Axis axis, double angle) {
  const Vec3 unit = axis == Axis::kX ? Vec3::UnitX() : axis == Axis::kY ? Vec3::UnitY() : Vec3::UnitZ();
  return Eigen::AngleAxisd(angle, unit).toRotationMatrix();
}

// Angle of the rotation about `axis` nearest to M (M should be such a rotation).
// Uses all four affected entries, so it stays accurate for any angle.
double AngleAbout(Axis axis, const Mat3& M) {
  switch (axis) {
    case Axis::kX: return std::atan2(M(2, 1) - M(1, 2), M(1, 1) + M(2, 2));
    case Axis::kY: return std::atan2(M(0, 2) - M(2, 0), M(0, 0) + M(2, 2));
    case Axis::kZ: return std::atan2(M(1, 0) - M(0, 1), M(0, 0) + M(1, 1));
  }
  return 0.0;
}

// Intrinsic Euler angles: R = R_first(a) * R_second(b) * R_third(c).
struct Euler {
  double a, b, c;
};

// Given a and b, the third angle is whatever makes R_first(a) R_second(b)
// R_third(c) closest to R. Computing it from the residual (rather than from two
// matrix entries) keeps the re-encoded matrix within rounding of R even when a
// is ill-conditioned close to gimbal lock.
double ThirdAngle(const Mat3& R, Axis first, double a, Axis second, double b, Axis third) {
  const Mat3 M = (Rot(first, a) * Rot(second, b)).transpose() * R;
  return AngleAbout(third, M);
}

// R = Rz(a) Ry(b) Rx(c); b in [-pi/2, pi/2], a, c in [-pi, pi].
Euler DecodeZyx(const Mat3& R) {
  const double cos_b = std::hypot(R(0, 0), R(1, 0));
  const double b = std::atan2(-R(2, 0), cos_b);
  const double a = cos_b > kGimbalEps ? std::atan2(R(1, 0), R(0, 0)) : 0.0;
  return {a, b, ThirdAngle(R, Axis::kZ, a, Axis::kY, b, Axis::kX)};
}

// R = Rx(a) Ry(b) Rz(c); b in [-pi/2, pi/2], a, c in [-pi, pi].
Euler DecodeXyz(const Mat3& R) {
  const double cos_b = std::hypot(R(1, 2), R(2, 2));
  const double b = std::atan2(R(0, 2), cos_b);
  const double a = cos_b > kGimbalEps ? std::atan2(-R(1, 2), R(2, 2)) : 0.0;
  return {a, b, ThirdAngle(R, Axis::kX, a, Axis::kY, b, Axis::kZ)};
}

// R = Rz(a) Ry(b) Rz(c); b in [0, pi], a, c in [-pi, pi].
Euler DecodeZyz(const Mat3& R) {
  const double sin_b = std::hypot(R(0, 2), R(1, 2));
  const double b = std::atan2(sin_b, R(2, 2));
  const double a = sin_b > kGimbalEps ? std::atan2(R(1, 2), R(0, 2)) : 0.0;
  return {a, b, ThirdAngle(R, Axis::kZ, a, Axis::kY, b, Axis::kZ)};
}

std::string Num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.10g", v);
  return buf;
}

char Lower(char ch) { return (ch >= 'A' && ch <= 'Z') ? static_cast<char>(ch - 'A' + 'a') : ch; }

// Lower case; '-' and ' ' read as '_' ("Omron-TM" == "omron_tm").
std::string NormalizeName(std::string_view name) {
  std::string out(name);
  for (char& ch : out) {
    ch = (ch == '-' || ch == ' ') ? '_' : Lower(ch);
  }
  return out;
}

struct RobotEntry {
  std::string_view name;
  RobotType type;
  OrientationConvention convention;
};

// Seed 000 "重要声明" table plus meta_1 ids. The first entry of each type is its
// canonical model (FindRobotModel(RobotType)). Omron TM, Siemens PLC and Other
// are not in the table: they default to fixed-axis XYZ (roll, pitch, yaw),
// which is what Techman uses for Rx, Ry, Rz. See docs/conventions.md.
constexpr RobotEntry kRobots[] = {
    {"abb", RobotType::kABB, OrientationConvention::kQuaternionXYZW},
    {"fanuc", RobotType::kFanuc, OrientationConvention::kEulerXYZExtrinsic},
    {"hanwha", RobotType::kHanwha, OrientationConvention::kEulerZYXIntrinsic},
    {"kuka", RobotType::kKuka, OrientationConvention::kEulerZYXIntrinsic},
    {"omron_tm", RobotType::kOmronTM, OrientationConvention::kEulerXYZExtrinsic},
    {"siemens_plc", RobotType::kSiemensPLC, OrientationConvention::kEulerXYZExtrinsic},
    {"staubli", RobotType::kStaubli, OrientationConvention::kEulerXYZIntrinsic},
    {"ur", RobotType::kUR, OrientationConvention::kAxisAngle},
    {"yaskawa", RobotType::kYaskawa, OrientationConvention::kEulerXYZExtrinsic},
    {"efort", RobotType::kEfort, OrientationConvention::kEulerZYZIntrinsic},
    {"aubo", RobotType::kAubo, OrientationConvention::kEulerZYXIntrinsic},
    {"dobot", RobotType::kDobot, OrientationConvention::kEulerZYXIntrinsic},
    {"mitsubishi", RobotType::kMitsubishi, OrientationConvention::kEulerZYXIntrinsic},
    {"other", RobotType::kOther, OrientationConvention::kEulerXYZExtrinsic},
    // In the convention table but without a meta_1 id: sent as Other (99).
    {"adept", RobotType::kOther, OrientationConvention::kEulerZYZIntrinsic},
    {"kawasaki", RobotType::kOther, OrientationConvention::kEulerZYZIntrinsic},
    {"comau", RobotType::kOther, OrientationConvention::kEulerZYZIntrinsic},
    {"syntec", RobotType::kOther, OrientationConvention::kEulerXYZExtrinsic},
    {"turin", RobotType::kOther, OrientationConvention::kEulerXYZIntrinsic},
};

RobotModel ToModel(const RobotEntry& e) { return RobotModel{std::string(e.name), e.type, e.convention}; }

constexpr OrientationConvention kConventions[] = {
    OrientationConvention::kAxisAngle,         OrientationConvention::kQuaternionXYZW,
    OrientationConvention::kEulerZYXIntrinsic, OrientationConvention::kEulerXYZExtrinsic,
    OrientationConvention::kEulerXYZIntrinsic, OrientationConvention::kEulerZYZIntrinsic,
};

template <typename Int>
Result<Int> ToFixedImpl(double value, double mult) {
  if (!std::isfinite(value)) {
    return Status::InvalidArgument("fixed point: value is not finite (" + Num(value) + ")");
  }
  if (!std::isfinite(mult) || mult <= 0.0) {
    return Status::InvalidArgument("fixed point: multiplier must be finite and > 0 (" + Num(mult) + ")");
  }
  // std::round: half away from zero, like std::llround. An overflowing product
  // is +-inf and fails the range check below.
  const double scaled = std::round(value * mult);
  constexpr double kMin = static_cast<double>(std::numeric_limits<Int>::min());
  constexpr double kMax = static_cast<double>(std::numeric_limits<Int>::max());
  if (!(scaled >= kMin && scaled <= kMax)) {
    return Status::OutOfRange("fixed point: " + Num(value) + " * " + Num(mult) + " does not fit in int" +
                              std::to_string(8 * sizeof(Int)));
  }
  return static_cast<Int>(scaled);
}

// How one GRI pose format lays out its 7 values.
struct GriLayout {
  double units_per_metre;  // position unit: 1 (m) or 1000 (mm)
  enum class Rotation { kQuaternion, kEulerRpy, kKukaAbc, kRotationVector, kFanucWpr } rotation;
  bool degrees;  // Euler angles in degrees (else radians)
};

std::optional<GriLayout> LayoutFor(GriPoseFormat f) {
  using R = GriLayout::Rotation;
  switch (f) {
    case GriPoseFormat::kMQuaternion: return GriLayout{1.0, R::kQuaternion, false};
    case GriPoseFormat::kMMQuaternion: return GriLayout{1000.0, R::kQuaternion, false};
    case GriPoseFormat::kMEulerDegree: return GriLayout{1.0, R::kEulerRpy, true};
    case GriPoseFormat::kMEulerRadians: return GriLayout{1.0, R::kEulerRpy, false};
    case GriPoseFormat::kMMEulerDegree: return GriLayout{1000.0, R::kEulerRpy, true};
    case GriPoseFormat::kMMEulerRadians: return GriLayout{1000.0, R::kEulerRpy, false};
    case GriPoseFormat::kMMAbcKuka: return GriLayout{1000.0, R::kKukaAbc, true};
    case GriPoseFormat::kMAxisAngle: return GriLayout{1.0, R::kRotationVector, false};
    case GriPoseFormat::kMMAxisAngle: return GriLayout{1000.0, R::kRotationVector, false};
    case GriPoseFormat::kMMWprFanuc: return GriLayout{1000.0, R::kFanucWpr, true};
    case GriPoseFormat::kUnknown: break;
  }
  return std::nullopt;
}

OrientationConvention ConventionFor(GriLayout::Rotation r) {
  using R = GriLayout::Rotation;
  switch (r) {
    case R::kQuaternion: return OrientationConvention::kQuaternionXYZW;
    case R::kEulerRpy: return OrientationConvention::kEulerXYZExtrinsic;
    case R::kKukaAbc: return OrientationConvention::kEulerZYXIntrinsic;
    case R::kRotationVector: return OrientationConvention::kAxisAngle;
    case R::kFanucWpr: return OrientationConvention::kEulerXYZExtrinsic;
  }
  return OrientationConvention::kQuaternionXYZW;
}

Status CheckGriArgs(GriPoseFormat f, QuaternionOrder q) {
  if (!LayoutFor(f)) {
    return Status::InvalidArgument("GRI pose format " + std::to_string(static_cast<int>(f)) +
                                   " is unknown (valid: 1..10)");
  }
  if (q != QuaternionOrder::kXYZW && q != QuaternionOrder::kWXYZ) {
    return Status::InvalidArgument("GRI quaternion order " + std::to_string(static_cast<int>(q)) + " is unknown");
  }
  return Status::Ok();
}

}  // namespace

std::string_view ToString(OrientationConvention c) {
  switch (c) {
    case OrientationConvention::kAxisAngle: return "axis_angle";
    case OrientationConvention::kQuaternionXYZW: return "quaternion_xyzw";
    case OrientationConvention::kEulerZYXIntrinsic: return "euler_zyx_intrinsic";
    case OrientationConvention::kEulerXYZExtrinsic: return "euler_xyz_extrinsic";
    case OrientationConvention::kEulerXYZIntrinsic: return "euler_xyz_intrinsic";
    case OrientationConvention::kEulerZYZIntrinsic: return "euler_zyz_intrinsic";
  }
  return "unknown";
}

std::optional<OrientationConvention> ParseOrientationConvention(std::string_view name) {
  const std::string key = NormalizeName(name);
  for (const OrientationConvention c : kConventions) {
    if (ToString(c) == key) return c;
  }
  return std::nullopt;
}

std::optional<RobotModel> FindRobotModel(std::string_view name) {
  const std::string key = NormalizeName(name);
  for (const RobotEntry& e : kRobots) {
    if (e.name == key) return ToModel(e);
  }
  return std::nullopt;
}

std::optional<RobotModel> FindRobotModel(RobotType type) {
  for (const RobotEntry& e : kRobots) {
    if (e.type == type) return ToModel(e);
  }
  return std::nullopt;
}

std::optional<RobotType> RobotTypeFromId(int32_t id) {
  for (const RobotEntry& e : kRobots) {
    if (static_cast<int32_t>(e.type) == id) return e.type;
  }
  return std::nullopt;
}

std::string_view ToString(RobotType type) {
  for (const RobotEntry& e : kRobots) {
    if (e.type == type) return e.name;
  }
  return "unknown";
}

std::array<double, 4> EncodeOrientation(const Mat3& R, OrientationConvention c) {
  switch (c) {
    case OrientationConvention::kAxisAngle: {
      // Via a quaternion (Shepperd's method inside Eigen): stable near 180 deg.
      // Angle in [0, pi]; at exactly pi, v and -v are the same rotation and the
      // sign follows Eigen's quaternion branch (deterministic for a given R).
      const Eigen::AngleAxisd aa(R);
      const Vec3 v = aa.angle() * aa.axis();
      return {v.x(), v.y(), v.z(), 0.0};
    }
    case OrientationConvention::kQuaternionXYZW: {
      Quat q(R);
      q.normalize();
      if (q.w() < 0.0) q.coeffs() = -q.coeffs();  // canonical: w >= 0
      return {q.x(), q.y(), q.z(), q.w()};
    }
    case OrientationConvention::kEulerZYXIntrinsic: {
      const Euler e = DecodeZyx(R);  // (A, B, C) = (z, y', x'')
      return {e.a, e.b, e.c, 0.0};
    }
    case OrientationConvention::kEulerXYZExtrinsic: {
      const Euler e = DecodeZyx(R);  // R = Rz(rz) Ry(ry) Rx(rx)
      return {e.c, e.b, e.a, 0.0};
    }
    case OrientationConvention::kEulerXYZIntrinsic: {
      const Euler e = DecodeXyz(R);
      return {e.a, e.b, e.c, 0.0};
    }
    case OrientationConvention::kEulerZYZIntrinsic: {
      const Euler e = DecodeZyz(R);
      return {e.a, e.b, e.c, 0.0};
    }
  }
  assert(false && "unknown OrientationConvention");
  return {0.0, 0.0, 0.0, 0.0};
}

Result<Mat3> DecodeOrientation(const std::array<double, 4>& f, OrientationConvention c) {
  const bool uses_fourth = c == OrientationConvention::kQuaternionXYZW;
  for (size_t i = 0; i < (uses_fourth ? 4u : 3u); ++i) {
    if (!std::isfinite(f[i])) {
      return Status::InvalidArgument("orientation field " + std::to_string(i + 1) + " is not finite (" +
                                     std::string(ToString(c)) + ")");
    }
  }
  switch (c) {
    case OrientationConvention::kAxisAngle: {
      const Vec3 v(f[0], f[1], f[2]);
      const double angle = v.norm();
      if (angle == 0.0) return Mat3(Mat3::Identity());
      return Mat3(Eigen::AngleAxisd(angle, v / angle).toRotationMatrix());
    }
    case OrientationConvention::kQuaternionXYZW: {
      const Quat q(f[3], f[0], f[1], f[2]);  // Eigen's constructor takes w first
      const double norm = q.norm();
      if (!(std::abs(norm - 1.0) <= kQuaternionNormTolerance)) {
        return Status::InvalidArgument("quaternion norm " + Num(norm) + " is not 1 (tolerance " +
                                       Num(kQuaternionNormTolerance) + ")");
      }
      return Mat3(q.normalized().toRotationMatrix());
    }
    case OrientationConvention::kEulerZYXIntrinsic:
      return Mat3(Rot(Axis::kZ, f[0]) * Rot(Axis::kY, f[1]) * Rot(Axis::kX, f[2]));
    case OrientationConvention::kEulerXYZExtrinsic:
      return Mat3(Rot(Axis::kZ, f[2]) * Rot(Axis::kY, f[1]) * Rot(Axis::kX, f[0]));
    case OrientationConvention::kEulerXYZIntrinsic:
      return Mat3(Rot(Axis::kX, f[0]) * Rot(Axis::kY, f[1]) * Rot(Axis::kZ, f[2]));
    case OrientationConvention::kEulerZYZIntrinsic:
      return Mat3(Rot(Axis::kZ, f[0]) * Rot(Axis::kY, f[1]) * Rot(Axis::kZ, f[2]));
  }
  return Status::InvalidArgument("unknown orientation convention " + std::to_string(static_cast<int>(c)));
}

Result<std::array<double, 7>> EncodeGriPose(const Pose& X, GriPoseFormat f, QuaternionOrder q) {
  if (Status s = CheckGriArgs(f, q); !s.ok()) return s;
  const GriLayout layout = *LayoutFor(f);
  const Vec3 p = X.translation() * layout.units_per_metre;
  std::array<double, 4> rot = EncodeOrientation(X.linear(), ConventionFor(layout.rotation));
  if (layout.rotation == GriLayout::Rotation::kQuaternion) {
    if (q == QuaternionOrder::kWXYZ) rot = {rot[3], rot[0], rot[1], rot[2]};
  } else if (layout.degrees) {
    for (double& angle : rot) angle *= kDegPerRad;
  }
  return std::array<double, 7>{p.x(), p.y(), p.z(), rot[0], rot[1], rot[2], rot[3]};
}

Result<Pose> DecodeGriPose(const std::array<double, 7>& v, GriPoseFormat f, QuaternionOrder q) {
  if (Status s = CheckGriArgs(f, q); !s.ok()) return s;
  const GriLayout layout = *LayoutFor(f);
  const Vec3 p(v[0], v[1], v[2]);
  if (!p.allFinite()) return Status::InvalidArgument("GRI pose position is not finite");
  std::array<double, 4> rot = {v[3], v[4], v[5], v[6]};
  if (layout.rotation == GriLayout::Rotation::kQuaternion) {
    if (q == QuaternionOrder::kWXYZ) rot = {v[4], v[5], v[6], v[3]};
  } else if (layout.degrees) {
    for (double& angle : rot) angle /= kDegPerRad;
  }
  Result<Mat3> R = DecodeOrientation(rot, ConventionFor(layout.rotation));
  if (!R.ok()) return R.status();
  return MakePose(*R, p / layout.units_per_metre);
}

Result<int32_t> ToFixed(double value, double mult) { return ToFixedImpl<int32_t>(value, mult); }

Result<int16_t> ToFixed16(double value, double mult) { return ToFixedImpl<int16_t>(value, mult); }

}  // namespace bp
