#!/usr/bin/env python3
"""Independent DDS subscriber for `odoctl bridge` (docs/ROS.md): Eclipse Cyclone DDS (the
`cyclonedds` package, not our code) with the ROS 2 types written here from the .msg
definitions, on the ROS 2 domain of ROS_DOMAIN_ID (default 0) ("rt/odom", "rt/tf",
"rt/diagnostics").

Prints "ready" once its readers exist, then collects for --timeout seconds (or until
--count /odom messages) and checks each /odom message against --expect (the unit's records:
x,y,heading,sigma_x,sigma_y,sigma_heading,cov_xy; matched by position): frames, position,
quaternion (yaw = pi/2 - heading), pose covariance layout, /tf equal to /odom, stamps
increasing. --expect-error TEXT instead requires an ERROR status containing TEXT on
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
    o = ap.parse_args()

    dp = DomainParticipant(int(os.environ.get("ROS_DOMAIN_ID", "0")))
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(1000))
    odom_r = DataReader(dp, Topic(dp, "rt/odom", Odometry), qos=qos)
    tf_r = DataReader(dp, Topic(dp, "rt/tf", TFMessage), qos=qos)
    diag_r = DataReader(dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=qos)
    print("ready", flush=True)

    odom, tf, diags = [], [], []
    end = time.time() + o.timeout
    while time.time() < end:
        odom += odom_r.take(100)
        tf += tf_r.take(100)
        diags += diag_r.take(100)
        if o.expect and len(odom) >= o.count and len(tf) >= o.count:
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

    with open(o.expect, newline="") as f:
        rows = list(csv.DictReader(f))
    by_pos = {(float(r["x"]), float(r["y"])): r for r in rows}
    check(len(odom) >= o.count, f"{len(odom)} /odom messages received, expected at least {o.count}")
    last = None
    for i, m in enumerate(odom):
        where = f"/odom #{i}"
        check(m.header.frame_id == "odom" and m.child_frame_id == "base_link", f"{where}: frames")
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
        check((c[0], c[7], c[35]) == (sx * sx, sy * sy, sh * sh), f"{where}: variances")
        check(c[1] == c[6] == f32(r["cov_xy"]), f"{where}: cov xy")
        check(c[14] == c[21] == c[28] == 1e6, f"{where}: unobserved variances")
        t = m.twist.covariance
        check(t[14] == t[21] == t[28] == 1e6 and t[0] > 0 and t[35] > 0, f"{where}: twist covariance")
        st = ns(m.header.stamp)
        check(last is None or st > last, f"{where}: stamp not increasing")
        last = st
    stamps = {ns(m.header.stamp): m for m in odom}
    matched = 0
    for x in tf:
        check(len(x.transforms) == 1, "/tf: one transform")
        tr = x.transforms[0]
        check(tr.header.frame_id == "odom" and tr.child_frame_id == "base_link", "/tf frames")
        m = stamps.get(ns(tr.header.stamp))
        if m is not None:
            matched += 1
            check((tr.transform.translation.x, tr.transform.translation.y) == (m.pose.pose.position.x, m.pose.pose.position.y),
                  "/tf translation != /odom position")
    check(matched >= o.count, f"only {matched} /tf messages match an /odom stamp")
    check(diags and all(s.name == "odometry unit" for d in diags for s in d.status), "/diagnostics")
    print(f"dds_subscriber: ok: {len(odom)} /odom, {len(tf)} /tf ({matched} matched), {len(diags)} /diagnostics")


if __name__ == "__main__":
    main()
