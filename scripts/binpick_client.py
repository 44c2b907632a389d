#!/usr/bin/env python3
"""Minimal DaoAI socket client for binpickd (standard library only).

Speaks the fixed-length protocol of docs/protocols.md: a request is 12 big-endian
int32 (48 bytes), a response 16 int32 (64 bytes); poses and payloads are scaled
by MULT = 10000. Use it from your own scripts:

    from binpick_client import DaoaiClient, PICK_POSE
    with DaoaiClient("127.0.0.1", 6969) as robot:
        robot.pose = (0.4, -0.3, 0.6, 3.1416, 0.0, 0.0, 0.0)  # x y z + 4 orientation fields
        print(robot.capture(task=0))
        reply = robot.pick_pose(task=0)
        print(reply.status_name, reply.position, reply.remaining, reply.part_class)

or from a shell:

    scripts/binpick_client.py --port 6969 pick --task 0
"""

import argparse
import math
import socket
import struct
import sys
import time

MULT = 10000.0
REQUEST = struct.Struct(">12i")   # position[3] orientation[4] command payload_1 payload_2 meta_1 meta_2
RESPONSE = struct.Struct(">16i")  # position[3] orientation[4] payload[6] status meta_1 meta_2

# Commands (seed 000 / 004).
NO_COMMAND = -1
START_MANUAL_CALIBRATION = 1
STOP_MANUAL_CALIBRATION = 2
START_AUTO_CALIBRATION = 4
MANUAL_ACCUMULATE_POSE = 6
AUTO_ACCUMULATE_POSE = 7
GUIDANCE_CALIBRATION = 10
START_2D_AUTO_CALIBRATION = 11
AUTO_ACCUMULATE_2D_POSE = 12
CAPTURE_AND_PROCESS_ASYNC = 19
CAPTURE_AND_PROCESS = 20
PICK_POSE = 21
SEND_POSE = 30
CHECK_EMPTY_BOX = 40
PRECISION_CHECK = 50
SWITCH_CONFIG = 69

# Response statuses; 4 means NO_IMAGE_CAPTURED in the socket_v1 dialect (seed 004).
STATUS_NAMES = {
    -1: "UNKNOWN_COMMAND", 2: "OBJECTS_FOUND", 3: "NO_OBJECT_FOUND", 4: "NO_COLLISION_FREE_POSE",
    5: "CAPTURE_SUCCESS", 6: "DROP_OFF_POSE", 9: "CAPTURE_FAIL", 10: "MODE_CALIBRATION",
    11: "MODE_AUTO_CALIBRATION", 12: "GUIDANCE_CALIBRATION_GOOD", 13: "GUIDANCE_CALIBRATION_BAD",
    14: "MODE_2D_AUTO_CALIBRATION", 32: "DONE_GUIDANCE_CALIBRATION", 33: "DONE_CALIBRATION",
    34: "DONE_2D_AUTO_CALIBRATION", 41: "BOX_EMPTY", 42: "BOX_NOT_EMPTY",
    51: "PRECISION_CHECK_SUCCESS", 52: "PRECISION_CHECK_FAIL", 66: "SWITCH_CONFIG_SUCCESS",
    67: "SWITCH_CONFIG_FAIL",
}

# Commands whose robot script reads no response, per dialect (the cell's
# robot.dialect, docs/protocols.md "Dialects"; never meta_2).
NO_RESPONSE = {"socket_v1": {NO_COMMAND, SEND_POSE},
               "vision_pilot": {NO_COMMAND, SEND_POSE, STOP_MANUAL_CALIBRATION, GUIDANCE_CALIBRATION}}


def _fixed(value):
    """floor(MULT * value), as the seed robot scripts send it, clamped to int32."""
    v = math.floor(value * MULT)
    return max(-2**31, min(2**31 - 1, v))


class Reply:
    """A decoded 64-byte response."""

    def __init__(self, fields, dialect):
        self.raw = fields
        self.position = tuple(f / MULT for f in fields[0:3])      # metres
        self.orientation = tuple(f / MULT for f in fields[3:7])   # robot convention
        self.payload = tuple(f / MULT for f in fields[7:13])
        self.status = fields[13]
        self.meta_1 = fields[14]
        self.meta_2 = fields[15]
        name = STATUS_NAMES.get(self.status, "STATUS_%d" % self.status)
        if dialect == "socket_v1" and self.status == 4:
            name = "NO_IMAGE_CAPTURED"
        self.status_name = name

    @property
    def remaining(self):
        """Pick pose: grasps left including this one."""
        return int(round(self.payload[0]))

    @property
    def part_class(self):
        return int(round(self.payload[1]))

    def __repr__(self):
        return "Reply(%s(%d) position=%s orientation=%s payload=%s meta=%d/%d)" % (
            self.status_name, self.status, self.position, self.orientation, self.payload,
            self.meta_1, self.meta_2)


