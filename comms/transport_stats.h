// Counters a socket server keeps for monitoring (binpickd's /metrics).
// Values are totals since the server started, read without stopping it.
#pragma once

#include <cstdint>

namespace bp {

struct TransportStats {
  uint64_t accepted = 0;         // connections accepted
  uint64_t open = 0;             // connections open now
  uint64_t read_timeouts = 0;    // connections closed for silence (read timeout)
  // Requests the server could not take as they came: unframeable or
  // undecodable bytes (GRI), too many requests without waiting for answers.
  uint64_t protocol_errors = 0;
  // Connections closed at accept, by reason (docs/reliability.md "Limits").
  uint64_t refused_allowlist = 0;
  uint64_t refused_max_connections = 0;
  uint64_t refused_per_peer = 0;
  uint64_t accept_errors = 0;  // failed accepts (out of descriptors: retried with a pause)
};

}  // namespace bp
