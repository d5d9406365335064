#!/usr/bin/env python3
"""Reads MAVLink 2 frames with pymavlink (ArduPilot's MAVLink library, common dialect) and
checks them: every frame's CRC (pymavlink checks it with the message's CRC_EXTRA) and
sequence number, the HEARTBEAT, and the ODOMETRY fields, against our own records when given.

Input: `--udp PORT` (listens on 127.0.0.1) or `--file PATH` (raw bytes of a link).
Options:
  --expect CSV     records: t_us,x,y,heading,sigma_x,sigma_y,sigma_heading,cov_xy,gamma_left,
                   gamma_right,fault,mismatch (quality -1 with a fault, 50 with a mismatch
                   in this record or one skipped since the previous ODOMETRY)
  --params D_L D_R W TICKS DELTA_L DELTA_R DELTA_DIFF   the paper model, for vx and yawspeed
  --count N        ODOMETRY frames to read (udp)
  --timeout S      seconds (udp)
  --rate HZ        expected ODOMETRY frames per second of time_usec (from the 2nd HEARTBEAT)
  --resets N       the last reset_counter; every step lands on a record with zero sigmas
  --reset-pose X Y HEADING   after the last step, the pose is this reset pose (ours)
  --reset-tolerance M  0 (default): exactly, with zero covariance (the step's record is the
                   reset sample's); else within M metres and M radians (the reset fell on a
                   sample that output_divider skipped: the step's record is a later one)
  --allow-gaps N   sequence gaps allowed (frames lost to our reply frames in the stream)
  --qualities Q..  the quality values allowed (default 100: no fault, no index mismatch)
Prints `read_mavlink: ok ...` or exits 1 with the first failure."""
import argparse
import bisect
import math
import socket
import struct
import sys
import time

from pymavlink.dialects.v20 import common as mavlink


def f32(v):
    return struct.unpack("<f", struct.pack("<f", v))[0]


def fail(msg):
    print(f"read_mavlink: FAIL: {msg}")
    sys.exit(1)


def close(a, b, tol, what):
    if not (abs(a - b) <= tol * max(1.0, abs(b))):
        fail(f"{what}: {a!r} != {b!r}")


def rel(a, b, tol, what, scale=0.0):
    """Within `tol` of |b| (or of `scale` where that is larger: a difference of variances)."""
    if not (abs(a - b) <= tol * max(abs(b), scale)):
        fail(f"{what}: {a!r} != {b!r}")


def frames_from(args):
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    out = []
    if args.file:
        data = open(args.file, "rb").read()
        for m in mav.parse_buffer(data) or []:
            out.append(m)
        return out
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", args.udp))
    sock.settimeout(0.5)
    print("ready", flush=True)
    end = time.time() + args.timeout
    odometry = 0
    while time.time() < end and odometry < args.count:
        try:
            data, _ = sock.recvfrom(65536)
        except socket.timeout:
            continue
        for m in mav.parse_buffer(data) or []:
            out.append(m)
            odometry += m.get_type() == "ODOMETRY"
    return out


def check_stream(msgs, allow_gaps):
    good, gaps, bad = [], 0, 0
    after_bad = False
    for m in msgs:
        if m.get_type() == "BAD_DATA":
            # The unit sends 0x00 after each frame (our frames' delimiter): skipped by
            # every parser as a byte outside a frame.
            if bytes(m.data) != b"\x00":
                bad += 1
                after_bad = True
            continue
        if good:
            expect = (good[-1].get_seq() + 1) % 256
            if m.get_seq() != expect:
                if not after_bad:
                    fail(f"sequence {good[-1].get_seq()} -> {m.get_seq()} with no bad data between")
                gaps += 1
        after_bad = False
        good.append(m)
    if gaps > allow_gaps:
        fail(f"{gaps} sequence gaps, at most {allow_gaps} allowed")
    return good, gaps, bad


def quaternion(heading):
    h = 0.5 * heading
    w, z = math.cos(h), math.sin(h)
    return (w, 0.0, 0.0, z) if w >= 0 else (-w, 0.0, 0.0, -z)


