// The DaoAI-style socket protocol's fixed-length messages (seeds 000, 003, 004).
//
// Every field is an int32 in network byte order (big-endian), two's
// complement. Seed 004 says "one's complement"; robot controllers send two's
// complement, so that is what binpick reads and writes (docs/protocols.md).
// There are no framing bytes: a message is kRequestSize / kResponseSize bytes
// by count.
//
// Request, 12 int32 = 48 bytes:
//   [0..2]  position x, y, z        (metres * MULT)
//   [3..6]  orientation (4 fields, robot convention, * MULT)
//   [7]     command
//   [8..9]  payload_1, payload_2
//   [10]    meta_1 robot type       [11] meta_2 protocol version
// Response, 16 int32 = 64 bytes:
//   [0..2]  position   [3..6] orientation   [7..12] payload_1..6
//   [13]    status     [14] meta_1          [15] meta_2
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace bp::daoai {

inline constexpr size_t kRequestFields = 12;
inline constexpr size_t kResponseFields = 16;
inline constexpr size_t kRequestSize = kRequestFields * 4;    // 48 bytes
inline constexpr size_t kResponseSize = kResponseFields * 4;  // 64 bytes

struct Request {
  std::array<int32_t, 3> position{};
  std::array<int32_t, 4> orientation{};
  int32_t command = 0;
  int32_t payload_1 = 0;
  int32_t payload_2 = 0;
  int32_t meta_1 = 0;
  int32_t meta_2 = 0;
  friend bool operator==(const Request&, const Request&) = default;
};

struct Response {
  std::array<int32_t, 3> position{};
  std::array<int32_t, 4> orientation{};
  std::array<int32_t, 6> payload{};
  int32_t status = 0;
  int32_t meta_1 = 0;
  int32_t meta_2 = 0;
  friend bool operator==(const Response&, const Response&) = default;
};

// Any 48 bytes are a syntactically valid request: validation of the command
// and meta fields is the request handler's job.
Request DecodeRequest(std::span<const uint8_t, kRequestSize> bytes);
std::array<uint8_t, kRequestSize> EncodeRequest(const Request& request);
Response DecodeResponse(std::span<const uint8_t, kResponseSize> bytes);
std::array<uint8_t, kResponseSize> EncodeResponse(const Response& response);

// Robot commands (seed 000 "机器人发送指令常量", seed 004 "Requests").
enum Command : int32_t {
  kNoCommand = -1,  // pose update, no response
  kStartManualCalibration = 1,
  kStopManualCalibration = 2,
  kStartAutoCalibration = 4,
  kManualAccumulatePose = 6,
  kAutoAccumulatePose = 7,
  kGuidanceCalibration = 10,
  kStart2DAutoCalibration = 11,
  kAutoAccumulate2DPose = 12,
  kCaptureAndProcessAsync = 19,
  kCaptureAndProcess = 20,
  kPickPose = 21,  // seed 004: RC_DAOAI_GET_NEXT_OBJECT
  kSendPose = 30,  // teach pose, no response
  kCheckEmptyBox = 40,
  kPrecisionCheck = 50,
  kSwitchConfig = 69,
  // binpick extension (docs/protocols.md "Failed-pick feedback"): the last
  // grasp of task payload_1 handed to this robot failed; payload_2 the
  // reason (PickFailure: 0 unspecified, 1 vacuum not built, 2 slipped).
  // No seed uses 60 or 61 (seeds 000, 003, 004 list their codes).
  kReportPickFailure = 60,
};

// The commands of a calibration (manual, auto, guided, 2D): each belongs to
// a calibration session, whose solve rewrites the hand-eye file.
constexpr bool IsCalibrationCommand(int32_t command) {
  switch (command) {
    case kStartManualCalibration:
    case kStopManualCalibration:
    case kStartAutoCalibration:
    case kManualAccumulatePose:
    case kAutoAccumulatePose:
    case kGuidanceCalibration:
    case kStart2DAutoCalibration:
    case kAutoAccumulate2DPose:
      return true;
    default:
      return false;
  }
}

// Response statuses. Version-dependent values are noted; see docs/protocols.md.
enum Status : int32_t {
  kUnknownCommand = -1,
  kObjectsFound = 2,
  kNoObjectFound = 3,
  kNoCollisionFreePose = 4,  // version 2 (seed 000)
  kNoImageCaptured = 4,      // version 1 (seed 004)
  kDetection = 5,            // CAPTURE_SUCCESS / DAOAI_DETECTION_MODE
  kDropOffPose = 6,
  kCaptureFail = 9,
  kModeCalibration = 10,
  kModeAutoCalibration = 11,
  kGuidanceGood = 12,
  kGuidanceBad = 13,
  kMode2DAutoCalibration = 14,
  kDoneGuidanceCalibration = 32,
  kDoneCalibration = 33,  // DAOAI_DONE_CALIBRATION / DAOAI_DONE_AUTO_CALIBRATION
  kDone2DAutoCalibration = 34,
  kBoxEmpty = 41,
  kBoxNotEmpty = 42,
  kPrecisionCheckSuccess = 51,
  kPrecisionCheckFail = 52,
  kSwitchConfigSuccess = 66,
  kSwitchConfigFail = 67,
  // binpick extension: answer to 60. payload_1 1 (x MULT) when the spot
  // reached the task's max_failures (binpick will not send the robot there
  // again), else 0.
  kPickFailureNoted = 61,
};

}  // namespace bp::daoai
