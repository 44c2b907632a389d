#include "comms/modbus_master.h"

#include <modbus.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>

#include <algorithm>
#include <limits>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>
#include <vector>

#include "comms/modbus_codec.h"

namespace bp {
namespace {

using Clock = std::chrono::steady_clock;

// The registers one poll reads: every register of the map, [lo, lo + count).
struct Span {
  int lo = 0;
  int count = 0;
  bool marker = false;  // request flag inside the response registers
  // Taking a request writes the marker and clears the request flag in one
  // FC16 when every register from the marker to the flag is a response
  // register (seed map: 139..144; 140..143 hold the last answer's payload_5,
  // payload_6, status and meta_1, which the robot has read: it is sending a
  // new request). Else two writes.
  bool one_write_take = false;
  // The answer and its flag in one FC16 when the flag follows the response
  // block (seed map: 129..145). The slave applies the registers in address
  // order, so the flag is still set last (seed 000: "在回应消息发送完成之后，此标志位
  // 必须置成值1").
  bool one_write_answer = false;
};

Span SpanOf(const ModbusRegisterMap& m) {
  const int req = static_cast<int>(daoai::kRequestFields);
  const int rsp = static_cast<int>(daoai::kResponseFields);
  Span s;
  s.lo = std::min({m.request_base, m.request_flag, m.response_base, m.response_flag});
  const int hi = std::max({m.request_base + req - 1, m.request_flag, m.response_base + rsp - 1,
                           m.response_flag});
  s.count = hi - s.lo + 1;
  s.marker = m.request_flag >= m.response_base && m.request_flag < m.response_base + rsp;
  const int marker_reg = m.request_base + modbus::kMarkerField;
  s.one_write_take = s.marker && marker_reg < m.request_flag && marker_reg >= m.response_base &&
                     m.request_flag - marker_reg <= 8 && m.response_flag != m.request_flag;
  for (int r = marker_reg + 1; s.one_write_take && r < m.request_flag; ++r) {
    const bool request_reg = r >= m.request_base && r < m.request_base + req;
    if (request_reg || r == m.response_flag || r >= m.response_base + rsp) s.one_write_take = false;
  }
  s.one_write_answer = m.response_flag == m.response_base + rsp;
  return s;
}

void SetTimeout(modbus_t* ctx, std::chrono::milliseconds t) {
  const auto us = std::chrono::duration_cast<std::chrono::microseconds>(t).count();
  modbus_set_response_timeout(ctx, static_cast<uint32_t>(us / 1000000),
                              static_cast<uint32_t>(us % 1000000));
}

}  // namespace

ModbusMasterOptions ModbusMasterOptionsFromCell(const RobotSpec& robot) {
  ModbusMasterOptions o;
  o.host = robot.modbus_host;
  o.port = robot.modbus_port;
  o.unit_id = robot.modbus_unit_id;
  o.map = robot.modbus_map;
  o.poll_interval = std::chrono::milliseconds(robot.modbus_poll_ms);
  return o;
}

class ModbusMaster::Impl {
 public:
  Impl(RequestHandler& handler, ModbusMasterOptions options)
      : handler_(handler), o_(std::move(options)), span_(SpanOf(o_.map)) {}
  ~Impl() { Stop(); }

  void Start() { thread_ = std::thread([this] { Run(); }); }

  // Wakes the thread wherever it waits: a sleep (the condition variable), a
  // request in the handler (Handle's abandon check), a libmodbus call (the
  // socket is shut down under it; it fails at once and the thread, not this
  // one, closes the descriptor).
  void Stop() {
    {
      std::lock_guard lock(mutex_);
      stopping_ = true;
      if (socket_ >= 0) ::shutdown(socket_, SHUT_RDWR);
    }
    cv_.notify_all();
    std::lock_guard join(join_mutex_);
    if (thread_.joinable()) thread_.join();
  }

  ModbusMasterStats stats() const {
    std::lock_guard lock(mutex_);
    return stats_;
  }
  std::string address() const { return o_.host + ":" + std::to_string(o_.port); }

