#!/usr/bin/env python3
"""Independent DDS subscriber for `odoctl bridge` (docs/ROS.md): Eclipse Cyclone DDS (the
`cyclonedds` package, not our code) with the ROS 2 types written here from the .msg
definitions, on the ROS 2 domain of ROS_DOMAIN_ID (default 0) ("rt/odom", "rt/tf",
"rt/joint_states", "rt/diagnostics"; under --ns the relative ones, "rt/NS/odom", ...).

Prints "ready" once its readers exist, then collects for --timeout seconds (or until
--count /odom messages) and checks each /odom message against --expect (the unit's records:
x,y,heading,sigma_x,sigma_y,sigma_heading,cov_xy,gamma_left,gamma_right; matched by
position): frames, position, quaternion (yaw = pi/2 - heading), pose covariance layout (the
variances at least 1e-10), /tf equal to /odom (none with --no-tf), /joint_states at the same
stamps with 2 pi gamma / --ticks rad, stamps increasing. --expect-error TEXT instead requires an ERROR status containing TEXT on
/diagnostics (a lost link) and no /odom message.
"""
import argparse
import os
import csv
import math
import struct
import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: sequence[DiagnosticStatus]


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header
    name: sequence[str]
    position: sequence[float64]
    velocity: sequence[float64]
    effort: sequence[float64]


FLOOR = 1.0e-10


def fail(msg):
    print("dds_subscriber: FAIL: " + msg, file=sys.stderr, flush=True)
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)


def f32(text):
    return struct.unpack("<f", struct.pack("<f", float(text)))[0]