class DaoaiClient:
    """One robot connection. Not thread-safe (one request at a time, like a robot)."""

    def __init__(self, host="127.0.0.1", port=6969, robot_type=7, version=2, timeout=30.0,
                 dialect="vision_pilot"):
        if dialect not in NO_RESPONSE:
            raise ValueError("dialect must be vision_pilot or socket_v1")
        self.robot_type = robot_type  # meta_1 (7 = UR)
        self.version = version        # meta_2 (echoed by binpickd)
        self.dialect = dialect        # the seed script's rules, as the cell's robot.dialect
        self.pose = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        self._sock = socket.create_connection((host, port), timeout=timeout)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def close(self):
        self._sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def send(self, command, payload_1=0, payload_2=0):
        fields = [_fixed(v) for v in self.pose] + [command, payload_1, payload_2,
                                                    self.robot_type, self.version]
        self._sock.sendall(REQUEST.pack(*fields))

    def receive(self):
        data = b""
        while len(data) < RESPONSE.size:
            chunk = self._sock.recv(RESPONSE.size - len(data))
            if not chunk:
                raise ConnectionError("server closed the connection")
            data += chunk
        return Reply(RESPONSE.unpack(data), self.dialect)

    def call(self, command, payload_1=0, payload_2=0):
        """Sends a command; returns its Reply, or None when the command has no response."""
        self.send(command, payload_1, payload_2)
        if command in NO_RESPONSE[self.dialect]:
            return None
        return self.receive()

    # The seed's helper functions.
    def capture(self, task=0):
        return self.call(CAPTURE_AND_PROCESS, task)

    def capture_async(self, task=0):
        return self.call(CAPTURE_AND_PROCESS_ASYNC, task)

    def pick_pose(self, task=0):
        return self.call(PICK_POSE, task)

    def check_empty_box(self, task=0):
        return self.call(CHECK_EMPTY_BOX, task)

    def precision_check(self, task=0):
        return self.call(PRECISION_CHECK, task)

    def switch_config(self, config_id):
        return self.call(SWITCH_CONFIG, config_id)

    def teach_pose(self, task=0):
        return self.call(SEND_POSE, task)


def _main(argv):
    parser = argparse.ArgumentParser(description="DaoAI socket client for binpickd")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=6969)
    parser.add_argument("--robot-type", type=int, default=7, help="meta_1 (7 = UR)")
    parser.add_argument("--protocol-version", type=int, default=2, help="meta_2")
    parser.add_argument("--dialect", default="vision_pilot", choices=sorted(NO_RESPONSE),
                        help="the server cell's robot.dialect")
    parser.add_argument("--pose", type=float, nargs=7, metavar="V",
                        default=[0.4, -0.3, 0.6, 3.1416, 0.0, 0.0, 0.0],
                        help="robot pose sent with requests: x y z (m) + 4 orientation fields")
    parser.add_argument("action", choices=["pick", "capture", "pick-pose", "empty-check",
                                           "precision", "switch-config", "teach", "raw"])
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument("--config", type=int, default=1)
    parser.add_argument("--command", type=int, default=0, help="raw: the command to send")
    args = parser.parse_args(argv)

    with DaoaiClient(args.host, args.port, args.robot_type, args.protocol_version,
                     dialect=args.dialect) as robot:
        robot.pose = tuple(args.pose)

        def show(what, reply):
            print("%s -> %s" % (what, reply if reply is not None else "sent (no response)"))
            return reply

        if args.action == "pick":
            picks = 0
            while True:
                t0 = time.perf_counter()
                r = show("capture", robot.capture(args.task))
                if r.status != 5:
                    return 1
                got = 0
                while True:
                    t0 = time.perf_counter()
                    r = robot.pick_pose(args.task)
                    ms = (time.perf_counter() - t0) * 1e3
                    print("pick-pose -> %s remaining=%d class=%d position=%s (%.3f ms)" % (
                        r.status_name, r.remaining, r.part_class, r.position, ms))
                    if r.status in (3, 4) or r.remaining <= 0:
                        break
                    got += 1
                picks += got
                if got == 0:
                    break
            r = show("empty-check", robot.check_empty_box(args.task))
            print("picks: %d" % picks)
            return 0 if r.status == 41 else 1
        if args.action == "capture":
            return 0 if show("capture", robot.capture(args.task)).status == 5 else 1
        if args.action == "pick-pose":
            return 0 if show("pick-pose", robot.pick_pose(args.task)).status in (2, 6) else 1
        if args.action == "empty-check":
            return 0 if show("empty-check", robot.check_empty_box(args.task)).status == 41 else 1
        if args.action == "precision":
            return 0 if show("precision", robot.precision_check(args.task)).status == 51 else 1
        if args.action == "switch-config":
            return 0 if show("switch-config", robot.switch_config(args.config)).status == 66 else 1
        if args.action == "teach":
            show("teach", robot.teach_pose(args.task))
            return 0
        show("command %d" % args.command, robot.call(args.command, args.task))
        return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
