#!/usr/bin/env python3
"""pymavlink peer for tests/replay_mavlink.rs: plays the flight controller's side of
`vidslam replay --mavlink` and records what arrives, for the test to compare with the replay's
own outputs (trajectory.tum, frames.csv, report.json).

Protocol with the test: binds a free UDP port on 127.0.0.1 and prints `PORT <n>`; receives until
a line `stop` arrives on stdin (sent after vidslam exited), drains the socket, then prints
`REPORT <json>` and exits 0. The report holds every ODOMETRY message's fields in arrival order
(pymavlink's decoding: CRC-checked MAVLink 2), the count of each message type and of bytes
pymavlink could not decode.
"""

import json
import math
import os
import select
import socket
import sys

os.environ["MAVLINK20"] = "1"  # before importing mavutil: decode MAVLink 2 (ODOMETRY is #331)
from pymavlink import mavutil  # noqa: E402

mavlink = mavutil.mavlink


def finite_or_none(v):
    return v if math.isfinite(v) else None


def main():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.bind(("127.0.0.1", 0))
    print(f"PORT {sock.getsockname()[1]}", flush=True)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.robust_parsing = True
    counts = {}
    odometry = []
    bad = 0
    stop = False
    while True:
        waits = [sock] if stop else [sock, sys.stdin]
        ready, _, _ = select.select(waits, [], [], 0.2 if stop else 5.0)
        if not ready:
            if stop:
                break
            continue
        if sys.stdin in ready:
            if sys.stdin.readline().strip() in ("stop", ""):
                stop = True
            continue
        data, _ = sock.recvfrom(65536)
        for m in mav.parse_buffer(data) or []:
            kind = m.get_type()
            if kind == "BAD_DATA":
                bad += len(m.data)
                continue
            counts[kind] = counts.get(kind, 0) + 1
            if kind == "ODOMETRY":
                odometry.append(
                    {
                        "time_usec": m.time_usec,
                        "frame_id": m.frame_id,
                        "child_frame_id": m.child_frame_id,
                        "xyz": [m.x, m.y, m.z],
                        "q": list(m.q),
                        "v": [m.vx, m.vy, m.vz],
                        "rates": [m.rollspeed, m.pitchspeed, m.yawspeed],
                        "pose_covariance_0": finite_or_none(m.pose_covariance[0]),
                        "reset_counter": m.reset_counter,
                        "quality": m.quality,
                        "sysid": m.get_srcSystem(),
                        "compid": m.get_srcComponent(),
                    }
                )
    report = {"counts": counts, "bad_bytes": bad, "odometry": odometry}
    print("REPORT " + json.dumps(report), flush=True)


if __name__ == "__main__":
    main()
