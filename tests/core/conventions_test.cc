// Property and golden tests for core/conventions.h. Expected matrices are built
// here from the angle definitions (TRx/TRy/TRz, Rodrigues, quaternion formula),
// never by calling the conversion code under test.
#include "core/conventions.h"

#include <gtest/gtest.h>

#include <cctype>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

namespace bp {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
constexpr double kTol = 1e-9;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

using Fields = std::array<double, 4>;
using C = OrientationConvention;

const std::vector<C> kAll = {C::kAxisAngle,         C::kQuaternionXYZW,    C::kEulerZYXIntrinsic,
                             C::kEulerXYZExtrinsic, C::kEulerXYZIntrinsic, C::kEulerZYZIntrinsic};
const std::vector<C> kEuler = {C::kEulerZYXIntrinsic, C::kEulerXYZExtrinsic, C::kEulerXYZIntrinsic,
                               C::kEulerZYZIntrinsic};
const std::vector<C> kTaitBryan = {C::kEulerZYXIntrinsic, C::kEulerXYZExtrinsic, C::kEulerXYZIntrinsic};

// --- Independent reference rotations -----------------------------------------

Mat3 TRx(double a) {
  const double c = std::cos(a), s = std::sin(a);
  Mat3 m;
  m << 1, 0, 0, 0, c, -s, 0, s, c;
  return m;
}
Mat3 TRy(double a) {
  const double c = std::cos(a), s = std::sin(a);
  Mat3 m;
  m << c, 0, s, 0, 1, 0, -s, 0, c;
  return m;
}
Mat3 TRz(double a) {
  const double c = std::cos(a), s = std::sin(a);
  Mat3 m;
  m << c, -s, 0, s, c, 0, 0, 0, 1;
  return m;
}

Mat3 Rodrigues(const Vec3& v) {
  const double theta = v.norm();
  if (theta == 0.0) return Mat3::Identity();
  const Vec3 k = v / theta;
  Mat3 K;
  K << 0, -k.z(), k.y(), k.z(), 0, -k.x(), -k.y(), k.x(), 0;
  return Mat3::Identity() + std::sin(theta) * K + (1.0 - std::cos(theta)) * K * K;
}

Mat3 QuatMatrix(double x, double y, double z, double w) {
  const double n = std::sqrt(x * x + y * y + z * z + w * w);
  x /= n, y /= n, z /= n, w /= n;
  Mat3 m;
  m << 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),  //
      2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),    //
      2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y);
  return m;
}

// The matrix the fields mean under convention c, from the definitions.
Mat3 Reference(const Fields& f, C c) {
  switch (c) {
    case C::kAxisAngle: return Rodrigues(Vec3(f[0], f[1], f[2]));
    case C::kQuaternionXYZW: return QuatMatrix(f[0], f[1], f[2], f[3]);
    case C::kEulerZYXIntrinsic: return TRz(f[0]) * TRy(f[1]) * TRx(f[2]);
    case C::kEulerXYZExtrinsic: return TRz(f[2]) * TRy(f[1]) * TRx(f[0]);
    case C::kEulerXYZIntrinsic: return TRx(f[0]) * TRy(f[1]) * TRz(f[2]);
    case C::kEulerZYZIntrinsic: return TRz(f[0]) * TRy(f[1]) * TRz(f[2]);
  }
  return Mat3::Zero();
}

double MaxDiff(const Mat3& a, const Mat3& b) { return (a - b).cwiseAbs().maxCoeff(); }

Vec3 RandomUnit(std::mt19937& rng) {
  std::normal_distribution<double> n;
  Vec3 v(n(rng), n(rng), n(rng));
  return v.normalized();
}

Mat3 RandomRotation(std::mt19937& rng) {
  std::normal_distribution<double> n;
  return QuatMatrix(n(rng), n(rng), n(rng), n(rng));
}

// Random fields for c (any values the decoder must accept, not only principal ranges).
Fields RandomFields(std::mt19937& rng, C c) {
  std::uniform_real_distribution<double> angle(-4.0, 4.0);
  std::normal_distribution<double> n;
  switch (c) {
    case C::kAxisAngle: {
      const Vec3 v = RandomUnit(rng) * std::uniform_real_distribution<double>(0.0, 3 * kPi)(rng);
      return {v.x(), v.y(), v.z(), 0.0};
    }
    case C::kQuaternionXYZW: {
      Eigen::Vector4d q(n(rng), n(rng), n(rng), n(rng));
      q.normalize();
      return {q[0], q[1], q[2], q[3]};
    }
    default: return {angle(rng), angle(rng), angle(rng), 0.0};
  }
}

Mat3 Decode(const Fields& f, C c) {
  Result<Mat3> R = DecodeOrientation(f, c);
  EXPECT_TRUE(R.ok()) << R.status().ToString();
  return R.ok() ? *R : Mat3(Mat3::Constant(kNaN));
}

// --- Orientation conventions -------------------------------------------------