def check_heartbeats(hb, odo):
    if not hb:
        fail("no HEARTBEAT")
    for h in hb:
        got = (h.type, h.autopilot, h.base_mode, h.custom_mode, h.system_status, h.mavlink_version)
        if got != (18, 8, 0, 0, 4, 3):
            fail(f"HEARTBEAT fields {got}")
    return len(hb)


def check_odometry_static(o, qualities):
    if (o.frame_id, o.child_frame_id, o.estimator_type) != (20, 12, 0):
        fail(f"frame ids / estimator {(o.frame_id, o.child_frame_id, o.estimator_type)}")
    if o.quality not in qualities:
        fail(f"quality {o.quality}, expected one of {qualities}")
    if o.z != 0 or o.q[1] != 0 or o.q[2] != 0 or o.vy != 0 or o.vz != 0:
        fail("z, q x/y, vy, vz must be 0")
    close(sum(c * c for c in o.q), 1.0, 1e-5, "|q|")
    if o.q[0] < 0:
        fail("q w < 0")
    pc = o.pose_covariance
    for i, v in enumerate(pc):
        if i not in (0, 1, 6, 20) and v != 0:
            fail(f"pose_covariance[{i}] = {v}")


def check_against_records(odo, rows, params):
    by_t = {int(r["t_us"]): r for r in rows}
    times = sorted(by_t)
    prev = None
    matched = 0
    for o in odo:
        r = by_t.get(o.time_usec)
        if r is None:
            fail(f"no record at time_usec {o.time_usec}")
        matched += 1
        if "fault" in r:
            # An index mismatch on a record that output_divider skips comes with the next
            # ODOMETRY: any mismatch in the records since the previous one.
            lo = bisect.bisect_right(times, int(prev["t_us"])) if prev else times.index(o.time_usec)
            hi = bisect.bisect_right(times, o.time_usec)
            mismatch = any(by_t[t]["mismatch"] for t in times[lo:hi])
            expect = -1 if r["fault"] else 50 if mismatch else 100
            if o.quality != expect:
                fail(f"quality {o.quality} at {o.time_usec}, expected {expect}")
        close(o.x, f32(r["y"]), 0, "x (north) = our y")
        close(o.y, f32(r["x"]), 0, "y (east) = our x")
        for a, b in zip(o.q, quaternion(r["heading"])):
            close(a, b, 1e-6, "q")
        pc = o.pose_covariance
        # Single-precision squares of the record's sigmas: exactly what the unit sends.
        close(pc[0], f32(f32(r["sigma_y"]) * f32(r["sigma_y"])), 0, "var north")
        close(pc[6], f32(f32(r["sigma_x"]) * f32(r["sigma_x"])), 0, "var east")
        close(pc[1], f32(r["cov_xy"]), 0, "cov north-east")
        close(pc[20], f32(f32(r["sigma_heading"]) * f32(r["sigma_heading"])), 0, "var yaw")
        vc = o.velocity_covariance
        if prev is None:
            if not (math.isnan(vc[0]) and o.vx == 0 and o.yawspeed == 0):
                fail("first ODOMETRY: velocity 0 with covariance[0] NaN expected")
        elif params:
            dl, dr, w, ticks, del_l, del_r, del_d = params
            dt = (int(r["t_us"]) - int(prev["t_us"])) * 1e-6
            nl = int(r["gamma_left"]) - int(prev["gamma_left"])
            nr = int(r["gamma_right"]) - int(prev["gamma_right"])
            sl, sr = nl * math.pi * dl / ticks, nr * math.pi * dr / ticks
            close(o.vx, (sl + sr) / 2 / dt, 1e-4, "vx")
            close(o.yawspeed, (sl - sr) / w / dt, 1e-4, "yawspeed (clockwise)")
            ql, qr = math.pi * dl / ticks, math.pi * dr / ticks
            vl = (del_l * nl) ** 2 + ql * ql / 6
            vr = (del_r * nr) ** 2 + qr * qr / 6
            ve = (del_d * (nl - nr)) ** 2
            # Relative: the unit computes them in single precision.
            rel(vc[0], (vl + vr) / 4 / dt ** 2, 1e-5, "var vx")
            close(vc[6], vc[0], 0, "var vy = var vx")
            rel(vc[20], (vl + vr + 4 * ve) / (w * w * dt * dt), 1e-5, "var yawspeed")
            scale = (vl + vr) / (2 * w * dt * dt)
            rel(vc[5], (vl - vr) / (2 * w * dt * dt), 1e-5, "cov vx yawspeed", scale)
        prev = r
    return matched


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--udp", type=int)
    p.add_argument("--file")
    p.add_argument("--expect")
    p.add_argument("--params", type=float, nargs=7)
    p.add_argument("--count", type=int, default=100)
    p.add_argument("--timeout", type=float, default=30)
    p.add_argument("--rate", type=float)
    p.add_argument("--resets", type=int)
    p.add_argument("--reset-pose", type=float, nargs=3)
    p.add_argument("--reset-tolerance", type=float, default=0.0)
    p.add_argument("--allow-gaps", type=int, default=0)
    p.add_argument("--qualities", type=int, nargs="+", default=[100])
    args = p.parse_args()
    good, gaps, bad = check_stream(frames_from(args), args.allow_gaps)
    odo = [m for m in good if m.get_type() == "ODOMETRY"]
    hb = [m for m in good if m.get_type() == "HEARTBEAT"]
    other = [m.get_type() for m in good if m.get_type() not in ("ODOMETRY", "HEARTBEAT")]
    if other:
        fail(f"unexpected messages {other[:5]}")
    if not odo:
        fail("no ODOMETRY")
    for m in good:
        if (m.get_srcSystem(), m.get_srcComponent()) != (1, 197):
            fail(f"ids {(m.get_srcSystem(), m.get_srcComponent())}")
    for o in odo:
        check_odometry_static(o, args.qualities)
    n_hb = check_heartbeats(hb, odo)
    matched = 0
    if args.expect:
        import csv
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(open(args.expect))]
        matched = check_against_records(odo, rows, args.params)
    t = [o.time_usec for o in odo]
    if any(b <= a for a, b in zip(t, t[1:])):
        fail("time_usec not increasing")
    # The rate from the second HEARTBEAT on: a new output_divider applies from the next
    # whole second (the first HEARTBEAT of a stream may come before it).
    beats = [i for i, m in enumerate(good) if m.get_type() == "HEARTBEAT"]
    if args.rate is not None and len(beats) >= 2:
        t = [m.time_usec for m in good[beats[1]:] if m.get_type() == "ODOMETRY"]
    span = (t[-1] - t[0]) * 1e-6
    rate = (len(t) - 1) / span if span > 0 else 0
    if args.rate is not None:
        close(rate, args.rate, 0.02, "ODOMETRY rate (per second of time_usec)")
    if args.resets is not None:
        counters = [o.reset_counter for o in odo]
        if counters[-1] != args.resets:
            fail(f"reset_counter ends at {counters[-1]}, expected {args.resets}")
        for a, b in zip(odo, odo[1:]):
            if b.reset_counter != a.reset_counter:
                if b.reset_counter != (a.reset_counter + 1) % 256:
                    fail("reset_counter must step by one")
                tol = args.reset_tolerance
                if tol == 0 and any(b.pose_covariance[i] != 0 for i in (0, 1, 6, 20)):
                    fail("a reset_counter step on a pose with non-zero covariance")
                if args.reset_pose and b.reset_counter == args.resets:
                    x, y, h = args.reset_pose
                    if tol == 0:
                        close(b.x, f32(y), 1e-6, "reset pose north")
                        close(b.y, f32(x), 1e-6, "reset pose east")
                        for a2, b2 in zip(b.q, quaternion(h)):
                            close(a2, b2, 1e-6, "reset pose q")
                    elif math.hypot(b.x - y, b.y - x) > tol or abs(
                        2 * math.atan2(b.q[3], b.q[0]) - math.remainder(h, 2 * math.pi)
                    ) > tol:
                        fail(f"reset pose {(b.x, b.y, b.q)} not within {tol} of {(y, x, h)}")
    print(
        f"read_mavlink: ok {len(odo)} ODOMETRY ({matched} matched to records, {rate:.2f}/s), "
        f"{n_hb} HEARTBEAT, {gaps} sequence gaps, {bad} bad data, "
        f"reset_counter {odo[-1].reset_counter}"
    )


if __name__ == "__main__":
    main()
