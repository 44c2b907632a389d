// DaoAI messages in Modbus holding registers (seed 000, UR Modbus TCP).
//
// Each field of daoai_message.h is one 16-bit register holding an int16 in
// two's complement: request field i at map.request_base + i (12 registers),
// response field i at map.response_base + i (16 registers). Metres and
// radians x MULT (10000) fit in +-3.2767.
//
// Range (docs/protocols.md "Modbus TCP / Value range"): a value is never
// wrapped. Robot -> binpick can not overflow (int16 widens to int32).
// binpick -> robot:
//   - payload_1 of OBJECTS_FOUND / DROP_OFF_POSE (objects remaining x MULT)
//     saturates at 32767: the robot reads 3.2767, "3 or more left"; the seed
//     programs only test it against 0, so every decision they make is kept;
//   - any other field that does not fit (a pose field, a class id >= 4, a
//     precision error >= 3.2767 mm, ...) refuses the whole response:
//     EncodeResponse returns OutOfRange and the master answers
//     RefusedResponse() instead (status UNKNOWN_COMMAND, pose and payloads 0)
//     so the robot never moves to, or acts on, a clipped value.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "comms/daoai_message.h"
#include "core/status.h"

namespace bp::modbus {

inline constexpr int kMaxReadRegisters = 125;  // Modbus FC3 limit

// The handshake's marker (docs/protocols.md "Modbus TCP / Handshake"):
// INT16_MIN, written to the request's last register (request_base + 11,
// the request's meta_2) with a response that leaves 1 in the request flag
// register. The robot writes that register last before the flag, and a
// request's meta_2 is 1 or 2, never the marker. In the seed map it is
// register 139, the response's payload_4 (unused by every command): the
// robot reads payload_4 = -3.2768 after such a response.
inline constexpr uint16_t kMarker = 0x8000;
inline constexpr int kMarkerField = 11;  // request field index

inline uint16_t ToRegister(int16_t v) { return static_cast<uint16_t>(v); }
inline int16_t FromRegister(uint16_t r) { return static_cast<int16_t>(r); }

// Robot side (what send_robot_data writes). @returns OutOfRange naming the
// field when one does not fit in int16.
Result<std::array<uint16_t, daoai::kRequestFields>> EncodeRequest(const daoai::Request& request);
daoai::Request DecodeRequest(std::span<const uint16_t, daoai::kRequestFields> registers);

// binpick side, with the range policy above. `saturated` (optional) receives
// one line per saturated field. @returns OutOfRange naming the first refused
// field.
Result<std::array<uint16_t, daoai::kResponseFields>> EncodeResponse(
    const daoai::Response& response, std::vector<std::string>* saturated = nullptr);
daoai::Response DecodeResponse(std::span<const uint16_t, daoai::kResponseFields> registers);

// The response sent instead of one that does not fit: status
// UNKNOWN_COMMAND, meta_1 / meta_2 of `original`, every other field 0.
daoai::Response RefusedResponse(const daoai::Response& original);

}  // namespace bp::modbus