 private:
  using Registers = std::array<uint16_t, daoai::kResponseFields>;
  // A request taken whose answer is not in the robot's registers yet: the
  // connection failed after the marker was written (the flag not cleared) or
  // before the response and its flag were written. After the reconnect it is
  // finished if the robot still waits for it (docs/protocols.md "Modbus
  // TCP", half-written exchanges).
  struct Unfinished {
    daoai::Request request;
    std::optional<Registers> response;  // built but not written
    // A pick's grasp, reserved until the registers are written
    // (ClientContext::settle): handed out then, put back if never.
    std::function<void(bool)> settle;
    // The response registers as the take left them, before any answer write:
    // what they hold if that write never reached the robot (Delivered).
    std::optional<Registers> before;
    // Two-write maps: the registers were written and the flag write failed.
    bool flag_write_failed;
  };

  bool stopping() {
    std::lock_guard lock(mutex_);
    return stopping_;
  }
  // Sleeps up to `d`; @returns false when stopping.
  bool Sleep(std::chrono::milliseconds d) {
    std::unique_lock lock(mutex_);
    if (d.count() > 0) cv_.wait_for(lock, d, [this] { return stopping_; });
    return !stopping_;
  }
  template <typename F>
  void Count(F f) {
    std::lock_guard lock(mutex_);
    f(stats_);
  }
  // The connection's socket, for Stop() to shut down (-1: none).
  void PublishSocket(int fd) {
    std::lock_guard lock(mutex_);
    socket_ = fd;
    if (stopping_ && fd >= 0) ::shutdown(fd, SHUT_RDWR);
  }

  void Run() {
    auto backoff = o_.backoff_min;
    bool warned = false;
    while (!stopping()) {
      // _pi: host names and IPv6 too (getaddrinfo).
      modbus_t* ctx = modbus_new_tcp_pi(o_.host.c_str(), std::to_string(o_.port).c_str());
      if (ctx == nullptr) {
        spdlog::error("modbus: {}: cannot create a context: {}", address(), modbus_strerror(errno));
        return;
      }
      modbus_set_slave(ctx, o_.unit_id);
      SetTimeout(ctx, o_.timeout);
      if (modbus_connect(ctx) != 0) {
        if (!warned) {
          spdlog::warn("modbus: cannot connect to robot {}: {}; retrying with backoff up to {} ms",
                       address(), modbus_strerror(errno), o_.backoff_max.count());
          warned = true;
        }
        modbus_free(ctx);
        if (!Sleep(backoff)) return;
        backoff = std::min(backoff * 2, o_.backoff_max);
        continue;
      }
      PublishSocket(modbus_get_socket(ctx));
      spdlog::info("modbus: connected to robot {} (unit {})", address(), o_.unit_id);
      warned = false;
      Count([](ModbusMasterStats& s) { ++s.connects; s.connected = true; });
      // The backoff restarts only after a connection that answered: a robot
      // that accepts but never answers (e.g. another unit id) is retried
      // ever more slowly.
      if (Serve(ctx)) backoff = o_.backoff_min;
      Count([](ModbusMasterStats& s) { s.connected = false; });
      PublishSocket(-1);
      modbus_close(ctx);
      modbus_free(ctx);
      if (!Sleep(backoff)) break;
      backoff = std::min(backoff * 2, o_.backoff_max);
    }
    if (unfinished_) DropUnfinished("the master stopped");
  }

  void Fail(const char* what) {
    spdlog::warn("modbus: robot {}: {} failed: {}; reconnecting", address(), what,
                 modbus_strerror(errno));
  }

  // An unfinished exchange the robot no longer waits for. An answer built
  // and not written is lost, counted and logged, and a pick's grasp goes back
  // to its queue (settle(false)); a request taken but not answered is only
  // logged (a robot whose flag is still set has it taken again).
  void DropUnfinished(const char* why) {
    if (unfinished_->response) {
      spdlog::warn("modbus: robot {}: the answer to command {} was never written and is dropped "
                   "({})", address(), unfinished_->request.command, why);
      Count([](ModbusMasterStats& s) { ++s.lost; });
    } else {
      spdlog::info("modbus: robot {}: command {} taken before the reconnect is not answered ({})",
                   address(), unfinished_->request.command, why);
    }
    if (unfinished_->settle) unfinished_->settle(false);  // its grasp goes back to the queue
    unfinished_.reset();
  }

