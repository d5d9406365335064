#!/usr/bin/env python3
"""Independent reader of odoctl's MCAP recordings (docs/ROS.md).

Reads the file with the `mcap` and `mcap-ros2-support` packages (not our code), decodes every
message from the ros2msg schemas in the file, and checks each field against values computed
here from the inputs by the rules of docs/ROS.md:

  --samples   the SAMPLES CSV that was replayed (counts, time columns, flags)
  --replay    the replay CSV of the same run (`odoctl replay --out`): t,x,y,heading,sigmas
  --expect    t,cov_xy,cov_x_heading,cov_y_heading per row (the integrator's covariance
              terms the replay CSV does not carry; written by the Rust test)
  --params    the parameter TOML of the replay (all keys explicit)
  --stamps    samples_t | utc | mcu_time: which stamps the file must carry
  --fault-at  optional sample index from which the left encoder fault flag is set
  --ns, --frame-prefix, --no-tf, --joints LEFT,RIGHT: the names the recording was made with
              (`--namespace`, `--frame-prefix`, `--no-tf`, `--*-wheel-joint`)

Exit status 0 when everything matches; prints what was checked.
"""
import argparse
import csv
import math
import struct
import sys
import tomllib

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

GPS_EPOCH_UNIX = 315964800
LEAP_2017 = 18  # GPS - UTC since 2017-01-01
UNOBSERVED = 1.0e6
FLOOR = 1.0e-10  # the least published variance of x, y, yaw, vx, vy, yaw rate


def f32(text):
    """The float32 value a CSV field holds, as a Python float."""
    return struct.unpack("<f", struct.pack("<f", float(text)))[0]


def fail(msg):
    print("read_mcap: FAIL: " + msg, file=sys.stderr)
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)


def close(a, b, rel=1e-12, abs_=0.0):
    return abs(a - b) <= max(abs_, rel * max(abs(a), abs(b)))


