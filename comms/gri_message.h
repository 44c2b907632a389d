// Roboception Generic Robot Interface (GRI) messages, in two wire formats
// (docs/protocols.md, "GRI"). Both are little-endian and fixed-length.
//
// Protocol v2 (seed 002), default port 10000:
//   Header, 5 bytes: magic int8 = 2, version int8 = 2, length int8,
//                    pose_format int8, action int8.
//   Request, 50 bytes:  [0..4] header, [5] job_id int8,
//                       [6..33] pose 7 x float32, [34..49] data_1..4 int32.
//   Response, 55 bytes: [0..4] header (magic 2, length 55), [5] job_id int8,
//                       [6] error_code int8, [7..34] pose 7 x float32,
//                       [35..54] data_1..5 int32.
// The official format, called "protocol V1" by its documentation, port 7100:
//   Header, 8 bytes: magic uint32 = bytes "GRI\0", version uint8 = 1,
//                    length uint8, pose_format uint8, action uint8.
//   Request, 54 bytes:  [0..7] header, [8..9] job_id uint16,
//                       [10..37] pose 7 x int32, [38..53] data_1..4 int32.
//   Response, 80 bytes: [0..7] header (length 80), [8..9] job_id uint16,
//                       [10..11] error_code int16, [12..39] pose 7 x int32,
//                       [40..79] data_1..10 int32.
//   Every official pose component is value x 1,000,000 (positions in mm),
//   rounded to nearest and range-checked: never wraps.
//
// Request / Response below hold either format. Pose values are in wire units
// (the unit the pose format names; official positions always in mm), already
// unscaled from fixed point.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string_view>
#include <vector>

#include "core/status.h"

namespace bp::gri {

enum class Format : uint8_t { kV2, kOfficial };
std::string_view ToString(Format f);

inline constexpr size_t kV2HeaderSize = 5;
inline constexpr size_t kV2RequestSize = 50;
inline constexpr size_t kV2ResponseSize = 55;
inline constexpr uint8_t kV2Magic = 2;  // requests and responses (seed 002 "Protocol Constants")
inline constexpr uint8_t kV2Version = 2;

inline constexpr size_t kOfficialHeaderSize = 8;
inline constexpr size_t kOfficialRequestSize = 54;
inline constexpr size_t kOfficialResponseSize = 80;
inline constexpr std::array<uint8_t, 4> kOfficialMagic = {'G', 'R', 'I', 0};  // uint32 0x00495247
inline constexpr uint8_t kOfficialVersion = 1;
inline constexpr double kOfficialPoseScale = 1e6;

size_t HeaderSize(Format f);
size_t RequestSize(Format f);
size_t ResponseSize(Format f);
// The format a message starting with `first_byte` is in: 2 -> v2, 'G' -> official.
std::optional<Format> DetectFormat(uint8_t first_byte);

enum Action : uint8_t {
  kStatus = 1,
  kTriggerJobSync = 2,
  kTriggerJobAsync = 3,
  kGetJobStatus = 4,
  kGetNextPose = 5,
  kGetRelatedPose = 6,
  kHecInit = 7,
  kHecSetPose = 8,
  kHecCalibrate = 9,
};
inline constexpr uint8_t kMaxPoseFormat = 10;  // core/conventions.h GriPoseFormat

// Job status (data_1 in v2, data_2 in the official format).
enum class JobStatus : int32_t { kInactive = 1, kRunning = 2, kDone = 3, kFailed = 4 };

// What an answer says, independent of the format; WireErrorCode maps it.
enum class Code {
  kOk,
  kUnknownError,
  kInternalError,
  kPipelineNotAvailable,
  kInvalidRequest,
  kInvalidRequestLength,
  kInvalidAction,
  kProcessingTimeout,
  kUnknownProtocolVersion,
  kJobDoesNotExist,
  kNoPosesFound,
  kNoRelatedPoses,  // v2: NO_ASSOCIATED_OBJECTS
  kJobStillRunning,
  kNotImplemented,  // official: HEC_CONFIG_ERROR (it has no NOT_IMPLEMENTED)
  kHecConfigError,            // v2 17 / official -14
  kHecInitError,              // 18 / -15
  kHecSetPoseError,           // 19 / -16
  kHecCalibrateError,         // 20 / -17
  kHecInsufficientDetection,  // 21 / -18
};
// v2: int8 codes of seed 002; official: int16, negative errors, positive warnings.
int32_t WireErrorCode(Format f, Code c);

struct Request {
  Format format = Format::kV2;
  uint8_t pose_format = 0;
  uint8_t action = 0;
  int32_t job_id = 0;            // v2: -128..127; official: 0..65535
  std::array<double, 7> pose{};  // x, y, z, rot_1..rot_4 in wire units
  std::array<int32_t, 4> data{};
};

struct Response {
  Format format = Format::kV2;
  uint8_t pose_format = 0;
  uint8_t action = 0;
  int32_t job_id = 0;
  int32_t error_code = 0;          // wire value (WireErrorCode)
  std::array<double, 7> pose{};    // wire units
  std::array<int32_t, 10> data{};  // v2 carries data_1..5 only
};

// Why a request cannot be decoded; each has its answer (docs/protocols.md).
enum class Fault {
  kShort,              // fewer bytes than the format's request size
  kLong,               // more bytes than the format's request size
  kWrongMagic,         // first byte(s) are neither format's magic
  kLengthMismatch,     // the length field disagrees with the bytes given
  kWrongVersion,       // magic of one format, another version
  kUnknownAction,      // action outside 1..9
  kUnknownPoseFormat,  // pose format outside 0..10
};
Code CodeFor(Fault fault);

// Decodes one whole request; the format is taken from the first byte. On
// failure the status names the fault precisely and `fault`, if given, is set.
// Checks, in order: magic, short header, version, length field vs size,
// size vs the format's request size, action, pose format. Pose format 0 is
// accepted here (actions without a pose send it); actions that need a pose
// reject it.
Result<Request> DecodeRequest(std::span<const uint8_t> bytes, Fault* fault = nullptr);
// @returns OutOfRange when job_id or a fixed-point pose value does not fit,
// InvalidArgument for a non-finite pose value.
Result<std::vector<uint8_t>> EncodeRequest(const Request& request);

Result<Response> DecodeResponse(std::span<const uint8_t> bytes);
// @returns OutOfRange when job_id, error_code or a fixed-point pose value does
// not fit, InvalidArgument for a non-finite pose value or data_6..10 set in v2.
Result<std::vector<uint8_t>> EncodeResponse(const Response& response);

}  // namespace bp::gri