  // One connection: polls until an error or Stop. @returns whether the
  // robot answered at least one read.
  bool Serve(modbus_t* ctx) {
    bool answered = false;
    ClientContext client;
    client.id = ++connections_;
    client.peer = "modbus " + address();
    // The registers' range: the handler checks every answer against it, a
    // pick pose before its grasp leaves the queue (docs/protocols.md "Value
    // range"), and gets back what the robot will read (saturated counts).
    // Called on this thread only, inside handler_.Handle().
    client.wire_range = [this](const daoai::Response& r) -> Result<daoai::Response> {
      Result<std::array<uint16_t, daoai::kResponseFields>> regs = modbus::EncodeResponse(r);
      if (!regs.ok()) {
        range_refused_ = true;
        return regs.status();
      }
      return modbus::DecodeResponse(*regs);
    };
    client.may_change_cell = o_.may_change_cell;
    // A pick's grasp is handed out when its registers are written.
    client.settle_after_write = true;
    // The last request taken had no response: a request flag of 1 with the
    // marker in place is then the robot's own late flag write (see below).
    bool taken_without_response = false;
    std::vector<uint16_t> regs(static_cast<size_t>(span_.count));
    const ModbusRegisterMap& m = o_.map;
    const int marker_reg = m.request_base + modbus::kMarkerField;
    auto at = [&](int reg) { return regs[static_cast<size_t>(reg - span_.lo)]; };
    while (!stopping()) {
      timing_ = ModbusRequestTiming{};
      timing_.read_start = Clock::now();
      if (modbus_read_registers(ctx, span_.lo, span_.count, regs.data()) != span_.count) {
        Fail("reading the registers");
        return answered;
      }
      answered = true;
      const bool flag = at(m.request_flag) == 1;
      const bool marked = span_.marker && at(marker_reg) == modbus::kMarker;
      if (unfinished_ && Delivered(*unfinished_, regs, flag, marked)) {
        // The answer's write reached the robot and only its reply was lost:
        // the robot has (or will read) it. Not written again (the robot would
        // read it twice), its grasp handed out once.
        spdlog::info("modbus: robot {}: the answer to command {} reached the robot before the "
                     "connection failed; not written again", address(),
                     unfinished_->request.command);
        if (unfinished_->settle) unfinished_->settle(true);
        client.last_answer = modbus::DecodeResponse(*unfinished_->response);
        unfinished_.reset();
        Count([](ModbusMasterStats& s) { ++s.delivered; ++s.responses; });
        continue;
      }
      if (unfinished_) {
        if (StillWaits(*unfinished_, regs, flag, marked)) {
          // Clear a flag the failed take left, then answer.
          if (flag && !unfinished_->response && modbus_write_register(ctx, m.request_flag, 0) != 1) {
            Fail("clearing the request flag of a half-taken request");
            return answered;
          }
          spdlog::info("modbus: robot {}: finishing command {} taken before the reconnect",
                       address(), unfinished_->request.command);
          Count([](ModbusMasterStats& s) { ++s.resumed; });
          if (flag && !unfinished_->response) regs[static_cast<size_t>(m.request_flag - span_.lo)] = 0;
          if (!Answer(ctx, client, unfinished_->request, unfinished_->response,
                      ResponseRegisters(regs), taken_without_response)) {
            return answered;
          }
          continue;
        }
        DropUnfinished(flag ? "the robot sent a new request" : "the robot's registers were reset");
      }
      if (flag && marked && taken_without_response) {
        // The robot wrote its flag (1 over the stale 1 of a version-1
        // response) after this master had already taken the request and
        // cleared it. The robot now waits for 0 before its next request, so
        // clearing cannot erase a new one.
        if (modbus_write_register(ctx, m.request_flag, 0) != 1) {
          Fail("clearing a late request flag");
          return answered;
        }
        taken_without_response = false;
        continue;
      }
      if (!flag || marked) {
        if (!Sleep(o_.poll_interval)) return answered;
        continue;
      }
      timing_.seen = Clock::now();
      std::array<uint16_t, daoai::kRequestFields> fields{};
      for (size_t i = 0; i < fields.size(); ++i) fields[i] = at(m.request_base + static_cast<int>(i));
      const daoai::Request request = modbus::DecodeRequest(fields);
      timing_.command = request.command;
      // Taken: the marker goes back first, then the flag is cleared. When the
      // request flag is a response register, the flag may have read 1 before
      // the robot wrote it (a version-1 response left 1 there); the robot's
      // flag write can then land after the clear, and the marker keeps that
      // late 1 from being taken for a second request.
      if (span_.one_write_take) {
        std::vector<uint16_t> take(static_cast<size_t>(m.request_flag - marker_reg + 1), 0);
        take.front() = modbus::kMarker;  // and 0 up to the request flag
        if (modbus_write_registers(ctx, marker_reg, static_cast<int>(take.size()), take.data()) !=
            static_cast<int>(take.size())) {
          // Applied or not: marked (finished after the reconnect) or still
          // flagged and unmarked (taken again).
          unfinished_ = Unfinished{request, std::nullopt, nullptr, std::nullopt, false};
          Fail("taking the request");
          return answered;
        }
      } else {
        if (span_.marker && modbus_write_register(ctx, marker_reg, modbus::kMarker) != 1) {
          unfinished_ = Unfinished{request, std::nullopt, nullptr, std::nullopt, false};
          Fail("marking the request taken");
          return answered;
        }
        if (modbus_write_register(ctx, m.request_flag, 0) != 1) {
          // Half-taken: marked but still flagged. Finished after the reconnect.
          unfinished_ = Unfinished{request, std::nullopt, nullptr, std::nullopt, false};
          Fail("clearing the request flag");
          return answered;
        }
      }
      // The registers as the take left them (Unfinished::before).
      auto set = [&](int reg, uint16_t v) { regs[static_cast<size_t>(reg - span_.lo)] = v; };
      if (span_.one_write_take) {
        for (int r = marker_reg; r <= m.request_flag; ++r) set(r, r == marker_reg ? modbus::kMarker : 0);
      } else {
        if (span_.marker) set(marker_reg, modbus::kMarker);
        set(m.request_flag, 0);
      }
      if (at(m.response_flag) != 0) {
        // The robot did not read the last response (its program restarted).
        spdlog::warn("modbus: robot {} sent command {} without reading the previous response; "
                     "dropping that response", address(), request.command);
        Count([](ModbusMasterStats& s) { ++s.unread; });
        if (modbus_write_register(ctx, m.response_flag, 0) != 1) {
          unfinished_ = Unfinished{request, std::nullopt, nullptr, std::nullopt, false};
          Fail("clearing the unread response flag");
          return answered;
        }
        set(m.response_flag, 0);
      }
      Count([](ModbusMasterStats& s) { ++s.requests; });
      timing_.taken = Clock::now();
      if (!Answer(ctx, client, request, std::nullopt, ResponseRegisters(regs),
                  taken_without_response)) {
        return answered;
      }
    }
    return answered;
  }

