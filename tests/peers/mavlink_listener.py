#!/usr/bin/env python3
"""pymavlink peer for tests/mavlink_pymavlink.rs: plays the flight controller's side of
`vidslam mavlink play` and checks everything it receives against the input trajectory.

Protocol with the test: binds a free UDP port on 127.0.0.1 and prints `PORT <n>`; receives until
a line `stop` arrives on stdin (sent after vidslam exited), drains the socket, then prints
`REPORT <json>` and exits 0 when no check failed, 1 otherwise.

As the FC (system 1, component 1) it sends one TIMESYNC request when the first message arrives
and checks the reply; with --fc-clock-offset-s it also answers vidslam's TIMESYNC requests from a
clock that is that far ahead of CLOCK_MONOTONIC, and checks that time stamps switch to it.

The expected values are computed here, independently of vidslam's Rust code, from the conventions
documented in src/output/frames.rs and src/cli/mavlink.rs: FC local = world rotated 180 deg about
x; FC body = r_fcbody_imu * IMU, r_fcbody_imu = Rz(yaw) Ry(pitch) Rx(roll); velocities are
central differences over +-half an output period.
"""

import argparse
import json
import math
import os
import select
import socket
import sys
import time

os.environ["MAVLINK20"] = "1"  # before importing mavutil: decode MAVLink 2 (ODOMETRY is #331)
from pymavlink import mavutil  # noqa: E402

mavlink = mavutil.mavlink

FLOAT_TOL = 1e-6
SAME_CLOCK_TOL_NS = 1_000_000_000  # "same time base" check; the bases under test differ by 1000 s


# ---- quaternions (w, x, y, z) -------------------------------------------------------------------
def qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def qconj(q):
    return (q[0], -q[1], -q[2], -q[3])


def qnorm(q):
    n = math.sqrt(sum(c * c for c in q))
    return tuple(c / n for c in q)


def qrot(q, v):
    return qmul(qmul(q, (0.0, v[0], v[1], v[2])), qconj(q))[1:]


def qaxis(axis, angle):
    s = math.sin(angle / 2)
    return (math.cos(angle / 2), axis[0] * s, axis[1] * s, axis[2] * s)


