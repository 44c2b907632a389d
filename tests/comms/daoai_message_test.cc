#include "comms/daoai_message.h"

#include <gtest/gtest.h>

#include <random>
#include <string>

#include "tests/testing/hex.h"

namespace bp::daoai {
namespace {

using testing::FromHex;

// A UR robot at x=0.5 m, y=-0.25 m, z=0.3 m, rotation vector (pi, 0, 0),
// asking for the pick pose of task 0 with protocol version 2: exactly what the
// seed's send_robot_data() writes (floor(MULT * value), two's complement).
const char* kPickRequestHex =
    "00001388 FFFFF63C 00000BB8"           // position 5000, -2500, 3000
    "00007AB8 00000000 00000000 00000000"  // rx, ry, rz, 0 = 31416, 0, 0, 0
    "00000015"                             // command 21
    "00000000 00000000"                    // payload_1 (task id 0), payload_2
    "00000007 00000002";                   // meta_1 UR, meta_2 version 2

// OBJECTS_FOUND at (0.612, 0.034, 0.1005) m, rotation vector (0, pi, 0),
// 5 remaining (x MULT), part class 2 (x MULT).
const char* kObjectsFoundHex =
    "000017E8 00000154 000003ED"
    "00000000 00007AB8 00000000 00000000"
    "0000C350 00004E20 00000000 00000000 00000000 00000000"
    "00000002 00000007 00000002";

TEST(DaoaiMessage, DecodesGoldenPickRequest) {
  const auto bytes = FromHex(kPickRequestHex);
  ASSERT_EQ(bytes.size(), kRequestSize);
  const Request r = DecodeRequest(std::span<const uint8_t, kRequestSize>(bytes.data(), kRequestSize));
  EXPECT_EQ(r.position, (std::array<int32_t, 3>{5000, -2500, 3000}));
  EXPECT_EQ(r.orientation, (std::array<int32_t, 4>{31416, 0, 0, 0}));
  EXPECT_EQ(r.command, kPickPose);
  EXPECT_EQ(r.payload_1, 0);
  EXPECT_EQ(r.meta_1, 7);
  EXPECT_EQ(r.meta_2, 2);
}

TEST(DaoaiMessage, EncodesGoldenPickRequest) {
  Request r;
  r.position = {5000, -2500, 3000};
  r.orientation = {31416, 0, 0, 0};
  r.command = kPickPose;
  r.meta_1 = 7;
  r.meta_2 = 2;
  const auto bytes = EncodeRequest(r);
  EXPECT_EQ(std::vector<uint8_t>(bytes.begin(), bytes.end()), FromHex(kPickRequestHex));
}

TEST(DaoaiMessage, EncodesGoldenObjectsFoundResponse) {
  Response r;
  r.position = {6120, 340, 1005};
  r.orientation = {0, 31416, 0, 0};
  r.payload = {50000, 20000, 0, 0, 0, 0};
  r.status = kObjectsFound;
  r.meta_1 = 7;
  r.meta_2 = 2;
  const auto bytes = EncodeResponse(r);
  EXPECT_EQ(std::vector<uint8_t>(bytes.begin(), bytes.end()), FromHex(kObjectsFoundHex));
  EXPECT_EQ(DecodeResponse(bytes), r);
}

TEST(DaoaiMessage, ReadsNegativeFieldsAsTwosComplement) {
  std::array<uint8_t, kRequestSize> bytes{};
  bytes.fill(0xFF);  // every field -1 in two's complement (would be -0 in one's complement)
  const Request r = DecodeRequest(bytes);
  EXPECT_EQ(r.command, -1);
  EXPECT_EQ(r.position[0], -1);
  bytes[0] = 0x80;
  bytes[1] = bytes[2] = bytes[3] = 0x00;
  EXPECT_EQ(DecodeRequest(bytes).position[0], INT32_MIN);
}

TEST(DaoaiMessage, RoundTripsRandomMessages) {
  std::mt19937 rng{42};
  std::uniform_int_distribution<int32_t> any(INT32_MIN, INT32_MAX);
  for (int i = 0; i < 2000; ++i) {
    Request q{{any(rng), any(rng), any(rng)}, {any(rng), any(rng), any(rng), any(rng)},
              any(rng), any(rng), any(rng), any(rng), any(rng)};
    EXPECT_EQ(DecodeRequest(EncodeRequest(q)), q);
    Response s;
    for (auto& v : s.position) v = any(rng);
    for (auto& v : s.orientation) v = any(rng);
    for (auto& v : s.payload) v = any(rng);
    s.status = any(rng);
    s.meta_1 = any(rng);
    s.meta_2 = any(rng);
    EXPECT_EQ(DecodeResponse(EncodeResponse(s)), s);
  }
}

TEST(DaoaiMessage, FieldsAreBigEndianAtTheirOffsets) {
  // Flip one byte of a golden request: only the field that owns it changes.
  auto bytes = FromHex(kPickRequestHex);
  bytes[4 * 7 + 3] ^= 0x01;  // low byte of the command
  const Request r = DecodeRequest(std::span<const uint8_t, kRequestSize>(bytes.data(), kRequestSize));
  EXPECT_EQ(r.command, 20);
  EXPECT_EQ(r.position, (std::array<int32_t, 3>{5000, -2500, 3000}));
  EXPECT_EQ(r.payload_1, 0);
}

}  // namespace
}  // namespace bp::daoai
