// The DaoAI socket server: TCP, fixed-length messages (comms/daoai_message.h),
// requests handled by a RequestHandler. Boost.Asio lives in the .cc.
//
// Per connection (one strand each, so its handlers never run concurrently):
//  - reads exactly 48 bytes per request; a short read is completed, never
//    taken for a message;
//  - keeps reading while a request is in progress, so a robot that
//    disconnects is noticed at once and its pending pick pose is not popped;
//    requests that arrive meanwhile are queued (at most max_queued_requests,
//    beyond that the connection is closed) and handled in order;
//  - writes exactly 64 bytes per response, for commands that have one;
//  - is closed when no complete request arrived for read_timeout while no
//    request was in progress (a silent robot, or half a message then silence).
//    Only that connection is affected.
#pragma once

#include <chrono>
#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "comms/request_handler.h"
#include "comms/transport_stats.h"
#include "core/status.h"

namespace bp {

struct DaoaiServerOptions {
  std::string bind = "127.0.0.1";
  int port = 6969;  // 0: an ephemeral port (tests); see DaoaiServer::port()
  std::chrono::milliseconds read_timeout{30000};
  size_t max_queued_requests = 16;
  int io_threads = 1;
  // Limits and allowlist (docs/reliability.md "Limits", "Security"):
  // connections beyond max_connections, and peers not in a non-empty
  // allowlist (exact IP addresses), are closed at accept with a log line; a
  // connection sending more than max_message_rate requests/s is read no
  // faster (nothing dropped). 0: unlimited.
  size_t max_connections = 64;
  size_t max_connections_per_peer = 16;
  double max_message_rate = 0;
  // Addresses or ADDR/PREFIX networks (core/address_list.h).
  std::vector<std::string> allowlist;
  // Peers that may change the cell (calibration, teach, camera config);
  // empty: every peer that may connect (ClientContext::may_change_cell).
  std::vector<std::string> config_allowlist;
  // TCP keepalive: a vanished robot is noticed after idle + interval *
  // probes (docs/reliability.md "Liveness"). 0 idle: off.
  std::chrono::seconds keepalive_idle{10};
  std::chrono::seconds keepalive_interval{2};
  int keepalive_probes = 3;
  int send_buffer_bytes = 0;  // SO_SNDBUF per connection; 0: the kernel's (tests only)
};

class DaoaiServer {
 public:
  // Binds, listens and starts the network thread(s). `handler` must outlive
  // the server. @returns InvalidArgument for a bad address, Unavailable when
  // the port cannot be bound.
  static Result<std::unique_ptr<DaoaiServer>> Start(RequestHandler& handler,
                                                    const DaoaiServerOptions& options);
  ~DaoaiServer();  // Stop()
  DaoaiServer(const DaoaiServer&) = delete;
  DaoaiServer& operator=(const DaoaiServer&) = delete;

  int port() const;              // the bound port (the ephemeral one for port 0)
  std::string address() const;   // "127.0.0.1:6969"
  size_t connection_count() const;
  TransportStats stats() const;  // thread-safe
  uint64_t refused_count() const;  // connections closed at accept (limits, allowlist)
  // Stops accepting, closes every connection and joins the network threads.
  // Replies still being computed are dropped (their grasps stay queued).
  // Idempotent.
  void Stop();

 private:
  class Impl;
  explicit DaoaiServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
