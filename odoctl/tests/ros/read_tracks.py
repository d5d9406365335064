#!/usr/bin/env python3
"""Independent reader of `odoctl validate --mcap` (docs/ROS.md): with the `mcap` and
`mcap-ros2-support` packages, checks `/reference/path` against the REFERENCE CSV (every row,
position bit for bit, orientation = its heading or the direction to the next point, stamps)
and `/odom/path` against the `--errors` CSV of the same validation (x, y, heading at each
common time).

usage: read_tracks.py --mcap F --reference R.csv --errors E.csv
"""
import argparse
import csv
import math
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def fail(msg):
    print("read_tracks: FAIL: " + msg, file=sys.stderr)
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)


def rows(path):
    with open(path, newline="") as f:
        r = [x for x in csv.reader(f) if x and not x[0].startswith("#")]
    return [dict(zip(r[0], x)) for x in r[1:]]


def yaw_q(heading):
    yaw = math.pi / 2 - heading
    yaw = math.atan2(math.sin(yaw), math.cos(yaw))
    return (math.sin(yaw / 2), math.cos(yaw / 2))


def ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def check_path(name, path, expected):
    check(len(path.poses) == len(expected), f"{name}: {len(path.poses)} poses, expected {len(expected)}")
    for i, (ps, (t, x, y, h)) in enumerate(zip(path.poses, expected)):
        where = f"{name} #{i}"
        check(ps.header.frame_id == "odom", f"{where}: frame {ps.header.frame_id}")
        check(abs(ns(ps.header.stamp) - round(t * 1e9)) <= 1, f"{where}: stamp")
        p, q = ps.pose.position, ps.pose.orientation
        check((p.x, p.y, p.z) == (x, y, 0.0), f"{where}: position {p} != {(x, y)}")
        z, w = yaw_q(h)
        check(abs(q.z - z) <= 1e-12 and abs(q.w - w) <= 1e-12 and q.x == 0 and q.y == 0, f"{where}: orientation")
    check(ns(path.header.stamp) == round(expected[-1][0] * 1e9), f"{name}: header stamp")


def main():
    ap = argparse.ArgumentParser()
    for a in ("--mcap", "--reference", "--errors"):
        ap.add_argument(a, required=True)
    o = ap.parse_args()
    ref = rows(o.reference)
    err = rows(o.errors)

    expected_ref = []
    along = 0.0
    for i, r in enumerate(ref):
        x, y = float(r["x"]), float(r["y"])
        if i + 1 < len(ref):
            dx, dy = float(ref[i + 1]["x"]) - x, float(ref[i + 1]["y"]) - y
            if dx != 0 or dy != 0:
                along = math.atan2(dx, dy)
        h = float(r["heading"]) if r.get("heading") else along
        expected_ref.append((float(r["t"]), x, y, h))
    expected_odo = [(float(e["t"]), float(e["x"]), float(e["y"]), float(e["heading"])) for e in err]

    got = {}
    with open(o.mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, msg in reader.iter_decoded_messages():
            check(schema.name == "nav_msgs/msg/Path" and schema.encoding == "ros2msg", f"{channel.topic}: schema {schema.name}")
            check(channel.topic not in got, f"{channel.topic}: more than one message")
            got[channel.topic] = msg
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    check(set(got) == {"/reference/path", "/odom/path"}, f"topics {sorted(got)}")
    check(meta["odoctl"]["command"] == "validate" and meta["odoctl"]["stamp_source"] == "samples_t", "metadata")
    check_path("/reference/path", got["/reference/path"], expected_ref)
    check_path("/odom/path", got["/odom/path"], expected_odo)
    print(f"read_tracks: ok: /reference/path {len(expected_ref)} poses, /odom/path {len(expected_odo)} poses")


if __name__ == "__main__":
    main()
