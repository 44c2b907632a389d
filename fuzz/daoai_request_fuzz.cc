// DaoAI request / response (comms/daoai_message.h): every 48 bytes decode, and
// encoding the decoded message gives the same bytes back.
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <span>

#include "comms/daoai_message.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace bp::daoai;
  if (size >= kRequestSize) {
    std::span<const uint8_t, kRequestSize> bytes(data, kRequestSize);
    const Request request = DecodeRequest(bytes);
    const auto again = EncodeRequest(request);
    if (std::memcmp(again.data(), data, kRequestSize) != 0) std::abort();
  }
  if (size >= kResponseSize) {
    std::span<const uint8_t, kResponseSize> bytes(data, kResponseSize);
    const Response response = DecodeResponse(bytes);
    const auto again = EncodeResponse(response);
    if (std::memcmp(again.data(), data, kResponseSize) != 0) std::abort();
  }
  return 0;
}
