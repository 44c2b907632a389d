// Connection machinery shared by the socket servers (DaoAI, GRI): a listener
// on one or more ports with its network threads, and the base of one
// connection (its strand, the read timeout, closing, writing, and delivering a
// request handler's completion onto the strand). Private to bp_comms: it is
// the one place that includes Boost.Asio for them.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

// After <utility>: Asio's awaitable.hpp uses std::exchange without including it.
#include <boost/asio.hpp>

#include "comms/request_handler.h"
#include "comms/transport_stats.h"
#include "core/address_list.h"
#include "core/status.h"

namespace bp::internal {

namespace asio = boost::asio;
using asio::ip::tcp;
using Strand = asio::strand<asio::io_context::executor_type>;

// Lets detection workers post completions into the io_context only while it
// exists: the listener closes the gate (under the mutex) before destroying it.
struct PostGate {
  std::mutex mutex;
  bool open = true;  // GUARDED_BY(mutex)
};

// Totals a listener and its sessions count (TransportStats); any thread.
struct TransportCounters {
  std::atomic<uint64_t> accepted{0};
  std::atomic<uint64_t> read_timeouts{0};
  std::atomic<uint64_t> protocol_errors{0};
  std::atomic<uint64_t> refused_allowlist{0};
  std::atomic<uint64_t> refused_max_connections{0};
  std::atomic<uint64_t> refused_per_peer{0};
  std::atomic<uint64_t> accept_errors{0};
};

// Limits of one listener (docs/reliability.md "Limits"). Zero: unlimited.
struct ConnectionLimits {
  // Connections open at once; one more is closed at accept, with a log line.
  size_t max_connections = 0;
  // Connections one peer address may hold at once (same handling).
  size_t max_connections_per_peer = 0;
  // Complete requests per second per connection; above it the connection is
  // not read until the rate allows (TCP back-pressure), nothing is dropped.
  double max_message_rate = 0;
  // Peers allowed to connect (addresses or ADDR/PREFIX, core/address_list.h);
  // empty: any peer.
  std::vector<std::string> allowlist;
  // Peers allowed to change the cell (ClientContext::may_change_cell);
  // empty: every peer allowed to connect.
  std::vector<std::string> config_allowlist;
  // TCP keepalive on every connection: a robot that vanished without FIN or
  // RST (power cut, cable pulled) is noticed after idle + interval * probes
  // (16 s by default) and its connection closed, so an answer is not
  // written, and its grasp not popped, into a dead connection's buffer. The
  // same bound applies to data the robot does not acknowledge
  // (TCP_USER_TIMEOUT). 0 idle: off.
  std::chrono::seconds keepalive_idle{10};
  std::chrono::seconds keepalive_interval{2};
  int keepalive_probes = 3;
  // SO_SNDBUF of each connection, bytes (the kernel doubles it); 0: the
  // kernel's autotuned default. Tests make a write block after a few answers.
  int send_buffer_bytes = 0;
};

struct SessionArgs {
  tcp::socket socket;
  Strand strand;
  std::shared_ptr<PostGate> gate;
  uint64_t id = 0;
  int local_port = 0;  // the listening port the robot connected to
  double max_message_rate = 0;  // ConnectionLimits::max_message_rate
  std::function<void(uint64_t)> on_closed;
  std::shared_ptr<TransportCounters> counters;
  bool may_change_cell = true;  // the peer is in the config allowlist
  const ConnectionLimits* limits = nullptr;  // the listener's (outlives the session)
};

// One robot connection. Everything below runs on the strand unless noted.
// The connection is closed when no complete request arrived for read_timeout
// while no request was in progress (a silent robot, or half a message then
// silence). Derived classes read, queue and answer requests.
class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(SessionArgs args, const char* log_name, std::chrono::milliseconds read_timeout);
  virtual ~Session() = default;
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  void Start();                 // any thread
  void Close(const char* why);  // any thread

 protected:
  virtual void BeginReading() = 0;
  // The response written by Write() is out (or there was none): next request.
  virtual void Done() = 0;
  virtual void OnClosed() {}