TEST(OrientationConvention, DecodeOfEncodeReturnsTheSameRotation) {
  std::mt19937 rng{42};
  for (C c : kAll) {
    double worst = 0.0;
    for (int i = 0; i < 5000; ++i) {
      const Mat3 R = RandomRotation(rng);
      worst = std::max(worst, MaxDiff(Decode(EncodeOrientation(R, c), c), R));
    }
    EXPECT_LT(worst, kTol) << ToString(c);
  }
}

TEST(OrientationConvention, DecodeMatchesIndependentlyBuiltMatrix) {
  std::mt19937 rng{42};
  for (C c : kAll) {
    double worst = 0.0;
    for (int i = 0; i < 3000; ++i) {
      const Fields f = RandomFields(rng, c);
      worst = std::max(worst, MaxDiff(Decode(f, c), Reference(f, c)));
    }
    EXPECT_LT(worst, 1e-12) << ToString(c);
  }
}

// Angles inside the principal ranges come back unchanged: pins the field order.
TEST(OrientationConvention, EncodeRecoversPrincipalAnglesOfIndependentMatrix) {
  std::mt19937 rng{42};
  std::uniform_real_distribution<double> outer(-kPi + 1e-3, kPi - 1e-3);
  std::uniform_real_distribution<double> pitch(-kPi / 2 + 1e-3, kPi / 2 - 1e-3);
  std::uniform_real_distribution<double> zyz_b(1e-3, kPi - 1e-3);
  for (C c : kEuler) {
    for (int i = 0; i < 2000; ++i) {
      const double b = c == C::kEulerZYZIntrinsic ? zyz_b(rng) : pitch(rng);
      const Fields f = {outer(rng), b, outer(rng), 0.0};
      const Fields got = EncodeOrientation(Reference(f, c), c);
      for (int k = 0; k < 4; ++k) ASSERT_NEAR(got[k], f[k], kTol) << ToString(c) << " field " << k;
    }
  }
  for (int i = 0; i < 2000; ++i) {
    const Vec3 v = RandomUnit(rng) * std::uniform_real_distribution<double>(1e-6, kPi - 1e-3)(rng);
    const Fields got = EncodeOrientation(Rodrigues(v), C::kAxisAngle);
    for (int k = 0; k < 3; ++k) ASSERT_NEAR(got[k], v[k], kTol);
    ASSERT_EQ(got[3], 0.0);
  }
  for (int i = 0; i < 2000; ++i) {
    Fields f = RandomFields(rng, C::kQuaternionXYZW);
    if (f[3] < 0) f = {-f[0], -f[1], -f[2], -f[3]};
    const Fields got = EncodeOrientation(Reference(f, C::kQuaternionXYZW), C::kQuaternionXYZW);
    for (int k = 0; k < 4; ++k) ASSERT_NEAR(got[k], f[k], kTol);
  }
}

TEST(OrientationConvention, ReencodingDecodedFieldsGivesTheSameMatrixAndFields) {
  std::mt19937 rng{42};
  for (C c : kAll) {
    for (int i = 0; i < 2000; ++i) {
      const Mat3 R = Decode(RandomFields(rng, c), c);
      const Fields once = EncodeOrientation(R, c);
      const Mat3 R2 = Decode(once, c);
      ASSERT_LT(MaxDiff(R2, R), kTol) << ToString(c);
      const Fields twice = EncodeOrientation(R2, c);
      for (int k = 0; k < 4; ++k) ASSERT_NEAR(twice[k], once[k], 1e-7) << ToString(c);
    }
  }
}

TEST(OrientationConvention, IdentityEncodesToZeroAnglesAndUnitQuaternion) {
  for (C c : kAll) {
    const Fields f = EncodeOrientation(Mat3::Identity(), c);
    const Fields want = c == C::kQuaternionXYZW ? Fields{0, 0, 0, 1} : Fields{0, 0, 0, 0};
    for (int k = 0; k < 4; ++k) EXPECT_NEAR(f[k], want[k], 1e-15) << ToString(c) << " field " << k;
    EXPECT_LT(MaxDiff(Decode(f, c), Mat3::Identity()), 1e-15);
  }
}

TEST(OrientationConvention, HalfTurnsRoundTrip) {
  std::mt19937 rng{42};
  std::vector<Mat3> turns = {TRx(kPi), TRy(kPi), TRz(kPi)};
  for (int i = 0; i < 200; ++i) turns.push_back(Rodrigues(RandomUnit(rng) * kPi));
  for (C c : kAll) {
    for (const Mat3& R : turns) {
      ASSERT_LT(MaxDiff(Decode(EncodeOrientation(R, c), c), R), kTol) << ToString(c) << "\n" << R;
    }
  }
}

// Index of the angle that is fixed to 0 at gimbal lock: the leftmost factor of
// the matrix product (for fixed XYZ that is rz, the last field).
int FirstFactorField(C c) { return c == C::kEulerXYZExtrinsic ? 2 : 0; }

