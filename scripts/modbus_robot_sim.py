#!/usr/bin/python3
"""A robot that is a Modbus TCP slave, written with pymodbus (Debian 12's
python3-pymodbus 3.0; its server needs python3-serial and
python3-serial-asyncio): a second implementation of the robot side of
docs/protocols.md "Modbus TCP", for a cross-implementation test of binpick's
Modbus master (tests/comms/modbus_test.cc).

It plays seed 000's UR script on its own holding registers:
  modbustcp_send_robot_data: request fields to 128..139, then 144 = 1;
  modbustcp_recv_daoai_data: wait for 145, read 129..144, clear 145;
sending RC_SWITCH_CONFIG (69) requests alternating configs 1 and 2, and
checks each answer (SWITCH_CONFIG_SUCCESS 66, meta_2 = its version).

  modbus_robot_sim.py --port P [--version 1|2] [--count N] [--unit 1]

Exit 0 when every answer was right, 1 otherwise, 2 on timeout.
"""
import argparse
import logging
import os
import sys
import threading
import time

from pymodbus.datastore import (ModbusSequentialDataBlock, ModbusServerContext,
                                ModbusSlaveContext)
from pymodbus.server import StartTcpServer

REQUEST_BASE, REQUEST_FLAG, RESPONSE_BASE, RESPONSE_FLAG = 128, 144, 129, 145
HOLDING = 3  # function code of the holding registers
UR = 7  # meta_1
SWITCH_CONFIG, SWITCH_CONFIG_SUCCESS = 69, 66


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--version", type=int, default=2)
    ap.add_argument("--count", type=int, default=50)
    ap.add_argument("--unit", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=10.0)
    args = ap.parse_args()
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

    slave = ModbusSlaveContext(hr=ModbusSequentialDataBlock(0, [0] * 256), zero_mode=True)
    context = ModbusServerContext(slaves={args.unit: slave}, single=False)
    server = threading.Thread(
        target=StartTcpServer,
        kwargs={"context": context, "address": ("127.0.0.1", args.port)},
        daemon=True)
    server.start()

    def get(address, count=1):
        return slave.getValues(HOLDING, address, count)

    def put(address, values):
        slave.setValues(HOLDING, address, values)

    def send_robot_data(fields):
        for i, v in enumerate(fields):  # register by register, as the UR script
            put(REQUEST_BASE + i, [v & 0xFFFF])
        put(REQUEST_FLAG, [1])

    def recv_daoai_data():
        deadline = time.monotonic() + args.timeout
        while get(RESPONSE_FLAG)[0] == 0:
            if time.monotonic() > deadline:
                return None
            time.sleep(0.0002)
        values = get(RESPONSE_BASE, 16)
        put(RESPONSE_FLAG, [0])
        return [v - 0x10000 if v >= 0x8000 else v for v in values]

    bad = 0
    for i in range(args.count):
        config = 1 + i % 2
        # Pose of the seed's detection pose (0.4, -0.3, 0.6 m, rx = pi) x 10000.
        send_robot_data([4000, -3000, 6000, 31415, 0, 0, 0, SWITCH_CONFIG, config, 0, UR,
                         args.version])
        answer = recv_daoai_data()
        if answer is None:
            print(f"request {i}: no answer within {args.timeout} s", flush=True)
            os._exit(2)
        status, meta_2 = answer[13], answer[15]
        if status != SWITCH_CONFIG_SUCCESS or meta_2 != args.version:
            bad += 1
            print(f"request {i}: status {status} meta_2 {meta_2}", flush=True)
    print(f"pymodbus robot: {args.count - bad} of {args.count} answers right "
          f"(version {args.version})", flush=True)
    # The robot sees the last response flag in its own registers as soon as the
    # server applied the master's write, before the server acknowledged it:
    # stay up briefly so that acknowledgement reaches the master.
    time.sleep(0.3)
    os._exit(0 if bad == 0 else 1)  # the server thread does not stop by itself


if __name__ == "__main__":
    sys.exit(main())