  // A complete request arrived.
  void MarkActivity() { last_activity_ = std::chrono::steady_clock::now(); }
  // Reads exactly `n` bytes into `data` (which must stay valid), a segment at
  // a time, then runs `done` on the strand; a read error closes (OnReadError).
  // After a segment that does not complete the message the peer is
  // acknowledged at once (AckNow): a robot whose socket keeps Nagle's
  // algorithm on sends the rest of a message split into several writes only
  // once its first segment is acknowledged.
  template <typename Done>
  void ReadExactly(uint8_t* data, size_t n, Done done) {
    socket_.async_read_some(
        asio::buffer(data, n),
        asio::bind_executor(strand_, [self = shared_from_this(), data, n, done = std::move(done)](
                                         boost::system::error_code ec, size_t got) mutable {
          if (self->closed_) return;
          if (ec) {
            self->OnReadError(ec);
            return;
          }
          if (got < n) {
            self->AckNow();
            self->ReadExactly(data + got, n - got, std::move(done));
            return;
          }
          done();
        }));
  }
  // Acknowledges the data read so far now instead of after the kernel's
  // delayed-ACK timer (Linux: TCP_QUICKACK, which the kernel clears again on
  // its own, so it is set after each read that gets no answer). Without it a
  // request that gets no answer (DaoAI pose update, teach, ...) leaves its
  // ACK delayed by 40 ms, and a robot with Nagle's algorithm on (the default
  // on robot controllers) holds its next request until then
  // (docs/protocols.md "TCP options").
  void AckNow();
  // Closes on a read error with the right log line.
  void OnReadError(boost::system::error_code ec);
  // After a complete request: BeginReading() the next one at once, or later
  // when the connection is above max_message_rate (token bucket, one second
  // of burst).
  void ReadNextRequest();
  // Writes `bytes`; then Done(), or closes with `close_reason` when given.
  // A write that does not complete within read_timeout (a robot that does not
  // read its answers) closes the connection. `on_written` (optional) hears
  // whether every byte went out (false: a write error, or the connection
  // closed first): how a popped grasp is settled (ClientContext::settle).
  void Write(std::vector<uint8_t> bytes, const char* close_reason = nullptr,
             std::function<void(bool written)> on_written = nullptr);
  // Takes the settlement the handler left on the client while building the
  // answer (ClientContext::settle), for Write's on_written.
  std::function<void(bool)> TakeSettle() { return std::exchange(client_.settle, nullptr); }
  void DoClose(const char* why);
  // The robot broke the protocol (counted in TransportStats::protocol_errors).
  void CountProtocolError() { counters_->protocol_errors.fetch_add(1, std::memory_order_relaxed); }
  // Ends the request in progress (after Done's caller wrote the answer).
  void Finish() {
    busy_ = false;
    MarkActivity();
  }

  // Wraps a handler completion for the request being started: called inside
  // the handler on this thread, it is kept and run by EndHandle() without a
  // trip through the io queue; called from a worker, it is posted to the
  // strand (dropped when the connection or the server is gone).
  // `on_reply` runs on the strand while the session is alive.
  template <typename ReplyT>
  std::function<void(ReplyT)> Completion(std::function<void(const ReplyT&)> on_reply) {
    std::weak_ptr<Session> weak = weak_from_this();
    return [weak, gate = gate_, caller = std::this_thread::get_id(),
            on_reply = std::move(on_reply)](ReplyT reply) {
      if (std::this_thread::get_id() == caller) {
        std::shared_ptr<Session> self = weak.lock();
        if (self && self->in_handle_) {
          self->sync_work_ = [on_reply, reply = std::move(reply)] { on_reply(reply); };
          return;
        }
      }
      std::lock_guard lock(gate->mutex);
      if (!gate->open) return;
      std::shared_ptr<Session> self = weak.lock();
      if (!self) return;  // closed and gone: nothing popped
      asio::post(self->strand_, [self, on_reply, reply = std::move(reply)] {
        if (!self->closed_) on_reply(reply);  // the robot left: do not pop its grasp
      });
    };
  }
  void BeginHandle() {
    busy_ = true;
    in_handle_ = true;
  }
  void EndHandle();

