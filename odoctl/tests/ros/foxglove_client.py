#!/usr/bin/env python3
"""A Foxglove WebSocket client written from the protocol's documentation (ws-protocol spec,
v1): connects with subprotocol foxglove.websocket.v1, reads serverInfo and advertise,
subscribes to every channel, decodes binary messageData (opcode 0x01: uint32 subscription id,
uint64 log time ns, payload) and checks what `odoctl bridge --foxglove` sends against the
unit's records (--expect CSV: t_us,x,y,heading,sigma_x,sigma_y,sigma_heading,cov_xy).

CDR payloads are decoded by mcap-ros2-support's decoder from the advertised ros2msg schema
text; JSON payloads by json. Prints `foxglove_client: ok ...` and exits 0 when every check
holds."""

import argparse
import asyncio
import json
import math
import struct
import sys
import time

import websockets
from mcap_ros2._dynamic import generate_dynamic


def fail(msg):
    print(f"foxglove_client: FAIL: {msg}", flush=True)
    sys.exit(1)


def read_expect(path):
    rows = []
    with open(path) as f:
        head = f.readline().strip().split(",")
        for line in f:
            v = dict(zip(head, line.strip().split(",")))
            # t_us is an integer; the sigmas are the record's float32 values.
            rows.append({k: (int(x) if k == "t_us" else f32(float(x)) if k.startswith("sigma")
                             else float(x)) for k, x in v.items()})
    return rows


def yaw_of(q):
    return 2.0 * math.atan2(q.z, q.w)


def wrap(a):
    while a > math.pi:
        a -= 2 * math.pi
    while a <= -math.pi:
        a += 2 * math.pi
    return a


