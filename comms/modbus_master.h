// binpick as Modbus TCP master (client) of a robot that is the Modbus slave
// (seed 000, UR Modbus TCP): one ModbusMaster per robot. It polls the
// robot's request flag, reads the request registers, feeds the request to the
// same RequestHandler as the DaoAI socket server and writes the response back
// into the robot's registers. Register layout, value range and the handshake
// are in comms/modbus_codec.h and docs/protocols.md "Modbus TCP".
//
// Handshake (map: request 128..139 + flag 144, response 129..144 + flag 145),
// each poll reading every register of the map in one Modbus read:
//   1. a new request is: request flag == 1, and register request_base + 11
//      does not hold the marker modbus::kMarker. The request flag can be a
//      response register (seed: 144 is the response's meta_2, and a version-1
//      response leaves 1 there), and a 1 written over a 1 cannot be seen. So
//      whenever the request flag is a response register the master keeps the
//      marker in request_base + 11 while no request is pending: it writes it
//      when it takes a request, and with any response that leaves 1 in the
//      flag (seed: the response's payload_4). The robot writes
//      request_base + 11 last before the flag, with its meta_2 (1 or 2, never
//      the marker), so a stale 1 is never taken for a request, a half-written
//      request is never read, and a request is never missed.
//   2. the master writes the marker, clears the request flag, then handles
//      the request. The robot's own flag write may land after that clear
//      (the flag already read 1): the marker makes that late 1 stale, and
//      after a command without a response, where the robot waits for the
//      flag to read 0, the master clears it again.
//   3. for a command with a response: writes the response registers (with
//      the marker when they leave 1 in the request flag), then the response
//      flag = 1. The robot reads and clears it.
//   A robot that writes a new request without clearing the response flag
//   (its program restarted) gets the new request served; the master clears
//   the stale response flag and logs it.
//   Commands without a response (pose update, teach, ...) leave the response
//   flag at 0: a robot program must not write its next request before the
//   request flag reads 0 again (the seed's script does not wait; the
//   simulator does).
//
// Half-written exchanges (the connection fails between the take and the
// answer): after the reconnect, a request the robot still waits for (the
// marker in place, the response flag 0) is finished: a half-taken one (the
// flag not cleared) is cleared and handled, an answer built but not written
// is written then, unless the registers show that the write reached the
// robot and only its reply was lost (Delivered in modbus_master.cc): then it
// is not written again and a pick's grasp counts as handed out. A robot
// that restarted meanwhile (its registers reset, or a new request) gets its
// new request served and the old answer is counted lost.
//
// Threading: one thread per master; the RequestHandler's Handle() blocks
// that thread while a request is processed (requests of one robot are
// sequential). Every libmodbus call stays on that thread. Stop() is safe
// from any thread, idempotent, and returns once the thread has ended: at
// once from a wait for the handler (the request is abandoned, nothing
// popped) and from a libmodbus call (its socket is shut down), so
// binpickd stops within its 2 s with a robot mid-handshake.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "comms/request_handler.h"
#include "core/cell.h"
#include "core/status.h"

namespace bp {

// Where one request's time went on the master's side (steady clock): the
// handshake breakdown of docs/protocols.md "Latency" (bench/server_bench.cc).
struct ModbusRequestTiming {
  using Time = std::chrono::steady_clock::time_point;
  Time read_start;  // the poll read (FC3) that found the request began
  Time seen;        // ... and returned
  Time taken;       // marker and request flag written
  Time handled;     // the handler's answer built
  Time written;     // response registers and response flag written (= handled without one)
  int32_t command = 0;
  bool answered = false;
};

struct ModbusMasterOptions {
  std::string host = "127.0.0.1";  // the robot (Modbus slave)
  int port = 502;
  int unit_id = 1;
  ModbusRegisterMap map;                         // default: seed 000's
  std::chrono::milliseconds poll_interval{2};    // between flag reads
  std::chrono::milliseconds timeout{1000};       // connect and per transaction
  std::chrono::milliseconds backoff_min{50};     // first reconnect delay
  std::chrono::milliseconds backoff_max{2000};   // doubling up to this
  // Called on the master's thread after each request taken (benches, tests).
  std::function<void(const ModbusRequestTiming&)> on_request;
  // The robot may change the cell (calibration, teach, camera config):
  // binpickd sets it from the config allowlist (ClientContext::may_change_cell).
  bool may_change_cell = true;
};

// From a cell's robot.modbus section (host, port, unit id, map, poll).
ModbusMasterOptions ModbusMasterOptionsFromCell(const RobotSpec& robot);

struct ModbusMasterStats {
  uint64_t connects = 0;       // successful connections
  uint64_t requests = 0;       // requests taken (flag cleared)
  uint64_t responses = 0;      // responses written with their flag set
  uint64_t refused = 0;        // requests whose answer had a value outside int16: a grasp left
                               // queued, or the answer turned into UNKNOWN_COMMAND
  uint64_t saturated = 0;      // responses with a saturated remaining count
  uint64_t lost = 0;           // responses never written: the robot moved on (restart) before
                               // the reconnect, or the master stopped
  uint64_t resumed = 0;        // exchanges finished after a reconnect (half-written)
  uint64_t delivered = 0;      // answers whose write reached the robot though its reply was
                               // lost: found in the registers after the reconnect, not rewritten
  uint64_t unread = 0;         // new requests found over an unread response
  bool connected = false;
};

class ModbusMaster {
 public:
  // Validates the options (InvalidArgument) and starts the thread; the first
  // connection is made there (an unreachable robot is retried, not an error).
  // `handler` must outlive the master.
  static Result<std::unique_ptr<ModbusMaster>> Start(RequestHandler& handler,
                                                     ModbusMasterOptions options);
  ~ModbusMaster();  // Stop()
  ModbusMaster(const ModbusMaster&) = delete;
  ModbusMaster& operator=(const ModbusMaster&) = delete;

  void Stop();
  ModbusMasterStats stats() const;
  std::string address() const;  // "host:port"

 private:
  class Impl;
  explicit ModbusMaster(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