def yaw_quaternion(heading):
    yaw = math.pi / 2 - heading
    yaw = math.atan2(math.sin(yaw), math.cos(yaw))
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def ns(stamp):
    """Nanoseconds of a builtin_interfaces/Time."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def read_csv(path):
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    head = rows[0]
    return [dict(zip(head, r)) for r in rows[1:]]


def main():
    ap = argparse.ArgumentParser()
    for a in ("--mcap", "--samples", "--replay", "--expect", "--params", "--stamps"):
        ap.add_argument(a, required=True)
    ap.add_argument("--fault-at", type=int, default=None)
    ap.add_argument("--ns", default="")
    ap.add_argument("--frame-prefix", default="")
    ap.add_argument("--no-tf", action="store_true")
    ap.add_argument("--joints", default="left_wheel_joint,right_wheel_joint")
    o = ap.parse_args()
    ns_ = "/" + o.ns.strip("/") if o.ns.strip("/") else ""
    odom_topic, joint_topic = ns_ + "/odom", ns_ + "/joint_states"
    odom_frame, base_frame = o.frame_prefix + "odom", o.frame_prefix + "base_link"
    joint_names = o.joints.split(",")

    samples = read_csv(o.samples)
    replay = read_csv(o.replay)
    expect = read_csv(o.expect)
    with open(o.params, "rb") as f:
        p = tomllib.load(f)
    n = len(samples)
    check(len(replay) == n and len(expect) == n, "row counts differ between the inputs")

    # Stamps (ns), by the rules of docs/ROS.md.
    stamps = []
    for s in samples:
        t = float(s["t"])
        if o.stamps == "samples_t":
            stamps.append(round(t * 1e9))
        elif o.stamps == "mcu_time":
            stamps.append(int(s["mcu_time_us"]) * 1000)
        else:
            week, tow_ms = int(s["gps_week"]), int(s["gps_tow_ms"])
            sub = t - tow_ms * 1e-3
            whole_ms = week * 604800 * 1000 + tow_ms + (GPS_EPOCH_UNIX - LEAP_2017) * 1000
            stamps.append(whole_ms * 1_000_000 + round(sub * 1e9))

    # Twist from the counts (constant transfer constants) and the model's variances.
    ticks = float(p["ticks_per_rev"])
    q = [math.pi * p["left_diameter"] / ticks, math.pi * p["right_diameter"] / ticks]
    w = p["track_width"]
    model = p["uncertainty_model"]

    def twist(i):
        if i == 0:
            return None
        n1 = int(samples[i]["left"]) - int(samples[i - 1]["left"])
        n2 = int(samples[i]["right"]) - int(samples[i - 1]["right"])
        dt = (stamps[i] - stamps[i - 1]) * 1e-9
        s1, s2 = n1 * q[0], n2 * q[1]
        if model == "paper":
            v1 = (f32(p["delta_left"]) * abs(n1)) ** 2
            v2 = (f32(p["delta_right"]) * abs(n2)) ** 2
            ve = (f32(p["delta_diff"]) * abs(n1 - n2)) ** 2
        else:
            v1 = f32(p["kappa_left"]) * abs(s1)
            v2 = f32(p["kappa_right"]) * abs(s2)
            ve = 0.0
        v1 += q[0] ** 2 / 6
        v2 += q[1] ** 2 / 6
        return dict(
            vx=(s1 + s2) / 2 / dt,
            wz=-(s1 - s2) / w / dt,
            var_vx=(v1 + v2) / 4 / dt**2,
            var_wz=(v1 + v2 + 4 * ve) / (w * w * dt**2),
            cov=-(v1 - v2) / (2 * w * dt**2),
        )

    with open(o.mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        topics = {c.topic: c for c in summary.channels.values()}
        want = {
            odom_topic: "nav_msgs/msg/Odometry",
            "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
            odom_topic + "/path": "nav_msgs/msg/Path",
            joint_topic: "sensor_msgs/msg/JointState",
        }
        if not o.no_tf:
            want["/tf"] = "tf2_msgs/msg/TFMessage"
        check(set(topics) == set(want), f"channels {sorted(topics)} != {sorted(want)}")
        for topic, schema in want.items():
            check(topic in topics, f"no channel {topic}")
            c = topics[topic]
            sc = summary.schemas[c.schema_id]
            check(c.message_encoding == "cdr", f"{topic}: encoding {c.message_encoding}")
            check(sc.encoding == "ros2msg" and sc.name == schema, f"{topic}: schema {sc.name} {sc.encoding}")
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        check("odoctl" in meta, "no odoctl metadata record")
        check(meta["odoctl"]["stamp_source"] == {"samples_t": "samples_t", "utc": "utc_from_gps_time_tag", "mcu_time": "mcu_time"}[o.stamps],
              f"stamp_source {meta['odoctl']['stamp_source']}")

        odom, tf, diags, paths, joints = [], [], [], [], []
        for schema, channel, message, msg in reader.iter_decoded_messages():
            {odom_topic: odom, "/tf": tf, "/diagnostics": diags, odom_topic + "/path": paths,
             joint_topic: joints}[channel.topic].append((message, msg))

    check(len(odom) == n, f"{len(odom)} /odom messages for {n} samples")
    check(len(tf) == (0 if o.no_tf else n), f"{len(tf)} /tf messages for {n} samples")
    check(len(joints) == n, f"{len(joints)} /joint_states messages for {n} samples")
    fields = 0
    for i, (mm, m) in enumerate(odom):
        r, e = replay[i], expect[i]
        where = f"/odom #{i} (t={r['t']})"
        st = ns(m.header.stamp)
        check(abs(st - stamps[i]) <= 1, f"{where}: stamp {st} != {stamps[i]}")
        check(mm.log_time == st, f"{where}: log time")
        check(m.header.frame_id == odom_frame and m.child_frame_id == base_frame, f"{where}: frames")
        pos = m.pose.pose.position
        check(pos.x == float(r["x"]) and pos.y == float(r["y"]) and pos.z == 0.0, f"{where}: position {pos}")
        qo = m.pose.pose.orientation
        qe = yaw_quaternion(float(r["heading"]))
        check(all(close(a, b, 0, 1e-12) for a, b in zip((qo.x, qo.y, qo.z, qo.w), qe)), f"{where}: quaternion {qo} != {qe}")
        c = m.pose.covariance
        sx, sy, sh = f32(r["sigma_x"]), f32(r["sigma_y"]), f32(r["sigma_heading"])
        xy, xa, ya = f32(e["cov_xy"]), f32(e["cov_x_heading"]), f32(e["cov_y_heading"])
        cexp = [0.0] * 36
        cexp[0], cexp[7], cexp[35] = max(sx * sx, FLOOR), max(sy * sy, FLOOR), max(sh * sh, FLOOR)
        cexp[1] = cexp[6] = xy
        cexp[5] = cexp[30] = -xa
        cexp[11] = cexp[31] = -ya
        cexp[14] = cexp[21] = cexp[28] = UNOBSERVED
        check(len(c) == 36, f"{where}: covariance length")
        for k in range(36):
            check(c[k] == cexp[k], f"{where}: pose covariance[{k}] {c[k]} != {cexp[k]}")
        tw = twist(i)
        lin, ang, tc = m.twist.twist.linear, m.twist.twist.angular, m.twist.covariance
        check(lin.y == 0 and lin.z == 0 and ang.x == 0 and ang.y == 0, f"{where}: twist off-plane")
        if tw is None:
            check(lin.x == 0 and ang.z == 0, f"{where}: first twist")
            check(all(tc[k] == (UNOBSERVED if k % 7 == 0 else 0.0) for k in range(36)), f"{where}: first twist covariance")
        else:
            check(close(lin.x, tw["vx"], 1e-9, 1e-12), f"{where}: vx {lin.x} != {tw['vx']}")
            check(close(ang.z, tw["wz"], 1e-9, 1e-12), f"{where}: wz {ang.z} != {tw['wz']}")
            texp = [0.0] * 36
            texp[0] = texp[7] = max(tw["var_vx"], FLOOR)
            texp[35] = max(tw["var_wz"], FLOOR)
            texp[5] = texp[30] = tw["cov"]
            texp[14] = texp[21] = texp[28] = UNOBSERVED
            for k in range(36):
                check(close(tc[k], texp[k], 1e-9, 1e-300), f"{where}: twist covariance[{k}] {tc[k]} != {texp[k]}")
        fields += 3 + 4 + 36 + 6 + 36
        if not o.no_tf:
            tm, t = tf[i]
            check(tm.log_time == st, f"{where}: /tf log time")
            check(len(t.transforms) == 1, f"{where}: /tf count")
            x = t.transforms[0]
            check(x.header.frame_id == odom_frame and x.child_frame_id == base_frame, f"{where}: /tf frames")
            check(ns(x.header.stamp) == st, f"{where}: /tf stamp")
            tr, ro = x.transform.translation, x.transform.rotation
            check((tr.x, tr.y, tr.z) == (pos.x, pos.y, pos.z), f"{where}: /tf translation")
            check((ro.x, ro.y, ro.z, ro.w) == (qo.x, qo.y, qo.z, qo.w), f"{where}: /tf rotation")
            fields += 7
        # Joint states: 2 pi counts / ticks_per_rev (rad); velocities over the interval.
        jm, j = joints[i]
        check(jm.log_time == st and ns(j.header.stamp) == st, f"{where}: /joint_states stamp")
        check(list(j.name) == joint_names, f"{where}: joint names {list(j.name)}")
        cl, cr = int(samples[i]["left"]), int(samples[i]["right"])
        check(list(j.position) == [2 * math.pi * cl / ticks, 2 * math.pi * cr / ticks],
              f"{where}: joint positions {list(j.position)}")
        check(len(j.effort) == 0, f"{where}: efforts")
        if i == 0:
            check(len(j.velocity) == 0, f"{where}: first joint velocities")
        else:
            dt = (stamps[i] - stamps[i - 1]) * 1e-9
            pl, pr = int(samples[i - 1]["left"]), int(samples[i - 1]["right"])
            vexp = [2 * math.pi * (cl - pl) / ticks / dt, 2 * math.pi * (cr - pr) / ticks / dt]
            check(len(j.velocity) == 2 and all(close(a, b, 1e-9, 1e-12) for a, b in zip(j.velocity, vexp)),
                  f"{where}: joint velocities {list(j.velocity)} != {vexp}")
        fields += 7

    # Diagnostics: stamps increase, at most one second apart while the status is unchanged,
    # ERROR with the fault named from the fault sample on.
    check(len(diags) >= 1, "no /diagnostics")
    last = None
    for dm, d in diags:
        st = ns(d.header.stamp)
        check(last is None or st >= last, "diagnostics stamps decrease")
        check(st in set(stamps), "a diagnostics stamp is no sample's stamp")
        check(len(d.status) == 1 and d.status[0].name == ns_[1:] + ("/" if ns_ else "") + "odoctl: odometry unit",
              f"diagnostics status {[x.name for x in d.status]}")
        s = d.status[0]
        i = stamps.index(st)
        kv = {v.key: v.value for v in s.values}
        check(kv.get("uncertainty_model") == model, f"diagnostics model {kv.get('uncertainty_model')}")
        if o.fault_at is not None and i >= o.fault_at:
            check(s.level == 2 and "left encoder fault" in s.message and kv["left_fault"] == "true",
                  f"diagnostics at sample {i}: level {s.level} {s.message!r}")
        else:
            check(s.level == 0 and s.message == "ok", f"diagnostics at sample {i}: level {s.level} {s.message!r}")
        last = st
    if o.fault_at is not None:
        check(any(stamps.index(ns(d.header.stamp)) == o.fault_at for _, d in diags),
              "no diagnostics at the fault's sample")
    diag_stamps = [ns(d.header.stamp) for _, d in diags] + [stamps[-1]]
    for a, b in zip(diag_stamps, diag_stamps[1:]):
        check(b - a <= 1_000_000_000 + max(y - x for x, y in zip(stamps, stamps[1:])), "diagnostics more than 1 s apart")

    # The path: every pose of /odom in order.
    check(len(paths) == 1, f"{len(paths)} /odom/path messages")
    path = paths[0][1]
    check(len(path.poses) == n, "path length")
    for i, ps in enumerate(path.poses):
        check(ps.pose.position.x == odom[i][1].pose.pose.position.x and ps.pose.position.y == odom[i][1].pose.pose.position.y,
              f"path pose {i}")
        check(ns(ps.header.stamp) == ns(odom[i][1].header.stamp), f"path stamp {i}")

    print(f"read_mcap: ok: {n} {odom_topic}, {len(tf)} /tf, {len(joints)} {joint_topic} messages "
          f"({fields} fields), {len(diags)} /diagnostics, 1 path of {n} poses; stamps {o.stamps}")


if __name__ == "__main__":
    main()