TEST(OrientationConvention, TaitBryanGimbalLockSetsFirstAngleToZero) {
  std::mt19937 rng{42};
  std::uniform_real_distribution<double> outer(-kPi, kPi);
  for (C c : kTaitBryan) {
    for (double pitch : {kPi / 2, -kPi / 2}) {
      for (int i = 0; i < 500; ++i) {
        const Fields f = {outer(rng), pitch, outer(rng), 0.0};
        const Mat3 R = Reference(f, c);
        const Fields got = EncodeOrientation(R, c);
        ASSERT_EQ(got[FirstFactorField(c)], 0.0) << ToString(c);
        ASSERT_NEAR(got[1], pitch, 1e-7) << ToString(c);
        ASSERT_LT(MaxDiff(Decode(got, c), R), kTol) << ToString(c);
      }
    }
  }
}

// The same rotation as Reference(f, c) for an Euler convention, but composed
// as a product of half-angle quaternions, so that every matrix entry carries
// rounding error (as matrices from a pose estimator do) instead of the exact
// products that TRz * TRy * TRx yields.
Mat3 ReferenceViaQuaternions(const Fields& f, C c) {
  auto q = [](double angle, int axis) {
    Eigen::Vector4d v = Eigen::Vector4d::Zero();  // x, y, z, w
    v[axis] = std::sin(angle / 2);
    v[3] = std::cos(angle / 2);
    return Quat(v[3], v[0], v[1], v[2]);
  };
  Quat p;
  switch (c) {
    case C::kEulerZYXIntrinsic: p = q(f[0], 2) * q(f[1], 1) * q(f[2], 0); break;
    case C::kEulerXYZExtrinsic: p = q(f[2], 2) * q(f[1], 1) * q(f[0], 0); break;
    case C::kEulerXYZIntrinsic: p = q(f[0], 0) * q(f[1], 1) * q(f[2], 2); break;
    case C::kEulerZYZIntrinsic: p = q(f[0], 2) * q(f[1], 1) * q(f[2], 2); break;
    default: p = Quat::Identity();
  }
  return QuatMatrix(p.x(), p.y(), p.z(), p.w());
}

TEST(OrientationConvention, TaitBryanNearGimbalLockRoundTrips) {
  std::mt19937 rng{42};
  std::uniform_real_distribution<double> outer(-kPi, kPi);
  for (C c : kTaitBryan) {
    for (double offset : {1e-8, -1e-8, 1e-11, -1e-11, 1e-13, 3e-16}) {
      for (double pitch : {kPi / 2 + offset, -kPi / 2 + offset}) {
        for (int i = 0; i < 200; ++i) {
          const Fields f = {outer(rng), pitch, outer(rng), 0.0};
          for (const Mat3& R : {Reference(f, c), ReferenceViaQuaternions(f, c)}) {
            ASSERT_LT(MaxDiff(Decode(EncodeOrientation(R, c), c), R), kTol)
                << ToString(c) << " pitch offset " << offset;
          }
        }
      }
    }
  }
}

TEST(OrientationConvention, ZyzWithZeroOrHalfTurnMiddleAngleSetsFirstAngleToZero) {
  std::mt19937 rng{42};
  std::uniform_real_distribution<double> outer(-kPi, kPi);
  const C c = C::kEulerZYZIntrinsic;
  for (double b : {0.0, kPi}) {
    for (int i = 0; i < 500; ++i) {
      const Mat3 R = Reference({outer(rng), b, outer(rng), 0.0}, c);
      const Fields got = EncodeOrientation(R, c);
      ASSERT_EQ(got[0], 0.0);
      ASSERT_NEAR(got[1], b, 1e-7);
      ASSERT_LT(MaxDiff(Decode(got, c), R), kTol);
    }
  }
  for (double b : {1e-8, 1e-11, kPi - 1e-8, kPi - 1e-11, -1e-8}) {
    for (int i = 0; i < 200; ++i) {
      const Fields f = {outer(rng), b, outer(rng), 0.0};
      for (const Mat3& R : {Reference(f, c), ReferenceViaQuaternions(f, c)}) {
        ASSERT_LT(MaxDiff(Decode(EncodeOrientation(R, c), c), R), kTol) << "b = " << b;
      }
    }
  }
}

TEST(OrientationConvention, QuaternionAndItsNegationDecodeToTheSameRotation) {
  std::mt19937 rng{42};
  for (int i = 0; i < 1000; ++i) {
    const Fields q = RandomFields(rng, C::kQuaternionXYZW);
    const Fields neg = {-q[0], -q[1], -q[2], -q[3]};
    ASSERT_LT(MaxDiff(Decode(q, C::kQuaternionXYZW), Decode(neg, C::kQuaternionXYZW)), 1e-15);
    const Fields enc = EncodeOrientation(Decode(neg, C::kQuaternionXYZW), C::kQuaternionXYZW);
    ASSERT_GE(enc[3], 0.0);
  }
}

TEST(OrientationConvention, QuaternionFarFromUnitNormIsRejected) {
  const double s = std::sqrt(0.5);
  for (double scale : {0.0, 0.5, 0.998, 1.0011, 2.0}) {
    const Result<Mat3> R = DecodeOrientation({0, 0, s * scale, s * scale}, C::kQuaternionXYZW);
    ASSERT_FALSE(R.ok()) << scale;
    EXPECT_EQ(R.status().code(), Status::Code::kInvalidArgument);
  }
  // Small deviations (fixed-point rounding) are normalised away.
  for (double scale : {0.9995, 1.0005}) {
    const Mat3 R = Decode({0, 0, s * scale, s * scale}, C::kQuaternionXYZW);
    EXPECT_LT(MaxDiff(R, TRz(kPi / 2)), 1e-12) << scale;
  }
}

