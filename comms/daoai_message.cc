#include "comms/daoai_message.h"

namespace bp::daoai {
namespace {

int32_t ReadBE32(const uint8_t* p) {
  const uint32_t u = (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) |
                     uint32_t{p[3]};
  return static_cast<int32_t>(u);  // two's complement (C++20 defines this conversion)
}

void WriteBE32(int32_t v, uint8_t* p) {
  const auto u = static_cast<uint32_t>(v);
  p[0] = static_cast<uint8_t>(u >> 24);
  p[1] = static_cast<uint8_t>(u >> 16);
  p[2] = static_cast<uint8_t>(u >> 8);
  p[3] = static_cast<uint8_t>(u);
}

template <size_t N>
std::array<int32_t, N> ReadFields(const uint8_t* bytes) {
  std::array<int32_t, N> f{};
  for (size_t i = 0; i < N; ++i) f[i] = ReadBE32(bytes + 4 * i);
  return f;
}

template <size_t N>
std::array<uint8_t, 4 * N> WriteFields(const std::array<int32_t, N>& f) {
  std::array<uint8_t, 4 * N> bytes{};
  for (size_t i = 0; i < N; ++i) WriteBE32(f[i], bytes.data() + 4 * i);
  return bytes;
}

}  // namespace

Request DecodeRequest(std::span<const uint8_t, kRequestSize> bytes) {
  const auto f = ReadFields<kRequestFields>(bytes.data());
  Request r;
  for (int i = 0; i < 3; ++i) r.position[i] = f[i];
  for (int i = 0; i < 4; ++i) r.orientation[i] = f[3 + i];
  r.command = f[7];
  r.payload_1 = f[8];
  r.payload_2 = f[9];
  r.meta_1 = f[10];
  r.meta_2 = f[11];
  return r;
}

std::array<uint8_t, kRequestSize> EncodeRequest(const Request& r) {
  return WriteFields<kRequestFields>({r.position[0], r.position[1], r.position[2],
                                      r.orientation[0], r.orientation[1], r.orientation[2],
                                      r.orientation[3], r.command, r.payload_1, r.payload_2,
                                      r.meta_1, r.meta_2});
}

Response DecodeResponse(std::span<const uint8_t, kResponseSize> bytes) {
  const auto f = ReadFields<kResponseFields>(bytes.data());
  Response r;
  for (int i = 0; i < 3; ++i) r.position[i] = f[i];
  for (int i = 0; i < 4; ++i) r.orientation[i] = f[3 + i];
  for (int i = 0; i < 6; ++i) r.payload[i] = f[7 + i];
  r.status = f[13];
  r.meta_1 = f[14];
  r.meta_2 = f[15];
  return r;
}

std::array<uint8_t, kResponseSize> EncodeResponse(const Response& r) {
  std::array<int32_t, kResponseFields> f{};
  for (int i = 0; i < 3; ++i) f[i] = r.position[i];
  for (int i = 0; i < 4; ++i) f[3 + i] = r.orientation[i];
  for (int i = 0; i < 6; ++i) f[7 + i] = r.payload[i];
  f[13] = r.status;
  f[14] = r.meta_1;
  f[15] = r.meta_2;
  return WriteFields(f);
}

}  // namespace bp::daoai