def ns(t):
    return t.sec * 1_000_000_000 + t.nanosec


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--expect")
    ap.add_argument("--expect-error")
    ap.add_argument("--count", type=int, default=50)
    ap.add_argument("--timeout", type=float, default=30)
    ap.add_argument("--max-step", type=float, default=None,
                    help="instead of --expect: /odom positions at most this far (m) apart in a row")
    ap.add_argument("--ns", default="")
    ap.add_argument("--frame-prefix", default="")
    ap.add_argument("--no-tf", action="store_true")
    ap.add_argument("--ticks", type=float, default=20000)
    ap.add_argument("--joints", default="left_wheel_joint,right_wheel_joint")
    o = ap.parse_args()
    ns_ = o.ns.strip("/")
    rel = (ns_ + "/") if ns_ else ""
    odom_frame, base_frame = o.frame_prefix + "odom", o.frame_prefix + "base_link"

    dp = DomainParticipant(int(os.environ.get("ROS_DOMAIN_ID", "0")))
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(1000))
    odom_r = DataReader(dp, Topic(dp, f"rt/{rel}odom", Odometry), qos=qos)
    tf_r = DataReader(dp, Topic(dp, "rt/tf", TFMessage), qos=qos)
    joint_r = DataReader(dp, Topic(dp, f"rt/{rel}joint_states", JointState), qos=qos)
    diag_r = DataReader(dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=qos)
    print("ready", flush=True)

    odom, tf, joints, diags = [], [], [], []
    end = time.time() + o.timeout
    while time.time() < end:
        odom += odom_r.take(100)
        tf += tf_r.take(100)
        joints += joint_r.take(100)
        diags += diag_r.take(100)
        if o.expect and len(odom) >= o.count and (o.no_tf or len(tf) >= o.count) and len(joints) >= o.count:
            break
        if o.max_step and len(odom) >= o.count:
            break
        if o.expect_error and any(s.level == 2 and o.expect_error in s.message for d in diags for s in d.status):
            break
        time.sleep(0.02)

    if o.expect_error:
        check(not odom, f"{len(odom)} /odom messages from a unit that is not there")
        msgs = [s.message for d in diags for s in d.status]
        check(any(s.level == 2 and o.expect_error in s.message for d in diags for s in d.status),
              f"no ERROR status with {o.expect_error!r}: {msgs}")
        print(f"dds_subscriber: ok: {len(diags)} /diagnostics, ERROR {o.expect_error!r}")
        return

    if o.max_step:
        # odom is continuous (REP-105): no jump between consecutive messages, whatever the
        # unit did (a reset_pose).
        check(len(odom) >= o.count, f"{len(odom)} /odom messages, expected at least {o.count}")
        steps = [math.hypot(b.pose.pose.position.x - a.pose.pose.position.x,
                            b.pose.pose.position.y - a.pose.pose.position.y)
                 for a, b in zip(odom, odom[1:])]
        check(all(m.header.frame_id == odom_frame and m.child_frame_id == base_frame for m in odom),
              "/odom frames")
        check(max(steps) <= o.max_step, f"/odom jumps by {max(steps)} m")
        resets = [s.message for d in diags for s in d.status if "reset_pose" in s.message]
        print(f"dds_subscriber: ok: {len(odom)} /{rel}odom continuous (largest step {max(steps):.4f} m), "
              f"{len(resets)} reset WARNs", flush=True)
        return

    with open(o.expect, newline="") as f:
        rows = list(csv.DictReader(f))
    by_pos = {(float(r["x"]), float(r["y"])): r for r in rows}
    check(len(odom) >= o.count, f"{len(odom)} /odom messages received, expected at least {o.count}")
    last = None
    for i, m in enumerate(odom):
        where = f"/odom #{i}"
        check(m.header.frame_id == odom_frame and m.child_frame_id == base_frame, f"{where}: frames")
        p = m.pose.pose.position
        r = by_pos.get((p.x, p.y))
        check(r is not None, f"{where}: position {p.x}, {p.y} is no record's")
        h = float(r["heading"])
        yaw = math.atan2(math.sin(math.pi / 2 - h), math.cos(math.pi / 2 - h))
        q = m.pose.pose.orientation
        check(abs(q.z - math.sin(yaw / 2)) < 1e-12 and abs(q.w - math.cos(yaw / 2)) < 1e-12 and q.x == 0 and q.y == 0,
              f"{where}: quaternion")
        c = m.pose.covariance
        sx, sy, sh = f32(r["sigma_x"]), f32(r["sigma_y"]), f32(r["sigma_heading"])
        check((c[0], c[7], c[35]) == (max(sx * sx, FLOOR), max(sy * sy, FLOOR), max(sh * sh, FLOOR)),
              f"{where}: variances")
        check(c[1] == c[6] == f32(r["cov_xy"]), f"{where}: cov xy")
        check(c[14] == c[21] == c[28] == 1e6, f"{where}: unobserved variances")
        t = m.twist.covariance
        check(t[14] == t[21] == t[28] == 1e6 and t[0] > 0 and t[35] > 0, f"{where}: twist covariance")
        st = ns(m.header.stamp)
        check(last is None or st > last, f"{where}: stamp not increasing")
        last = st
    stamps = {ns(m.header.stamp): m for m in odom}
    jmatched = 0
    for j in joints:
        check(list(j.name) == o.joints.split(","), f"/joint_states names {list(j.name)}")
        m = stamps.get(ns(j.header.stamp))
        if m is None:
            continue
        r = by_pos[(m.pose.pose.position.x, m.pose.pose.position.y)]
        want = [2 * math.pi * int(r["gamma_left"]) / o.ticks, 2 * math.pi * int(r["gamma_right"]) / o.ticks]
        check(list(j.position) == want, f"/joint_states positions {list(j.position)} != {want}")
        check(len(j.velocity) in (0, 2) and len(j.effort) == 0, "/joint_states velocity/effort")
        jmatched += 1
    check(jmatched >= o.count, f"only {jmatched} /joint_states match an /odom stamp")
    matched, others = 0, 0
    for x in tf:
        check(len(x.transforms) == 1, "/tf: one transform")
        tr = x.transforms[0]
        if tr.child_frame_id != base_frame:
            # Another robot's transform on the shared /tf (its own prefixed frames).
            check(tr.header.frame_id != odom_frame, f"/tf: {tr.child_frame_id} under our {odom_frame}")
            others += 1
            continue
        check(tr.header.frame_id == odom_frame, "/tf frames")
        m = stamps.get(ns(tr.header.stamp))
        if m is not None:
            matched += 1
            check((tr.transform.translation.x, tr.transform.translation.y) == (m.pose.pose.position.x, m.pose.pose.position.y),
                  "/tf translation != /odom position")
    if o.no_tf:
        check(not tf, f"{len(tf)} /tf messages with --no-tf")
    else:
        check(matched >= o.count, f"only {matched} /tf messages match an /odom stamp")
    unit = rel + "odoctl_bridge: odometry unit"
    check(diags and any(s.name == unit for d in diags for s in d.status),
          f"/diagnostics: no status {unit!r}: {sorted(set(s.name for d in diags for s in d.status))}")
    print(f"dds_subscriber: ok: {len(odom)} /{rel}odom, {len(tf)} /tf ({matched} matched), "
          f"{len(joints)} /{rel}joint_states ({jmatched} matched), {len(diags)} /diagnostics; "
          f"{others} /tf of other robots")


if __name__ == "__main__":
    main()