TEST(OrientationConvention, QuaternionSurvivesMultFixedPoint) {
  std::mt19937 rng{42};
  for (int i = 0; i < 2000; ++i) {
    const Fields q = RandomFields(rng, C::kQuaternionXYZW);
    Fields wire;
    for (int k = 0; k < 4; ++k) wire[k] = FromFixed(*ToFixed(q[k]));
    const Result<Mat3> R = DecodeOrientation(wire, C::kQuaternionXYZW);
    ASSERT_TRUE(R.ok()) << R.status().ToString();
    ASSERT_LT(MaxDiff(*R, Reference(q, C::kQuaternionXYZW)), 5e-4);
  }
}

TEST(OrientationConvention, NonFiniteFieldsAreRejected) {
  for (C c : kAll) {
    const int used = c == C::kQuaternionXYZW ? 4 : 3;
    for (int k = 0; k < used; ++k) {
      for (double bad : {kNaN, kInf, -kInf}) {
        Fields f = c == C::kQuaternionXYZW ? Fields{0, 0, 0, 1} : Fields{0.1, 0.2, 0.3, 0};
        f[k] = bad;
        const Result<Mat3> R = DecodeOrientation(f, c);
        ASSERT_FALSE(R.ok()) << ToString(c) << " field " << k;
        EXPECT_EQ(R.status().code(), Status::Code::kInvalidArgument);
      }
    }
  }
}

TEST(OrientationConvention, FourthFieldIsWrittenZeroAndIgnoredForThreeValueConventions) {
  std::mt19937 rng{42};
  for (C c : kAll) {
    if (c == C::kQuaternionXYZW) continue;
    for (int i = 0; i < 100; ++i) {
      const Mat3 R = RandomRotation(rng);
      Fields f = EncodeOrientation(R, c);
      ASSERT_EQ(f[3], 0.0) << ToString(c);
      const Mat3 want = Decode(f, c);
      for (double junk : {123.0, -1.0, kNaN, kInf}) {
        f[3] = junk;
        ASSERT_EQ(Decode(f, c), want) << ToString(c) << " junk " << junk;
      }
    }
  }
}

// Matrices written out by hand (columns are the rotated axes).
TEST(OrientationConvention, HandComputedVectors) {
  Mat3 rz90, rx90, rz90_rx90, rx90_rz90, rz90_ry90, rx180;
  rz90 << 0, -1, 0, 1, 0, 0, 0, 0, 1;
  rx90 << 1, 0, 0, 0, 0, -1, 0, 1, 0;
  rz90_rx90 << 0, 0, 1, 1, 0, 0, 0, 1, 0;
  rx90_rz90 << 0, -1, 0, 0, 0, -1, 1, 0, 0;
  rz90_ry90 << 0, -1, 0, 0, 0, 1, -1, 0, 0;
  rx180 << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  const double h = kPi / 2, s = std::sqrt(0.5);
  struct Case {
    C c;
    Fields f;
    Mat3 R;
  };
  const std::vector<Case> cases = {
      {C::kAxisAngle, {0, 0, h, 0}, rz90},             // UR (0, 0, pi/2)
      {C::kAxisAngle, {kPi, 0, 0, 0}, rx180},          // UR half turn about x
      {C::kQuaternionXYZW, {0, 0, s, s}, rz90},        // ABB x, y, z, w
      {C::kEulerZYXIntrinsic, {h, 0, 0, 0}, rz90},     // KUKA A=90
      {C::kEulerZYXIntrinsic, {0, 0, h, 0}, rx90},     // KUKA C=90
      {C::kEulerZYXIntrinsic, {h, 0, h, 0}, rz90_rx90},  // KUKA A=90, C=90
      {C::kEulerXYZExtrinsic, {h, 0, 0, 0}, rx90},     // Fanuc W=90
      {C::kEulerXYZExtrinsic, {0, 0, h, 0}, rz90},     // Fanuc R=90
      {C::kEulerXYZExtrinsic, {h, 0, h, 0}, rz90_rx90},  // Fanuc W=90, R=90
      {C::kEulerXYZIntrinsic, {h, 0, h, 0}, rx90_rz90},  // Staubli
      {C::kEulerZYZIntrinsic, {h, h, 0, 0}, rz90_ry90},  // Kawasaki O=90, A=90
  };
  for (const Case& k : cases) {
    EXPECT_LT(MaxDiff(Decode(k.f, k.c), k.R), 1e-15) << ToString(k.c);
    const Fields enc = EncodeOrientation(k.R, k.c);
    EXPECT_LT(MaxDiff(Decode(enc, k.c), k.R), 1e-15) << ToString(k.c);
    if (k.c != C::kAxisAngle || k.f[0] != kPi) {  // half turn: sign of v is free
      for (int i = 0; i < 4; ++i) EXPECT_NEAR(enc[i], k.f[i], 1e-15) << ToString(k.c) << " field " << i;
    }
  }
}