def f32(v):
    return struct.unpack("<f", struct.pack("<f", v))[0]


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--expect", required=True)
    ap.add_argument("--min-odom", type=int, default=50)
    ap.add_argument("--timeout", type=float, default=30)
    ap.add_argument("--until-records", type=int, default=0,
                    help="stop once the record with this index was received")
    ap.add_argument("--expect-unit-status", action="append", default=[],
                    help="a server status with this text under the unit's id")
    ap.add_argument("--expect-status", action="append", default=[],
                    help="a /diagnostics ERROR whose message contains this")
    a = ap.parse_args()
    recs = read_expect(a.expect)

    ws = None
    for _ in range(100):
        try:
            ws = await websockets.connect(a.url, subprotocols=["foxglove.websocket.v1"],
                                          max_size=None)
            break
        except OSError:
            await asyncio.sleep(0.1)
    if ws is None:
        fail("cannot connect")
    if ws.subprotocol != "foxglove.websocket.v1":
        fail(f"subprotocol {ws.subprotocol}")

    info = json.loads(await ws.recv())
    if info.get("op") != "serverInfo" or "name" not in info or "capabilities" not in info:
        fail(f"serverInfo expected first: {info}")
    adv = json.loads(await ws.recv())
    if adv.get("op") != "advertise":
        fail(f"advertise expected: {adv}")
    chans = {c["topic"]: c for c in adv["channels"]}
    want = {"/odom": ("cdr", "nav_msgs/msg/Odometry", "ros2msg"),
            "/tf": ("cdr", "tf2_msgs/msg/TFMessage", "ros2msg"),
            "/diagnostics": ("cdr", "diagnostic_msgs/msg/DiagnosticArray", "ros2msg"),
            "/odom/path": ("cdr", "nav_msgs/msg/Path", "ros2msg"),
            "/joint_states": ("cdr", "sensor_msgs/msg/JointState", "ros2msg"),
            "/odom/ellipse": ("json", "foxglove.SceneUpdate", "jsonschema")}
    decoders = {}
    for topic, (enc, name, senc) in want.items():
        c = chans.get(topic)
        if c is None:
            fail(f"{topic} not advertised: {list(chans)}")
        if (c["encoding"], c["schemaName"], c["schemaEncoding"]) != (enc, name, senc):
            fail(f"{topic}: {c['encoding']} {c['schemaName']} {c['schemaEncoding']}")
        if enc == "cdr":
            decoders[topic] = generate_dynamic(name, c["schema"])[name]
        else:
            json.loads(c["schema"])
            decoders[topic] = lambda b: json.loads(b.decode())
    subs = {}
    for i, topic in enumerate(want):
        subs[100 + i] = topic
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": sid, "channelId": chans[t]["id"]} for sid, t in subs.items()]}))

    got = {t: [] for t in want}
    statuses = []
    nbytes = {}
    end = time.monotonic() + a.timeout
    while time.monotonic() < end:
        try:
            m = await asyncio.wait_for(ws.recv(), timeout=max(0.01, end - time.monotonic()))
        except asyncio.TimeoutError:
            break
        except websockets.ConnectionClosed:
            break
        if isinstance(m, str):
            statuses.append(json.loads(m))
            continue
        if m[0] != 0x01:
            fail(f"unknown binary opcode {m[0]}")
        sid, log_time = struct.unpack_from("<IQ", m, 1)
        if sid not in subs:
            fail(f"subscription id {sid} not ours")
        topic = subs[sid]
        nbytes[topic] = nbytes.get(topic, 0) + len(m) - 13
        msg = decoders[topic](m[13:])
        got[topic].append((log_time, msg))
        if topic == "/odom":
            if len(got["/odom"]) >= a.min_odom and a.until_records == 0:
                break
        if topic == "/odom" and a.until_records:
            p = msg.pose.pose.position
            r = recs[a.until_records]
            if p.x == r["x"] and p.y == r["y"]:
                # a little more for the path and ellipse of the same time
                end = min(end, time.monotonic() + 0.7)
    await ws.close()

    # /odom: every message is one of the unit's records, in order, none twice (no stale
    # pose published as new); stamps = log times, on the unit's clock.
    odom = got["/odom"]
    if len(odom) < a.min_odom:
        fail(f"{len(odom)} /odom messages, {a.min_odom} expected")
    # The stamps are the unit's clock on the host's: anchored at a pose that only one record
    # has, each stamp names one record, whose pose it must carry.
    count = {}
    for r in recs:
        count[(r["x"], r["y"])] = count.get((r["x"], r["y"]), 0) + 1
    by_t = {r["t_us"]: k for k, r in enumerate(recs)}
    offset = None
    for lt, o in odom:
        p = o.pose.pose.position
        if count.get((p.x, p.y)) == 1:
            k = next(k for k, r in enumerate(recs) if (r["x"], r["y"]) == (p.x, p.y))
            offset = lt - recs[k]["t_us"] * 1000
            break
    if offset is None:
        fail("no /odom pose unique among the records")
    idx = []
    for lt, o in odom:
        p = o.pose.pose.position
        t_ns = lt - offset
        k = by_t.get(t_ns // 1000) if t_ns % 1000 == 0 else None
        if k is None:
            fail(f"/odom stamp {lt} is no record's time on the unit's clock")
        r = recs[k]
        if (r["x"], r["y"]) != (p.x, p.y):
            fail(f"/odom at ({p.x!r}, {p.y!r}) stamped as record #{k} at ({r['x']!r}, {r['y']!r})")
        if idx and k <= idx[-1]:
            fail(f"record #{k} published after #{idx[-1]} (repeated or stale)")
        idx.append(k)
        if o.header.frame_id != "odom" or o.child_frame_id != "base_link":
            fail("frames")
        stamp = o.header.stamp.sec * 1_000_000_000 + o.header.stamp.nanosec
        if stamp != lt:
            fail(f"log time {lt} != header stamp {stamp}")
        yaw = yaw_of(o.pose.pose.orientation)
        if abs(wrap(yaw - (math.pi / 2 - r["heading"]))) > 1e-6:
            fail(f"yaw {yaw} for heading {r['heading']}")
        c = o.pose.covariance
        sx, sy, cxy = r["sigma_x"], r["sigma_y"], r["cov_xy"]
        # Variances at least the published floor, 1e-10 (docs/ROS.md).
        if c[0] != max(sx * sx, 1e-10) or c[7] != max(sy * sy, 1e-10) or c[1] != cxy or c[6] != cxy:
            fail(f"covariance {c[0]}, {c[7]}, {c[1]} for sigmas {sx}, {sy} and cov_xy {cxy}")
    gaps = sum(1 for i0, i1 in zip(idx, idx[1:]) if i1 != i0 + 1)

    # /tf: the /odom pose.
    by_stamp = {lt: o for lt, o in odom}
    # /joint_states: both wheels, at the stamps of /odom.
    for lt, j in got["/joint_states"]:
        if list(j.name) != ["left_wheel_joint", "right_wheel_joint"] or len(j.position) != 2:
            fail(f"/joint_states {list(j.name)} {list(j.position)}")
        if lt not in by_stamp:
            fail(f"/joint_states at {lt}: no /odom there")
    if len(got["/joint_states"]) < len(odom) // 2:
        fail(f"{len(got['/joint_states'])} /joint_states for {len(odom)} /odom")
    for lt, tf in got["/tf"]:
        t = tf.transforms[0]
        o = by_stamp.get(lt)
        if o is None:
            continue
        if (t.header.frame_id, t.child_frame_id) != ("odom", "base_link") or \
                t.transform.translation.x != o.pose.pose.position.x or \
                t.transform.rotation.w != o.pose.pose.orientation.w:
            fail("/tf differs from /odom")

    # /odom/path: poses are records in order, the last the latest /odom; it grows.
    paths = got["/odom/path"]
    if len(paths) < 2:
        fail(f"{len(paths)} /odom/path messages")
    sizes = []
    for lt, path in paths:
        j = 0
        for ps in path.poses:
            p = ps.pose.position
            while j < len(recs) and not (recs[j]["x"] == p.x and recs[j]["y"] == p.y):
                j += 1
            if j == len(recs):
                fail(f"path pose ({p.x}, {p.y}) out of order or none of the records")
            j += 1
        o = by_stamp.get(lt)
        if o is not None and path.poses[-1].pose.position.x != o.pose.pose.position.x:
            fail("path does not end at the current pose")
        sizes.append(len(path.poses))
    if sizes != sorted(sizes) or sizes[-1] <= sizes[0]:
        fail(f"path does not grow: {sizes}")

    # /odom/ellipse: every outline point p (about the centre, rotated by the pose) lies on the
    # 1-sigma ellipse of the record at the centre: p^T adj(S) p = det(S).
    ells = got["/odom/ellipse"]
    if len(ells) < a.min_odom // 2:
        fail(f"{len(ells)} ellipses")
    checked = 0
    for lt, sc in ells:
        e = sc["entities"][0]
        if e["frame_id"] != "odom" or e["id"] != "position_1sigma":
            fail("ellipse entity")
        line = e["lines"][0]
        if line["type"] != 1:
            fail("ellipse is not a LINE_LOOP")
        pos = line["pose"]["position"]
        q = line["pose"]["orientation"]
        ang = 2 * math.atan2(q["z"], q["w"])
        r = next((r for r in recs if r["x"] == pos["x"] and r["y"] == pos["y"]), None)
        if r is None:
            fail("ellipse centre is none of the records")
        # The published covariance: variances at least the floor, 1e-10.
        sxx, syy, sxy = max(r["sigma_x"] ** 2, 1e-10), max(r["sigma_y"] ** 2, 1e-10), r["cov_xy"]
        det = sxx * syy - sxy * sxy
        if det <= 1e-30:
            continue
        ca, sa = math.cos(ang), math.sin(ang)
        for pt in line["points"]:
            x = ca * pt["x"] - sa * pt["y"]
            y = sa * pt["x"] + ca * pt["y"]
            v = syy * x * x - 2 * sxy * x * y + sxx * y * y
            if abs(v - det) > 1e-6 * det:
                fail(f"ellipse point off the 1-sigma ellipse: {v} vs {det}")
        size = e["cylinders"][0]["size"]
        lam = 0.5 * (sxx + syy) + math.hypot(0.5 * (sxx - syy), sxy)
        if abs(size["x"] - 2 * math.sqrt(lam)) > 1e-6 * size["x"]:
            fail(f"disc major axis {size['x']} vs 2 sqrt({lam})")
        checked += 1
    if checked < 10:
        fail(f"only {checked} ellipses with a non-degenerate covariance")

    # /diagnostics and server status.
    diags = [(d.status[0].level, d.status[0].message) for _, d in got["/diagnostics"]]
    # Server statuses: the unit's faults under the unit's id, the link's under the link's.
    for s in statuses:
        if s.get("op") != "status":
            continue
        unit = "encoder fault" in s.get("message", "")
        if not s.get("id", "").endswith(": odometry unit" if unit else ": link"):
            fail(f"a server status under the wrong id: {s}")
    for want_msg in a.expect_unit_status:
        if not any(s.get("op") == "status" and want_msg in s.get("message", "")
                   and s.get("id") == "odoctl_bridge: odometry unit" for s in statuses):
            fail(f"no server status of the unit with `{want_msg}`: {statuses}")
    for want_msg in a.expect_status:
        if not any(l == 2 and want_msg in m for l, m in diags):
            fail(f"no /diagnostics ERROR with `{want_msg}`: {diags}")
        if not any(s.get("op") == "status" and s.get("level") == 2 and want_msg in s.get("message", "")
                   for s in statuses):
            fail(f"no server status error with `{want_msg}`")
    print(f"foxglove_client: ok: {len(odom)} /odom (records #{idx[0]}..#{idx[-1]}, {gaps} gaps), "
          f"{len(got['/tf'])} /tf, {len(paths)} /odom/path ({sizes[0]} -> {sizes[-1]} poses), "
          f"{len(ells)} /odom/ellipse ({checked} checked), {len(diags)} /diagnostics "
          f"(levels {sorted(set(l for l, _ in diags))}), {len(statuses)} status messages; "
          "mean payload bytes: " + ", ".join(f"{t} {nbytes[t] / len(got[t]):.0f}" for t in want
                                              if got[t]),
          flush=True)


asyncio.run(main())