  // Whether the robot still waits for the unfinished exchange, from the
  // registers read after the reconnect. A half-taken request: our marker in
  // place, no response flag. An answer built but not (completely) written:
  // no response flag, no new request, and our marker in place or the
  // response registers holding exactly the answer (the marker can be one of
  // them). A restarted robot's registers are reset; a new request replaces
  // the marker.
  bool StillWaits(const Unfinished& u, const std::vector<uint16_t>& regs, bool flag,
                  bool marked) const {
    const ModbusRegisterMap& m = o_.map;
    const auto at = [&](int reg) { return regs[static_cast<size_t>(reg - span_.lo)]; };
    if (at(m.response_flag) != 0) return false;
    if (!u.response) return marked;
    if (flag && !marked) return false;
    if (marked) return true;
    for (size_t i = 0; i < u.response->size(); ++i) {
      if (at(m.response_base + static_cast<int>(i)) != (*u.response)[i]) return false;
    }
    return true;
  }

  Registers ResponseRegisters(const std::vector<uint16_t>& regs) const {
    Registers out{};
    for (size_t i = 0; i < out.size(); ++i) {
      out[i] = regs[static_cast<size_t>(o_.map.response_base - span_.lo) + i];
    }
    return out;
  }

  // Whether the answer's write, whose reply was lost (the connection failed),
  // reached the robot, from the registers read after the reconnect. Only the
  // response registers the robot never writes are compared (not its request
  // block, which a new request rewrites, nor the flags). One-write answers
  // (registers and flag in one FC16, applied at once or not at all): they
  // hold the answer and either the response flag is still set (unread) or
  // they held something else before (read, the flag cleared by the robot).
  // Two-write answers whose flag write failed: they hold the answer and the
  // flag is set, or the robot sent a new request (it read the answer). Not
  // decidable, and left to StillWaits (written again): an answer equal to
  // the registers before it whose flag the robot already cleared, and a
  // two-write flag write whose reply was lost, read and cleared before the
  // reconnect (docs/protocols.md, "Modbus TCP").
  bool Delivered(const Unfinished& u, const std::vector<uint16_t>& regs, bool flag,
                 bool marked) const {
    if (!u.response || !u.before) return false;
    const ModbusRegisterMap& m = o_.map;
    const int req = static_cast<int>(daoai::kRequestFields);
    bool differs = false;
    for (size_t i = 0; i < u.response->size(); ++i) {
      const int reg = m.response_base + static_cast<int>(i);
      const bool robot_writes = (reg >= m.request_base && reg < m.request_base + req) ||
                                reg == m.request_flag || reg == m.response_flag;
      if (robot_writes) continue;
      if (regs[static_cast<size_t>(reg - span_.lo)] != (*u.response)[i]) return false;
      differs = differs || (*u.before)[i] != (*u.response)[i];
    }
    const bool unread = regs[static_cast<size_t>(m.response_flag - span_.lo)] != 0;
    if (span_.one_write_answer) return unread || differs;
    return u.flag_write_failed && (unread || (flag && !marked));
  }