TEST(OrientationConvention, AxisAngleNearHalfTurnIsRobust) {
  std::mt19937 rng{42};
  for (int i = 0; i < 500; ++i) {
    const Vec3 axis = RandomUnit(rng);
    for (double angle : {kPi - 1e-3, kPi - 1e-6, kPi - 1e-9, kPi - 1e-12, kPi}) {
      const Mat3 R = Rodrigues(axis * angle);
      const Fields f = EncodeOrientation(R, C::kAxisAngle);
      ASSERT_NEAR(Vec3(f[0], f[1], f[2]).norm(), angle, 1e-7);
      ASSERT_LT(MaxDiff(Decode(f, C::kAxisAngle), R), kTol);
    }
    // v and -v are the same half turn.
    const Vec3 v = axis * kPi;
    ASSERT_LT(MaxDiff(Decode({v.x(), v.y(), v.z(), 0}, C::kAxisAngle),
                      Decode({-v.x(), -v.y(), -v.z(), 0}, C::kAxisAngle)),
              1e-12);
  }
}

TEST(OrientationConvention, NamesRoundTripCaseInsensitively) {
  for (C c : kAll) {
    EXPECT_EQ(ParseOrientationConvention(ToString(c)), c);
    std::string upper(ToString(c));
    for (char& ch : upper) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
    EXPECT_EQ(ParseOrientationConvention(upper), c);
  }
  EXPECT_EQ(ParseOrientationConvention("euler"), std::nullopt);
  EXPECT_EQ(ParseOrientationConvention(""), std::nullopt);
}

// --- Robot models ------------------------------------------------------------

TEST(RobotModel, Meta1IdsMatchTheProtocolTable) {
  EXPECT_EQ(static_cast<int>(RobotType::kABB), 0);
  EXPECT_EQ(static_cast<int>(RobotType::kFanuc), 1);
  EXPECT_EQ(static_cast<int>(RobotType::kHanwha), 2);
  EXPECT_EQ(static_cast<int>(RobotType::kKuka), 3);
  EXPECT_EQ(static_cast<int>(RobotType::kOmronTM), 4);
  EXPECT_EQ(static_cast<int>(RobotType::kSiemensPLC), 5);
  EXPECT_EQ(static_cast<int>(RobotType::kStaubli), 6);
  EXPECT_EQ(static_cast<int>(RobotType::kUR), 7);
  EXPECT_EQ(static_cast<int>(RobotType::kYaskawa), 8);
  EXPECT_EQ(static_cast<int>(RobotType::kEfort), 9);
  EXPECT_EQ(static_cast<int>(RobotType::kAubo), 10);
  EXPECT_EQ(static_cast<int>(RobotType::kDobot), 11);
  EXPECT_EQ(static_cast<int>(RobotType::kMitsubishi), 12);
  EXPECT_EQ(static_cast<int>(RobotType::kOther), 99);
}

struct ExpectedRobot {
  const char* name;
  RobotType type;
  C convention;
};
const ExpectedRobot kExpectedRobots[] = {
    {"ur", RobotType::kUR, C::kAxisAngle},
    {"abb", RobotType::kABB, C::kQuaternionXYZW},
    {"kuka", RobotType::kKuka, C::kEulerZYXIntrinsic},
    {"fanuc", RobotType::kFanuc, C::kEulerXYZExtrinsic},
    {"yaskawa", RobotType::kYaskawa, C::kEulerXYZExtrinsic},
    {"staubli", RobotType::kStaubli, C::kEulerXYZIntrinsic},
    {"adept", RobotType::kOther, C::kEulerZYZIntrinsic},
    {"kawasaki", RobotType::kOther, C::kEulerZYZIntrinsic},
    {"mitsubishi", RobotType::kMitsubishi, C::kEulerZYXIntrinsic},
    {"comau", RobotType::kOther, C::kEulerZYZIntrinsic},
    {"syntec", RobotType::kOther, C::kEulerXYZExtrinsic},
    {"aubo", RobotType::kAubo, C::kEulerZYXIntrinsic},
    {"dobot", RobotType::kDobot, C::kEulerZYXIntrinsic},
    {"hanwha", RobotType::kHanwha, C::kEulerZYXIntrinsic},
    {"efort", RobotType::kEfort, C::kEulerZYZIntrinsic},
    {"turin", RobotType::kOther, C::kEulerXYZIntrinsic},
    {"omron_tm", RobotType::kOmronTM, C::kEulerXYZExtrinsic},
    {"siemens_plc", RobotType::kSiemensPLC, C::kEulerXYZExtrinsic},
    {"other", RobotType::kOther, C::kEulerXYZExtrinsic},
};

TEST(RobotModel, EveryDocumentedNameMapsToItsIdAndConvention) {
  for (const ExpectedRobot& e : kExpectedRobots) {
    const std::optional<RobotModel> m = FindRobotModel(e.name);
    ASSERT_TRUE(m.has_value()) << e.name;
    EXPECT_EQ(m->name, e.name);
    EXPECT_EQ(m->type, e.type) << e.name;
    EXPECT_EQ(m->convention, e.convention) << e.name;
  }
}

