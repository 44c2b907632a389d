// The robot side of the Modbus transport (seed 000, UR Modbus TCP): a
// Modbus TCP slave (libmodbus) holding the robot's registers, and the seed's
// UR script functions played register by register on them:
//   modbustcp_send_robot_data: write the 12 request registers one by one,
//     then the request flag = 1;
//   modbustcp_recv_daoai_data: wait for the response flag, read the 16
//     response registers, write the response flag = 0.
// One addition to the seed script: after a request without a response, the
// next write waits until the master has cleared the request flag (else a
// back-to-back request would overwrite one the master has not read).
//
// Used by the tests and by `binpick robot --modbus` through Transport(), so
// the same flows (comms/robot_flows.h) run over Modbus and over the socket.
//
// Threading: the slave runs on its own thread; the robot functions may be
// called from one other thread. Register access is serialized with the
// slave's handling of each Modbus request (a master's read or write is
// atomic with respect to the robot's register writes).
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include "comms/daoai_message.h"
#include "comms/robot_client.h"
#include "core/cell.h"
#include "core/status.h"

namespace bp {

struct ModbusRobotSimOptions {
  std::string bind = "127.0.0.1";
  int port = 0;        // 0: an ephemeral port (see port())
  int unit_id = 1;     // requests for another unit are ignored (0xFF is accepted)
  ModbusRegisterMap map;
  // Between two register writes of a request (a UR script writes one
  // register per controller cycle, 8 ms at 125 Hz). 0: back to back.
  std::chrono::microseconds write_interval{0};
};

struct ModbusRobotSimStats {
  uint64_t requests_sent = 0;        // request flags set
  uint64_t responses_read = 0;       // responses read and acknowledged
  uint64_t unexpected_responses = 0; // response flag set with no request waiting
  uint64_t masters = 0;              // master connections accepted
  uint64_t dropped_writes = 0;       // writes dropped by DropNextWriteTo
  uint64_t lost_replies = 0;         // writes applied without a reply (LoseReplyToNextWrite)
};

class ModbusRobotSim {
 public:
  // @returns Unavailable when the address cannot be bound.
  static Result<std::unique_ptr<ModbusRobotSim>> Start(const ModbusRobotSimOptions& options);
  ~ModbusRobotSim();  // Stop()
  ModbusRobotSim(const ModbusRobotSim&) = delete;
  ModbusRobotSim& operator=(const ModbusRobotSim&) = delete;

  // Closes the listening socket and the master's connection; the robot
  // functions then fail with Unavailable. Idempotent.
  void Stop();
  int port() const;
  // @returns false if no master connected within `timeout`.
  bool WaitForMaster(std::chrono::milliseconds timeout);

  // The seed's modbustcp_send_robot_data. Unavailable on timeout (waiting
  // for a request without response to be taken) or after Stop.
  Status SendRobotData(const daoai::Request& request, bool expects_response,
                       std::chrono::milliseconds timeout);
  // The seed's modbustcp_recv_daoai_data. Unavailable on timeout / Stop.
  Result<daoai::Response> RecvDaoaiData(std::chrono::milliseconds timeout);

  // Fault injection (tests of half-written exchanges): the master's next
  // write (function 6 or 16) starting at `address` is not applied; the
  // slave closes the master's connection instead, as a network cut between
  // the write and its reply would.
  void DropNextWriteTo(int address);
  // The master's next write starting at `address` is applied, then the
  // connection is closed before the reply: a network cut between the write
  // and its reply, seen by the master as a failed write that took effect.
  void LoseReplyToNextWrite(int address);

  // Raw register access (as the robot's own read/write_port_register).
  uint16_t ReadRegister(int address) const;
  void WriteRegister(int address, uint16_t value);
  ModbusRobotSimStats stats() const;

  // A RobotTransport over this robot for RobotClient::Over. The simulator
  // must outlive the transport.
  std::unique_ptr<RobotTransport> Transport();

 private:
  class Impl;
  explicit ModbusRobotSim(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
