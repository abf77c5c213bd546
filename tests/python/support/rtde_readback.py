"""Reads an RTDE controller on 127.0.0.1:30004 with ur-rtde (``rtde_receive``) and prints what it
read, one JSON line per data package seen: ``{"timestamp": hex, "values": {getter: [hex…]}}``,
floats as ``float.hex`` so that the comparison is bit for bit.

Run by test_rtde.py inside a private network namespace, where port 30004 is free:
``python rtde_readback.py FREQUENCY COUNT VARIABLE…``. A package is printed only if the timestamp
read before and after its values is the same (ur-rtde updates its state on a thread of its own).
"""

from __future__ import annotations

import json
import sys
import time

import rtde_receive

GETTERS = {
    "actual_q": "getActualQ",
    "actual_TCP_pose": "getActualTCPPose",
    "actual_qd": "getActualQd",
    "joint_temperatures": "getJointTemperatures",
    "robot_mode": "getRobotMode",
    "safety_mode": "getSafetyMode",
    "robot_status_bits": "getRobotStatus",
    "speed_scaling": "getSpeedScaling",
    "payload": "getPayload",
    "payload_cog": "getPayloadCog",
    "joint_mode": "getJointMode",
    "actual_digital_input_bits": "getActualDigitalInputBits",
}


def encode(value):
    if isinstance(value, float):
        return value.hex()
    if isinstance(value, (list, tuple)):
        return [encode(v) for v in value]
    return value


def main() -> None:
    frequency, count, variables = float(sys.argv[1]), int(sys.argv[2]), sys.argv[3:]
    receive = rtde_receive.RTDEReceiveInterface("127.0.0.1", frequency, variables)
    seen = set()
    deadline = time.monotonic() + 20
    while len(seen) < count and time.monotonic() < deadline:
        before = receive.getTimestamp()
        values = {name: encode(getattr(receive, GETTERS[name])()) for name in variables if name != "timestamp"}
        after = receive.getTimestamp()
        if before == after and before not in seen and before > 0:
            seen.add(before)
            print(json.dumps({"timestamp": before.hex(), "values": values}), flush=True)
        time.sleep(0.0005)
    receive.disconnect()


if __name__ == "__main__":
    main()