TEST(RobotModel, NamesAreCaseInsensitive) {
  EXPECT_EQ(FindRobotModel("KUKA")->type, RobotType::kKuka);
  EXPECT_EQ(FindRobotModel("Ur")->type, RobotType::kUR);
  EXPECT_EQ(FindRobotModel("Kawasaki")->convention, C::kEulerZYZIntrinsic);
  EXPECT_EQ(FindRobotModel("Omron_TM")->type, RobotType::kOmronTM);
  EXPECT_EQ(FindRobotModel("omron-tm")->type, RobotType::kOmronTM);
  EXPECT_EQ(FindRobotModel("SIEMENS_PLC")->name, "siemens_plc");
}

TEST(RobotModel, UnknownNameIsNotFound) {
  for (const char* name : {"", "ur5", "kukaa", "robot", " ur"}) {
    EXPECT_EQ(FindRobotModel(name), std::nullopt) << "'" << name << "'";
  }
}

TEST(RobotModel, EachMeta1IdHasACanonicalModel) {
  for (int id : {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 99}) {
    const std::optional<RobotType> type = RobotTypeFromId(id);
    ASSERT_TRUE(type.has_value()) << id;
    EXPECT_EQ(static_cast<int>(*type), id);
    const std::optional<RobotModel> m = FindRobotModel(*type);
    ASSERT_TRUE(m.has_value()) << id;
    EXPECT_EQ(m->type, *type);
    EXPECT_EQ(m->name, ToString(*type));
    const std::optional<RobotModel> by_name = FindRobotModel(m->name);
    ASSERT_TRUE(by_name.has_value());
    EXPECT_EQ(by_name->type, *type);
    EXPECT_EQ(by_name->convention, m->convention);
  }
  EXPECT_EQ(FindRobotModel(RobotType::kOther)->name, "other");
  EXPECT_EQ(FindRobotModel(RobotType::kUR)->convention, C::kAxisAngle);
}

TEST(RobotModel, ValuesOutsideTheMeta1TableAreRejected) {
  for (int id : {-1, 13, 42, 98, 100}) EXPECT_EQ(RobotTypeFromId(id), std::nullopt) << id;
  EXPECT_EQ(FindRobotModel(static_cast<RobotType>(42)), std::nullopt);
  EXPECT_EQ(ToString(static_cast<RobotType>(42)), "unknown");
}

// --- GRI pose formats --------------------------------------------------------

const GriPoseFormat kGriFormats[] = {
    GriPoseFormat::kMQuaternion,    GriPoseFormat::kMMQuaternion,    GriPoseFormat::kMEulerDegree,
    GriPoseFormat::kMEulerRadians,  GriPoseFormat::kMMEulerDegree,   GriPoseFormat::kMMEulerRadians,
    GriPoseFormat::kMMAbcKuka,      GriPoseFormat::kMAxisAngle,      GriPoseFormat::kMMAxisAngle,
    GriPoseFormat::kMMWprFanuc,
};

bool IsMm(GriPoseFormat f) {
  return f == GriPoseFormat::kMMQuaternion || f == GriPoseFormat::kMMEulerDegree ||
         f == GriPoseFormat::kMMEulerRadians || f == GriPoseFormat::kMMAbcKuka ||
         f == GriPoseFormat::kMMAxisAngle || f == GriPoseFormat::kMMWprFanuc;
}

TEST(GriPose, EveryFormatRoundTrips) {
  std::mt19937 rng{42};
  std::uniform_real_distribution<double> pos(-2.0, 2.0);
  for (GriPoseFormat f : kGriFormats) {
    for (QuaternionOrder q : {QuaternionOrder::kXYZW, QuaternionOrder::kWXYZ}) {
      for (int i = 0; i < 1000; ++i) {
        const Pose X = MakePose(RandomRotation(rng), Vec3(pos(rng), pos(rng), pos(rng)));
        const Result<std::array<double, 7>> v = EncodeGriPose(X, f, q);
        ASSERT_TRUE(v.ok()) << v.status().ToString();
        const Result<Pose> back = DecodeGriPose(*v, f, q);
        ASSERT_TRUE(back.ok()) << back.status().ToString();
        ASSERT_LT(MaxDiff(back->linear(), X.linear()), kTol) << static_cast<int>(f);
        ASSERT_LT((back->translation() - X.translation()).cwiseAbs().maxCoeff(), 1e-12) << static_cast<int>(f);
      }
    }
  }
}

TEST(GriPose, PositionUnitFollowsTheFormat) {
  const Pose X = MakePose(Mat3(Mat3::Identity()), Vec3(0.125, -0.25, 1.5));
  for (GriPoseFormat f : kGriFormats) {
    const std::array<double, 7> v = *EncodeGriPose(X, f);
    const double scale = IsMm(f) ? 1000.0 : 1.0;
    EXPECT_DOUBLE_EQ(v[0], 0.125 * scale) << static_cast<int>(f);
    EXPECT_DOUBLE_EQ(v[1], -0.25 * scale) << static_cast<int>(f);
    EXPECT_DOUBLE_EQ(v[2], 1.5 * scale) << static_cast<int>(f);
  }
}

