// The GRI socket server: both wire formats (comms/gri_message.h) on one
// listener, requests handled by a GriHandler. Boost.Asio lives in the .cc.
//
// Two ports by default, v2 (10000) and official (7100); each serves both
// formats, told apart per message by the first byte (2 or 'G'). The port
// only picks the format of the answer to a message whose first byte is
// neither.
//
// Per connection (one strand each), framing and recovery:
//  - reads the first byte, then the rest of the header, then the body, as
//    the header's format says; a short read is completed, never taken for a
//    message (a robot that stops half-way is closed by the read timeout);
//  - wrong magic or a length field other than the format's request size:
//    the stream cannot be re-synchronised, so the answer is
//    INVALID_REQUEST_ERROR / INVALID_REQUEST_LENGTH and the connection is
//    closed after writing it;
//  - wrong version, unknown action, unknown pose format: the message was
//    framed correctly, so it is answered with its error and the connection
//    stays open;
//  - requests that arrive while one is in progress are queued (at most
//    max_queued_requests) and answered in order;
//  - a request without an answer after processing_timeout is answered
//    PROCESSING_TIMEOUT; its late result is dropped (nothing popped);
//  - read timeout as the DaoAI server.
#pragma once

#include <chrono>
#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "comms/gri_handler.h"
#include "comms/transport_stats.h"
#include "core/status.h"

namespace bp {

struct GriServerOptions {
  std::string bind = "127.0.0.1";
  // 0 disables a port; -1 asks for an ephemeral one (tests). At least one
  // port must be enabled.
  int v2_port = 10000;
  int official_port = 7100;
  std::chrono::milliseconds read_timeout{30000};
  std::chrono::milliseconds processing_timeout{70000};
  size_t max_queued_requests = 16;
  int io_threads = 1;
  // As DaoaiServerOptions (docs/reliability.md "Limits", "Security").
  size_t max_connections = 64;
  size_t max_connections_per_peer = 16;
  double max_message_rate = 0;
  std::vector<std::string> allowlist;
  std::vector<std::string> config_allowlist;  // HEC actions
  std::chrono::seconds keepalive_idle{10};
  std::chrono::seconds keepalive_interval{2};
  int keepalive_probes = 3;
};

class GriServer {
 public:
  // `handler` must outlive the server. @returns InvalidArgument for a bad
  // address or port (or none enabled), Unavailable when a port cannot be bound.
  static Result<std::unique_ptr<GriServer>> Start(GriHandler& handler,
                                                  const GriServerOptions& options);
  ~GriServer();  // Stop()
  GriServer(const GriServer&) = delete;
  GriServer& operator=(const GriServer&) = delete;

  int v2_port() const;           // bound port; 0 when disabled
  int official_port() const;     // bound port; 0 when disabled
  std::string Describe() const;  // "v2 127.0.0.1:10000, official 127.0.0.1:7100"
  size_t connection_count() const;
  TransportStats stats() const;  // thread-safe
  uint64_t refused_count() const;  // connections closed at accept (limits, allowlist)
  void Stop();  // idempotent

 private:
  class Impl;
  explicit GriServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