  // Handles a taken request (unless `built` holds its answer already) and
  // writes the answer. `before`: the response registers before the answer
  // is written (Unfinished::before). @returns false when the connection
  // failed (the exchange is then unfinished_) or the master is stopping.
  bool Answer(modbus_t* ctx, ClientContext& client, daoai::Request request,
              std::optional<Registers> built, const Registers& before,
              bool& taken_without_response) {
    if (!unfinished_) unfinished_ = Unfinished{request, built, nullptr, std::nullopt, false};
    if (!unfinished_->before) unfinished_->before = before;
    if (!built) {
      range_refused_ = false;
      const std::optional<daoai::Response> response =
          handler_.Handle(request, client, [this] { return stopping(); });
      timing_.handled = Clock::now();
      unfinished_->settle = std::exchange(client.settle, nullptr);
      if (stopping()) return false;
      if (range_refused_) Count([](ModbusMasterStats& s) { ++s.refused; });
      taken_without_response = !response.has_value();
      timing_.answered = response.has_value();
      if (!response) {  // no response for this command
        if (unfinished_->settle) unfinished_->settle(false);
        unfinished_.reset();
        timing_.written = timing_.handled;
        if (o_.on_request) o_.on_request(timing_);
        return true;
      }
      bool refused = false;
      built = Encode(request, *response, &refused);
      // A refused answer (a field beyond 16 bits) carries no grasp: it stays
      // queued (docs/protocols.md "Value range").
      if (refused && unfinished_->settle) std::exchange(unfinished_->settle, nullptr)(false);
      unfinished_->response = built;
    }
    if (!WriteResponse(ctx, *built, &unfinished_->flag_write_failed)) {
      spdlog::warn("modbus: robot {}: writing the response to command {} failed: {}; it is "
                   "written after the reconnect if the robot still waits for it",
                   address(), request.command, modbus_strerror(errno));
      return false;
    }
    if (unfinished_->settle) unfinished_->settle(true);
    unfinished_.reset();
    client.last_answer = modbus::DecodeResponse(*built);
    Count([](ModbusMasterStats& s) { ++s.responses; });
    timing_.written = Clock::now();
    if (o_.on_request) o_.on_request(timing_);
    return true;
  }

