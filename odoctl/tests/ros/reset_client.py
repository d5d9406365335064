#!/usr/bin/env python3
"""Independent ROS 2 service client for the bridge's `reset_pose` (docs/ROS.md): Eclipse
Cyclone DDS (the `cyclonedds` package, not our code) with `std_srvs/srv/Trigger` written here
as rmw_cyclonedds puts it on DDS: topics `rq/<ns>/reset_poseRequest` and
`rr/<ns>/reset_poseReply`, types `std_srvs::srv::dds_::Trigger_Request_` / `_Response_`, each
sample prefixed by the request header (client GUID as uint64, sequence number as int64).

Waits until both topics are matched with the bridge (at most --timeout seconds), sends one
request and waits for the reply with the same header; prints
`reset_client: ok: success=... message=...` or fails.
"""
import argparse
import os
import random
import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import int64, uint8, uint64
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class TriggerRequest(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Request_"):
    client_guid: uint64
    sequence: int64
    structure_needs_at_least_one_member: uint8


@dataclass
class TriggerResponse(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Response_"):
    client_guid: uint64
    sequence: int64
    success: bool
    message: str


def fail(msg):
    print("reset_client: FAIL: " + msg, file=sys.stderr, flush=True)
    sys.exit(1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ns", default="")
    ap.add_argument("--timeout", type=float, default=15)
    o = ap.parse_args()
    rel = (o.ns.strip("/") + "/") if o.ns.strip("/") else ""

    dp = DomainParticipant(int(os.environ.get("ROS_DOMAIN_ID", "0")))
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(10))
    w = DataWriter(dp, Topic(dp, f"rq/{rel}reset_poseRequest", TriggerRequest), qos=qos)
    r = DataReader(dp, Topic(dp, f"rr/{rel}reset_poseReply", TriggerResponse), qos=qos)
    end = time.time() + o.timeout
    while not (w.get_matched_subscriptions() and r.get_matched_publications()):
        if time.time() > end:
            fail(f"no service rq/{rel}reset_poseRequest matched within {o.timeout} s")
        time.sleep(0.05)
    guid, seq = random.getrandbits(63), 1
    t0 = time.time()
    w.write(TriggerRequest(guid, seq, 0))
    while time.time() < end:
        for s in r.take(10):
            if (s.client_guid, s.sequence) == (guid, seq):
                print(f"reset_client: ok: success={s.success} message={s.message!r} "
                      f"after {time.time() - t0:.3f} s", flush=True)
                return
        time.sleep(0.01)
    fail("no reply")


if __name__ == "__main__":
    main()