  tcp::socket socket_;
  Strand strand_;
  const char* log_name_;
  ClientContext client_;
  bool busy_ = false;
  bool closed_ = false;

 private:
  void ArmTimer();

  // Sets TCP keepalive and TCP_USER_TIMEOUT (ConnectionLimits).
  void SetKeepAlive(const ConnectionLimits& limits);

  asio::steady_timer timer_;
  asio::steady_timer throttle_timer_;
  const double max_message_rate_;
  double tokens_ = 0;
  std::chrono::steady_clock::time_point tokens_at_ = std::chrono::steady_clock::now();
  bool throttle_logged_ = false;
  bool writing_ = false;
  std::chrono::steady_clock::time_point write_start_;
  std::shared_ptr<PostGate> gate_;
  std::function<void(uint64_t)> on_closed_;
  std::shared_ptr<TransportCounters> counters_;
  const std::chrono::milliseconds read_timeout_;
  std::vector<uint8_t> write_buf_;
  bool in_handle_ = false;           // inside the handler's HandleAsync
  std::function<void()> sync_work_;  // completed inside HandleAsync
  std::chrono::steady_clock::time_point last_activity_ = std::chrono::steady_clock::now();
};

// Accepts connections on one or more ports and runs the network threads.
class Listener {
 public:
  using Factory = std::function<std::shared_ptr<Session>(SessionArgs)>;

  Listener(const char* log_name, Factory factory, ConnectionLimits limits = {});
  ~Listener();  // Stop(), then late completions are dropped
  Listener(const Listener&) = delete;
  Listener& operator=(const Listener&) = delete;

  // Binds every port (0: an ephemeral one) and starts io_threads threads.
  // @returns InvalidArgument for a bad address, port or allowlist entry,
  // Unavailable when a port cannot be bound.
  Status Listen(const std::string& bind, const std::vector<int>& ports, int io_threads);
  const std::vector<int>& ports() const { return ports_; }  // bound, in Listen's order
  size_t connection_count() const;
  TransportStats stats() const;
  // Connections closed at accept (allowlist, max_connections, per peer).
  uint64_t refused_count() const;
  // Stops accepting, closes every connection and joins the threads. Idempotent.
  void Stop();

 private:
  void Accept(size_t index);
  // An accept failed: out of descriptors (EMFILE, ENFILE) or memory is
  // retried after a pause that doubles up to 1 s, not at once (the pending
  // connection would fail again and spin a core); logged once per burst.
  void OnAcceptError(size_t index, boost::system::error_code ec);
  // Applies the allowlist, max_connections and the per-peer limit; closes a
  // refused socket. @returns the peer address (text) of an admitted one.
  std::optional<std::string> Admit(tcp::socket& socket);

  struct Connection {
    std::weak_ptr<Session> session;
    std::string peer;  // address, for the per-peer count
  };

  const char* log_name_;
  Factory factory_;
  const ConnectionLimits limits_;
  AddressList allowed_;         // parsed limits_.allowlist
  AddressList config_allowed_;  // parsed limits_.config_allowlist
  std::shared_ptr<PostGate> gate_ = std::make_shared<PostGate>();
  std::shared_ptr<TransportCounters> counters_ = std::make_shared<TransportCounters>();
  asio::io_context io_;
  std::vector<std::unique_ptr<tcp::acceptor>> acceptors_;
  std::vector<std::unique_ptr<asio::steady_timer>> accept_timers_;  // one per acceptor
  std::vector<std::chrono::milliseconds> accept_backoff_;  // per acceptor, its strand only
  std::vector<Strand> accept_strands_;                     // one per acceptor
  std::vector<int> ports_;
  std::vector<std::thread> threads_;
  std::atomic<bool> stopped_{false};
  uint64_t next_id_ = 0;  // io threads, under mutex_
  mutable std::mutex mutex_;
  std::unordered_map<uint64_t, Connection> connections_;     // GUARDED_BY(mutex_)
  std::unordered_map<std::string, size_t> per_peer_;         // GUARDED_BY(mutex_)
};

}  // namespace bp::internal