def qlog(q):
    if q[0] < 0:
        q = tuple(-c for c in q)
    vn = math.sqrt(q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    if vn < 1e-15:
        return (2 * q[1], 2 * q[2], 2 * q[3])
    angle = 2 * math.atan2(vn, q[0])
    return tuple(c / vn * angle for c in q[1:])


def euler_zyx(q):
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


Q_LOCAL_WORLD = qaxis((1, 0, 0), math.pi)


def read_euroc_csv(path):
    poses = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            c = [s.strip() for s in line.split(",")]
            t = int(c[0])
            p = tuple(float(v) for v in c[1:4])
            q = qnorm(tuple(float(v) for v in c[4:8]))
            poses.append((t, p, q))
    return poses


def expected_samples(poses, rate_hz, q_mount):
    """k -> dict of expected FC-frame values (the trajectory must hold every time used)."""
    by_t = {t: (p, q) for t, p, q in poses}
    t0, t_last = poses[0][0], poses[-1][0]
    period = round(1e9 / rate_hz)
    half = max(period // 2, 1)
    out = {}
    k = 0
    while t0 + k * period <= t_last:
        t = t0 + k * period
        ta, tb = max(t - half, t0), min(t + half, t_last)
        (p, q), (pa, qa), (pb, qb) = by_t[t], by_t[ta], by_t[tb]
        dt = (tb - ta) / 1e9
        v_w = tuple((b - a) / dt for a, b in zip(pa, pb))
        w_imu = tuple(c / dt for c in qlog(qmul(qconj(qa), qb)))
        q_fc = qmul(qmul(Q_LOCAL_WORLD, q), qconj(q_mount))
        out[k] = {
            "pos": (p[0], -p[1], -p[2]),
            "q": q_fc,
            "v_body": qrot(q_mount, qrot(qconj(q), v_w)),
            "v_local": (v_w[0], -v_w[1], -v_w[2]),
            "rates": qrot(q_mount, w_imu),
            "euler": euler_zyx(q_fc),
        }
        k += 1
    return out, period


class Checker:
    def __init__(self):
        self.failures = []

    def check(self, ok, what):
        if not ok and len(self.failures) < 50:
            self.failures.append(what)
        return ok

    def close(self, got, want, what):
        for i, (g, w) in enumerate(zip(got, want)):
            if not (math.isfinite(g) and abs(g - w) <= FLOAT_TOL):
                self.check(False, f"{what}[{i}] = {g!r}, expected {w!r} (tolerance {FLOAT_TOL})")
                return False
        return True


def covariance_expectation(stds, full3=False):
    """Expected covariance array; None stds = unknown (NaN in element 0, zeros elsewhere)."""
    if stds is None:
        return None
    if full3:
        a = [0.0] * 9
        for i, s in enumerate(stds):
            a[4 * i] = s * s
        return a
    a = [0.0] * 21
    for i, s in enumerate(stds):
        a[[0, 6, 11, 15, 18, 20][i]] = s * s
    return a


def check_covariance(c, got, want, what):
    got = list(got)
    if want is None:
        c.check(math.isnan(got[0]) and all(v == 0.0 for v in got[1:]),
                f"{what}: expected unknown (NaN in element 0 only), got {got}")
    else:
        c.check(all(math.isfinite(v) for v in got) and
                all(abs(g - w) <= 1e-9 + 1e-6 * abs(w) for g, w in zip(got, want)),
                f"{what}: got {got}, expected {want}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trajectory", required=True, help="EuRoC CSV given to vidslam")
    ap.add_argument("--rate-hz", type=float, required=True)
    ap.add_argument("--mount-rpy-deg", default="180,0,0")
    ap.add_argument("--messages", choices=["odometry", "legacy"], default="odometry")
    ap.add_argument("--frame", choices=["frd", "ned"], default="frd")
    ap.add_argument("--pose-std", default=None, help="POSITION_M,ATTITUDE_RAD or absent = unknown")
    ap.add_argument("--velocity-std", default=None, help="VELOCITY_M_S,RATE_RAD_S or absent")
    ap.add_argument("--discontinuity-at", type=int, action="append", default=[])
    ap.add_argument("--inject-nan-at", type=int, action="append", default=[])
    ap.add_argument("--fc-clock-offset-s", type=float, default=None)
    args = ap.parse_args()

    roll, pitch, yaw = (math.radians(float(v)) for v in args.mount_rpy_deg.split(","))
    q_mount = qmul(qmul(qaxis((0, 0, 1), yaw), qaxis((0, 1, 0), pitch)), qaxis((1, 0, 0), roll))
    poses = read_euroc_csv(args.trajectory)
    expect, period_ns = expected_samples(poses, args.rate_hz, q_mount)
    pose_std = [float(v) for v in args.pose_std.split(",")] if args.pose_std else None
    vel_std = [float(v) for v in args.velocity_std.split(",")] if args.velocity_std else None
    fc_offset_ns = None if args.fc_clock_offset_s is None else int(args.fc_clock_offset_s * 1e9)

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    sock.bind(("127.0.0.1", 0))
    print(f"PORT {sock.getsockname()[1]}", flush=True)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)  # we play the FC
    mav.robust_parsing = True  # CRC failures come back as BAD_DATA instead of exceptions

    received = []  # (recv_monotonic_ns, msg)
    our_request = None  # (ts1, index in received at send time)
    answered_requests = 0
    stop = False
    give_up = time.monotonic() + 120  # only against a hung test: the test sends 'stop'

    def handle(data, addr, now_ns):
        nonlocal our_request, answered_requests
        for msg in mav.parse_buffer(data) or []:
            received.append((now_ns, msg))
            if our_request is None:
                ts1 = time.monotonic_ns()
                sock.sendto(mavlink.MAVLink_timesync_message(0, ts1).pack(mav), addr)
                our_request = (ts1, len(received))
            if (fc_offset_ns is not None and msg.get_type() == "TIMESYNC" and msg.tc1 == 0
                    and msg.get_srcComponent() == 197):
                reply = mavlink.MAVLink_timesync_message(time.monotonic_ns() + fc_offset_ns, msg.ts1)
                sock.sendto(reply.pack(mav), addr)
                answered_requests += 1

    while time.monotonic() < give_up:
        ready, _, _ = select.select([sock, sys.stdin], [], [], 1.0)
        if sock in ready:
            data, addr = sock.recvfrom(65536)
            handle(data, addr, time.monotonic_ns())
        if sys.stdin in ready:
            line = sys.stdin.readline()
            if line == "" or line.strip() == "stop":
                stop = True
                break
    sock.setblocking(False)
    while True:  # drain what vidslam sent before it exited
        try:
            data, addr = sock.recvfrom(65536)
        except BlockingIOError:
            break
        handle(data, addr, time.monotonic_ns())

    c = Checker()
    c.check(stop, "no 'stop' from the test before the safety deadline")
    counts = {}
    for _, m in received:
        counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
    # 1. CRC and protocol version of every message.
    c.check(counts.get("BAD_DATA", 0) == 0, f"{counts.get('BAD_DATA', 0)} messages failed pymavlink's CRC/parse")
    for _, m in received:
        if m.get_type() != "BAD_DATA":
            c.check(m.get_msgbuf()[0] == 0xFD, f"{m.get_type()} is not MAVLink 2")
            c.check((m.get_srcSystem(), m.get_srcComponent()) == (1, 197),
                    f"{m.get_type()} from {m.get_srcSystem()}/{m.get_srcComponent()}, expected 1/197")

    # 2. Heartbeats.
    hbs = [m for _, m in received if m.get_type() == "HEARTBEAT"]
    duration_s = (len(expect) - 1) * period_ns / 1e9
    c.check(len(hbs) >= int(duration_s) + 1, f"{len(hbs)} heartbeats for a {duration_s:.2f} s stream")
    for h in hbs:
        c.check(h.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER and h.autopilot == mavlink.MAV_AUTOPILOT_INVALID,
                f"heartbeat type/autopilot {h.type}/{h.autopilot}")
        c.check(h.system_status in (mavlink.MAV_STATE_STANDBY, mavlink.MAV_STATE_ACTIVE,
                                    mavlink.MAV_STATE_CRITICAL, mavlink.MAV_STATE_FLIGHT_TERMINATION),
                f"heartbeat state {h.system_status}")
    c.check(bool(hbs) and hbs[-1].system_status == mavlink.MAV_STATE_FLIGHT_TERMINATION,
            "last heartbeat is not MAV_STATE_FLIGHT_TERMINATION")

    # 3. Pose messages.
    pose_type = "ODOMETRY" if args.messages == "odometry" else "VISION_POSITION_ESTIMATE"
    poses_rx = [(t, m) for t, m in received if m.get_type() == pose_type]
    speeds = [m for _, m in received if m.get_type() == "VISION_SPEED_ESTIMATE"]
    want_idx = sorted(set(expect) - set(args.inject_nan_at))
    c.check(0 not in args.inject_nan_at, "test setup: sample 0 anchors the time grid")
    c.check(len(poses_rx) == len(want_idx),
            f"{len(poses_rx)} {pose_type} for {len(expect)} samples at {args.rate_hz} Hz "
            f"minus {len(args.inject_nan_at)} NaN: expected {len(want_idx)}")
    if args.messages == "legacy":
        c.check(len(speeds) == len(poses_rx), f"{len(speeds)} VISION_SPEED_ESTIMATE for {len(poses_rx)} positions")

    def usec_of(m):
        return m.time_usec if pose_type == "ODOMETRY" else m.usec

    # Time base of each stamp: our CLOCK_MONOTONIC (companion) or the fake FC clock.
    bases = []
    latencies_ns = []  # stamp to receipt, companion base: reported, not checked
    for t_rx, m in poses_rx:
        u_ns = usec_of(m) * 1000
        if abs(u_ns - t_rx) < SAME_CLOCK_TOL_NS:
            bases.append("companion")
            latencies_ns.append(t_rx - u_ns)
        elif fc_offset_ns is not None and abs(u_ns - (t_rx + fc_offset_ns)) < SAME_CLOCK_TOL_NS:
            bases.append("fc")
        else:
            bases.append("unknown")
            c.check(False, f"{pose_type} time_usec {usec_of(m)} is in no known time base (received at {t_rx} ns)")
    if fc_offset_ns is None:
        c.check(all(b == "companion" for b in bases), "stamps not all on the host monotonic clock")
    else:
        first_fc = bases.index("fc") if "fc" in bases else None
        c.check(first_fc is not None, "time stamps never switched to the FC time base")
        if first_fc is not None:
            c.check(all(b == "companion" for b in bases[:first_fc]) and all(b == "fc" for b in bases[first_fc:]),
                    f"time bases not companion* then fc+: {bases}")

    seen = []
    u0 = usec_of(poses_rx[0][1]) if poses_rx else 0
    after_nan = {k + 1 for k in args.inject_nan_at}
    for (t_rx, m), base in zip(poses_rx, bases):
        rel_ns = usec_of(m) * 1000 - u0 * 1000 - (fc_offset_ns if base == "fc" else 0)
        k = round(rel_ns / period_ns)
        seen.append(k)
        if k not in expect:
            c.check(False, f"{pose_type} at t+{rel_ns} ns matches no output sample")
            continue
        if base == "companion":
            c.check(abs(rel_ns - k * period_ns) <= 1000,
                    f"sample {k}: time_usec offset {rel_ns} ns, expected {k * period_ns} +- 1 us")
        e = expect[k]
        resets = sum(1 for d in args.discontinuity_at if d <= k)
        c.check(m.reset_counter == resets, f"sample {k}: reset_counter {m.reset_counter}, expected {resets}")
        if pose_type == "ODOMETRY":
            c.check(m.frame_id == (mavlink.MAV_FRAME_LOCAL_FRD if args.frame == "frd" else mavlink.MAV_FRAME_LOCAL_NED),
                    f"sample {k}: frame_id {m.frame_id}")
            c.check(m.child_frame_id == mavlink.MAV_FRAME_BODY_FRD, f"sample {k}: child_frame_id {m.child_frame_id}")
            c.check(m.estimator_type == mavlink.MAV_ESTIMATOR_TYPE_VIO, f"sample {k}: estimator_type {m.estimator_type}")
            want_q = -1 if k in after_nan else 100
            c.check(m.quality == want_q, f"sample {k}: quality {m.quality}, expected {want_q}")
            c.close((m.x, m.y, m.z), e["pos"], f"sample {k} position")
            q = tuple(m.q)
            c.check(abs(math.sqrt(sum(v * v for v in q)) - 1) <= FLOAT_TOL, f"sample {k}: |q| = {q}")
            sign = 1.0 if sum(a * b for a, b in zip(q, e["q"])) >= 0 else -1.0
            c.close(q, tuple(sign * v for v in e["q"]), f"sample {k} quaternion")
            c.close((m.vx, m.vy, m.vz), e["v_body"], f"sample {k} body velocity")
            c.close((m.rollspeed, m.pitchspeed, m.yawspeed), e["rates"], f"sample {k} angular rates")
            check_covariance(c, m.pose_covariance, covariance_expectation(pose_std and pose_std[:1] * 3 + pose_std[1:] * 3),
                             f"sample {k} pose_covariance")
            check_covariance(c, m.velocity_covariance, covariance_expectation(vel_std and vel_std[:1] * 3 + vel_std[1:] * 3),
                             f"sample {k} velocity_covariance")
        else:
            c.close((m.x, m.y, m.z), e["pos"], f"sample {k} position")
            c.close((m.roll, m.pitch, m.yaw), e["euler"], f"sample {k} roll/pitch/yaw")
            check_covariance(c, m.covariance, covariance_expectation(pose_std and pose_std[:1] * 3 + pose_std[1:] * 3),
                             f"sample {k} covariance")
    for s in speeds:
        rel_candidates = [k for (t_rx, m), k in zip(poses_rx, seen) if m.usec == s.usec]
        if not c.check(len(rel_candidates) == 1, f"VISION_SPEED_ESTIMATE usec {s.usec} matches no position"):
            continue
        k = rel_candidates[0]
        if k in expect:
            c.close((s.x, s.y, s.z), expect[k]["v_local"], f"sample {k} local velocity")
            check_covariance(c, s.covariance, covariance_expectation(vel_std and vel_std[:1] * 3, True),
                             f"sample {k} speed covariance")
    c.check(sorted(seen) == want_idx, f"samples seen {sorted(seen)}, expected {want_idx}")
    for _, m in received:  # nothing non-finite anywhere but the unknown-covariance marker
        d = m.to_dict()
        for key, v in d.items():
            vals = v if isinstance(v, list) else [v]
            for i, x in enumerate(vals):
                if isinstance(x, float) and not math.isfinite(x):
                    c.check(math.isnan(x) and i == 0 and "covariance" in key,
                            f"{m.get_type()}.{key}[{i}] = {x}")

    # 4. TIMESYNC: the reply to our request.
    replies = [(t, m) for t, m in received if m.get_type() == "TIMESYNC" and m.tc1 != 0]
    reply_ok = False
    if our_request is not None:
        ts1, idx = our_request
        mine = [(t, m) for t, m in replies if m.ts1 == ts1]
        if c.check(len(mine) == 1, f"{len(mine)} TIMESYNC replies to our request ts1={ts1}"):
            t_rx, r = mine[0]
            before = [usec_of(m) * 1000 for t, m in received[:idx] if m.get_type() == pose_type]
            reply_ok = (c.check(abs(r.tc1 - t_rx) < SAME_CLOCK_TOL_NS,
                                f"TIMESYNC tc1 {r.tc1} not on CLOCK_MONOTONIC (received at {t_rx})")
                        and c.check(fc_offset_ns is not None or not before or r.tc1 >= max(before),
                                    f"TIMESYNC tc1 {r.tc1} earlier than a pose stamped before it"))
    else:
        c.check(False, "nothing received, no TIMESYNC request sent")
    requests = sum(1 for _, m in received if m.get_type() == "TIMESYNC" and m.tc1 == 0)

    report = {
        "failures": c.failures,
        "counts": counts,
        "pose_messages": len(poses_rx),
        "expected_pose_messages": len(want_idx),
        "heartbeats": len(hbs),
        "timesync_reply_ok": reply_ok,
        "timesync_requests_from_vidslam": requests,
        "timesync_requests_answered": answered_requests,
        "time_bases": {b: bases.count(b) for b in set(bases)},
        "reset_counters": sorted({m.reset_counter for _, m in poses_rx}),
        "stamp_to_receipt_us": {
            "median": sorted(latencies_ns)[len(latencies_ns) // 2] / 1000 if latencies_ns else None,
            "max": max(latencies_ns) / 1000 if latencies_ns else None,
        },
        "pose_frame_bytes": len(poses_rx[0][1].get_msgbuf()) if poses_rx else None,
    }
    print("REPORT " + json.dumps(report), flush=True)
    sys.exit(0 if not c.failures else 1)


if __name__ == "__main__":
    main()
