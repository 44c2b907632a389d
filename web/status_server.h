// The status page's HTTP server (Boost.Beast, kept in the .cc): the page,
// its JSON API and /metrics. docs/status_page.md lists the endpoints.
//
// One network thread of its own, separate from the robot-facing servers: a
// slow or hostile browser delays only other browsers. Requests are GET or HEAD
// with at most max_request_bytes of headers and body (405 / 413 / 400
// otherwise, never a crash); at most max_connections at once (more are
// answered 503 and closed); a connection idle for idle_timeout is closed.
//
// Allowlist (docs/reliability.md "Security"): a peer whose address is not in
// options.allowlist is closed at accept, before anything is read or written
// (no 403: it gets no session, no buffer and no timer, so a scanner cannot
// hold the slots of max_connections, and learns nothing about the server).
// Each refusal is a log line and counts in
// binpick_http_refused_connections_total{reason="allowlist"}; a 503 over the
// limit counts with reason="max_connections".
#pragma once

#include <chrono>
#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "core/status.h"
#include "web/metrics.h"
#include "web/status_state.h"

namespace bp {

struct StatusServerOptions {
  std::string bind = "127.0.0.1";
  int port = 8080;  // 0: an ephemeral port (tests); see StatusServer::port()
  size_t max_connections = 16;  // 0: unlimited
  // Peer IP addresses allowed to connect (exact; IPv4-mapped IPv6 peers
  // compare as IPv4). Empty: any peer.
  std::vector<std::string> allowlist;
  size_t max_request_bytes = 16 * 1024;
  std::chrono::milliseconds idle_timeout{15000};
};

class StatusServer {
 public:
  // Binds, listens and starts the thread. `state` and `metrics` must outlive
  // the server. @returns InvalidArgument for a bad address or port,
  // Unavailable when the port cannot be bound.
  static Result<std::unique_ptr<StatusServer>> Start(const StatusState& state,
                                                     MetricsRegistry& metrics,
                                                     const StatusServerOptions& options);
  ~StatusServer();  // Stop()
  StatusServer(const StatusServer&) = delete;
  StatusServer& operator=(const StatusServer&) = delete;

  int port() const;
  std::string address() const;  // "127.0.0.1:8080"
  // Closes the listener and every connection, joins the thread. Idempotent.
  void Stop();

 private:
  class Impl;
  explicit StatusServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
