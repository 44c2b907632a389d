// The Modbus register block (comms/modbus_codec.h): the 12 request registers
// and 16 response registers a master reads, and the register map a cell
// declares. Response encoding never wraps: what it encodes decodes to the
// same response, or it refuses.
#include <array>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "comms/modbus_codec.h"
#include "core/cell.h"

namespace {

uint16_t Reg(const uint8_t* data, size_t i) {
  return static_cast<uint16_t>(data[2 * i] | (data[2 * i + 1] << 8));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace bp;
  constexpr size_t kReq = daoai::kRequestFields, kResp = daoai::kResponseFields;
  if (size >= 2 * kReq) {
    std::array<uint16_t, kReq> regs{};
    for (size_t i = 0; i < kReq; ++i) regs[i] = Reg(data, i);
    const daoai::Request request = modbus::DecodeRequest(regs);
    Result<std::array<uint16_t, kReq>> again = modbus::EncodeRequest(request);
    if (!again.ok() || *again != regs) std::abort();
  }
  if (size >= 2 * kResp) {
    std::array<uint16_t, kResp> regs{};
    for (size_t i = 0; i < kResp; ++i) regs[i] = Reg(data, i);
    const daoai::Response response = modbus::DecodeResponse(regs);
    std::vector<std::string> saturated;
    Result<std::array<uint16_t, kResp>> again = modbus::EncodeResponse(response, &saturated);
    if (again.ok() && saturated.empty() && modbus::DecodeResponse(*again) != response) std::abort();
    // A response in int32 range: encoded exactly, saturated, or refused.
    daoai::Response wide = response;
    if (size >= 2 * kResp + 8) {
      int32_t a = 0, b = 0;
      std::memcpy(&a, data + 2 * kResp, 4);
      std::memcpy(&b, data + 2 * kResp + 4, 4);
      wide.payload[0] = a;
      wide.position[0] = b;
      Result<std::array<uint16_t, kResp>> w = modbus::EncodeResponse(wide, &saturated);
      if (w.ok()) {
        const daoai::Response back = modbus::DecodeResponse(*w);
        if (back.position[0] != b) std::abort();  // a pose field is never clipped
      } else {
        (void)modbus::EncodeResponse(modbus::RefusedResponse(wide));
      }
    }
  }
  if (size >= 16) {
    // The map from the input's last 16 bytes, as four int32.
    std::array<int32_t, 4> v{};
    std::memcpy(v.data(), data + size - 16, 16);
    ModbusRegisterMap map;
    map.request_base = v[0];
    map.response_base = v[1];
    map.request_flag = v[2];
    map.response_flag = v[3];
    (void)ValidateModbusRegisterMap(map);
  }
  return 0;
}
