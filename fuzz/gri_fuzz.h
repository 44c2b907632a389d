// One GRI format's request and response decoders (comms/gri_message.h). A
// decoded message re-encodes, and decoding that encoding gives the same
// message (the fixed-point and float fields survive the round trip).
#pragma once

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <span>
#include <vector>

#include "comms/gri_message.h"

namespace bp::fuzz {

inline void CheckGri(gri::Format format, const uint8_t* data, size_t size) {
  // The message's first byte(s) are the format's magic, so that the decoder
  // gets past the magic check; the rest is the fuzzer's.
  std::vector<uint8_t> bytes(data, data + size);
  if (format == gri::Format::kV2) {
    if (!bytes.empty()) bytes[0] = gri::kV2Magic;
  } else {
    for (size_t i = 0; i < bytes.size() && i < gri::kOfficialMagic.size(); ++i) {
      bytes[i] = gri::kOfficialMagic[i];
    }
  }
  gri::Fault fault{};
  Result<gri::Request> request = gri::DecodeRequest(bytes, &fault);
  if (request.ok()) {
    if (request->format != format) std::abort();
    Result<std::vector<uint8_t>> encoded = gri::EncodeRequest(*request);
    if (encoded.ok()) {
      Result<gri::Request> again = gri::DecodeRequest(*encoded);
      if (!again.ok() || again->action != request->action || again->job_id != request->job_id ||
          again->data != request->data || again->pose_format != request->pose_format) {
        std::abort();
      }
    }
  } else {
    (void)gri::CodeFor(fault);
  }
  Result<gri::Response> response = gri::DecodeResponse(bytes);
  if (response.ok()) {
    Result<std::vector<uint8_t>> encoded = gri::EncodeResponse(*response);
    if (encoded.ok()) {
      Result<gri::Response> again = gri::DecodeResponse(*encoded);
      if (!again.ok() || again->data != response->data || again->job_id != response->job_id ||
          again->error_code != response->error_code) {
        std::abort();
      }
    }
  }
}

}  // namespace bp::fuzz