  // The response's registers (refused: UNKNOWN_COMMAND with pose and
  // payloads 0, when a field does not fit 16 bits), with the marker where
  // the response leaves 1 in the request flag.
  Registers Encode(const daoai::Request& request, const daoai::Response& response, bool* refused) {
    const ModbusRegisterMap& m = o_.map;
    Result<Registers> encoded = modbus::EncodeResponse(response);
    *refused = !encoded.ok();
    if (!encoded.ok()) {
      // Not reached: the handler range-checked the answer (wire_range).
      spdlog::error("modbus: robot {} command {}: {}; refused: answering UNKNOWN_COMMAND "
                    "(status -1) with pose and payloads 0", address(), request.command,
                    encoded.status().message());
      Count([](ModbusMasterStats& s) { ++s.refused; });
      encoded = modbus::EncodeResponse(modbus::RefusedResponse(response));
    } else if ((response.status == daoai::kObjectsFound || response.status == daoai::kDropOffPose) &&
               response.payload[0] == std::numeric_limits<int16_t>::max()) {
      // wire_range saturated the remaining count (a multiple of MULT otherwise).
      spdlog::debug("modbus: robot {} command {}: remaining count saturated to 3.2767", address(),
                    request.command);
      Count([](ModbusMasterStats& s) { ++s.saturated; });
    }
    Registers out = *encoded;
    const int marker_reg = m.request_base + modbus::kMarkerField;
    if (span_.marker && out[static_cast<size_t>(m.request_flag - m.response_base)] == 1 &&
        marker_reg >= m.response_base &&
        marker_reg < m.response_base + static_cast<int>(out.size())) {
      // The response leaves 1 in the request flag: it also keeps the marker
      // (seed: in payload_4). A marker outside the response is still there
      // from the take.
      out[static_cast<size_t>(marker_reg - m.response_base)] = modbus::kMarker;
    }
    return out;
  }

  // The response registers and the response flag = 1: one FC16 when the
  // flag follows the response block (the slave applies the registers in
  // address order, so the flag is still set last), else two writes.
  bool WriteResponse(modbus_t* ctx, const Registers& out, bool* flag_write_failed) {
    const ModbusRegisterMap& m = o_.map;
    *flag_write_failed = false;
    if (span_.one_write_answer) {
      std::array<uint16_t, daoai::kResponseFields + 1> with_flag{};
      std::copy(out.begin(), out.end(), with_flag.begin());
      with_flag.back() = 1;
      return modbus_write_registers(ctx, m.response_base, static_cast<int>(with_flag.size()),
                                    with_flag.data()) == static_cast<int>(with_flag.size());
    }
    if (modbus_write_registers(ctx, m.response_base, static_cast<int>(out.size()), out.data()) !=
        static_cast<int>(out.size())) {
      return false;
    }
    *flag_write_failed = modbus_write_register(ctx, m.response_flag, 1) != 1;
    return !*flag_write_failed;
  }

  RequestHandler& handler_;
  const ModbusMasterOptions o_;
  const Span span_;
  uint64_t connections_ = 0;             // touched by the thread only
  std::optional<Unfinished> unfinished_;  // touched by the thread only
  bool range_refused_ = false;   // thread only: wire_range refused the request being handled
  ModbusRequestTiming timing_;    // thread only: the request being handled (on_request)
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  bool stopping_ = false;     // GUARDED_BY(mutex_)
  int socket_ = -1;           // GUARDED_BY(mutex_): the connection's, for Stop()
  ModbusMasterStats stats_;   // GUARDED_BY(mutex_)
  std::mutex join_mutex_;      // one Stop() joins
  std::thread thread_;
};

Result<std::unique_ptr<ModbusMaster>> ModbusMaster::Start(RequestHandler& handler,
                                                          ModbusMasterOptions options) {
  if (options.host.empty()) return Status::InvalidArgument("modbus: robot host is empty");
  if (options.port < 1 || options.port > 65535) {
    return Status::InvalidArgument("modbus: robot port " + std::to_string(options.port) +
                                   " is not in 1..65535");
  }
  if (options.unit_id < 0 || options.unit_id > 255) {
    return Status::InvalidArgument("modbus: unit id " + std::to_string(options.unit_id) +
                                   " is not in 0..255");
  }
  if (options.poll_interval.count() < 0 || options.timeout.count() <= 0 ||
      options.backoff_min.count() <= 0 || options.backoff_max < options.backoff_min) {
    return Status::InvalidArgument("modbus: poll interval must be >= 0, timeout and backoff > 0");
  }
  if (Status s = ValidateModbusRegisterMap(options.map); !s.ok()) return s;
  auto impl = std::make_unique<Impl>(handler, std::move(options));
  impl->Start();
  return std::unique_ptr<ModbusMaster>(new ModbusMaster(std::move(impl)));
}

ModbusMaster::ModbusMaster(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ModbusMaster::~ModbusMaster() { Stop(); }
void ModbusMaster::Stop() { impl_->Stop(); }
ModbusMasterStats ModbusMaster::stats() const { return impl_->stats(); }
std::string ModbusMaster::address() const { return impl_->address(); }

}  // namespace bp
