#include "comms/gri_message.h"

#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include "core/conventions.h"

namespace bp::gri {
namespace {

// Little-endian field access at byte offsets.
template <typename T>
T Read(std::span<const uint8_t> b, size_t at) {
  using U = std::make_unsigned_t<std::conditional_t<std::is_floating_point_v<T>, int32_t, T>>;
  U u = 0;
  for (size_t i = 0; i < sizeof(T); ++i) u |= static_cast<U>(U{b[at + i]} << (8 * i));
  return std::bit_cast<T>(u);
}

template <typename T>
void Write(std::vector<uint8_t>& b, size_t at, T value) {
  using U = std::make_unsigned_t<std::conditional_t<std::is_floating_point_v<T>, int32_t, T>>;
  const U u = std::bit_cast<U>(value);
  for (size_t i = 0; i < sizeof(T); ++i) b[at + i] = static_cast<uint8_t>(u >> (8 * i));
}

template <typename Int>
Result<Int> Narrow(int64_t v, const char* what) {
  if (v < std::numeric_limits<Int>::min() || v > std::numeric_limits<Int>::max()) {
    return Status::OutOfRange(std::string("gri: ") + what + " " + std::to_string(v) +
                              " does not fit in " + std::to_string(8 * sizeof(Int)) + " bits");
  }
  return static_cast<Int>(v);
}

std::string Fmt(Format f) { return std::string(ToString(f)); }

// Writes header + job id; @returns the offset after the job id.
Result<size_t> WriteHead(std::vector<uint8_t>& b, Format f, size_t length, uint8_t pose_format,
                         uint8_t action, int32_t job_id) {
  const bool v2 = f == Format::kV2;
  const size_t magic = v2 ? 1 : 4;
  if (v2) {
    b[0] = kV2Magic;
  } else {
    std::memcpy(b.data(), kOfficialMagic.data(), magic);
  }
  b[magic] = v2 ? kV2Version : kOfficialVersion;
  b[magic + 1] = static_cast<uint8_t>(length);
  b[magic + 2] = pose_format;
  b[magic + 3] = action;
  const size_t id_at = magic + 4;
  if (v2) {
    Result<int8_t> id = Narrow<int8_t>(job_id, "job_id");
    if (!id.ok()) return id.status();
    Write<int8_t>(b, id_at, *id);
    return id_at + 1;
  }
  Result<uint16_t> id = Narrow<uint16_t>(job_id, "job_id");
  if (!id.ok()) return id.status();
  Write<uint16_t>(b, id_at, *id);
  return id_at + 2;
}

Status WritePose(std::vector<uint8_t>& b, Format f, size_t at, const std::array<double, 7>& pose) {
  for (size_t i = 0; i < 7; ++i) {
    if (!std::isfinite(pose[i])) {
      return Status::InvalidArgument("gri: pose value " + std::to_string(i + 1) + " is not finite");
    }
    if (f == Format::kV2) {
      Write<float>(b, at + 4 * i, static_cast<float>(pose[i]));
    } else {
      Result<int32_t> v = ToFixed(pose[i], kOfficialPoseScale);
      if (!v.ok()) return v.status();
      Write<int32_t>(b, at + 4 * i, *v);
    }
  }
  return Status::Ok();
}

std::array<double, 7> ReadPose(std::span<const uint8_t> b, Format f, size_t at) {
  std::array<double, 7> pose{};
  for (size_t i = 0; i < 7; ++i) {
    pose[i] = f == Format::kV2 ? static_cast<double>(Read<float>(b, at + 4 * i))
                               : FromFixed(Read<int32_t>(b, at + 4 * i), kOfficialPoseScale);
  }
  return pose;
}

// Common header checks of requests and responses. `expected` is the message
// size of the format.
Status CheckFrame(std::span<const uint8_t> b, Format& f, size_t (*expected)(Format), Fault& fault) {
  if (b.empty() || !DetectFormat(b[0])) {
    fault = Fault::kWrongMagic;
    return Status::Corruption(b.empty() ? "gri: empty message"
                                        : "gri: wrong magic: first byte " + std::to_string(b[0]) +
                                              " is neither 2 (v2) nor 'G' (official)");
  }
  f = *DetectFormat(b[0]);
  const size_t header = HeaderSize(f);
  if (b.size() < header) {
    fault = Fault::kShort;
    return Status::Corruption("gri: " + Fmt(f) + " message of " + std::to_string(b.size()) +
                              " bytes is shorter than its " + std::to_string(header) +
                              "-byte header");
  }
  if (f == Format::kOfficial && std::memcmp(b.data(), kOfficialMagic.data(), 4) != 0) {
    fault = Fault::kWrongMagic;
    return Status::Corruption("gri: wrong magic: official messages start with \"GRI\\0\"");
  }
  const uint8_t version = b[1 + (f == Format::kOfficial ? 3 : 0)];
  const uint8_t want_version = f == Format::kV2 ? kV2Version : kOfficialVersion;
  if (version != want_version) {
    fault = Fault::kWrongVersion;
    return Status::InvalidArgument("gri: " + Fmt(f) + " message has protocol version " +
                                   std::to_string(version) + ", expected " +
                                   std::to_string(want_version));
  }
  const uint8_t length = b[2 + (f == Format::kOfficial ? 3 : 0)];
  if (length != b.size()) {
    fault = Fault::kLengthMismatch;
    return Status::Corruption("gri: length field says " + std::to_string(length) +
                              " bytes but the message has " + std::to_string(b.size()));
  }
  if (b.size() != expected(f)) {
    fault = b.size() < expected(f) ? Fault::kShort : Fault::kLong;
    return Status::Corruption("gri: " + Fmt(f) + " message is " + std::to_string(b.size()) +
                              " bytes, expected " + std::to_string(expected(f)));
  }
  return Status::Ok();
}

// Reads pose format, action and job id of a checked frame; @returns v2-ness.
template <typename Message>
bool ReadHead(std::span<const uint8_t> b, Message& m) {
  const bool v2 = m.format == Format::kV2;
  m.pose_format = b[v2 ? 3 : 6];
  m.action = b[v2 ? 4 : 7];
  m.job_id = v2 ? Read<int8_t>(b, 5) : Read<uint16_t>(b, 8);
  return v2;
}

}  // namespace

std::string_view ToString(Format f) { return f == Format::kV2 ? "v2" : "official"; }

size_t HeaderSize(Format f) { return f == Format::kV2 ? kV2HeaderSize : kOfficialHeaderSize; }
size_t RequestSize(Format f) { return f == Format::kV2 ? kV2RequestSize : kOfficialRequestSize; }
size_t ResponseSize(Format f) { return f == Format::kV2 ? kV2ResponseSize : kOfficialResponseSize; }

std::optional<Format> DetectFormat(uint8_t first_byte) {
  if (first_byte == kV2Magic) return Format::kV2;
  if (first_byte == kOfficialMagic[0]) return Format::kOfficial;
  return std::nullopt;
}

int32_t WireErrorCode(Format f, Code c) {
  const bool v2 = f == Format::kV2;
  // clang-format off
  switch (c) {
    case Code::kOk: return 0;
    case Code::kUnknownError: return v2 ? 1 : -1;
    case Code::kInternalError: return v2 ? 2 : -2;
    case Code::kPipelineNotAvailable: return v2 ? 4 : -5;
    case Code::kInvalidRequest: return v2 ? 5 : -6;
    case Code::kInvalidRequestLength: return v2 ? 6 : -7;
    case Code::kInvalidAction: return v2 ? 7 : -8;
    case Code::kProcessingTimeout: return v2 ? 8 : -9;
    case Code::kUnknownProtocolVersion: return v2 ? 9 : -10;
    case Code::kJobDoesNotExist: return v2 ? 10 : -12;
    case Code::kNoPosesFound: return v2 ? 13 : 1;
    case Code::kNoRelatedPoses: return v2 ? 14 : 2;
    case Code::kJobStillRunning: return v2 ? 16 : 4;
    case Code::kNotImplemented: return v2 ? 100 : -14;
    case Code::kHecConfigError: return v2 ? 17 : -14;
    case Code::kHecInitError: return v2 ? 18 : -15;
    case Code::kHecSetPoseError: return v2 ? 19 : -16;
    case Code::kHecCalibrateError: return v2 ? 20 : -17;
    case Code::kHecInsufficientDetection: return v2 ? 21 : -18;
  }
  // clang-format on
  return v2 ? 1 : -1;
}

Code CodeFor(Fault fault) {
  switch (fault) {
    case Fault::kShort:
    case Fault::kLong:
    case Fault::kLengthMismatch:
      return Code::kInvalidRequestLength;
    case Fault::kWrongMagic:
      return Code::kInvalidRequest;
    case Fault::kWrongVersion:
      return Code::kUnknownProtocolVersion;
    case Fault::kUnknownAction:
      return Code::kInvalidAction;
    case Fault::kUnknownPoseFormat:
      return Code::kInvalidRequest;
  }
  return Code::kInvalidRequest;
}

Result<Request> DecodeRequest(std::span<const uint8_t> b, Fault* fault) {
  Fault local = Fault::kShort;
  Fault& out = fault ? *fault : local;
  Request r;
  if (Status s = CheckFrame(b, r.format, &RequestSize, out); !s.ok()) return s;
  const bool v2 = ReadHead(b, r);
  const size_t pose_at = v2 ? 6 : 10;
  r.pose = ReadPose(b, r.format, pose_at);
  for (size_t i = 0; i < 4; ++i) r.data[i] = Read<int32_t>(b, pose_at + 28 + 4 * i);
  if (r.action < kStatus || r.action > kHecCalibrate) {
    out = Fault::kUnknownAction;
    return Status::InvalidArgument("gri: unknown action " + std::to_string(r.action) +
                                   " (valid: 1..9)");
  }
  if (r.pose_format > kMaxPoseFormat) {
    out = Fault::kUnknownPoseFormat;
    return Status::InvalidArgument("gri: unknown pose format " + std::to_string(r.pose_format) +
                                   " (valid: 1..10)");
  }
  return r;
}

Result<std::vector<uint8_t>> EncodeRequest(const Request& r) {
  std::vector<uint8_t> b(RequestSize(r.format));
  Result<size_t> at = WriteHead(b, r.format, b.size(), r.pose_format, r.action, r.job_id);
  if (!at.ok()) return at.status();
  if (Status s = WritePose(b, r.format, *at, r.pose); !s.ok()) return s;
  for (size_t i = 0; i < 4; ++i) Write<int32_t>(b, *at + 28 + 4 * i, r.data[i]);
  return b;
}

Result<Response> DecodeResponse(std::span<const uint8_t> b) {
  Fault fault;
  Response r;
  if (Status s = CheckFrame(b, r.format, &ResponseSize, fault); !s.ok()) return s;
  const bool v2 = ReadHead(b, r);
  r.error_code = v2 ? Read<int8_t>(b, 6) : Read<int16_t>(b, 10);
  const size_t pose_at = v2 ? 7 : 12;
  r.pose = ReadPose(b, r.format, pose_at);
  for (size_t i = 0; i < (v2 ? 5u : 10u); ++i) r.data[i] = Read<int32_t>(b, pose_at + 28 + 4 * i);
  return r;
}

Result<std::vector<uint8_t>> EncodeResponse(const Response& r) {
  const bool v2 = r.format == Format::kV2;
  std::vector<uint8_t> b(ResponseSize(r.format));
  Result<size_t> at = WriteHead(b, r.format, b.size(), r.pose_format, r.action, r.job_id);
  if (!at.ok()) return at.status();
  if (v2) {
    Result<int8_t> code = Narrow<int8_t>(r.error_code, "error_code");
    if (!code.ok()) return code.status();
    Write<int8_t>(b, 6, *code);
  } else {
    Result<int16_t> code = Narrow<int16_t>(r.error_code, "error_code");
    if (!code.ok()) return code.status();
    Write<int16_t>(b, 10, *code);
  }
  const size_t pose_at = *at + (v2 ? 1 : 2);
  if (Status s = WritePose(b, r.format, pose_at, r.pose); !s.ok()) return s;
  const size_t n = v2 ? 5 : 10;
  for (size_t i = n; i < r.data.size(); ++i) {
    if (r.data[i] != 0) {
      return Status::InvalidArgument("gri: v2 responses carry data_1..5; data_" +
                                     std::to_string(i + 1) + " is set");
    }
  }
  for (size_t i = 0; i < n; ++i) Write<int32_t>(b, pose_at + 28 + 4 * i, r.data[i]);
  return b;
}

}  // namespace bp::gri
