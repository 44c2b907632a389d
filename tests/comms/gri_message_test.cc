// GRI codecs: golden byte vectors written by hand from the tables in
// docs/protocols.md ("GRI"), then every decode fault on purpose.
#include "comms/gri_message.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "tests/testing/hex.h"

namespace bp::gri {
namespace {

using testing::FromHex;

// v2 TRIGGER_JOB_SYNC, job 0, MM_QUATERNION (2), robot at (500, -100, 100) mm,
// quaternion x, y, z, w = 0, 0, 0, 1; data zero.
const char* kV2TriggerHex =
    "02 02 32 02 02"                        // magic 2, version 2, length 50, format 2, action 2
    "00"                                    // job 0
    "0000FA43 0000C8C2 0000C842"            // 500.0f, -100.0f, 100.0f
    "00000000 00000000 00000000 0000803F"   // 0, 0, 0, 1.0f
    "00000000 00000000 00000000 00000000";  // data_1..4

// v2 GET_NEXT_POSE answer, job 1, NO_ERROR, (500, -80, 100) mm, quaternion
// (0, 0, 0.70710677, 0.70710677); data_1 = 2 primary left, data_2 = 1 related.
const char* kV2PoseHex =
    "02 02 37 02 05"                       // magic 2, version 2, length 55, format 2, action 5
    "01 00"                                // job 1, error 0
    "0000FA43 0000A0C2 0000C842"           // 500.0f, -80.0f, 100.0f
    "00000000 00000000 F304353F F304353F"  // 0, 0, 0.70710677f, 0.70710677f
    "02000000 01000000 00000000 00000000 00000000";

// Official TRIGGER_JOB_SYNC, job 0, pose format 1 (w, x, y, z), robot at
// (500, -100, 100) mm, identity; every value x 1e6.
const char* kOfficialTriggerHex =
    "47524900 01 36 01 02"                 // "GRI\0", version 1, length 54, format 1, action 2
    "0000"                                 // job 0 (uint16)
    "0065CD1D 001F0AFA 00E1F505"           // 500e6, -100e6, 100e6
    "40420F00 00000000 00000000 00000000"  // w = 1e6, x, y, z
    "00000000 00000000 00000000 00000000";

// Official GET_NEXT_POSE answer, job 1, success, format 2 (x, y, z, w),
// (500, -80, 100) mm, quaternion (0, 0, 0.707107, 0.707107) x 1e6;
// data_1 node return code 0, data_2 = 2 primary left, data_3 = 1 related.
const char* kOfficialPoseHex =
    "47524900 01 50 02 05"                 // "GRI\0", version 1, length 80, format 2, action 5
    "0100 0000"                            // job 1, error 0 (int16)
    "0065CD1D 004C3BFB 00E1F505"           // 500e6, -80e6, 100e6
    "00000000 00000000 23CA0A00 23CA0A00"  // 0, 0, 707107, 707107
    "00000000 02000000 01000000 00000000 00000000"
    "00000000 00000000 00000000 00000000 00000000";

Request TriggerRequest(Format f) {
  Request r;
  r.format = f;
  r.pose_format = f == Format::kV2 ? 2 : 1;
  r.action = kTriggerJobSync;
  r.pose = f == Format::kV2 ? std::array<double, 7>{500, -100, 100, 0, 0, 0, 1}
                            : std::array<double, 7>{500, -100, 100, 1, 0, 0, 0};
  return r;
}

// GET_NEXT_POSE answer for job 1 with 2 primary and 1 related pose left.
Response PoseResponse(Format f) {
  Response r;
  r.format = f;
  r.pose_format = 2;
  r.action = kGetNextPose;
  r.job_id = 1;
  const double q = f == Format::kV2 ? 0.70710677f : 0.70710678;
  r.pose = {500, -80, 100, 0, 0, q, q};
  const size_t slot = f == Format::kV2 ? 0 : 1;  // official data_1 is the node return code
  r.data[slot] = 2;
  r.data[slot + 1] = 1;
  return r;
}

TEST(GriMessage, RequestsMatchGoldenBytesBothWays) {
  for (auto [f, hex] :
       {std::pair{Format::kV2, kV2TriggerHex}, std::pair{Format::kOfficial, kOfficialTriggerHex}}) {
    SCOPED_TRACE(ToString(f));
    const Request r = TriggerRequest(f);
    Result<std::vector<uint8_t>> bytes = EncodeRequest(r);
    ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
    EXPECT_EQ(*bytes, FromHex(hex));
    Result<Request> decoded = DecodeRequest(FromHex(hex));
    ASSERT_TRUE(decoded.ok()) << decoded.status().ToString();
    EXPECT_EQ(decoded->format, f);
    EXPECT_EQ(decoded->action, kTriggerJobSync);
    EXPECT_EQ(decoded->pose_format, r.pose_format);
    EXPECT_EQ(decoded->pose, r.pose);
  }
}

TEST(GriMessage, ResponsesMatchGoldenBytesBothWays) {
  for (auto [f, hex] :
       {std::pair{Format::kV2, kV2PoseHex}, std::pair{Format::kOfficial, kOfficialPoseHex}}) {
    SCOPED_TRACE(ToString(f));
    const Response r = PoseResponse(f);
    Result<std::vector<uint8_t>> bytes = EncodeResponse(r);
    ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
    EXPECT_EQ(*bytes, FromHex(hex));
    Result<Response> decoded = DecodeResponse(FromHex(hex));
    ASSERT_TRUE(decoded.ok()) << decoded.status().ToString();
    EXPECT_EQ(decoded->job_id, 1);
    EXPECT_EQ(decoded->data, r.data);
    EXPECT_DOUBLE_EQ(decoded->pose[1], -80.0);
    // v2 floats come back exactly; official values to 1e-6.
    EXPECT_NEAR(decoded->pose[6], r.pose[6], f == Format::kV2 ? 0.0 : 1e-6);
  }
}

TEST(GriMessage, OfficialJobIdIsUnsigned16AndV2JobIdSigned8) {
  std::vector<uint8_t> official = FromHex(kOfficialTriggerHex);
  official[8] = 0xFF;
  official[9] = 0xFF;
  EXPECT_EQ(DecodeRequest(official)->job_id, 65535);
  std::vector<uint8_t> v2 = FromHex(kV2TriggerHex);
  v2[5] = 0xFF;
  EXPECT_EQ(DecodeRequest(v2)->job_id, -1);

  Request r;
  r.job_id = 200;  // v2 job ids are int8
  EXPECT_EQ(EncodeRequest(r).status().code(), Status::Code::kOutOfRange);
  r.format = Format::kOfficial;
  r.job_id = 65536;
  EXPECT_EQ(EncodeRequest(r).status().code(), Status::Code::kOutOfRange);
}

TEST(GriMessage, OfficialFixedPointIsRangeCheckedNotWrapped) {
  Response r;
  r.format = Format::kOfficial;
  r.pose = {2147.483647, 0, 0, 0, 0, 0, 1};  // the largest position, in mm
  EXPECT_TRUE(EncodeResponse(r).ok());
  r.pose[0] = 2147.5;  // 2.1475 m does not fit
  EXPECT_EQ(EncodeResponse(r).status().code(), Status::Code::kOutOfRange);
  r.pose[0] = std::nan("");
  EXPECT_FALSE(EncodeResponse(r).ok());
}

TEST(GriMessage, ErrorCodesAreTheFormatsOwn) {
  EXPECT_EQ(WireErrorCode(Format::kV2, Code::kNoPosesFound), 13);
  EXPECT_EQ(WireErrorCode(Format::kOfficial, Code::kNoPosesFound), 1);
  EXPECT_EQ(WireErrorCode(Format::kV2, Code::kJobDoesNotExist), 10);
  EXPECT_EQ(WireErrorCode(Format::kOfficial, Code::kJobDoesNotExist), -12);
  EXPECT_EQ(WireErrorCode(Format::kV2, Code::kProcessingTimeout), 8);
  EXPECT_EQ(WireErrorCode(Format::kOfficial, Code::kProcessingTimeout), -9);
  EXPECT_EQ(WireErrorCode(Format::kV2, Code::kNotImplemented), 100);
  EXPECT_EQ(WireErrorCode(Format::kOfficial, Code::kNotImplemented), -14);
  Response r;
  r.error_code = 100;  // fits int8
  EXPECT_TRUE(EncodeResponse(r).ok());
  r.error_code = 200;
  EXPECT_EQ(EncodeResponse(r).status().code(), Status::Code::kOutOfRange);
}

struct Corruption {
  const char* name;
  const char* hex;
  std::function<void(std::vector<uint8_t>&)> corrupt;
  Fault fault;
  const char* message;
};

TEST(GriMessage, EveryCorruptedRequestIsRejectedWithItsFault) {
  // clang-format off
  const std::vector<Corruption> cases = {
      {"v2 wrong first byte", kV2TriggerHex, [](auto& b) { b[0] = 7; }, Fault::kWrongMagic, "wrong magic"},
      {"official magic GRX", kOfficialTriggerHex, [](auto& b) { b[2] = 'X'; }, Fault::kWrongMagic, "wrong magic"},
      {"v2 version 3", kV2TriggerHex, [](auto& b) { b[1] = 3; }, Fault::kWrongVersion, "version 3"},
      {"official version 2", kOfficialTriggerHex, [](auto& b) { b[4] = 2; }, Fault::kWrongVersion, "version 2"},
      {"v2 length field 49", kV2TriggerHex, [](auto& b) { b[2] = 49; }, Fault::kLengthMismatch, "says 49"},
      {"official length field 80", kOfficialTriggerHex, [](auto& b) { b[5] = 80; }, Fault::kLengthMismatch, "says 80"},
      {"v2 short", kV2TriggerHex, [](auto& b) { b.resize(49); b[2] = 49; }, Fault::kShort, "expected 50"},
      {"official short", kOfficialTriggerHex, [](auto& b) { b.resize(50); b[5] = 50; }, Fault::kShort, "expected 54"},
      {"v2 long", kV2TriggerHex, [](auto& b) { b.resize(51); b[2] = 51; }, Fault::kLong, "expected 50"},
      {"official long", kOfficialTriggerHex, [](auto& b) { b.resize(58); b[5] = 58; }, Fault::kLong, "expected 54"},
      {"short header", kOfficialTriggerHex, [](auto& b) { b.resize(6); }, Fault::kShort, "header"},
      {"v2 action 0", kV2TriggerHex, [](auto& b) { b[4] = 0; }, Fault::kUnknownAction, "action 0"},
      {"official action 10", kOfficialTriggerHex, [](auto& b) { b[7] = 10; }, Fault::kUnknownAction, "action 10"},
      {"v2 pose format 11", kV2TriggerHex, [](auto& b) { b[3] = 11; }, Fault::kUnknownPoseFormat, "pose format 11"},
      {"official pose format 255", kOfficialTriggerHex, [](auto& b) { b[6] = 255; }, Fault::kUnknownPoseFormat, "pose format 255"},
  };
  // clang-format on
  for (const Corruption& c : cases) {
    SCOPED_TRACE(c.name);
    std::vector<uint8_t> bytes = FromHex(c.hex);
    c.corrupt(bytes);
    Fault fault = Fault::kShort;
    Result<Request> r = DecodeRequest(bytes, &fault);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(fault, c.fault);
    EXPECT_NE(r.status().message().find(c.message), std::string::npos) << r.status().message();
  }
}

TEST(GriMessage, FormatIsDetectedFromTheFirstByte) {
  EXPECT_EQ(DetectFormat(2), Format::kV2);
  EXPECT_EQ(DetectFormat('G'), Format::kOfficial);
  EXPECT_FALSE(DetectFormat(3).has_value());
  EXPECT_FALSE(DetectFormat(0).has_value());
}

}  // namespace
}  // namespace bp::gri