TEST(GriPose, RotationFieldsFollowTheFormat) {
  // roll 10, pitch 20, yaw 30 degrees, built independently.
  const Pose X = MakePose(Mat3(TRz(30 * kDeg) * TRy(20 * kDeg) * TRx(10 * kDeg)), Vec3::Zero());
  struct Case {
    GriPoseFormat f;
    std::array<double, 4> rot;
  };
  const Case cases[] = {
      {GriPoseFormat::kMEulerDegree, {10, 20, 30, 0}},
      {GriPoseFormat::kMMEulerDegree, {10, 20, 30, 0}},
      {GriPoseFormat::kMEulerRadians, {10 * kDeg, 20 * kDeg, 30 * kDeg, 0}},
      {GriPoseFormat::kMMEulerRadians, {10 * kDeg, 20 * kDeg, 30 * kDeg, 0}},
      {GriPoseFormat::kMMAbcKuka, {30, 20, 10, 0}},
      {GriPoseFormat::kMMWprFanuc, {10, 20, 30, 0}},
  };
  for (const Case& k : cases) {
    const std::array<double, 7> v = *EncodeGriPose(X, k.f);
    for (int i = 0; i < 4; ++i) EXPECT_NEAR(v[3 + i], k.rot[i], 1e-12) << static_cast<int>(k.f) << " rot " << i;
  }
  // Axis-angle formats: rotation vector in radians, 4th field 0.
  const Pose Z = MakePose(Mat3(TRz(kPi / 2)), Vec3::Zero());
  for (GriPoseFormat f : {GriPoseFormat::kMAxisAngle, GriPoseFormat::kMMAxisAngle}) {
    const std::array<double, 7> v = *EncodeGriPose(Z, f);
    EXPECT_NEAR(v[3], 0, 1e-15);
    EXPECT_NEAR(v[4], 0, 1e-15);
    EXPECT_NEAR(v[5], kPi / 2, 1e-15);
    EXPECT_EQ(v[6], 0.0);
  }
}

TEST(GriPose, QuaternionOrderSelectsWhereWTravels) {
  const double s = std::sqrt(0.5);
  const Pose Z = MakePose(Mat3(TRz(kPi / 2)), Vec3::Zero());
  for (GriPoseFormat f : {GriPoseFormat::kMQuaternion, GriPoseFormat::kMMQuaternion}) {
    const std::array<double, 7> xyzw = *EncodeGriPose(Z, f, QuaternionOrder::kXYZW);
    const std::array<double, 7> wxyz = *EncodeGriPose(Z, f, QuaternionOrder::kWXYZ);
    const std::array<double, 4> want_xyzw = {0, 0, s, s}, want_wxyz = {s, 0, 0, s};
    for (int i = 0; i < 4; ++i) {
      EXPECT_NEAR(xyzw[3 + i], want_xyzw[i], 1e-15);
      EXPECT_NEAR(wxyz[3 + i], want_wxyz[i], 1e-15);
    }
    // The same 4 numbers mean different rotations under the two orders.
    const std::array<double, 7> v = {0, 0, 0, 1, 0, 0, 0};
    EXPECT_LT(MaxDiff(DecodeGriPose(v, f, QuaternionOrder::kWXYZ)->linear(), Mat3::Identity()), 1e-15);
    EXPECT_LT(MaxDiff(DecodeGriPose(v, f, QuaternionOrder::kXYZW)->linear(), TRx(kPi)), 1e-15);
  }
  // Formats without a quaternion ignore the order.
  const std::array<double, 7> a = *EncodeGriPose(Z, GriPoseFormat::kMMAbcKuka, QuaternionOrder::kXYZW);
  const std::array<double, 7> b = *EncodeGriPose(Z, GriPoseFormat::kMMAbcKuka, QuaternionOrder::kWXYZ);
  EXPECT_EQ(a, b);
}

TEST(GriPose, UnknownFormatIsRejected) {
  const std::array<double, 7> v = {0, 0, 0, 0, 0, 0, 1};
  for (int raw : {0, 11, 127, 255}) {
    const auto f = static_cast<GriPoseFormat>(raw);
    const Result<std::array<double, 7>> enc = EncodeGriPose(Pose::Identity(), f);
    ASSERT_FALSE(enc.ok()) << raw;
    EXPECT_EQ(enc.status().code(), Status::Code::kInvalidArgument);
    const Result<Pose> dec = DecodeGriPose(v, f);
    ASSERT_FALSE(dec.ok()) << raw;
    EXPECT_EQ(dec.status().code(), Status::Code::kInvalidArgument);
  }
}

