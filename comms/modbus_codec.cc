#include "comms/modbus_codec.h"

#include <limits>

namespace bp::modbus {
namespace {

constexpr int32_t kMin = std::numeric_limits<int16_t>::min();
constexpr int32_t kMax = std::numeric_limits<int16_t>::max();

bool Fits(int32_t v) { return v >= kMin && v <= kMax; }

std::array<int32_t, daoai::kRequestFields> Fields(const daoai::Request& r) {
  return {r.position[0],    r.position[1],    r.position[2],   r.orientation[0],
          r.orientation[1], r.orientation[2], r.orientation[3], r.command,
          r.payload_1,      r.payload_2,      r.meta_1,         r.meta_2};
}

std::array<int32_t, daoai::kResponseFields> Fields(const daoai::Response& r) {
  return {r.position[0],    r.position[1],    r.position[2],    r.orientation[0],
          r.orientation[1], r.orientation[2], r.orientation[3], r.payload[0],
          r.payload[1],     r.payload[2],     r.payload[3],     r.payload[4],
          r.payload[5],     r.status,         r.meta_1,         r.meta_2};
}

const char* const kResponseNames[daoai::kResponseFields] = {
    "position x",  "position y",  "position z",  "orientation 1", "orientation 2", "orientation 3",
    "orientation 4", "payload_1", "payload_2", "payload_3",   "payload_4",     "payload_5",
    "payload_6",   "status",      "meta_1",      "meta_2"};
const char* const kRequestNames[daoai::kRequestFields] = {
    "position x",    "position y", "position z", "orientation 1", "orientation 2", "orientation 3",
    "orientation 4", "command",    "payload_1",  "payload_2",     "meta_1",        "meta_2"};

}  // namespace

Result<std::array<uint16_t, daoai::kRequestFields>> EncodeRequest(const daoai::Request& request) {
  const auto f = Fields(request);
  std::array<uint16_t, daoai::kRequestFields> regs{};
  for (size_t i = 0; i < f.size(); ++i) {
    if (!Fits(f[i])) {
      return Status::OutOfRange(std::string("request ") + kRequestNames[i] + " " +
                                std::to_string(f[i]) + " does not fit an int16 register");
    }
    regs[i] = ToRegister(static_cast<int16_t>(f[i]));
  }
  return regs;
}

daoai::Request DecodeRequest(std::span<const uint16_t, daoai::kRequestFields> r) {
  daoai::Request q;
  for (int i = 0; i < 3; ++i) q.position[i] = FromRegister(r[i]);
  for (int i = 0; i < 4; ++i) q.orientation[i] = FromRegister(r[3 + i]);
  q.command = FromRegister(r[7]);
  q.payload_1 = FromRegister(r[8]);
  q.payload_2 = FromRegister(r[9]);
  q.meta_1 = FromRegister(r[10]);
  q.meta_2 = FromRegister(r[11]);
  return q;
}

Result<std::array<uint16_t, daoai::kResponseFields>> EncodeResponse(
    const daoai::Response& response, std::vector<std::string>* saturated) {
  const auto f = Fields(response);
  const bool has_count =
      response.status == daoai::kObjectsFound || response.status == daoai::kDropOffPose;
  std::array<uint16_t, daoai::kResponseFields> regs{};
  for (size_t i = 0; i < f.size(); ++i) {
    int32_t v = f[i];
    if (!Fits(v)) {
      if (i == 7 && has_count) {  // payload_1: objects remaining
        if (saturated) {
          saturated->push_back("payload_1 (objects remaining x MULT) " + std::to_string(v) +
                               " saturated to " + std::to_string(v > 0 ? kMax : kMin));
        }
        v = v > 0 ? kMax : kMin;
      } else {
        return Status::OutOfRange(std::string("response ") + kResponseNames[i] + " " +
                                  std::to_string(v) + " (status " +
                                  std::to_string(response.status) +
                                  ") does not fit an int16 register");
      }
    }
    regs[i] = ToRegister(static_cast<int16_t>(v));
  }
  return regs;
}

daoai::Response DecodeResponse(std::span<const uint16_t, daoai::kResponseFields> r) {
  daoai::Response p;
  for (int i = 0; i < 3; ++i) p.position[i] = FromRegister(r[i]);
  for (int i = 0; i < 4; ++i) p.orientation[i] = FromRegister(r[3 + i]);
  for (int i = 0; i < 6; ++i) p.payload[i] = FromRegister(r[7 + i]);
  p.status = FromRegister(r[13]);
  p.meta_1 = FromRegister(r[14]);
  p.meta_2 = FromRegister(r[15]);
  return p;
}

daoai::Response RefusedResponse(const daoai::Response& original) {
  daoai::Response r;
  r.status = daoai::kUnknownCommand;
  r.meta_1 = original.meta_1;
  r.meta_2 = original.meta_2;
  return r;
}

}  // namespace bp::modbus