TEST(GriPose, NonFiniteOrNonUnitValuesAreRejected) {
  for (GriPoseFormat f : kGriFormats) {
    for (int i = 0; i < 6; ++i) {  // position and the first three rotation fields matter everywhere
      std::array<double, 7> v = *EncodeGriPose(Pose::Identity(), f);
      v[i] = kNaN;
      const Result<Pose> dec = DecodeGriPose(v, f);
      ASSERT_FALSE(dec.ok()) << static_cast<int>(f) << " field " << i;
      EXPECT_EQ(dec.status().code(), Status::Code::kInvalidArgument);
    }
  }
  const Result<Pose> zero_quat = DecodeGriPose({0, 0, 0, 0, 0, 0, 0}, GriPoseFormat::kMQuaternion);
  EXPECT_EQ(zero_quat.status().code(), Status::Code::kInvalidArgument);
}

// --- MULT fixed point ----------------------------------------------------------

TEST(FixedPoint, RoundsToNearestWithTiesAwayFromZero) {
  EXPECT_EQ(*ToFixed(1.23456), 12346);
  EXPECT_EQ(*ToFixed(-1.23454), -12345);
  EXPECT_EQ(*ToFixed(0.00004), 0);
  EXPECT_EQ(*ToFixed(0.00006), 1);
  EXPECT_EQ(*ToFixed(-0.00006), -1);
  EXPECT_EQ(*ToFixed(-0.0), 0);
  // Exact ties (the product is exactly representable).
  EXPECT_EQ(*ToFixed(0.5, 1.0), 1);
  EXPECT_EQ(*ToFixed(1.5, 1.0), 2);
  EXPECT_EQ(*ToFixed(2.5, 1.0), 3);  // not banker's rounding
  EXPECT_EQ(*ToFixed(-2.5, 1.0), -3);
  EXPECT_EQ(*ToFixed(0.25, 2.0), 1);
  EXPECT_EQ(*ToFixed16(-0.5, 1.0), -1);
  EXPECT_EQ(*ToFixed16(2.5, 1.0), 3);
}

TEST(FixedPoint, Int32BoundariesAndOverflow) {
  constexpr int32_t kMax = std::numeric_limits<int32_t>::max(), kMin = std::numeric_limits<int32_t>::min();
  EXPECT_EQ(*ToFixed(214748.3647), kMax);
  EXPECT_EQ(*ToFixed(-214748.3648), kMin);
  EXPECT_EQ(*ToFixed(2147483647.49, 1.0), kMax);
  EXPECT_EQ(*ToFixed(-2147483648.49, 1.0), kMin);
  for (double v : {214748.3648, -214748.3649, 1e300, -1e300, std::numeric_limits<double>::max()}) {
    const Result<int32_t> r = ToFixed(v);
    ASSERT_FALSE(r.ok()) << v;
    EXPECT_EQ(r.status().code(), Status::Code::kOutOfRange) << v;
  }
  for (double v : {2147483647.5, -2147483648.5, 4294967296.0}) {  // rounds out of range; never wraps
    const Result<int32_t> r = ToFixed(v, 1.0);
    ASSERT_FALSE(r.ok()) << v;
    EXPECT_EQ(r.status().code(), Status::Code::kOutOfRange) << v;
  }
}

TEST(FixedPoint, Int16BoundariesAndOverflow) {
  EXPECT_EQ(*ToFixed16(3.2767), 32767);
  EXPECT_EQ(*ToFixed16(-3.2768), -32768);
  EXPECT_EQ(*ToFixed16(32767.49, 1.0), 32767);
  EXPECT_EQ(*ToFixed16(-32768.49, 1.0), -32768);
  for (double v : {3.2768, -3.2769, 100.0, -1e9}) {
    const Result<int16_t> r = ToFixed16(v);
    ASSERT_FALSE(r.ok()) << v;
    EXPECT_EQ(r.status().code(), Status::Code::kOutOfRange) << v;
  }
  for (double v : {32767.5, -32768.5, 65536.0}) {
    const Result<int16_t> r = ToFixed16(v, 1.0);
    ASSERT_FALSE(r.ok()) << v;
    EXPECT_EQ(r.status().code(), Status::Code::kOutOfRange) << v;
  }
}

TEST(FixedPoint, NonFiniteValueOrBadMultIsInvalidArgument) {
  for (double v : {kNaN, kInf, -kInf}) {
    EXPECT_EQ(ToFixed(v).status().code(), Status::Code::kInvalidArgument) << v;
    EXPECT_EQ(ToFixed16(v).status().code(), Status::Code::kInvalidArgument) << v;
  }
  for (double mult : {0.0, -10000.0, kNaN, kInf}) {
    EXPECT_EQ(ToFixed(1.0, mult).status().code(), Status::Code::kInvalidArgument) << mult;
    EXPECT_EQ(ToFixed16(1.0, mult).status().code(), Status::Code::kInvalidArgument) << mult;
  }
}

TEST(FixedPoint, FromFixedRecoversTheValueWithinHalfAUnit) {
  std::mt19937 rng{42};
  std::uniform_real_distribution<double> value(-214748.0, 214748.0);
  for (int i = 0; i < 10000; ++i) {
    const double v = value(rng);
    const Result<int32_t> fixed = ToFixed(v);
    ASSERT_TRUE(fixed.ok()) << v;
    ASSERT_LE(std::abs(FromFixed(*fixed) - v), 0.5 / kMult + 1e-10) << v;
  }
}

}  // namespace
}  // namespace bp
